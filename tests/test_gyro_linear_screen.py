"""The rows' rotations carried to first order in the gyro bias (eq. M4 of methods/gyro/model.py), by the screening
fits and, within FINAL_TURN, by the fit kept and the halves: against the full integration, and the calibration
they lead to against the one with every sample integrated."""

from __future__ import annotations

import numpy as np
import pytest

import magfit
from magfit.methods.gyro import model
from magfit.vehicle import simulate_vehicle

SOFT_IRON = np.array([[1.15, 0.06, -0.04], [0.06, 0.9, 0.05], [-0.04, 0.05, 1.0]])
HARD_IRON = np.array([0.3, -0.2, 0.25])
GYRO_BIAS = np.array([0.01, -0.02, 0.015])


def _recording(n: int, motion: str = "tumble", seed: int = 3):
    return simulate_vehicle(n, motion, soft_iron=SOFT_IRON, hard_iron=HARD_IRON, noise=0.005, gyro_noise=0.003,
                            gyro_bias=GYRO_BIAS, seed=seed)  # fmt: skip


def _exact(traj: model._Trajectory, beta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    turns, running = model._integrated(traj, beta)
    return turns[traj.rows], running[traj.rows] - running[traj.first[traj.rows]]


@pytest.mark.parametrize("motion", ["tumble", "car"])
def test_the_rows_rotations_follow_the_integration(motion: str) -> None:
    sim = _recording(30_000, motion)
    traj = model._trajectory(sim.samples, sim.gyro, sim.time_s, 10.0, np.eye(9), model.SCREEN_ROWS, linear=True)
    assert traj.linear and traj.rows.size <= model.SCREEN_ROWS
    model.forget_integration()
    try:
        # at the bias it was integrated at, the chain over the rows is the integration (to rounding)
        turns, running = model._linearized(traj, GYRO_BIAS)
        exact_turns, exact_running = _exact(traj, GYRO_BIAS)
        assert np.max(np.abs(turns - exact_turns)) < 1e-10
        assert np.max(np.abs(running - exact_running)) < 1e-9 * np.max(np.abs(exact_running))
        # a bias moved within LINEAR_TURN: first order, well below the magnetometer's noise (0.005)
        reach = model._LINEAR[-1].reach
        moved = GYRO_BIAS + 0.9 * model.LINEAR_TURN / reach * np.array([0.6, -0.64, 0.48])
        turns, _ = model._linearized(traj, moved)
        assert len(model._LINEAR) == 1  # carried, not integrated again
        error = np.max(np.abs(turns - _exact(traj, moved)[0]))
        assert 0 < error < 1e-4
        # beyond it: integrated again, exact again
        far = GYRO_BIAS + 3 * model.LINEAR_TURN / reach
        turns, _ = model._linearized(traj, far)
        assert np.max(np.abs(turns - _exact(traj, far)[0])) < 1e-10
    finally:
        model.forget_integration()


def test_short_strides_integrate_every_sample() -> None:
    sim = _recording(6_000)
    traj = model._trajectory(sim.samples, sim.gyro, sim.time_s, 10.0, np.eye(9), model.SCREEN_ROWS, linear=True)
    assert not traj.linear  # rows two samples apart: nothing to save


def test_the_calibration_is_the_one_with_every_sample_integrated(monkeypatch: pytest.MonkeyPatch) -> None:
    sim = _recording(20_000)

    def fit() -> magfit.Calibration:
        return magfit.fit(sim.samples, method="gyro", gyro=sim.gyro, time_s=sim.time_s)

    carried = fit()
    monkeypatch.setattr(model, "LINEAR_STRIDE", 10**9)  # every screening fit integrates every sample
    integrated = fit()
    assert carried.support is not None and integrated.support is not None
    assert carried.support.verdict == integrated.support.verdict == "supported"
    assert carried.gyro is not None and integrated.gyro is not None
    assert carried.gyro.mapping == integrated.gyro.mapping
    np.testing.assert_allclose(carried.offset, integrated.offset, rtol=1e-8, atol=1e-10)
    np.testing.assert_allclose(carried.matrix, integrated.matrix, rtol=1e-8, atol=1e-10)
    # and both against the truth: the offset within four of its stated one-sigmas
    sigma = np.asarray(carried.details["offset_sigma"])
    assert np.all(np.abs(carried.offset - HARD_IRON) < 4 * sigma + 1e-9)


def test_the_fit_kept_carries_its_rotations_within_a_few_hundred_millionths_of_a_radian() -> None:
    sim = _recording(60_000)
    traj = model._trajectory(sim.samples, sim.gyro, sim.time_s, 10.0, np.eye(9), model.MAX_RESIDUAL_SAMPLES,
                             linear=True, turn=model.FINAL_TURN)  # fmt: skip
    assert traj.linear  # rows three samples apart
    model.forget_integration()
    try:
        model._linearized(traj, GYRO_BIAS)
        reach = model._LINEAR[-1].reach
        moved = GYRO_BIAS + 0.9 * model.FINAL_TURN / reach * np.array([0.6, -0.64, 0.48])
        turns, running = model._linearized(traj, moved)
        assert len(model._LINEAR) == 1  # carried, not integrated again
        exact_turns, exact_running = _exact(traj, moved)
        assert 0 < np.max(np.abs(turns - exact_turns)) < 2e-8  # 1.1e-8 here: second order, summed down a stretch
        # C (the Jacobian in the bias only) is carried to first order: 3.6e-5 of itself here
        assert np.max(np.abs(running - exact_running)) < 1e-4 * np.max(np.abs(exact_running))
    finally:
        model.forget_integration()


@pytest.mark.slow
def test_a_long_recording_s_calibration_is_the_one_with_every_sample_integrated(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    sim = _recording(60_000)

    def fit() -> magfit.Calibration:
        return magfit.fit(sim.samples, method="gyro", gyro=sim.gyro, time_s=sim.time_s)

    carried = fit()  # the fit kept and the halves carry their rows' rotations (rows three samples apart)
    monkeypatch.setattr(model, "LINEAR_STRIDE", 10**9)
    integrated = fit()
    assert carried.support is not None and integrated.support is not None
    assert carried.support.verdict == integrated.support.verdict == "supported"
    sigma = np.asarray(carried.details["offset_sigma"])
    assert np.all(np.abs(carried.offset - integrated.offset) < 1e-2 * sigma)
    np.testing.assert_allclose(carried.details["offset_sigma"], integrated.details["offset_sigma"], rtol=1e-3)
    assert carried.gyro is not None and integrated.gyro is not None
    stated = integrated.gyro.heading_sigma_deg
    assert abs(carried.gyro.heading_sigma_deg - stated) < 1e-3 * stated
    assert np.all(np.abs(carried.offset - HARD_IRON) < 4 * sigma + 1e-9)
