"""A sensor whose offset creeps along the recording (warming up): the verdict names the change between the
recording's halves and the heading one-sigma covers the error against the sensor's state at the end."""

from __future__ import annotations

import dataclasses
import sys
from pathlib import Path

import numpy as np
import pytest

import magfit

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
from _common import heading_error_deg


def _warming(seed: int, share: float) -> tuple[magfit.Simulation, np.ndarray, np.ndarray]:
    """A tumble of the MPU-9250 scenario whose offset creeps linearly by ``share`` of the field (x) and two thirds
    of that (−y) over the recording: samples, and the whole drift (the offset at the end minus the truth's)."""
    sim = magfit.scenario("mpu9250", "none").simulate(1500, seed=seed)
    drift = np.array([share, -2.0 * share / 3.0, 0.0]) * sim.truth.field_strength
    return sim, sim.samples + np.linspace(0.0, 1.0, len(sim.samples))[:, None] * drift, drift


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_a_creeping_offset_is_named_and_its_change_counted(seed: int) -> None:
    sim, samples, drift = _warming(seed, 0.03)
    fitted = magfit.fit(samples)
    assert fitted.support is not None and "inconsistent_halves" in fitted.support.codes, fitted.support
    assert fitted.support.verdict == "weak"
    stated = fitted.diagnostics.uncertainty.heading_sigma_deg
    # Ground truth: at the end of the recording the offset is the truth's plus the whole drift, at its start the
    # truth's; both states are within the stated one-sigma's reach.
    at_the_end = dataclasses.replace(fitted, offset=np.asarray(fitted.offset) - drift)
    assert heading_error_deg(at_the_end, sim) <= 2 * stated, (heading_error_deg(at_the_end, sim), stated)
    assert heading_error_deg(fitted, sim) <= 2 * stated, (heading_error_deg(fitted, sim), stated)
    # The offset one-sigmas carry the change too: the end state's offset is within 3 of them on every axis.
    sigma = np.asarray(fitted.diagnostics.uncertainty.offset_sigma)
    end_offset = np.asarray(sim.truth.offset) + drift
    assert np.all(np.abs(np.asarray(fitted.offset) - end_offset) <= 3 * sigma), (fitted.offset, end_offset, sigma)


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_a_steady_sensor_s_halves_agree(seed: int) -> None:
    sim, samples, _ = _warming(seed, 0.0)
    fitted = magfit.fit(samples)
    assert fitted.support is not None and fitted.support.verdict == "supported", fitted.support
    stated = fitted.diagnostics.uncertainty.heading_sigma_deg
    assert heading_error_deg(fitted, sim) <= 3 * stated


def test_the_offset_trend_tells_a_changed_sensor_from_halves_that_saw_other_directions() -> None:
    from magfit.diagnostics.diagnose import TREND_LEVEL, offset_trend_p_value

    rng = np.random.default_rng(7)
    centres = rng.uniform(-180.0, 180.0, (6, 3)) * np.array([1.0, 0.5, 1.0])
    attitudes = np.repeat(centres, 200, axis=0) + rng.normal(0.0, 3.0, (1200, 3))  # each attitude held in turn
    sim = magfit.simulate(1200, hard_iron=[0.3, -0.2, 0.1], noise=0.01, orientations=attitudes, seed=7)
    held = magfit.fit(sim.samples, method="ellipsoid")
    assert offset_trend_p_value(sim.samples, "full", held) > TREND_LEVEL
    # Ground truth: the same attitudes with the offset creeping 3 % of the field along the recording.
    creeping = sim.samples + np.linspace(0.0, 1.0, 1200)[:, None] * np.array([0.03, -0.02, 0.0])
    assert offset_trend_p_value(creeping, "full", magfit.fit(creeping, method="ellipsoid")) < TREND_LEVEL
