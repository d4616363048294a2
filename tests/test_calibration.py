"""Calibration: the one convention, its shapes, and its JSON form."""

from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

import magfit
from magfit import Calibration, MagfitError, SampleError

finite = st.floats(-1e6, 1e6, allow_nan=False, allow_infinity=False)


def random_calibration(seed: int) -> Calibration:
    rng = np.random.default_rng(seed)
    matrix = np.eye(3) + 0.3 * rng.standard_normal((3, 3))
    while np.linalg.cond(matrix) > 100:  # a nearly singular matrix is no soft iron: from_json refuses it
        matrix = np.eye(3) + 0.3 * rng.standard_normal((3, 3))
    matrix[0] *= np.sign(np.linalg.det(matrix))  # a mirror is no calibration: from_json refuses it
    return Calibration("ellipsoid", rng.normal(0, 50, 3), matrix, float(rng.uniform(10, 60)), unit="uT")


def test_identity_changes_nothing() -> None:
    samples = np.random.default_rng(0).normal(0, 40, (50, 3))
    assert np.array_equal(Calibration.identity().apply(samples), samples)
    assert np.array_equal(Calibration.identity().apply(samples[0]), samples[0])


@given(
    seed=st.integers(0, 10_000), samples=arrays(np.float64, st.tuples(st.integers(1, 20), st.just(3)), elements=finite)
)
def test_apply_is_the_stated_formula(seed: int, samples: np.ndarray) -> None:
    cal = random_calibration(seed)
    expected = np.array([cal.matrix @ (row - cal.offset) for row in samples])  # corrected = matrix @ (raw - offset)
    np.testing.assert_allclose(cal.apply(samples), expected, rtol=1e-12, atol=1e-6)
    np.testing.assert_allclose(
        cal.apply(samples, normalized=True), expected / cal.field_strength, rtol=1e-12, atol=1e-6
    )


def test_apply_keeps_the_shape() -> None:
    cal = random_calibration(1)
    assert cal.apply(np.zeros((7, 3))).shape == (7, 3)
    assert cal.apply(np.zeros(3)).shape == (3,)
    with pytest.raises(SampleError, match=r"got shape \(3, 7\)"):
        cal.apply(np.zeros((3, 7)))


@settings(max_examples=50)
@given(seed=st.integers(0, 10_000))
def test_json_round_trip_is_lossless(seed: int) -> None:
    cal = random_calibration(seed)
    cal = Calibration(
        cal.method, cal.offset, cal.matrix, cal.field_strength, unit="uT", n_samples=seed, details={"root": "sqrt"}
    )
    back = Calibration.from_json(cal.to_json())
    assert back == cal
    assert np.array_equal(back.matrix, cal.matrix) and np.array_equal(back.offset, cal.offset)


def test_json_states_schema_and_convention() -> None:
    data = json.loads(random_calibration(2).to_json())
    assert data["schema_version"] == 2
    assert data["convention"] == "corrected = matrix @ (raw - offset)" == magfit.CONVENTION
    assert data["method"] == "ellipsoid" and data["unit"] == "uT"


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("[1, 2]", "must be an object"),
        ("{not json", "not valid JSON"),
        ('{"schema": "other"}', "not a magfit calibration"),
        ('{"schema": "magfit.calibration", "schema_version": 99}', "version 99 is not supported"),
    ],
)
def test_from_json_rejects_foreign_files(text: str, message: str) -> None:
    with pytest.raises(MagfitError, match=message):
        Calibration.from_json(text)


def test_calibration_is_immutable() -> None:
    cal = random_calibration(3)
    with pytest.raises(AttributeError):
        cal.offset = np.zeros(3)  # type: ignore[misc]
    with pytest.raises(ValueError, match="read-only"):
        cal.matrix[0, 0] = 5.0
    with pytest.raises(TypeError):
        cal.details["x"] = 1  # type: ignore[index]


def test_invalid_calibration_values_are_refused() -> None:
    with pytest.raises(SampleError, match="positive"):
        Calibration("x", np.zeros(3), np.eye(3), -1.0)
    with pytest.raises(SampleError, match="singular"):
        Calibration("x", np.zeros(3), np.zeros((3, 3)), 1.0)
    with pytest.raises(SampleError, match="NaN"):
        Calibration("x", [np.nan, 0, 0], np.eye(3), 1.0)


def test_semi_axes_follow_the_sensor_axes() -> None:
    # An ellipsoid with semi-axes 2 (along y), 5 (along z), 1 (along x), turned 10° about z.
    angle = np.radians(10)
    turn = np.array([[np.cos(angle), -np.sin(angle), 0], [np.sin(angle), np.cos(angle), 0], [0, 0, 1]])
    lengths = np.array([1.0, 2.0, 5.0])
    shape = turn @ np.diag(1 / lengths**2) @ turn.T  # (x − V)ᵀ A (x − V) = 1
    eigenvalues, eigenvectors = np.linalg.eigh(shape)
    root = eigenvectors @ np.diag(np.sqrt(eigenvalues)) @ eigenvectors.T
    cal = Calibration("ellipsoid", np.zeros(3), 3.0 * root, 3.0)
    np.testing.assert_allclose(cal.semi_axes, lengths)
    np.testing.assert_allclose(cal.axes, turn, atol=1e-12)
    np.testing.assert_allclose(cal.ellipsoid_matrix, shape)
