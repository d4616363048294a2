"""The gyro method's integration of the rates (eq. K1-K2 of methods/gyro/kinematics.py) and its structured solve
(eq. M3 of methods/gyro/model.py), each against a plain oracle: a loop of rotations, numpy's dense solve."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from magfit.methods.gyro.kinematics import _quaternion_product, _segmented_scan, _turns
from magfit.methods.gyro.model import _eigh_serial, _inverse_arrow, _solve_arrow


def _unit_quaternions(rng: np.random.Generator, n: int) -> np.ndarray:
    q = rng.normal(size=(n, 4))
    return q / np.linalg.norm(q, axis=1, keepdims=True)


@pytest.mark.parametrize("n", [1, 2, 31, 32, 33, 1025, 5000])
def test_the_blocked_scan_is_the_running_product_reset_at_each_start(n: int) -> None:
    rng = np.random.default_rng(n)
    q = _unit_quaternions(rng, n)
    start = rng.random(n) < 0.01
    expected = q.copy()
    for k in range(1, n):  # the oracle: one product per step
        if not start[k]:
            expected[k] = _quaternion_product(expected[k - 1], q[k])
    assert np.allclose(_segmented_scan(q, start), expected, atol=1e-12)


def test_the_turns_are_the_rotations_chained_step_by_step_from_each_stretch_start() -> None:
    rng = np.random.default_rng(5)
    n = 700
    t = np.cumsum(rng.uniform(0.01, 0.03, n))
    w = rng.normal(0.0, 1.5, (n, 3))
    beta = np.array([0.01, -0.02, 0.03])
    segment = np.repeat(np.arange(4), [100, 250, 1, 349])
    turns = _turns(w, t, beta, segment)
    steps = Rotation.from_rotvec((0.5 * (w[:-1] + w[1:]) - beta) * np.diff(t)[:, None]).as_matrix()
    expected = np.empty((n, 3, 3))
    for k in range(n):  # R_k = D_s … D_{k−1} (eq. K2)
        expected[k] = np.eye(3) if k == 0 or segment[k] != segment[k - 1] else expected[k - 1] @ steps[k - 1]
    assert np.allclose(turns, expected, atol=1e-12)
    assert np.allclose(np.einsum("kji,kjl->kil", turns, turns), np.eye(3), atol=1e-12)


def test_the_arrow_solve_is_the_dense_solve() -> None:
    rng = np.random.default_rng(6)
    head, count, rows = 16, 40, 3000
    jac = np.zeros((rows, head + 2 * count))
    jac[:, :head] = rng.normal(size=(rows, head))
    stretch = np.sort(rng.integers(0, count, rows))
    for shift in range(2):
        jac[np.arange(rows), head + 2 * stretch + shift] = rng.normal(size=rows)
    normal = jac.T @ jac
    normal += 1e-3 * np.diag(np.diag(normal))
    rhs = rng.normal(size=normal.shape[0])
    assert np.allclose(_solve_arrow(normal, rhs, head), np.linalg.solve(normal, rhs), rtol=1e-10, atol=1e-12)
    singular = normal.copy()
    singular[head : head + 2, :] = 0.0
    singular[:, head : head + 2] = 0.0
    with pytest.raises(np.linalg.LinAlgError):
        _solve_arrow(singular, rhs, head)


def test_the_arrow_inverse_is_the_dense_inverse_or_declines() -> None:
    rng = np.random.default_rng(7)
    head, count, rows = 16, 40, 3000
    jac = np.zeros((rows, head + 2 * count))
    jac[:, :head] = rng.normal(size=(rows, head))
    stretch = np.sort(rng.integers(0, count, rows))
    for shift in range(2):
        jac[np.arange(rows), head + 2 * stretch + shift] = rng.normal(size=rows)
    information = jac.T @ jac
    inverse = _inverse_arrow(information, head)
    assert inverse is not None
    assert np.allclose(inverse, np.linalg.pinv(information), rtol=1e-9, atol=1e-12)
    jac[:, 3] = jac[:, 2]  # a direction the data do not determine: left to the pseudo-inverse
    assert _inverse_arrow(jac.T @ jac, head) is None


@pytest.mark.parametrize("size", [1, 2, 3, 10, 136])
def test_the_serial_eigh_is_numpy_s(size: int) -> None:
    rng = np.random.default_rng(size)
    matrix = rng.normal(size=(size, size))
    matrix = matrix + matrix.T
    matrix[:, -1] *= 1e-6  # scales as different as a covariance's
    matrix[-1, :] *= 1e-6
    values, vectors = _eigh_serial(matrix)
    expected = np.linalg.eigvalsh(matrix)
    assert np.allclose(np.sort(values), expected, rtol=0, atol=1e-12 * np.abs(expected).max())
    assert np.allclose(vectors.T @ vectors, np.eye(size), atol=1e-12)
    assert np.allclose((vectors * values) @ vectors.T, matrix, atol=1e-12 * np.abs(matrix).max())
