"""The simulator of eq. (1) and the paper's scenarios."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import magfit
from magfit import OptionError
from magfit.simulate import rotation_matrices


def axis_rotation(axis: int, degrees: float) -> np.ndarray:
    """The standard right-handed rotation about one axis."""
    c, s = np.cos(np.radians(degrees)), np.sin(np.radians(degrees))
    return [
        np.array([[1, 0, 0], [0, c, -s], [0, s, c]]),
        np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]]),
        np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]),
    ][axis]


def test_rotation_is_the_product_of_eq_1() -> None:
    roll, pitch, yaw = 30.0, -20.0, 75.0
    expected = axis_rotation(0, roll) @ axis_rotation(1, pitch) @ axis_rotation(2, yaw)
    np.testing.assert_allclose(rotation_matrices([roll, pitch, yaw])[0], expected, atol=1e-12)


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), strength=st.floats(0.1, 1e4))
def test_true_calibration_undoes_the_distortion(seed: int, strength: float) -> None:
    rng = np.random.default_rng(seed)
    soft_iron = np.eye(3) + 0.4 * rng.uniform(-1, 1, (3, 3))
    if abs(np.linalg.det(soft_iron)) < 0.05:
        return
    sim = magfit.simulate(
        50, soft_iron=soft_iron, hard_iron=rng.normal(0, strength, 3), field_strength=strength, seed=seed
    )
    corrected = sim.truth.apply(sim.clean)
    np.testing.assert_allclose(np.linalg.norm(corrected, axis=1), strength, rtol=1e-9)
    # and it recovers the earth field of eq. (1) rotated into the sensor frame
    delta = np.radians(sim.inclination_deg)
    field = strength * np.array([np.cos(delta), 0.0, np.sin(delta)])
    np.testing.assert_allclose(corrected, rotation_matrices(sim.attitudes) @ field, atol=1e-9 * strength)


def test_uniform_orientations_cover_the_sphere() -> None:
    sim = magfit.simulate(20_000, seed=3)
    directions = sim.clean / np.linalg.norm(sim.clean, axis=1, keepdims=True)
    # uniform on the sphere: mean direction ~0, second moment ~I/3
    np.testing.assert_allclose(directions.mean(axis=0), 0, atol=0.03)
    np.testing.assert_allclose(directions.T @ directions / len(directions), np.eye(3) / 3, atol=0.02)


def test_restricted_and_yaw_orientations() -> None:
    restricted = magfit.simulate(2000, orientations="restricted", max_tilt_deg=15, seed=4)
    assert np.all(np.abs(restricted.attitudes[:, :2]) <= 15)
    assert np.ptp(restricted.attitudes[:, 2]) > 300
    level = magfit.simulate(100, orientations="yaw", seed=4)
    assert np.all(level.attitudes[:, :2] == 0)


def test_noise_and_quantisation() -> None:
    sim = magfit.simulate(20_000, field_strength=300, noise=5.0, resolution=1.0, seed=5)
    assert np.all(sim.samples == np.round(sim.samples))
    assert np.std(sim.samples - sim.clean) == pytest.approx(np.sqrt(25 + 1 / 12), rel=0.03)


def test_same_seed_same_samples() -> None:
    assert np.array_equal(
        magfit.simulate(10, noise=0.1, seed=9).samples, magfit.simulate(10, noise=0.1, seed=9).samples
    )


@pytest.mark.parametrize("sensor", magfit.SENSORS)
@pytest.mark.parametrize("disturbance", magfit.DISTURBANCES)
def test_scenarios_reproduce_the_papers_tables(sensor: str, disturbance: str) -> None:
    scenario = magfit.scenario(sensor, disturbance)
    truth = scenario.simulate(10, seed=0).truth
    np.testing.assert_allclose(truth.offset, scenario.hard_iron)
    # the true distortion's ellipsoid has the paper's semi-axes, each along its sensor axis
    np.testing.assert_allclose(truth.semi_axes, scenario.semi_axes, rtol=1e-9)


def test_bad_simulation_options() -> None:
    with pytest.raises(OptionError, match="orientations"):
        magfit.simulate(10, orientations="sideways")
    with pytest.raises(OptionError, match="invertible"):
        magfit.simulate(10, soft_iron=np.zeros((3, 3)))
    with pytest.raises(OptionError, match="unknown sensor 'bmx'"):
        magfit.scenario("bmx", "none")
    with pytest.raises(OptionError, match="choose one of: none, steel, smartphone"):
        magfit.scenario("mpu9250", "magnet")
