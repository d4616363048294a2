"""The shared Levenberg–Marquardt solver (magfit._optimize), against exact answers and scipy's MINPACK."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import least_squares

from magfit._optimize import Evaluation, bracketed_root, levenberg_marquardt

TIMES = np.linspace(0.0, 4.0, 200)


def decay_residuals(p: np.ndarray, observed: np.ndarray) -> np.ndarray:
    return p[0] * np.exp(-p[1] * TIMES) + p[2] - observed


def decay_jacobian(p: np.ndarray, observed: np.ndarray) -> np.ndarray:
    e = np.exp(-p[1] * TIMES)
    return np.column_stack([e, -p[0] * TIMES * e, np.ones_like(TIMES)])


def decay_problem(observed: np.ndarray):
    def evaluate(p: np.ndarray, _: object) -> Evaluation:
        with np.errstate(all="ignore"):
            r = decay_residuals(p, observed)
            j = decay_jacobian(p, observed)
        return Evaluation(0.5 * float(r @ r), j.T @ j, j.T @ r)

    return evaluate


def test_recovers_exact_parameters_from_a_distant_start() -> None:
    truth = np.array([3.0, 1.7, -0.5])
    observed = decay_residuals(truth, np.zeros_like(TIMES))
    solution = levenberg_marquardt(
        decay_problem(observed), np.array([1.0, 0.2, 0.0]), n_residuals=TIMES.size, max_iterations=200
    )
    assert solution.status > 0, solution.message
    np.testing.assert_allclose(solution.params, truth, rtol=1e-7)


def test_noisy_optimum_matches_minpack() -> None:
    truth = np.array([3.0, 1.7, -0.5])
    noise = np.random.default_rng(4).normal(0.0, 0.05, TIMES.size)
    observed = decay_residuals(truth, np.zeros_like(TIMES)) + noise
    start = np.array([2.0, 1.0, 0.0])
    ours = levenberg_marquardt(decay_problem(observed), start, n_residuals=TIMES.size, max_iterations=200)
    minpack = least_squares(decay_residuals, start, jac=decay_jacobian, args=(observed,), method="lm", xtol=1e-14)
    assert ours.status > 0, ours.message
    # Stopping at 1e-3 standard errors: the parameters agree far inside their uncertainty, the cost to 1e-9.
    covariance = np.linalg.inv(minpack.jac.T @ minpack.jac) * 2 * minpack.cost / (TIMES.size - 3)
    assert np.all(np.abs(ours.params - minpack.x) < 1e-2 * np.sqrt(np.diag(covariance)))
    assert ours.evaluation.cost == pytest.approx(minpack.cost, rel=1e-9)


def test_non_finite_start_returns_without_iterating() -> None:
    observed = np.zeros_like(TIMES)
    solution = levenberg_marquardt(
        decay_problem(observed), np.array([1.0, -1e6, 0.0]), n_residuals=TIMES.size, max_iterations=50
    )
    assert solution.status == 0 and solution.iterations == 0
    assert "not finite" in solution.message


def test_a_parameter_the_residuals_ignore_does_not_break_the_solve() -> None:
    # A zero Jacobian column makes JᵀJ singular; the damping keeps the step defined and the others converge.
    truth = np.array([3.0, 1.7, -0.5])
    observed = decay_residuals(truth, np.zeros_like(TIMES))

    def evaluate(p: np.ndarray, _: object) -> Evaluation:
        r = decay_residuals(p[:3], observed)
        j = np.column_stack([decay_jacobian(p[:3], observed), np.zeros_like(TIMES)])
        return Evaluation(0.5 * float(r @ r), j.T @ j, j.T @ r)

    solution = levenberg_marquardt(evaluate, np.array([2.0, 1.0, 0.0, 5.0]), n_residuals=TIMES.size, max_iterations=200)
    assert solution.status > 0, solution.message
    np.testing.assert_allclose(solution.params[:3], truth, rtol=1e-6)
    assert solution.params[3] == 5.0


@pytest.mark.parametrize(
    ("function", "low", "high", "root", "tolerance"),
    [
        (lambda x: np.cos(x) - x, 0.0, 1.0, 0.7390851332151607, 1e-12),
        (lambda x: np.exp(x) - 2.0, 5.0, -5.0, np.log(2.0), 1e-12),  # ends given in either order
        (lambda x: np.tanh(50.0 * (x - 0.3)), 0.0, 1.0, 0.3, 1e-12),  # a steep step
        # Flat at the root (zero to round-off within 1e-2 of it): brentq gives up after 100 iterations here.
        (lambda x: (x - 0.7) ** 9, 0.0, 1.0, 0.7, 2e-2),
        (lambda x: x - 1e-13, 0.0, 1e-12, 1e-13, 1e-12),  # a tiny bracket
    ],
)
def test_bracketed_root_finds_the_root_to_the_tolerance(
    function, low: float, high: float, root: float, tolerance: float
) -> None:
    calls = []

    def counted(x: float) -> float:
        calls.append(x)
        return float(function(x))

    found = bracketed_root(counted, low, high, xtol=1e-15, rtol=1e-12)
    assert isinstance(found, float)
    assert abs(found - root) <= tolerance * abs(root) + 1e-15
    assert len(calls) < 200


def test_bracketed_root_refuses_a_bracket_without_a_sign_change() -> None:
    with pytest.raises(ValueError, match="no sign change"):
        bracketed_root(lambda x: x * x + 1.0, -1.0, 1.0)
