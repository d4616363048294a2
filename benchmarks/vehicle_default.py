"""The default fit (``magfit calibrate FILE`` without ``--method``) of vehicle recordings, against the truth.

Each trial is a simulated vehicle (:func:`magfit.vehicle.simulate_vehicle`, the recording of
tests/test_vehicle_default.py: 3000 samples, field 50 µT dipping 60°, random symmetric soft iron ±8 %, hard
iron about 0.5 B, mounting a few degrees off, attitude noise 0.5°, gyro bias and noise, 20 ms attitude lag),
written as a samples file with its attitude, reference, gyroscope, accelerometer and time columns, and
calibrated by :func:`magfit.calibrate_file` with no method (auto, then the vehicle methods when auto refuses:
:mod:`magfit.pipeline.vehicle`). Scored as tests/test_vehicle_default.py scores it: the RMS heading error over
the recording, the calibrated noise-free readings turned into the world by the TRUE attitude, against the
stated level-heading one-sigma. A ``weak`` or ``supported`` result whose error passes 3x its one-sigma is a
confident wrong result. Also timed: the default against ``--method auto`` on a plain 3-column file of the same
car (nothing to rescue with).

    PYTHONPATH=src python benchmarks/vehicle_default.py [seeds] > benchmarks/results/vehicle_default.md
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

import magfit
from test_vehicle_default import _heading_error, _recording, _save  # the tests' recording and score


def main(seeds: int = 5) -> None:
    print("# The default fit of vehicle recordings (benchmarks/vehicle_default.py)\n")
    print("| motion | seed | method returned | verdict | heading error ° | stated one-sigma ° | error / sigma |")
    print("|---|---|---|---|---|---|---|")
    wrong = 0
    with tempfile.TemporaryDirectory() as folder:
        for motion in ("car", "boat", "flight", "tumble", "yaw"):
            for seed in range(seeds):
                sim, columns = _recording(motion, seed)
                path = _save(Path(folder) / f"{motion}{seed}.csv", columns)
                try:
                    cal = magfit.calibrate_file(path, unit="uT").compasses[0].calibration
                except magfit.CalibrationError as error:
                    print(f"| {motion} | {seed} | refused ({', '.join(error.codes)}) | | | | |")
                    continue
                error_deg = _heading_error(cal, sim)
                uncertainty = cal.diagnostics.uncertainty if cal.diagnostics is not None else None
                sigma = uncertainty.heading_sigma_deg if uncertainty is not None else None
                ratio = error_deg / sigma if sigma else float("inf")
                wrong += ratio > 3
                verdict = cal.support.verdict if cal.support is not None else "?"
                print(f"| {motion} | {seed} | {cal.method} | {verdict} | {error_deg:.2f} | {sigma:.2f} | {ratio:.2f} |")
        print(f"\nResults beyond 3x their stated one-sigma: {wrong}.\n")
        plain_car = Path(folder) / "car_plain.csv"
        car = _recording("car", 1)[0].samples
        np.savetxt(plain_car, car, fmt="%.5f", delimiter=",", header="mx,my,mz", comments="")
        level = magfit.simulate(200_000, hard_iron=[10, -5, 20], field_strength=50.0, inclination_deg=60, noise=0.3,
                                orientations="yaw", seed=1)  # fmt: skip
        plain_level = Path(folder) / "level_plain.csv"
        np.savetxt(plain_level, level.samples, fmt="%.5f", delimiter=",", header="mx,my,mz", comments="")
        for name, plain in (("the car's 3 000 rows", plain_car), ("200 000 rows of level turns", plain_level)):
            for label, method in (("default", None), ("--method auto", "auto")):
                best, outcome = float("inf"), "fitted"
                for _ in range(3):
                    start = time.perf_counter()
                    try:
                        magfit.calibrate_file(plain, method, unit="uT")
                    except magfit.CalibrationError as error:
                        outcome = f"refused ({', '.join(error.codes)})"
                    best = min(best, time.perf_counter() - start)
                print(f"- plain 3-column file, {name}, {label}: {outcome}, {best:.2f} s (best of 3)")


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 5)
