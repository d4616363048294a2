"""The gyro method on recordings with one thing wrong: a mirrored magnetometer (left-handed against the gyro), a
compass held between its readings, a compass late on the gyro with a glitch."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import magfit
from magfit.vehicle import VehicleSimulation, simulate_vehicle


def _vehicle(motion: str, seed: int, inclination_deg: float = 60.0) -> VehicleSimulation:
    rng = np.random.default_rng(seed)
    w = np.eye(3) + rng.normal(0, 0.08, (3, 3))
    return simulate_vehicle(
        3000, motion, soft_iron=(w + w.T) / 2, hard_iron=rng.normal(0, 0.5, 3) * 50,
        mounting=Rotation.from_euler("xyz", rng.normal(0, 5, 3), degrees=True).as_matrix(), field_strength=50.0,
        inclination_deg=inclination_deg, declination_deg=5, noise=0.3, attitude_noise_deg=0.5, gyro_noise=0.002,
        gyro_bias=[0.01, -0.005, 0.003], accel_noise=0.05, seed=seed,
    )  # fmt: skip


def _heading_error_deg(cal: magfit.Calibration, sim: VehicleSimulation, raw: np.ndarray) -> float:
    """RMS heading error over the recording with the true attitude (the calibration is in the gyro's axes), on
    the noiseless samples ``raw``."""
    world = np.einsum("kij,kj->ki", sim.attitude, cal.apply(raw))
    truth = np.arctan2(sim.field_world[1], sim.field_world[0])
    wrapped = (np.degrees(np.arctan2(world[:, 1], world[:, 0]) - truth) + 180.0) % 360.0 - 180.0
    return float(np.sqrt(np.mean(wrapped**2)))


@pytest.mark.parametrize(("motion", "columns", "signs", "fix"), [
    ("car", [1, 0, 2], [1, 1, 1], "swap mx and my"),
    ("tumble", [0, 1, 2], [1, 1, -1], "negate mz"),
    ("boat", [0, 1, 2], [-1, 1, 1], "negate mx"),
])  # fmt: skip
def test_a_left_handed_magnetometer_is_refused_naming_the_axis(motion: str, columns: list[int], signs: list[int],
                                                               fix: str) -> None:  # fmt: skip
    sim = _vehicle(motion, 1)
    mirrored = sim.samples[:, columns] * signs
    # Without the inclination, a field pointing up is a mirror or the southern hemisphere: cannot tell (exit 1).
    with pytest.raises(magfit.CalibrationError) as undetermined:
        magfit.fit(mirrored, method="gyro", gyro=sim.gyro, time_s=sim.time_s, accel=sim.accel)
    assert undetermined.value.codes == ("handedness_undetermined",)
    assert fix in str(undetermined.value) and "southern hemisphere" in str(undetermined.value)
    # With it (+60°, the simulation's), the mirror is told, naming the axis.
    with pytest.raises(magfit.OptionError) as refused:
        magfit.fit(mirrored, method="gyro", gyro=sim.gyro, time_s=sim.time_s, accel=sim.accel, inclination_deg=60.0)
    assert refused.value.codes == ("mag_handedness",)
    assert fix in str(refused.value)
    # Ground truth: the axes fixed as told, the same recording calibrates within its one-sigma.
    cal = magfit.fit(sim.samples, method="gyro", gyro=sim.gyro, time_s=sim.time_s, accel=sim.accel)
    assert cal.gyro is not None
    assert _heading_error_deg(cal, sim, sim.clean) <= 3 * cal.gyro.heading_sigma_deg


def test_the_southern_hemisphere_is_calibrated_when_its_inclination_is_given() -> None:
    sim = _vehicle("tumble", 3, inclination_deg=-55.0)
    with pytest.raises(magfit.CalibrationError) as refused:  # the field points up: a mirror, or the south
        magfit.fit(sim.samples, method="gyro", gyro=sim.gyro, time_s=sim.time_s, accel=sim.accel)
    assert refused.value.codes == ("handedness_undetermined",)  # no accusation: exit 1, the inclination asked
    cal = magfit.fit(sim.samples, method="gyro", gyro=sim.gyro, time_s=sim.time_s, accel=sim.accel,
                     inclination_deg=-55.0)  # fmt: skip
    assert cal.gyro is not None
    assert _heading_error_deg(cal, sim, sim.clean) <= 3 * cal.gyro.heading_sigma_deg
    # ... and a mirrored magnetometer there is refused against the given inclination.
    with pytest.raises(magfit.OptionError) as mirrored:
        magfit.fit(sim.samples * [1, 1, -1], method="gyro", gyro=sim.gyro, time_s=sim.time_s, accel=sim.accel,
                   inclination_deg=-55.0)  # fmt: skip
    assert mirrored.value.codes == ("mag_handedness",)


def test_a_held_compass_is_fitted_on_its_fresh_samples_within_its_one_sigma() -> None:
    sim = _vehicle("tumble", 1)
    held = np.repeat(sim.samples[::5], 5, axis=0)[: len(sim.samples)]  # 10 Hz read, logged at 50 Hz
    cal = magfit.fit(held, method="gyro", gyro=sim.gyro, time_s=sim.time_s, accel=sim.accel)
    assert cal.gyro is not None
    assert cal.n_samples == 600
    assert "held_samples" in cal.details
    # Measured: 0.32° for ±0.16° (2.0° for ±0.43° when every row was fitted as a sample).
    assert _heading_error_deg(cal, sim, sim.clean) <= 3 * cal.gyro.heading_sigma_deg


def test_a_clean_recording_is_not_taken_as_held() -> None:
    sim = _vehicle("car", 22)
    cal = magfit.fit(sim.samples, method="gyro", gyro=sim.gyro, time_s=sim.time_s, accel=sim.accel)
    assert cal.n_samples == 3000 and "held_samples" not in cal.details


def test_a_late_compass_with_a_glitch_at_the_start_has_its_lag_found() -> None:
    sim = _vehicle("tumble", 1)
    late = np.roll(sim.samples, 2, axis=0)  # 40 ms late; its first two rows from the recording's end
    cal = magfit.fit(late, method="gyro", gyro=sim.gyro, time_s=sim.time_s, accel=sim.accel)
    assert cal.gyro is not None
    assert cal.gyro.lag_s == pytest.approx(0.04, abs=0.005)  # 0 before: the glitch's window ruled the search
    assert _heading_error_deg(cal, sim, sim.clean) <= 3 * cal.gyro.heading_sigma_deg


def test_a_gyro_scale_error_the_turning_determines_is_corrected() -> None:
    sim = _vehicle("car", 2)
    cal = magfit.fit(sim.samples, method="gyro", gyro=sim.gyro * 1.02, time_s=sim.time_s, accel=sim.accel)
    assert cal.gyro is not None
    # A car turns about z: that axis's scale is determined (the rates read 2 % high want 1/1.02), the others not.
    assert cal.details["gyro_scale_correction"][2] == pytest.approx(1 / 1.02 - 1, abs=0.005)
    assert cal.details["gyro_scale_sigma"][2] < 0.005
    # Measured: 0.39° for ±0.25° (0.89° for ±0.20° before the scale was estimated).
    assert _heading_error_deg(cal, sim, sim.clean) <= 3 * cal.gyro.heading_sigma_deg


def test_a_true_gyro_scale_is_left_alone() -> None:
    sim = _vehicle("tumble", 22)
    cal = magfit.fit(sim.samples, method="gyro", gyro=sim.gyro, time_s=sim.time_s, accel=sim.accel)
    assert cal.details["gyro_scale_correction"] == [0.0, 0.0, 0.0]
    assert max(cal.details["gyro_scale_sigma"]) < 0.001  # a tumble determines all three
