"""The correlation in time on a bounded part of a long recording: the windows against the whole recording."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.signal import lfilter

import magfit
from magfit.diagnostics.uncertainty import (
    CORRELATION_ROWS,
    _identity_parameters,
    _isotropic_frame,
    _isotropic_to_corrected,
    correlation_excess,
    correlation_rows,
)
from magfit.geometry.frame import Frame, calibration_from_parameters, distances, parameters


def _turning_sphere(n: int, correlation: float, seed: int) -> np.ndarray:
    """Unit-sphere samples turned smoothly in time, radial noise AR(1) with ``correlation`` samples."""
    t = np.arange(n, dtype=np.float64)
    polar = 0.5 * math.pi * (1.0 + np.sin(2 * math.pi * t / 3001.0))
    azimuth = 2 * math.pi * t / 997.0
    directions = np.column_stack([np.sin(polar) * np.cos(azimuth), np.sin(polar) * np.sin(azimuth), np.cos(polar)])
    white = np.random.default_rng(seed).normal(0.0, 0.01, n)
    a = math.exp(-1.0 / correlation) if correlation > 1 else 0.0
    noise = lfilter([math.sqrt(1.0 - a * a)], [1.0, -a], white) if a else white
    return directions * (1.0 + noise)[:, None]


def _excess_trace(z: np.ndarray, windowed: bool) -> tuple[float, float]:
    """(offset excess, independent offset variance) of the identity sphere model on all of ``z``."""
    p = _identity_parameters("full")
    n = z.shape[0]
    d = distances(p, z, "full")
    variance = float(d @ d / n)
    rows, windows = correlation_rows(z) if windowed else (z, 0)
    excess = correlation_excess(p, rows, "full", n, variance, windows=windows)
    from magfit.geometry.frame import distance_jacobian

    jac = distance_jacobian(p, z, "full")
    independent = variance * np.linalg.inv(jac.T @ jac)
    return float(np.trace(excess[:3, :3])), float(np.trace(independent[:3, :3]))


def test_correlation_rows_are_bounded_windows_of_the_recording() -> None:
    series = np.arange(3 * 1_000_000, dtype=np.float64).reshape(-1, 3)
    rows, windows = correlation_rows(series)
    assert rows.shape == (CORRELATION_ROWS, 3) and windows == 20
    length = CORRELATION_ROWS // 20
    assert rows[0, 0] == 0 and rows[-1, 0] == series[-1, 0]  # from the start to the end
    assert np.all(np.diff(rows[:length, 0]) == 3)  # contiguous within a window
    small, none = correlation_rows(series[:1000])
    assert none == 0 and small.shape == (1000, 3)


@pytest.mark.parametrize("correlation", [30.0, 300.0])
@pytest.mark.slow
def test_windows_read_the_correlation_the_whole_recording_shows(correlation: float) -> None:
    z = _turning_sphere(1_000_000, correlation, seed=1)
    whole, independent = _excess_trace(z, windowed=False)
    windowed, _ = _excess_trace(z, windowed=True)
    assert whole > 5 * independent  # the correlation matters here
    # Both read 19 degrees of freedom (a relative error of about 0.3 each): they agree within that, where a
    # stride of the recording scaled to its rows read 1/5 of it.
    assert 0.5 < windowed / whole < 2.0, (windowed, whole)


@pytest.mark.slow
def test_windows_add_little_on_independent_noise() -> None:
    z = _turning_sphere(1_000_000, 1.0, seed=2)
    windowed, independent = _excess_trace(z, windowed=True)
    whole, _ = _excess_trace(z, windowed=False)
    # (the positive part of a noisy estimate: some excess on independent samples, as on the whole recording)
    assert windowed < 1.0 * independent, (windowed, whole, independent)


@pytest.mark.parametrize("kind", ["sphere", "diag", "full"])
def test_isotropic_covariance_carried_into_the_corrected_frame(kind: str) -> None:
    """G of _isotropic_to_corrected against finite differences of the two frames' parameters."""
    soft_iron = [[1.2, 0.1, 0.0], [0.1, 0.9, 0.05], [0.0, 0.05, 1.0]] if kind == "full" else np.diag([1.2, 0.9, 1.0])
    sim = magfit.simulate(3000, soft_iron=soft_iron, hard_iron=[0.3, -0.2, 0.1], noise=0.01, seed=4)
    method = {"sphere": "sphere", "diag": "diag", "full": "ellipsoid"}[kind]
    calibration = magfit.fit(sim.samples, method, diagnostics=False, allow_undetermined=True)
    isotropic = _isotropic_frame(calibration)
    corrected = Frame.corrected(calibration)
    base = parameters(calibration, kind, isotropic)
    k = base.size
    numeric = np.zeros((k, k))
    for j in range(k):
        step = np.zeros(k)
        step[j] = 1e-6
        moved = calibration_from_parameters(base + step, kind, isotropic, method)
        numeric[:, j] = (parameters(moved, kind, corrected) - parameters(calibration, kind, corrected)) / 1e-6
    covariance = np.random.default_rng(0).normal(size=(k, k))
    covariance = covariance @ covariance.T
    expected = numeric @ covariance @ numeric.T
    np.testing.assert_allclose(_isotropic_to_corrected(calibration, kind, covariance), expected, rtol=1e-3, atol=1e-6)


def test_regularized_beta_is_scipys() -> None:
    from scipy.special import betainc

    from magfit.diagnostics.uncertainty import regularized_beta

    for a in (0.5, 1.5, 3.0, 50.0, 2_000.0, 5e5):
        for b in (0.5, 1.0, 1.5, 2.5, 3.0):
            for x in (0.0, 1e-6, 0.01, 0.3, 0.5, 0.9, 0.99, 0.999_99, 1.0):
                expected = float(betainc(a, b, x))
                assert regularized_beta(a, b, x) == pytest.approx(expected, rel=1e-8, abs=1e-300), (a, b, x)
    # The F test's p-values where the verdict is decided (n − 9 degrees of freedom, 3 or 5 extra parameters).
    for dof in (40.0, 3_000.0, 1e6):
        for extra in (3.0, 5.0):
            for statistic in (0.5, 3.0, 6.0, 20.0):
                x = dof / (dof + extra * statistic)
                assert regularized_beta(dof / 2, extra / 2, x) == pytest.approx(
                    float(betainc(dof / 2, extra / 2, x)), rel=1e-9
                )
