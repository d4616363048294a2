"""The fit's passes over the samples, made once: the same statistics, clipping and verdict as before."""

from __future__ import annotations

import numpy as np
import pytest

import magfit
from magfit.diagnostics import diagnose as diagnose_samples
from magfit.methods.core import refitter
from magfit.saturation import Clipping, find_clipped, statistics_and_clipping
from magfit.statistics import Statistics, design_matrix
from test_speed_clipping import sensor_samples


@pytest.mark.parametrize("chunk", [1, 7, 1000, 8192, 1 << 16])
def test_scatter_is_the_design_matrix_product_at_every_chunk_size(chunk: int) -> None:
    """The oracle: the (n, 10) design matrix of eq. (4) in the canonical frame, ``DᵀD`` in one NumPy line."""
    rng = np.random.default_rng(chunk)
    samples = rng.normal(size=(20_000, 3)) * [300.0, 250.0, 200.0] + [1e4, -5e3, 40.0]
    samples[:3000] = samples[0] + rng.normal(size=(3000, 3))  # a still start: the frame moves later on
    statistics = Statistics(chunk).update(samples)
    z = (samples - statistics.centre) / statistics.scale
    design = design_matrix(z)
    expected = design.T @ design
    np.testing.assert_allclose(statistics.scatter, expected, rtol=1e-11, atol=1e-9 * np.abs(expected).max())
    np.testing.assert_array_equal(statistics.minimum, samples.min(axis=0))
    np.testing.assert_array_equal(statistics.maximum, samples.max(axis=0))


def test_nothing_clipped_costs_no_mask() -> None:
    none = Clipping.none(10_000_000)
    assert none.n_clipped == 0 and none.n_kept == 10_000_000 and none.clipped.strides == (0,)
    assert not none.clipped[[0, -1]].any()


def test_the_fit_passes_its_clipping_and_the_verdict_is_the_same() -> None:
    """Diagnosed with the fit's clipping (nothing clipped) or searching again: the same report."""
    sim = magfit.scenario("mpu9250", "steel").simulate(50_000, seed=5)
    calibration = magfit.fit(sim.samples, "ellipsoid", diagnostics=False)
    refit = refitter("ellipsoid", {})
    given = diagnose_samples(calibration, sim.samples, refit=refit, clipping=Clipping.none(50_000))
    searched = diagnose_samples(calibration, sim.samples, refit=refit)
    assert given.support == searched.support and given.support is not None
    assert given.support.verdict == "supported"
    assert given.uncertainty.offset_sigma == searched.uncertainty.offset_sigma
    assert given.notes == searched.notes


def test_clipped_rows_are_still_left_out_of_the_diagnostics() -> None:
    """Samples clipped at a range: the fit records the ends, and its diagnostics leave those rows out too."""
    sim = magfit.scenario("mpu9250", "steel").simulate(20_000, seed=6)
    counts = np.round(sim.samples)
    limit = np.round(0.9 * np.abs(counts).max(axis=0))
    clipped = np.clip(counts, -limit, limit)
    found = find_clipped(clipped)
    assert found.n_clipped > 0
    calibration = magfit.fit(clipped, "ellipsoid", allow_undetermined=True)
    assert calibration.details["saturation"]["n_clipped"] == found.n_clipped
    notes = calibration.diagnostics.notes
    assert any(f"{found.n_clipped} samples clipped" in note for note in notes), notes
    truth = sim.truth
    # Without the clipped rows the fit keeps to the truth: within 4 stated one-sigmas (or 0.5 % of the field).
    error = np.abs(np.asarray(calibration.offset) - np.asarray(truth.offset))
    sigma = np.asarray(calibration.diagnostics.uncertainty.offset_sigma)
    assert np.all(error < np.maximum(4 * sigma, 0.005 * truth.field_strength)), (error, sigma)


@pytest.mark.parametrize("seed", range(30))
def test_one_pass_gives_the_statistics_and_the_clipping_of_the_two_passes(seed: int) -> None:
    """statistics_and_clipping against Statistics.from_samples and find_clipped, on clipped and clean sensors."""
    samples = sensor_samples(seed, (5, 300, 5_000, 20_000, 70_000))
    statistics, clipping = statistics_and_clipping(samples)
    separate = find_clipped(samples)
    assert clipping.ends == separate.ends and clipping.n_clipped == separate.n_clipped
    np.testing.assert_array_equal(clipping.clipped, separate.clipped)
    expected = Statistics.from_samples(samples)
    assert statistics.n == expected.n
    np.testing.assert_array_equal(statistics.scatter, expected.scatter)
    np.testing.assert_array_equal(statistics.minimum, expected.minimum)


def test_one_pass_refuses_what_the_statistics_refuse() -> None:
    samples = np.random.default_rng(1).normal(size=(30_000, 3))
    samples[20_001, 1] = np.nan
    with pytest.raises(magfit.SampleError, match="row 20001"):
        statistics_and_clipping(samples)
