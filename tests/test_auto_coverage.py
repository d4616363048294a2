"""auto's stated one-sigma covers its real error, against the simulated truth.

The paper's six scenarios (two sensors; no disturbance, a steel plate, a smartphone), full tumbles: the offset
error over its stated one-sigma, per axis, and the level-heading error over the stated heading one-sigma.
Below and beyond the rows auto's maximum-likelihood refit reads (``REFIT_ROWS``: the one-sigma is stated for the
stride it read). ``benchmarks/auto_coverage.py`` runs the larger sweep (1e3 to 1e6 samples, restricted tilt, the
trust campaign's kinds).
"""

from __future__ import annotations

import importlib
import sys
from pathlib import Path

import numpy as np
import pytest

import magfit
from magfit.methods.auto import REFIT_ROWS

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
heading_error_deg = importlib.import_module("_common").heading_error_deg

SCENARIOS = [(sensor, disturbance) for sensor in magfit.SENSORS for disturbance in magfit.DISTURBANCES]


def _scores(cases: list[tuple[str, str]], n: int, seeds: range) -> tuple[np.ndarray, np.ndarray]:
    """Offset errors over their one-sigma (every axis of every fit) and heading errors over theirs."""
    offsets, headings = [], []
    for index, (sensor, disturbance) in enumerate(cases):
        for seed in seeds:
            sim = magfit.scenario(sensor, disturbance).simulate(n, seed=1000 * index + seed)
            calibration = magfit.fit(sim.samples, "auto")  # a full tumble: never refused
            assert calibration.support is not None and calibration.support.verdict != "refused"
            uncertainty = calibration.diagnostics.uncertainty
            offsets.extend((calibration.offset - sim.truth.offset) / np.asarray(uncertainty.offset_sigma))
            headings.append(heading_error_deg(calibration, sim) / uncertainty.heading_sigma_deg)
    return np.abs(np.asarray(offsets)), np.asarray(headings)


def _rms(values: np.ndarray) -> float:
    return float(np.sqrt(np.mean(values**2)))


def test_the_stated_one_sigma_covers_the_error_on_the_papers_scenarios() -> None:
    # 18 fits of 2 000 samples. Measured (benchmarks/results/auto_coverage.md, 1e3): offsets 33 / 4 / 0 % beyond
    # 1 / 2 / 3 sigma (Gaussian 32 / 5 / 0.3 %), heading ratio at most 2.1. A one-sigma 1.5x short fails here.
    offsets, headings = _scores(SCENARIOS, 2_000, range(3))
    assert _rms(offsets) <= 1.3, offsets
    assert np.mean(offsets > 2.0) <= 0.12 and offsets.max() <= 4.5, offsets
    assert headings.max() <= 3.0, headings
    # Not covered by being far too wide either: the one-sigma is the fit's, not a blanket bound.
    assert _rms(offsets) >= 0.5, offsets


@pytest.mark.slow
def test_beyond_the_rows_the_refit_reads_the_one_sigma_is_that_of_the_rows_read() -> None:
    # 4 x REFIT_ROWS samples: the refit reads every 4th. Stated for all the samples (as it once was), the
    # one-sigma would be 2x short where the noise dominates: RMS error over one-sigma near 2.
    offsets, headings = _scores([("mpu9250", "steel"), ("ellipse2a", "steel")], 4 * REFIT_ROWS, range(3))
    assert _rms(offsets) <= 1.4, offsets
    assert offsets.max() <= 4.0 and headings.max() <= 3.0, (offsets, headings)
    assert _rms(offsets) >= 0.4, offsets


def test_a_distortion_the_chosen_model_leaves_out_is_in_the_offset_one_sigma_too() -> None:
    # The paper's smartphone tilted within ±30°: auto returns the sphere (weak), the full model showing soft iron
    # it does not determine. Its offset along z was 20-26 one-sigmas from the truth when only the heading
    # one-sigma held the left-out distortion (benchmarks/results/auto_coverage.md, before).
    scenario = magfit.scenario("mpu9250", "smartphone")
    for seed in range(2500, 2503):
        sim = scenario.simulate(1_000, seed=seed, orientations="restricted", max_tilt_deg=30.0)
        calibration = magfit.fit(sim.samples, "auto")
        assert calibration.auto.model == "sphere" and calibration.auto.omitted is not None
        assert calibration.support.verdict == "weak" and "model_inadequate" in calibration.support.codes
        sigma = np.asarray(calibration.diagnostics.uncertainty.offset_sigma)
        error = np.abs(calibration.offset - sim.truth.offset)
        assert np.all(error <= 3.0 * sigma), (seed, error, sigma)
        # magfit.diagnose of the calibration states the same one-sigma.
        again = magfit.diagnose(calibration, sim.samples)
        np.testing.assert_allclose(again.uncertainty.offset_sigma, sigma, rtol=1e-9)


def test_a_diag_sensor_on_many_clean_samples_is_supported_not_a_missed_distortion() -> None:
    # The paper's undisturbed MPU-9250 (axis-aligned soft iron) on 100 000 samples of a tumble: the F test of the
    # diag model against the full one counted every sample for sums over 2 000 rows, and found a distortion
    # (p 1e-6) on 8 of 8 such trials at 1e5 and 1e6 (benchmarks/results/auto_coverage.md, before).
    for seed in (200, 201):
        sim = magfit.scenario("mpu9250", "none").simulate(100_000, seed=seed)
        calibration = magfit.fit(sim.samples, "auto")
        assert calibration.auto.model == "diag"
        assert calibration.support.verdict == "supported", calibration.support.codes
        uncertainty = calibration.diagnostics.uncertainty
        error = np.abs(calibration.offset - sim.truth.offset)
        assert np.all(error <= 4.0 * np.asarray(uncertainty.offset_sigma)), (error, uncertainty.offset_sigma)
        assert heading_error_deg(calibration, sim) <= 3.0 * uncertainty.heading_sigma_deg
