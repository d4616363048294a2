"""magfit.gravity: the samples on which the accelerometer sees gravity alone, against the simulated truth."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from magfit.errors import SampleError
from magfit.gravity import still_samples
from magfit.vehicle import simulate_vehicle


def _simulation(motion: str, seed: int = 4):
    return simulate_vehicle(6000, motion, rate_hz=10.0, noise=0.005, accel_noise=0.05, gyro_noise=0.002, seed=seed)


def _tilt_error_deg(sim, keep: np.ndarray) -> np.ndarray:
    """Angle between the apparent and the true down direction (body frame) on the kept samples."""
    true_down = np.einsum("kji,j->ki", sim.attitude, [0.0, 0.0, 1.0])
    apparent = -sim.accel / np.linalg.norm(sim.accel, axis=1, keepdims=True)
    cosine = np.clip(np.sum(true_down * apparent, axis=1), -1.0, 1.0)
    return np.degrees(np.arccos(cosine))[keep]


def test_a_car_keeps_its_straight_stretches_and_drops_its_turns():
    sim = _simulation("car")
    still = still_samples(sim.accel, mag=sim.samples, gyro=sim.gyro, time_s=sim.time_s)
    # Most of the drive turns (|a| up to 1.3 g): g is taken where it turns slowly, so the straights remain.
    assert still.keep.sum() > 800
    assert np.percentile(_tilt_error_deg(sim, still.keep), 95) < 1.0  # the accelerometer's noise: 0.3° a sample
    everything = np.ones(len(sim.accel), dtype=bool)
    assert np.percentile(_tilt_error_deg(sim, everything), 95) > 10.0  # what the gate keeps out


def test_a_rolling_boat_is_kept_whatever_way_the_imu_is_mounted():
    # Rolling accelerates nothing at the sensor; the heading's rate is that of the axis that stays level, so an
    # IMU mounted sideways or on end keeps the same samples as one whose x points forward.
    sim = _simulation("boat")
    base = still_samples(sim.accel, gyro=sim.gyro, time_s=sim.time_s)
    assert base.keep.mean() > 0.9
    for turn in (Rotation.from_euler("z", 90, degrees=True), Rotation.from_euler("y", -90, degrees=True)):
        imu = turn.as_matrix()  # body = imu @ imu-frame: the streams in the IMU's axes
        mounted = still_samples(sim.accel @ imu, gyro=sim.gyro @ imu, time_s=sim.time_s)
        np.testing.assert_array_equal(mounted.keep, base.keep)


def test_without_a_gyroscope_the_directions_turning_gate_the_samples():
    sim = _simulation("car")
    still = still_samples(sim.accel, mag=sim.samples, time_s=sim.time_s)
    # A weaker gate than the gyroscope's (the directions' own noise, over two seconds): few samples, most of them
    # right; the edge of a slow turn gets through (this recording: a fifth of the kept samples 2.4-3° off), which
    # the alignment's robust loss and its dip scatter must then catch.
    assert 0 < still.keep.sum() < len(sim.accel) / 10
    assert np.median(_tilt_error_deg(sim, still.keep)) < 0.6
    assert any("turning of the field and gravity directions" in reason for reason in still.dropped)


def test_a_zero_accelerometer_is_a_sample_error():
    with pytest.raises(SampleError, match="reads zero"):
        still_samples(np.zeros((100, 3)))
