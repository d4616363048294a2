"""How much slower is ``method="gyro"`` than ``method="ellipsoid"`` on the same samples? Ratios in one run.

    .venv/bin/python benchmarks/gyro_speed.py                 # 1e4 and 1e5 samples, 3 repeats
    .venv/bin/python benchmarks/gyro_speed.py --sizes 10000 --repeat 1

The samples are ``simulate_vehicle``'s tumble (every attitude, smoothly: a hand-held calibration, on which
``ellipsoid`` is supported too) at 50 Hz, the magnetometer turned 180° about x, with a soft and hard iron, the
magnetometer's and the gyro's noise and a gyro bias. Both methods run with their default diagnostics on the
same samples, taking turns; each time is the least of ``--repeat`` runs (the least disturbed by other
processes on the machine), and the ratio is gyro's over ellipsoid's. Target: gyro within 10x ellipsoid on
1e5 samples (wall-clock). The processor time of the same runs (``time.process_time``: every thread of this
process) follows in three more columns: on a machine shared with other work it moves less with the load than
the wall-clock does (ellipsoid's BLAS threads count in it). The table goes to stdout and, with ``--out``, to a
Markdown file (``benchmarks/results/gyro_speed.md``; ``--title`` names the run, e.g. the commit measured).
"""

from __future__ import annotations

import argparse
import os
import platform
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

import magfit
from magfit.vehicle import simulate_vehicle

SOFT_IRON = np.array([[1.15, 0.06, -0.04], [0.06, 0.9, 0.05], [-0.04, 0.05, 1.0]])
HARD_IRON = np.array([0.3, -0.2, 0.25])
GYRO_BIAS = np.array([0.01, -0.02, 0.015])
ROLL_180 = np.diag([1.0, -1.0, -1.0])
TARGET = 10.0


def _timed(run: Callable[[], object]) -> tuple[float, float]:
    """Wall-clock and processor seconds of one run."""
    start, cpu = time.perf_counter(), time.process_time()
    run()
    return time.perf_counter() - start, time.process_time() - cpu


def measure(n: int, repeat: int) -> dict[str, float | str]:
    """Least times (s) of gyro and ellipsoid on ``n`` samples of one simulated tumble, wall-clock and processor
    (``cpu_gyro``, ``cpu_ellipsoid``), and gyro's verdict."""
    sim = simulate_vehicle(
        n, "tumble", soft_iron=SOFT_IRON, hard_iron=HARD_IRON, mounting=ROLL_180, noise=0.005, gyro_noise=0.003,
        gyro_bias=GYRO_BIAS, seed=7,
    )  # fmt: skip
    gyro = magfit.fit(sim.samples, method="gyro", gyro=sim.gyro, time_s=sim.time_s)  # warm-up, and its verdict
    runs = {
        "ellipsoid": lambda: magfit.fit(sim.samples, method="ellipsoid"),
        "gyro": lambda: magfit.fit(sim.samples, method="gyro", gyro=sim.gyro, time_s=sim.time_s),
    }
    times = {key: float("inf") for key in ("gyro", "ellipsoid", "cpu_gyro", "cpu_ellipsoid")}
    for _ in range(repeat):  # taking turns: a burst of load slows both alike
        for name, run in runs.items():
            wall, cpu = _timed(run)
            times[name] = min(times[name], wall)
            times[f"cpu_{name}"] = min(times[f"cpu_{name}"], cpu)
    verdict = gyro.support.verdict if gyro.support is not None else "none"
    return {**times, "ratio": times["gyro"] / times["ellipsoid"],
            "cpu_ratio": times["cpu_gyro"] / times["cpu_ellipsoid"], "verdict": verdict}  # fmt: skip


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", default="10000,100000", help="comma-separated sample counts")
    parser.add_argument("--repeat", type=int, default=3, help="runs per method and size (the least is kept)")
    parser.add_argument("--out", type=Path, help="also write the Markdown table here")
    parser.add_argument("--title", default="gyro against ellipsoid: time on the same samples (one run)")
    args = parser.parse_args(argv)
    sizes = [int(float(size)) for size in args.sizes.split(",")]
    rows = []
    for n in sizes:
        result = measure(n, args.repeat)
        rows.append(
            f"| {n:,} | {result['gyro']:.3f} | {result['ellipsoid']:.4f} | {result['ratio']:.1f} | "
            f"{'—' if n < 100_000 else 'yes' if float(result['ratio']) <= TARGET else 'no'} | {result['verdict']} | "
            f"{result['cpu_gyro']:.3f} | {result['cpu_ellipsoid']:.4f} | {result['cpu_ratio']:.1f} |"
        )
        print(rows[-1], flush=True)
    loads = os.getloadavg() if hasattr(os, "getloadavg") else (float("nan"),) * 3
    text = "\n".join([
        f"## {args.title}",
        "",
        f"`benchmarks/gyro_speed.py --repeat {args.repeat}`; simulate_vehicle's tumble at 50 Hz (seed 7); the least of "
        f"{args.repeat} runs each, taking turns; default diagnostics. magfit {magfit.__version__}, Python "
        f"{platform.python_version()}, NumPy {np.__version__}, {os.cpu_count()} cores, load average "
        f"{loads[0]:.2f} (1 min), {loads[1]:.2f} (5 min) at the end.",
        "",
        f"| samples | gyro (s) | ellipsoid (s) | gyro / ellipsoid | within {TARGET:.0f}x (1e5) | gyro's verdict "
        "| gyro CPU (s) | ellipsoid CPU (s) | CPU ratio |",
        "|---:|---:|---:|---:|:---:|:---|---:|---:|---:|",
        *rows,
        "",
    ])  # fmt: skip
    print(text)
    if args.out is not None:
        args.out.write_text(text, encoding="utf-8")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
