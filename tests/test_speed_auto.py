"""``auto``'s candidates and refit share the fit's passes over the samples: the same fits as separate passes."""

from __future__ import annotations

import importlib
from dataclasses import replace

import numpy as np
import pytest

import magfit
from magfit.methods.core import estimate
from magfit.methods.registry import FitInput
from magfit.methods.robust import fit_model
from magfit.saturation import find_clipped
from magfit.statistics import Statistics

auto_module = importlib.import_module("magfit.methods.auto")
core_module = importlib.import_module("magfit.methods.core")


def _counting_searches(monkeypatch: pytest.MonkeyPatch, n: int) -> list[int]:
    """Every search for clipped rows over ``n`` rows (the whole recording), wherever it is made."""
    searched: list[int] = []

    def counted(samples: np.ndarray) -> object:
        if samples.shape[0] == n:
            searched.append(n)
        return find_clipped(samples)

    monkeypatch.setattr(core_module, "find_clipped", counted)
    monkeypatch.setattr(auto_module, "find_clipped", counted)
    return searched


def test_the_candidates_read_the_samples_for_clipped_rows_no_more(monkeypatch: pytest.MonkeyPatch) -> None:
    """The fit's statistics' pass found the clipped rows: none of the three candidates searches again."""
    sim = magfit.scenario("mpu9250", "steel").simulate(30_000, seed=21)
    searched = _counting_searches(monkeypatch, 30_000)
    calibration = magfit.fit(sim.samples, "auto")
    assert searched == []
    assert calibration.auto is not None and calibration.auto.model == "full"
    error = np.abs(np.asarray(calibration.offset) - np.asarray(sim.truth.offset))
    sigma = np.asarray(calibration.diagnostics.uncertainty.offset_sigma)
    assert np.all(error < 5 * sigma), (error, sigma)


def test_called_without_the_fits_clipping_auto_searches_once(monkeypatch: pytest.MonkeyPatch) -> None:
    """``estimate`` on bare statistics and samples (no clipping found yet): one search for all the candidates."""
    sim = magfit.scenario("mpu9250", "steel").simulate(30_000, seed=22)
    searched = _counting_searches(monkeypatch, 30_000)
    estimate(FitInput(Statistics.from_samples(sim.samples), sim.samples), "auto")
    assert len(searched) == 2  # estimate's own (without_clipped) and auto's, shared by the candidates and ml


@pytest.mark.parametrize(("scenario", "model"), [("none", "sphere"), ("none", "diag"), ("steel", "full")])
def test_a_candidate_with_the_shared_clipping_is_the_models_own_fit(scenario: str, model: str) -> None:
    """A candidate fitted with the fit's statistics and clipping equals ``fit_model`` searching on its own."""
    sim = magfit.scenario("mpu9250", scenario).simulate(20_000, seed=23)
    counts = np.round(sim.samples)
    limit = np.round(0.95 * np.abs(counts).max(axis=0))
    clipped = np.clip(counts, -limit, limit)
    found = find_clipped(clipped)
    assert found.n_clipped > 0
    shared = auto_module._fit_candidate(model, FitInput(Statistics.from_samples(clipped), clipped, found), False)
    own = fit_model(model, clipped, Statistics.from_samples(clipped))
    np.testing.assert_array_equal(shared.offset, own.offset)
    np.testing.assert_array_equal(shared.matrix, own.matrix)
    assert shared.details["saturation"] == own.details["saturation"]
    # Without the clipped rows the fit keeps near the truth.
    error = np.max(np.abs(np.asarray(shared.offset) - np.asarray(sim.truth.offset)))
    assert error < 0.01 * sim.truth.field_strength, error


def test_the_refit_reads_what_it_is_given_only_when_it_reads_every_row() -> None:
    """``refine_chosen`` given the samples' statistics and clipping equals it computing them."""
    sim = magfit.scenario("mpu9250", "steel").simulate(8_000, seed=24)
    start = fit_model("full", sim.samples)
    data = FitInput(Statistics.from_samples(sim.samples), sim.samples, find_clipped(sim.samples))
    given = auto_module.refine_chosen("full", start, sim.samples, data)
    computed = auto_module.refine_chosen("full", start, sim.samples)
    np.testing.assert_array_equal(given.offset, computed.offset)
    np.testing.assert_array_equal(given.matrix, computed.matrix)
    assert np.max(np.abs(np.asarray(given.offset) - np.asarray(sim.truth.offset))) < 0.01 * sim.truth.field_strength


def test_auto_on_more_samples_than_its_refit_reads_states_the_uncertainty_of_the_rows_it_read() -> None:
    """``auto``'s refit reads a regular stride of at most ``REFIT_ROWS``: its one-sigma is that of those rows.

    Stated for every sample given, the offset one-sigma at 1e6 clean samples was 1.5x short of the error (RMS
    of error/sigma over 30 offsets, 10 seeds; 0.97 for ``ml`` on every sample): a stride of 2 here.
    """
    n = 2 * auto_module.REFIT_ROWS + 2
    sim = magfit.scenario("mpu9250", "steel").simulate(n, seed=26)
    calibration = magfit.fit(sim.samples, "auto")
    read = sim.samples[::3]  # ⌈n / REFIT_ROWS⌉ = 3
    report = calibration.diagnostics
    assert any(f"regular stride of {read.shape[0]} of the {n} samples" in note for note in report.notes), report.notes
    # The same statement as diagnosing the rows the fit read, as the command line does when it streams them.
    alone = magfit.diagnose(replace(calibration, details={}), read)
    np.testing.assert_allclose(report.uncertainty.offset_sigma, alone.uncertainty.offset_sigma, rtol=1e-9)
    error = np.abs(np.asarray(calibration.offset) - np.asarray(sim.truth.offset))
    assert np.all(error < 4 * np.asarray(report.uncertainty.offset_sigma)), (error, report.uncertainty.offset_sigma)
    assert calibration.support is not None and calibration.support.verdict != "refused"
