"""Does ``robust``'s stated one-sigma cover its real error? Error over stated one-sigma against the simulated truth.

Run (from the checkout, in magfit's development environment)::

    python benchmarks/robust_coverage.py                  # 90 trials, a few minutes
    python benchmarks/robust_coverage.py --no-write

Trials: the paper's six scenarios (``magfit.scenario``: the MPU-9250 and the Ellipse2-A; no disturbance, a steel
plate, a smartphone), each as a full tumble, with roll and pitch within ±30° (a vehicle) and as level flight
(``orientations="flight"``), at 30, 100, 1 000 and 10 000 samples; and each scenario's tumble and tilt at 1 000
samples with 2 % spikes (30 % of the field, random directions), what ``robust`` is for. Each is fitted as
``magfit.fit(samples, "robust")`` (the verdict with the full diagnostics) and scored as
``benchmarks/auto_coverage.py`` scores auto: the level-heading error over the stated heading one-sigma, each
axis's offset error over its stated one-sigma; the shares above 1, 2 and 3 one-sigmas.

Writes ``benchmarks/results/robust_coverage.md`` and ``.json`` (``--output``); ``--before`` adds an earlier run's
columns.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

import magfit

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import heading_error_deg

RESULTS = Path(__file__).resolve().parent / "results"
SCENARIOS = tuple((sensor, disturbance) for sensor in magfit.SENSORS for disturbance in magfit.DISTURBANCES)
SIZES = (30, 100, 1_000, 10_000)
ORIENTATIONS = ("tumble", "tilt", "flight")
SPIKES = 0.02


def simulate(sensor: str, disturbance: str, orientation: str, n: int, seed: int, spikes: bool) -> Any:
    scenario = magfit.scenario(sensor, disturbance)
    if orientation == "tumble":
        sim = scenario.simulate(n, seed=seed)
    elif orientation == "tilt":
        sim = scenario.simulate(n, seed=seed, orientations="restricted", max_tilt_deg=30.0)
    else:
        sim = scenario.simulate(n, seed=seed, orientations="flight")
    samples = np.array(sim.samples)
    if spikes:
        rng = np.random.default_rng(seed + 1)
        chosen = rng.choice(n, max(1, round(SPIKES * n)), replace=False)
        directions = rng.normal(size=(chosen.size, 3))
        directions /= np.linalg.norm(directions, axis=1)[:, None]
        samples[chosen] += 0.3 * sim.truth.field_strength * directions
    return sim, samples


def score(sensor: str, disturbance: str, orientation: str, n: int, seed: int, spikes: bool) -> dict[str, Any]:
    sim, samples = simulate(sensor, disturbance, orientation, n, seed, spikes)
    case = f"{sensor}/{disturbance} {orientation}" + (" +spikes" if spikes else "")
    row: dict[str, Any] = {"case": case, "n": n, "seed": seed}
    try:
        calibration = magfit.fit(samples, "robust")
    except magfit.CalibrationError as error:
        return {**row, "verdict": "refused", "codes": list(error.codes)}
    support = calibration.support
    uncertainty = calibration.diagnostics.uncertainty
    row.update(
        verdict=support.verdict, codes=list(support.codes), heading_error_deg=heading_error_deg(calibration, sim)
    )
    row["heading_sigma_deg"] = uncertainty.heading_sigma_deg if uncertainty is not None else None
    if uncertainty is not None and uncertainty.offset_sigma is not None:
        z = (calibration.offset - sim.truth.offset) / np.asarray(uncertainty.offset_sigma)
        row["offset_z"] = [float(v) for v in z]
    return row


def shares(values: list[float]) -> str:
    if not values:
        return "—"
    a = np.abs(np.asarray(values))
    return (
        f"{100 * np.mean(a > 1):.0f} / {100 * np.mean(a > 2):.1f} / {100 * np.mean(a > 3):.1f} % "
        f"(worst {a.max():.2f}, n {a.size})"
    )


def groups(rows: list[dict[str, Any]]) -> dict[str, list[dict[str, Any]]]:
    accepted = [r for r in rows if r["verdict"] != "refused"]
    out = {"all accepted": accepted}
    for n in SIZES:
        out[f"n = {n:,}"] = [r for r in accepted if r["n"] == n and "spikes" not in r["case"]]
    for orientation in ORIENTATIONS:
        out[orientation] = [r for r in accepted if f" {orientation}" in r["case"] and "spikes" not in r["case"]]
    out["with spikes"] = [r for r in accepted if "spikes" in r["case"]]
    return out


def table(rows: list[dict[str, Any]]) -> list[str]:
    lines = ["| group | accepted | heading | offset |", "|---|---|---|---|"]
    for label, selected in groups(rows).items():
        heading = [r["heading_error_deg"] / r["heading_sigma_deg"] for r in selected if r.get("heading_sigma_deg")]
        offset = [z for r in selected for z in r.get("offset_z", [])]
        lines.append(f"| {label} | {len(selected)} | {shares(heading)} | {shares(offset)} |")
    return lines


def report(results: dict[str, Any], before: dict[str, Any] | None) -> str:
    rows = results["rows"]
    verdicts: dict[str, int] = {}
    for r in rows:
        verdicts[r["verdict"]] = verdicts.get(r["verdict"], 0) + 1
    lines = [
        "# robust: real error over stated one-sigma, against the simulated truth",
        "",
        f"`{results['command']}` — {results['date']}, {results['seconds']:.0f} s, magfit {results['label']}",
        "",
        f"{len(rows)} trials; verdicts: " + ", ".join(f"{k} {v}" for k, v in sorted(verdicts.items())) + ". Cells: "
        "the share of accepted fits (heading) or axes (offset) whose true error is above 1 / 2 / 3 stated "
        "one-sigmas, the worst ratio, how many were scored (a Gaussian: 31.7 / 4.6 / 0.3 %).",
        "",
        *table(rows),
    ]
    if before is not None:
        old = before["rows"]
        old_verdicts: dict[str, int] = {}
        for r in old:
            old_verdicts[r["verdict"]] = old_verdicts.get(r["verdict"], 0) + 1
        lines += [
            "",
            f"## Before: {before['label']} ({before['date']})",
            "",
            "Verdicts: " + ", ".join(f"{k} {v}" for k, v in sorted(old_verdicts.items())) + ".",
            "",
            *table(old),
        ]
    worst = sorted(
        (r for r in rows if r.get("heading_sigma_deg")), key=lambda r: -r["heading_error_deg"] / r["heading_sigma_deg"]
    )[:8]
    lines += ["", "## The largest heading ratios", "", "| case | n | seed | verdict | error | stated | ratio |",
              "|---|---|---|---|---|---|---|"]  # fmt: skip
    for r in worst:
        e, s = r["heading_error_deg"], r["heading_sigma_deg"]
        lines.append(
            f"| {r['case']} | {r['n']:,} | {r['seed']} | {r['verdict']} | {e:.3g}° | ±{s:.3g}° | {e / s:.2f} |"
        )
    worst_offset = sorted((r for r in rows if r.get("offset_z")), key=lambda r: -max(abs(z) for z in r["offset_z"]))[:5]
    lines += [
        "",
        "## The largest offset ratios (worst axis)",
        "",
        "| case | n | seed | verdict | z |",
        "|---|---|---|---|---|",
    ]
    for r in worst_offset:
        z = ", ".join(f"{v:+.2f}" for v in r["offset_z"])
        lines.append(f"| {r['case']} | {r['n']:,} | {r['seed']} | {r['verdict']} | {z} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    parser.add_argument("--seed", type=int, default=7000)
    parser.add_argument("--output", type=Path, default=RESULTS / "robust_coverage.md")
    parser.add_argument("--before", type=Path, default=None, help="an earlier run's JSON, shown below")
    parser.add_argument("--label", default="(this checkout)", help="what version of magfit ran")
    parser.add_argument("--no-write", action="store_true")
    args = parser.parse_args(argv)
    started = time.perf_counter()
    rows = []
    seed = args.seed
    for sensor, disturbance in SCENARIOS:
        for orientation in ORIENTATIONS:
            for n in SIZES:
                seed += 1
                rows.append(score(sensor, disturbance, orientation, n, seed, False))
                print(rows[-1]["case"], n, rows[-1]["verdict"], flush=True)
        for orientation in ("tumble", "tilt"):
            seed += 1
            rows.append(score(sensor, disturbance, orientation, 1_000, seed, True))
            print(rows[-1]["case"], 1_000, rows[-1]["verdict"], flush=True)
    results = {
        "command": "python benchmarks/robust_coverage.py " + " ".join(argv if argv is not None else sys.argv[1:]),
        "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
        "label": args.label,
        "seconds": time.perf_counter() - started,
        "rows": rows,
    }
    before = json.loads(args.before.read_text(encoding="utf-8")) if args.before else None
    text = report(results, before)
    print(text)
    if not args.no_write:
        args.output.write_text(text, encoding="utf-8")
        args.output.with_suffix(".json").write_text(json.dumps(results, indent=1) + "\n", encoding="utf-8")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
