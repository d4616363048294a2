"""The vehicle simulator: its truth, its gyroscope, accelerometer and lagged attitude agree with its trajectory."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import magfit
from magfit.vehicle import GRAVITY, MOTIONS, simulate_vehicle

MOUNTING = Rotation.from_euler("xyz", [10, -20, 30], degrees=True).as_matrix()


@pytest.mark.parametrize("motion", MOTIONS)
def test_the_truth_returns_the_body_field_and_the_gyro_the_rotation(motion):
    sim = simulate_vehicle(
        2000, motion, hard_iron=[0.1, -0.2, 0.3], soft_iron=np.diag([1.1, 0.9, 1.0]), mounting=MOUNTING, seed=3
    )
    body = np.einsum("kji,j->ki", sim.attitude, sim.field_world)
    np.testing.assert_allclose(sim.truth.apply(sim.clean), body, atol=1e-12)
    assert sim.truth.frame == "vehicle" and sim.truth_sensor.frame == "sensor"
    # the magnitude-only truth puts the samples on the sphere, in the sensor's own axes
    np.testing.assert_allclose(np.linalg.norm(sim.truth_sensor.apply(sim.clean), axis=1), 1.0, atol=1e-12)
    # R(k+1) = R(k) exp(ω dt): the rotation between samples is the mean body rate times dt
    dt = sim.time_s[1] - sim.time_s[0]
    between = np.einsum("kji,kjl->kil", sim.attitude[:-1], sim.attitude[1:])
    rates = Rotation.from_matrix(between).as_rotvec() / dt
    mean_gyro = 0.5 * (sim.gyro[:-1] + sim.gyro[1:])
    assert np.abs(rates - mean_gyro).max() < 1e-3 * max(1.0, np.abs(sim.gyro).max())
    # at rest and level the accelerometer reads -g on z; gravity's direction always follows the attitude
    down = np.einsum("kji,j->ki", sim.attitude, [0.0, 0.0, 1.0])
    if motion in {"boat", "tumble", "yaw"}:  # no acceleration but gravity
        np.testing.assert_allclose(sim.accel, -GRAVITY * down, atol=1e-9)


def test_the_logged_attitude_lags_and_errs_as_asked():
    still = simulate_vehicle(3000, "tumble", lag_s=0.0, seed=5)
    lagged = simulate_vehicle(3000, "tumble", lag_s=0.1, attitude_noise_deg=0.0, seed=5)
    np.testing.assert_allclose(still.attitude_measured, still.attitude, atol=1e-12)
    # the lagged estimate at k is the truth 5 samples (0.1 s at 50 Hz) earlier
    np.testing.assert_allclose(lagged.attitude_measured[5:], lagged.attitude[:-5], atol=1e-6)
    noisy = simulate_vehicle(20000, "flight", attitude_noise_deg=1.0, attitude_noise_time_s=0.0, seed=6)
    error = Rotation.from_matrix(np.einsum("kji,kjl->kil", noisy.attitude, noisy.attitude_measured)).as_rotvec()
    np.testing.assert_allclose(np.degrees(error.std(axis=0)), 1.0, rtol=0.05)
    np.testing.assert_allclose(
        noisy.reference, np.einsum("kji,j->ki", noisy.attitude_measured, noisy.field_world), atol=1e-12
    )


def test_flight_banks_as_a_coordinated_turn_within_the_tilt():
    sim = simulate_vehicle(6000, "flight", max_tilt_deg=15.0, seed=7)
    roll_pitch = np.degrees(Rotation.from_matrix(sim.attitude).as_euler("ZYX")[:, 1:])
    assert np.abs(roll_pitch).max() <= 15.0 + 1e-9
    assert np.abs(sim.accel[:, 1]).max() < 2e-3 * GRAVITY  # coordinated: no side force (but for the pitch)


def test_bad_options_are_refused():
    with pytest.raises(magfit.OptionError, match="motion"):
        simulate_vehicle(100, "submarine")
    with pytest.raises(magfit.OptionError, match="mounting"):
        simulate_vehicle(100, mounting=np.diag([1.0, 1.0, 2.0]))
    with pytest.raises(magfit.OptionError, match="at least 10"):
        simulate_vehicle(3)
