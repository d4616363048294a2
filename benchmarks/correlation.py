"""Does the stated one-sigma of a long recording cover its error when the noise is correlated in time?

    .venv/bin/python benchmarks/correlation.py [--n 1000000] [--seeds 12]

The uncertainty's correlation in time is read on a bounded part of a long recording
(``magfit.diagnostics.uncertainty.correlation_rows``: 20 windows of contiguous rows). This benchmark
measures what that costs in honesty: samples of the paper's MPU-9250 beside a steel plate, turned smoothly
through every attitude (a tumble in time order), with Gaussian noise of the sensor's own size made
correlated in time by a first-order filter (AR(1), correlation time L samples), fitted with
``magfit.fit(samples, "ellipsoid")`` for several seeds. For each L: the RMS over seeds and axes of the
offset error in stated one-sigmas (1 when the one-sigma is honest; above 1 it is too small), the largest,
and the stated one-sigma against the true spread of the offsets over the seeds. Results:
``benchmarks/results/speed-correlation.md``.
"""

from __future__ import annotations

import argparse
import datetime as _dt
import math
import os
import time
from pathlib import Path

import numpy as np
from scipy.signal import lfilter

import magfit

ROOT = Path(__file__).resolve().parents[1]
SCENARIO = ("mpu9250", "steel")


def tumble_in_time(n: int) -> np.ndarray:
    """(roll, pitch, yaw) in degrees: smooth, incommensurate periods, every attitude visited many times."""
    t = np.arange(n, dtype=np.float64)
    roll = 180.0 * np.sin(2 * math.pi * t / 7919.0)
    pitch = 89.0 * np.sin(2 * math.pi * t / 3001.0 + 1.0)
    yaw = (360.0 * t / 997.0) % 360.0
    return np.column_stack([roll, pitch, yaw])


def samples(n: int, correlation: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Raw counts of the scenario with AR(1) noise of correlation time ``correlation`` samples, and the true offset."""
    scenario = magfit.scenario(*SCENARIO)
    clean = scenario.simulate(n, seed=seed, orientations=tumble_in_time(n), noise=0.0)
    rng = np.random.default_rng(1000 + seed)
    white = rng.normal(0.0, scenario.noise, size=(n, 3))
    a = math.exp(-1.0 / correlation) if correlation > 1 else 0.0
    noise = lfilter([math.sqrt(1.0 - a * a)], [1.0, -a], white, axis=0) if a else white
    return np.round(clean.samples + noise), np.asarray(clean.truth.offset)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=1_000_000)
    parser.add_argument("--seeds", type=int, default=12)
    parser.add_argument("--correlations", default="1,30,300")
    parser.add_argument("--output", default=str(ROOT / "benchmarks" / "results" / "speed-correlation.md"))
    args = parser.parse_args()
    started = time.time()
    load = os.getloadavg()
    lines = []
    for correlation in (float(c) for c in args.correlations.split(",")):
        errors, sigmas, verdicts = [], [], []
        for seed in range(args.seeds):
            x, offset = samples(args.n, correlation, seed)
            calibration = magfit.fit(x, "ellipsoid", allow_undetermined=True)
            errors.append(np.asarray(calibration.offset) - offset)
            sigmas.append(np.asarray(calibration.diagnostics.uncertainty.offset_sigma))
            verdicts.append(calibration.support.verdict if calibration.support is not None else "none")
        error, sigma = np.array(errors), np.array(sigmas)
        z = error / sigma
        spread = error.std(axis=0, ddof=1)
        lines.append(
            f"| {correlation:g} | {math.sqrt(float(np.mean(z**2))):.2f} | {float(np.max(np.abs(z))):.2f} | "
            f"{float(np.mean(sigma)):.3g} | {float(np.mean(spread)):.3g} | "
            f"{', '.join(f'{v} {verdicts.count(v)}' for v in sorted(set(verdicts)))} |"
        )
        print(lines[-1], flush=True)
    end_load = os.getloadavg()
    text = [
        "# The one-sigma of long recordings with noise correlated in time",
        "",
        f"Command: `python benchmarks/correlation.py --n {args.n} --seeds {args.seeds} --correlations "
        f"{args.correlations}`  ",
        f"Date: {_dt.datetime.now(_dt.timezone.utc):%Y-%m-%d %H:%M} UTC, "
        f"runtime {(time.time() - started) / 60:.1f} min  ",
        f"Load average (1, 5, 15 min) at the start: {', '.join(f'{v:.1f}' for v in load)}; at the end: "
        f"{', '.join(f'{v:.1f}' for v in end_load)} (2 cores shared)",
        "",
        f"{args.n:,} samples of `magfit.scenario{SCENARIO}` turned smoothly through every attitude, AR(1) noise "
        "of the sensor's size (6.4 counts) with correlation time L samples, rounded to counts; "
        f"`magfit.fit(samples, 'ellipsoid')`, {args.seeds} seeds per row. z: offset error over its stated one-sigma "
        "(per axis); 1 is honest.",
        "",
        "| L (samples) | RMS z | largest abs z | stated offset one-sigma (counts) | true spread over seeds (counts) "
        "| verdicts |",
        "|---|---|---|---|---|---|",
        *lines,
        "",
    ]
    Path(args.output).write_text("\n".join(text), encoding="utf-8")


if __name__ == "__main__":
    main()
