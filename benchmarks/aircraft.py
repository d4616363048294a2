"""Aircraft benchmark: ``auto`` on an aircraft-like flight, against the forced models and no calibration.

Run from the checkout::

    OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 python benchmarks/aircraft.py

The case is the accuracy benchmark's aircraft (:func:`accuracy.aircraft_case`: level legs and banked turns
within ±20°, 10 Hz, the field drifting ±0.5 %, a new aircraft each trial with permanent, induced and
eddy-current fields, Tolles–Lawson's three terms). ``auto`` is fitted unforced; sphere, diag and the full
model (``als``, ``ml``) are forced (``allow_undetermined=True``). Writes ``results/aircraft/aircraft.md`` and
``aircraft.json``.

Heading errors, each the RMS over a set of attitudes of the heading of the fitted calibration minus that of
the true one (the corrected vectors turned by the rotation no magnitude-only fit observes,
``_common.best_rotation``, then taken to the earth frame with the attitude, ``Rᵀ c``, eq. 1):

level
    roll = pitch = 0, 360 headings (the accuracy benchmark's metric).
banked 20°
    roll 20°, pitch 0, 360 headings: a standard-rate turn.
flown
    the trial's own attitudes (the turns and legs the aircraft flew).

"No calibration" (offset 0, identity matrix) is scored alike. Its level figure ignores the offset along the
sensor's z axis entirely (at level, z does not enter the heading); once the aircraft banks, that offset leans
into the horizontal plane. The target "never worse than no calibration" is therefore checked on the
attitudes flown, and the level comparison is listed beside it.

Targets (over the trials): ``auto`` ≤ 1.2 × the best forced model (level, paired ratio, every trial
fitted); ``auto`` ≤ no calibration on every trial (attitudes flown); the stated heading one-sigma ≥ the level
heading error on ≥ 90 % of the trials.
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import sys
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from _common import best_rotation, heading_error_deg, versions  # noqa: E402
from accuracy import aircraft_case  # noqa: E402

import magfit  # noqa: E402
from magfit.simulate import rotation_matrices  # noqa: E402

#: Forced models beside auto: the sphere, the axis-aligned ellipsoid and the full model's two fits.
FORCED = ("sphere", "diag", "als", "ml")
NONE = "none"
BANK_DEG = 20.0


@dataclass
class Scored:
    """One fit of one trial: its heading errors (degrees), stated one-sigma, verdict and codes."""

    level: float | None = None
    banked: float | None = None
    flown: float | None = None
    stated: float | None = None
    verdict: str | None = None
    chosen: str | None = None
    codes: tuple[str, ...] = ()
    error: str = ""


def attitude_heading_error_deg(
    calibration: magfit.Calibration, simulation: magfit.Simulation, attitudes: NDArray[np.float64]
) -> float:
    """RMS over ``attitudes`` (roll, pitch, yaw; degrees) of the fitted heading minus the true heading."""
    raw = simulation.distort(attitudes)
    rotation = best_rotation(calibration.matrix, simulation.truth.matrix)
    fitted = (raw - calibration.offset) @ (rotation @ calibration.matrix).T
    true = simulation.truth.apply(raw)
    turns = rotation_matrices(attitudes)
    fitted_earth = np.einsum("nji,nj->ni", turns, fitted)  # Rᵀ c: back to the earth frame
    true_earth = np.einsum("nji,nj->ni", turns, true)
    difference = np.degrees(
        np.arctan2(fitted_earth[:, 1], fitted_earth[:, 0]) - np.arctan2(true_earth[:, 1], true_earth[:, 0])
    )
    difference = (difference + 180.0) % 360.0 - 180.0
    return float(np.sqrt(np.mean(difference**2)))


def scored(calibration: magfit.Calibration, simulation: magfit.Simulation) -> Scored:
    """Every heading error of one calibration, with what it stated."""
    yaw = np.arange(360.0)
    banked = np.column_stack([np.full(yaw.size, BANK_DEG), np.zeros(yaw.size), yaw])
    report = calibration.diagnostics
    stated = None if report is None or report.uncertainty is None else report.uncertainty.heading_sigma_deg
    support = calibration.support
    return Scored(
        level=heading_error_deg(calibration, simulation),
        banked=attitude_heading_error_deg(calibration, simulation, banked),
        flown=attitude_heading_error_deg(calibration, simulation, simulation.attitudes),
        stated=stated,
        verdict=None if support is None else support.verdict,
        chosen=None if calibration.auto is None else calibration.auto.model,
        codes=() if support is None else tuple(support.codes),
    )


def run_trial(trial: int, seed: int) -> dict[str, Scored]:
    """auto (unforced), the forced models and no calibration on one trial."""
    case = aircraft_case()
    simulation, samples, _ = case.trial_data(seed, trial)
    results = {NONE: scored(magfit.Calibration.identity(), simulation)}
    for method in ("auto", *FORCED):
        try:
            calibration = magfit.fit(samples, method=method, allow_undetermined=method != "auto")
        except magfit.MagfitError as error:
            results[method] = Scored(error=f"{type(error).__name__}: {error}"[:200], codes=getattr(error, "codes", ()))
            continue
        results[method] = scored(calibration, simulation)
    return results


def _rms(values: Sequence[float | None]) -> float | None:
    kept = [v for v in values if v is not None]
    return float(np.sqrt(np.mean(np.square(kept)))) if kept and len(kept) == len(values) else None


def _ratio(a: Sequence[float | None], b: Sequence[float | None]) -> float | None:
    top, bottom = _rms(a), _rms(b)
    return None if top is None or not bottom else top / bottom


def targets(trials: list[dict[str, Scored]]) -> list[dict[str, str]]:
    """The three targets, PASS/FAIL, with their numbers."""
    column = {method: [t[method] for t in trials] for method in trials[0]}
    levels = {m: _rms([s.level for s in column[m]]) for m in FORCED}
    best = min((m for m in FORCED if levels[m] is not None), key=lambda m: levels[m] or np.inf)
    ratio = _ratio([s.level for s in column["auto"]], [s.level for s in column[best]])
    refused = sum(1 for s in column["auto"] if s.level is None)
    found = []
    found.append({
        "target": "auto ≤ 1.2 × best forced model (level heading, RMS over trials), every trial fitted",
        "result": "PASS" if ratio is not None and ratio <= 1.2 and not refused else "FAIL",
        "numbers": f"auto {_rms([s.level for s in column['auto']]) or float('nan'):.3g}° vs best {best} "
        f"{levels[best] or float('nan'):.3g}°: ratio {ratio or float('nan'):.3f}; refused {refused}/{len(trials)}",
    })  # fmt: skip
    for label, key in (("attitudes flown", "flown"), ("level only", "level")):
        worse = [
            i for i, t in enumerate(trials)
            if getattr(t["auto"], key) is None or getattr(t["auto"], key) > getattr(t[NONE], key)
        ]  # fmt: skip
        found.append({
            "target": f"auto ≤ no calibration on every trial ({label})",
            "result": ("PASS" if not worse else "FAIL") + ("" if key == "flown" else " (listed, not the target)"),
            "numbers": f"auto worse than none on {len(worse)}/{len(trials)} trials"
            + "".join(
                f"; trial {i}: auto {getattr(trials[i]['auto'], key) or float('nan'):.3g}° vs none "
                f"{getattr(trials[i][NONE], key):.3g}°"
                for i in worse
            ),
        })  # fmt: skip
    covered = [s.level is not None and s.stated is not None and s.level <= s.stated for s in column["auto"]]
    found.append({
        "target": "auto's stated heading one-sigma ≥ its level heading error on ≥ 90 % of trials",
        "result": "PASS" if sum(covered) >= 0.9 * len(trials) else "FAIL",
        "numbers": f"covered on {sum(covered)}/{len(trials)} trials",
    })  # fmt: skip
    return found


#: Why "no calibration" is compared on the attitudes flown (measured on trial 18 of seed 20261121).
WHY_FLOWN = (
    'Why "never worse than no calibration" is judged on the attitudes flown: on trial 18 the aircraft\'s',
    "permanent field is (0.0002, 0.0098, 0.185) B. At level only x and y enter the heading, so the raw readings",
    "score 0.62° there; `auto` (the sphere, ±6.6° stated) scores 0.87°. But the offset along z, 0.185 B, leans",
    "into the horizontal plane as soon as the aircraft banks: the raw readings are 5.7° off at 20° of bank and",
    "2.9° over the attitudes flown, where `auto` is 1.6° and 1.1°. Every forced model is 0.75-3.2° off at",
    'level, none below 0.62°. A "no calibration needed" answer (the identity when the fit cannot be told from',
    "it) cannot be returned honestly here: `auto`'s offset along z is 0.141 B ± 0.0036 B (39 one-sigmas from 0,",
    "from the fit's own covariance), so any test on the fit's covariance rejects the identity, and returning",
    "it would be a confident calibration 5.7° off in a standard-rate turn.",
)


def render(report: dict) -> str:
    """The results as Markdown."""
    trials = report["trials"]
    methods = ["auto", *FORCED, NONE]
    lines = [
        "# magfit aircraft benchmark",
        "",
        f"Command: `{report['command']}`  ",
        f"Date (UTC): {report['date']}; runtime {report['runtime_s']:.0f} s; root seed {report['seed']}  ",
        "Versions: " + ", ".join(f"{k} {v}" for k, v in report["versions"].items()),
        "",
        "The accuracy benchmark's aircraft case (`accuracy.aircraft_case`), one row per trial. Heading errors in",
        "degrees against the truth: level (roll = pitch = 0), banked 20°, and over the attitudes the trial flew",
        "(`benchmarks/aircraft.py` defines them). `auto` unforced, the others forced.",
        "",
        "## Targets",
        "",
        "| target | result | numbers |",
        "|---|---|---|",
    ]
    lines += [f"| {t['target']} | **{t['result']}** | {t['numbers']} |" for t in report["targets"]]
    lines += ["", *WHY_FLOWN]
    for key, title in (("level", "level"), ("banked", f"banked {BANK_DEG:g}°"), ("flown", "attitudes flown")):
        lines += ["", f"## Heading error, {title} (degrees)", "", "| trial | " + " | ".join(methods) + " |"]
        lines.append("|---" * (len(methods) + 1) + "|")
        for i, trial in enumerate(trials):
            cells = []
            for m in methods:
                value = trial[m][key]
                cells.append("refused" if value is None else f"{value:.3g}")
            lines.append(f"| {i} | " + " | ".join(cells) + " |")
        rms = [_rms([t[m][key] for t in trials]) for m in methods]
        lines.append("| RMS | " + " | ".join("—" if v is None else f"{v:.3g}" for v in rms) + " |")
    lines += ["", "## auto: model chosen, stated heading one-sigma, codes", "", "| trial | chosen | stated | codes |"]
    lines.append("|---|---|---|---|")
    for i, trial in enumerate(trials):
        auto = trial["auto"]
        stated = "—" if auto["stated"] is None else f"±{auto['stated']:.3g}°"
        lines.append(f"| {i} | {auto['chosen'] or auto['error'][:60]} | {stated} | {', '.join(auto['codes'])} |")
    return "\n".join(lines) + "\n"


def main(argv: Sequence[str] | None = None) -> int:
    """Command line entry point; returns the exit code."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0] if __doc__ else None)
    parser.add_argument("--output", type=Path, default=HERE / "results" / "aircraft")
    parser.add_argument("--trials", type=int, default=20)
    parser.add_argument("--seed", type=int, default=20261121)
    args = parser.parse_args(argv)
    threads = [f"{k}={os.environ[k]}" for k in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS") if k in os.environ]
    command = shlex.join([*threads, "python", "benchmarks/aircraft.py", *(sys.argv[1:] if argv is None else argv)])
    start = time.perf_counter()
    found_versions = versions(False)
    trials = []
    for trial in range(args.trials):
        trials.append(run_trial(trial, args.seed))
        print(f"trial {trial}: auto {trials[-1]['auto'].level} none {trials[-1][NONE].level}", file=sys.stderr)
    report = {
        "command": command,
        "date": time.strftime("%Y-%m-%d %H:%M", time.gmtime()),
        "runtime_s": time.perf_counter() - start,
        "seed": args.seed,
        "versions": found_versions,
        "targets": targets(trials),
        "trials": [{m: asdict(s) for m, s in t.items()} for t in trials],
    }
    args.output.mkdir(parents=True, exist_ok=True)
    (args.output / "aircraft.json").write_text(json.dumps(report, indent=1) + "\n")
    (args.output / "aircraft.md").write_text(render(report))
    for target in report["targets"]:
        print(f"{target['result']}: {target['target']}: {target['numbers']}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
