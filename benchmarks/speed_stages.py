"""Where the time of ``magfit.fit(samples, "ellipsoid")`` goes: wall time per stage, least of several fits.

    .venv/bin/python benchmarks/speed_stages.py                # 10 million samples, 5 fits
    .venv/bin/python benchmarks/speed_stages.py --n 1e6 --repeat 9

Each stage is a function of the fit wrapped with a timer (only its outermost call counts, so a refit inside
the diagnostics counts once, in its stage). The samples and the floor (one chunked NumPy pass over the
10-column design matrix) are those of ``benchmarks/speed.py``; the floor is timed before each fit, so the
two see the same load. Stages the code does not have (e.g. a second search for clipped rows) are left out.
"""

from __future__ import annotations

import argparse
import collections
import importlib
import os
import time
from collections.abc import Callable
from typing import Any

from speed import floor_scatter, make_samples

import magfit

#: (module, function, label): the stages, in the order the fit runs them.
STAGES = (
    ("magfit.fit", "prepare", "Statistics (the one pass: scatter, min/max, finite check; the clipped rows too)"),
    ("magfit.methods.core", "find_clipped", "clipped rows, searched by the fit's estimate in a pass of their own"),
    ("magfit.diagnostics.diagnose", "check_finite", "finite check, again in the diagnostics"),
    ("magfit.diagnostics.diagnose", "find_clipped", "clipped rows, searched again in the diagnostics"),
    ("magfit.diagnostics.diagnose", "weighted_even_subsample", "the diagnostics' even subsample"),
    ("magfit.diagnostics.diagnose", "analyse", "observability and uncertainty (the correlation's windows)"),
    ("magfit.diagnostics.diagnose", "_with_block_jackknife", "block jackknife"),
    ("magfit.diagnostics.diagnose", "_goodness", "held-out folds"),
    ("magfit.diagnostics.diagnose", "_halves", "halves"),
    ("magfit.diagnostics.diagnose", "compare_with_drift", "drift"),
    ("magfit.diagnostics.diagnose", "consistency", "consistency (maximum likelihood)"),
    ("magfit.diagnostics.diagnose", "compare_with_full", "compared with the full model"),
    ("magfit.diagnostics.diagnose", "coverage", "coverage"),
    ("magfit.diagnostics.diagnose", "flat_axis", "flat axis"),
)


def instrument(spent: dict[str, float]) -> list[str]:
    """Wrap each stage's function with a timer adding to ``spent``; the labels of the stages found."""
    depth = [0]
    found = []
    for module_name, name, label in STAGES:
        module = importlib.import_module(module_name)
        function = getattr(module, name, None)
        if function is None:
            continue

        def timed(*args: Any, _function: Callable[..., Any] = function, _label: str = label, **kwargs: Any) -> Any:
            if depth[0]:
                return _function(*args, **kwargs)
            depth[0] += 1
            start = time.perf_counter()
            try:
                return _function(*args, **kwargs)
            finally:
                spent[_label] += time.perf_counter() - start
                depth[0] -= 1

        setattr(module, name, timed)
        found.append(label)
    return found


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", default="1e7", help="samples (default 1e7)")
    parser.add_argument("--repeat", type=int, default=5, help="fits; each stage's least time is kept")
    args = parser.parse_args(argv)
    n = int(float(args.n))
    samples = make_samples(n)
    spent: dict[str, float] = collections.defaultdict(float)
    labels = instrument(spent)
    magfit.fit(samples[:5000], "ellipsoid")  # imports and caches outside the timing
    best: dict[str, float] = collections.defaultdict(lambda: float("inf"))
    floors = []
    for _ in range(args.repeat):
        start = time.perf_counter()
        floor_scatter(samples)
        floors.append(time.perf_counter() - start)
        spent.clear()
        start = time.perf_counter()
        magfit.fit(samples, "ellipsoid")
        total = time.perf_counter() - start
        for label in labels:
            best[label] = min(best[label], spent.get(label, 0.0))
        best["the rest (thinning, gathering, the method itself)"] = min(
            best["the rest (thinning, gathering, the method itself)"], total - sum(spent.values())
        )
        best["the fit"] = min(best["the fit"], total)
    load = ", ".join(f"{value:.1f}" for value in os.getloadavg())
    print(f"magfit.fit(samples, 'ellipsoid') on {n:,} samples, least of {args.repeat}; load average {load}")
    print(f"| stage | ms |\n|---|---:|\n| the floor (chunked design matrix, XᵀX) | {1e3 * min(floors):.0f} |")
    for label, seconds in best.items():
        print(f"| {label} | {1e3 * seconds:.0f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
