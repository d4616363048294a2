"""The gyro's handedness against the magnetometer's: refused as wrong only where the recording tells it, "cannot
tell" (exit 1, a code of its own) where it does not, calibrated where the rates as given are told right. Each
case is a simulation whose axes are known (right-handed, or one gyro axis flipped), compared against it."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import magfit
from magfit.vehicle import VehicleSimulation, simulate_vehicle

FLIP_Z = np.diag([1.0, 1.0, -1.0])  # a gyro with one axis sign-flipped: the other handedness


def _vehicle(motion: str, seed: int) -> VehicleSimulation:
    """A vehicle with a small soft iron, hard iron (field 50) and mounting, the gyro and magnetometer right-handed
    and agreeing; the magnetometer 0.02 s late."""
    rng = np.random.default_rng(seed)
    soft = np.eye(3) + rng.normal(0, 0.05, (3, 3))
    hard = rng.normal(0, 0.3, 3) * 50
    mounting = Rotation.from_euler("xyz", rng.normal(0, 3, 3), degrees=True).as_matrix()
    return simulate_vehicle(
        3000, motion, soft_iron=0.5 * (soft + soft.T), hard_iron=hard, mounting=mounting,
        field_strength=50.0, inclination_deg=60, declination_deg=5, noise=0.3, attitude_noise_deg=0.5, gyro_noise=0.002,
        gyro_bias=[0.01, -0.005, 0.003], accel_noise=0.05, lag_s=0.02, seed=seed,
    )  # fmt: skip


def _heading_error_deg(cal: magfit.Calibration, sim: VehicleSimulation) -> float:
    ours = np.einsum("kij,kj->ki", sim.attitude, cal.apply(sim.clean))
    truth = np.einsum("kij,kj->ki", sim.attitude, sim.truth.apply(sim.clean))
    difference = np.arctan2(ours[:, 1], ours[:, 0]) - np.arctan2(truth[:, 1], truth[:, 0])
    return float(np.degrees(np.sqrt(np.mean(np.angle(np.exp(1j * difference)) ** 2))))


@pytest.mark.parametrize("accel", [False, True])
def test_a_right_handed_boat_the_windows_misread_is_calibrated_within_its_one_sigma(accel: bool) -> None:
    # Rolling about one axis, the windows of stage 1 fit this boat's rates negated 4.6 times better; the fit of
    # every sample fits them as given 22 000 noise variances better: the handedness is told, and right.
    sim = _vehicle("boat", 2)
    cal = magfit.fit(sim.samples, method="gyro", gyro=sim.gyro, time_s=sim.time_s,
                     accel=sim.accel if accel else None)  # fmt: skip
    assert cal.support is not None and cal.support.verdict != "refused"
    assert cal.gyro is not None
    assert _heading_error_deg(cal, sim) <= 3.0 * cal.gyro.heading_sigma_deg


def test_a_flight_that_cannot_tell_the_handedness_says_so_with_its_code() -> None:
    # This flight's rates negated leave a third of the given rates' residual, yet far from the samples' noise:
    # neither handedness is told. Refused as such (exit 1), not as the wrong axes (exit 2).
    sim = _vehicle("flight", 7)
    with pytest.raises(magfit.CalibrationError) as refused:
        magfit.fit(sim.samples, method="gyro", gyro=sim.gyro, time_s=sim.time_s, accel=sim.accel)
    assert refused.value.codes == ("handedness_undetermined",)
    assert ("method", "vector") in refused.value.remedy
    assert "gyro_axes" not in refused.value.codes


@pytest.mark.parametrize("motion", ["boat", "car", "tumble"])
def test_a_flipped_gyro_axis_is_refused_as_the_other_handedness(motion: str) -> None:
    # car and boat: told by the fit of every sample (the windows are not overwhelming there); tumble: by the windows
    sim = _vehicle(motion, 22)
    with pytest.raises(magfit.OptionError) as refused:
        magfit.fit(sim.samples, method="gyro", gyro=sim.gyro @ FLIP_Z, time_s=sim.time_s)
    assert refused.value.codes == ("gyro_axes",)
