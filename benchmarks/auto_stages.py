"""Where ``magfit.fit(samples, "auto")`` spends its time: wall time per stage, beside ``ellipsoid`` on the same samples.

    PYTHONPATH=src .venv/bin/python benchmarks/auto_stages.py --n 1000000 --repeat 7

The samples are those of ``benchmarks/speed.py`` (the paper's MPU-9250 beside a steel plate, one clean tumble).
Each stage's function is wrapped in a timer (the wrapping costs microseconds a call); the run whose total
``auto`` time is the least counts (the least disturbed on a shared machine), and ``ellipsoid`` takes turns
with it. Stages nest: the diagnostics' parts (indented) are inside the candidates' reports and the final
verdict, and the final verdict's refits (halves, block jackknife, held-out folds) are the chosen model's
first-order fits.
"""

from __future__ import annotations

import argparse
import collections
import functools
import importlib
import os
import sys
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))

from speed import make_samples

import magfit

TIMES: collections.defaultdict[str, float] = collections.defaultdict(float)


def _wrap(module: Any, name: str, label: str) -> None:
    function = getattr(module, name)

    @functools.wraps(function)
    def timed(*args: Any, **kwargs: Any) -> Any:
        start = time.perf_counter()
        try:
            return function(*args, **kwargs)
        finally:
            TIMES[label] += time.perf_counter() - start

    setattr(module, name, timed)


def instrument() -> None:
    """Wrap the stages (module attributes, so that the callers' global look-ups find the timers)."""
    fit = importlib.import_module("magfit.fit")
    auto = importlib.import_module("magfit.methods.auto")
    diagnose = importlib.import_module("magfit.diagnostics.diagnose")
    _wrap(fit, "prepare", "statistics and clipped rows (one pass, shared with ellipsoid)")
    _wrap(auto, "_screen", "outlier screen")
    _wrap(auto, "_fit_candidate", "candidate fits (sphere, diag, full)")
    _wrap(auto, "_optimal_rss", "candidates' first-order optima")
    _wrap(auto, "_candidate_report", "candidates' verdicts")
    _wrap(auto, "_blocked_scores", "held-out blocks (model choice)")
    _wrap(auto, "refine_chosen", "maximum-likelihood refit of the chosen model")
    _wrap(fit, "_judged", "final verdict and diagnostics")
    for name in ("weighted_even_subsample", "analyse", "compare_with_drift", "_goodness", "_halves",
                 "_with_block_jackknife"):  # fmt: skip
        _wrap(diagnose, name, f"  diagnostics: {name.lstrip('_')}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--n", type=float, default=1e6, help="samples (default 1e6)")
    parser.add_argument("--repeat", type=int, default=7, help="runs; the least total counts (default 7)")
    args = parser.parse_args(argv)
    samples = make_samples(int(args.n), seed=20)
    instrument()
    magfit.fit(samples, "auto")  # imports and caches outside the timing
    magfit.fit(samples, "ellipsoid")
    ellipsoid: list[float] = []
    best: tuple[float, dict[str, float]] | None = None
    for _ in range(args.repeat):
        start = time.perf_counter()
        magfit.fit(samples, "ellipsoid")
        ellipsoid.append(time.perf_counter() - start)
        TIMES.clear()
        start = time.perf_counter()
        calibration = magfit.fit(samples, "auto")
        total = time.perf_counter() - start
        if best is None or total < best[0]:
            best = (total, dict(TIMES))
    assert best is not None
    verdict = calibration.support.verdict if calibration.support is not None else "none"
    chosen = calibration.auto.chosen if calibration.auto is not None else "?"
    print(f"{int(args.n):,} samples; load average {', '.join(f'{v:.1f}' for v in os.getloadavg())}")
    refit = importlib.import_module("magfit.methods.auto").REFIT_ROWS
    step = -(-samples.shape[0] // refit)
    print(f"the ml refit and the final diagnostics read every {step} sample(s): {len(samples[::step]):,} rows "
          f"(REFIT_ROWS {refit:,})")  # fmt: skip
    print(f"ellipsoid (least of {args.repeat}): {1000 * min(ellipsoid):.1f} ms")
    print(f"auto (least of {args.repeat}): {1000 * best[0]:.1f} ms = {best[0] / min(ellipsoid):.2f} x ellipsoid "
          f"({verdict}, chose {chosen})")  # fmt: skip
    for label, seconds in best[1].items():
        print(f"  {label:62s} {1000 * seconds:7.1f} ms")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
