"""Every bad input gets its own error type and a message that says what is wrong and what to do."""

from __future__ import annotations

import numpy as np
import pytest

import magfit
from magfit import CalibrationError, OptionError, SampleError

GOOD = magfit.scenario("ellipse2a", "none").simulate(500, seed=1).samples


@pytest.mark.parametrize(
    ("samples", "message"),
    [
        (GOOD.T, r"shape \(N, 3\), got shape \(3, 500\); it looks like one sample per column: pass samples.T"),
        (GOOD[0], r"got shape \(3,\); a single sample needs shape \(1, 3\)"),
        (np.zeros((10, 4)), r"got shape \(10, 4\)"),
        (np.zeros((2, 10, 3)), r"got shape \(2, 10, 3\)"),
        (np.array([["a", "b", "c"]]), "must be numbers"),
    ],
)
def test_wrong_shape_or_type(samples: np.ndarray, message: str) -> None:
    with pytest.raises(SampleError, match=message):
        magfit.fit(samples)


def test_non_finite_values_name_the_row() -> None:
    samples = GOOD.copy()
    samples[7, 1] = np.nan
    samples[9, 0] = np.inf
    with pytest.raises(SampleError, match=r"NaN or inf in 2 row\(s\), the first is row 7; drop them"):
        magfit.fit(samples)


@pytest.mark.parametrize(("method", "minimum"), [("ellipsoid", 9), ("sphere", 4), ("minmax", 4)])
def test_too_few_samples_names_the_minimum(method: str, minimum: int) -> None:
    with pytest.raises(CalibrationError, match=f"needs at least {minimum} samples, got {minimum - 1}"):
        magfit.fit(GOOD[: minimum - 1], method=method)


def test_identical_samples() -> None:
    with pytest.raises(CalibrationError, match="all 50 samples are identical .* record while rotating"):
        magfit.fit(np.tile([20.0, -5.0, 40.0], (50, 1)))


def test_flat_samples_name_the_missing_direction() -> None:
    angle = np.linspace(0, 2 * np.pi, 200)
    ring = np.column_stack([30 * np.cos(angle), 30 * np.sin(angle), np.full_like(angle, 12.0)])
    with pytest.raises(CalibrationError, match="lie in a plane: nothing varies along the sensor z axis"):
        magfit.fit(ring, method="sphere")
    tilted = ring @ magfit_rotation().T
    with pytest.raises(CalibrationError, match=r"nothing varies along direction \("):
        magfit.fit(tilted)


def test_too_few_distinct_samples_for_an_ellipsoid() -> None:
    distinct = magfit.scenario("ellipse2a", "none").simulate(6, seed=3).samples
    with pytest.raises(CalibrationError, match="do not single out one ellipsoid"):
        magfit.fit(np.vstack([distinct, distinct]))  # 12 samples, but only 6 distinct


def test_samples_on_a_line() -> None:
    line = np.outer(np.linspace(-1, 1, 100), [1.0, 2.0, 3.0])
    with pytest.raises(CalibrationError, match=r"lie on a line along direction \(\+0.27, \+0.53, \+0.80\)"):
        magfit.fit(line)


def test_not_an_ellipsoid_is_refused_never_abs() -> None:
    # Samples on a hyperboloid of one sheet: x² + y² − z² = 1.
    rng = np.random.default_rng(0)
    t, height = rng.uniform(0, 2 * np.pi, 500), rng.uniform(-2, 2, 500)
    radius = np.sqrt(1 + height**2)
    hyperboloid = np.column_stack([radius * np.cos(t), radius * np.sin(t), height])
    with pytest.raises(CalibrationError, match="hyperboloid, not an ellipsoid .* use method='sphere'"):
        magfit.fit(hyperboloid)
    with pytest.raises(CalibrationError, match="lie on no ellipsoid|do not outline an ellipsoid"):
        magfit.fit(hyperboloid, method="sphere")


def test_unknown_method_lists_the_valid_ones() -> None:
    with pytest.raises(OptionError, match="unknown method 'elipsoid'; valid methods: .*ellipsoid.*sphere"):
        magfit.fit(GOOD, method="elipsoid")


def test_unknown_option_lists_the_valid_ones() -> None:
    with pytest.raises(OptionError, match="method 'ellipsoid' has no option 'rot'; valid options: root"):
        magfit.fit(GOOD, rot="sqrt")
    with pytest.raises(OptionError, match="has no option 'root'; valid options: centre"):
        magfit.fit(GOOD, method="minmax", root="sqrt")


def test_bad_option_values() -> None:
    with pytest.raises(OptionError, match="root='cube' is not valid; choose one of: sqrt, cholesky"):
        magfit.fit(GOOD, root="cube")
    with pytest.raises(OptionError, match="centre='median' is not valid; choose one of: mean, midrange"):
        magfit.fit(GOOD, method="minmax", centre="median")


def test_errors_are_value_errors() -> None:
    for error in (SampleError, OptionError, CalibrationError, magfit.DataFileError):
        assert issubclass(error, ValueError)


def magfit_rotation() -> np.ndarray:
    from magfit.simulate import rotation_matrices

    return rotation_matrices([30.0, 20.0, 0.0])[0]
