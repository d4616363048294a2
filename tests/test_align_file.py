"""align_file: what `magfit align` does, as a library function, against the simulated mounting."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import magfit
from magfit.findings import Reason, Support
from magfit.pipeline.align import alignment_of_vector
from magfit.rotations import angle_between_deg, euler_matrix
from magfit.vehicle import simulate_vehicle


def _boat(tmp_path, mounting):  # type: ignore[no-untyped-def]
    sim = simulate_vehicle(
        6000, "boat", rate_hz=10.0, mounting=mounting, soft_iron=np.array([[1.02, 0.01, 0.0], [0.01, 0.98, 0.0],
        [0.0, 0.0, 1.01]]), hard_iron=[0.2, -0.1, 0.3], noise=0.005, accel_noise=0.05, gyro_noise=0.002,
        gyro_bias=[0.004, -0.006, 0.003], seed=31,
    )  # fmt: skip
    path = tmp_path / "boat.csv"
    table = np.column_stack([sim.time_s, sim.samples, sim.accel, sim.gyro])
    np.savetxt(path, table, delimiter=",", header="t,mx,my,mz,ax,ay,az,gx,gy,gz", comments="")
    return sim, path


def test_align_file_finds_the_mounting_and_caps_it_by_its_calibration(tmp_path) -> None:  # type: ignore[no-untyped-def]
    mounting = euler_matrix(4.0, -6.0, 25.0)
    sim, path = _boat(tmp_path, mounting)
    truth = sim.truth_sensor  # the sensor's own magnitude-only calibration, known
    truth = dataclasses.replace(truth, support=Support.judged((), (), ""))
    found = magfit.align_file(path, gyro_columns=["gx", "gy", "gz"], calibration=truth, inclination_deg=64.0,
                              allow_mirror=False)  # fmt: skip
    assert found.inclination_source == "given" and found.recording.gyro is not None
    assert angle_between_deg(found.alignment.proper_matrix, mounting) < 0.5
    assert found.alignment.verdict == "supported" and np.allclose(found.total, found.alignment.proper_matrix)
    # The same calibration, weak: the alignment is weak at best, the calibration's reason named.
    weak = dataclasses.replace(truth, support=Support.judged((), (Reason("near the attitudes seen", "coverage"),), ""))
    capped = magfit.align_file(path, gyro_columns=["gx", "gy", "gz"], calibration=weak, inclination_deg=64.0,
                               allow_mirror=False)  # fmt: skip
    assert capped.alignment.verdict == "weak"
    assert "(near the attitudes seen)" in capped.alignment.warnings[-1]
    assert angle_between_deg(capped.alignment.proper_matrix, mounting) < 0.5  # the numbers are the same
    with pytest.raises(magfit.DataFileError, match="vehicle-frame"):
        magfit.align_file(path, calibration=dataclasses.replace(truth, frame="vehicle"), inclination_deg=64.0)


def test_the_vector_fits_rotation_is_an_alignment() -> None:
    # A car, 1° of attitude error, with the accelerometer and gyro (the gravity rows pin the vertical).
    mounting = euler_matrix(5.0, -8.0, 20.0)
    sim = simulate_vehicle(3000, "car", rate_hz=10.0, mounting=mounting, hard_iron=[12.0, -5.0, 3.0],
                           field_strength=50.0, noise=0.25, attitude_noise_deg=1.0, gyro_noise=0.002,
                           accel_noise=0.05, seed=3)  # fmt: skip
    # measured: 0.23° from the mounting, stated ±0.79°
    calibration = magfit.fit(sim.samples, "vector", reference=sim.reference, time_s=sim.time_s, accel=sim.accel,
                             gyro=sim.gyro)  # fmt: skip
    aligned = alignment_of_vector(calibration, len(sim.samples))
    assert calibration.vector is not None and aligned.sigma_deg[0] == calibration.vector.alignment_sigma_deg
    error = angle_between_deg(aligned.proper_matrix, mounting)
    assert not aligned.mirror and error < 1.0 and error < 3 * aligned.sigma_deg[0], (error, aligned.sigma_deg)
    assert calibration.support is not None and aligned.verdict == calibration.support.verdict
