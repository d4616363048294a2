"""Diagnostics against ground truth: coverage of known sample sets, the one-sigma offset against the
spread over repeated simulations, the weak direction of restricted attitudes, and the JSON round trip."""

from __future__ import annotations

import json

import numpy as np
import pytest

import magfit
from magfit.diagnostics import Diagnostics, diagnose, weighted_even_subsample
from magfit.diagnostics.coverage import coverage, partition


def _unit_vectors(n: int, seed: int) -> np.ndarray:
    vectors = np.random.default_rng(seed).normal(size=(n, 3))
    return vectors / np.linalg.norm(vectors, axis=1)[:, None]


def test_partition_has_equal_area_cells() -> None:
    cells = partition(100)
    assert cells.cells_per_zone.sum() == 100
    # Every cell centre lies in its own cell.
    np.testing.assert_array_equal(cells.cell(cells.centres()), np.arange(100))
    # Uniform directions fill the cells equally: 200 000 draws, 2000 per cell, Poisson sd ≈ 45.
    counts = np.bincount(cells.cell(_unit_vectors(200_000, 0)), minlength=100)
    assert np.all(np.abs(counts - 2000) < 5 * np.sqrt(2000))


def test_coverage_of_full_tumble_is_complete() -> None:
    sim = magfit.scenario("mpu9250", "steel").simulate(3000, seed=3)
    cal = magfit.fit(sim.samples, "ellipsoid")
    report = cal.diagnostics
    assert report is not None and report.coverage is not None
    assert report.coverage.share >= 0.97
    assert report.coverage.missing == ()


def test_coverage_of_half_sphere_is_half_and_names_the_missing_side() -> None:
    # Field directions only with z < 0: the +z half of the sphere is never seen.
    directions = _unit_vectors(4000, 1)
    directions[:, 2] = -np.abs(directions[:, 2])
    report = coverage(directions)
    assert 0.45 <= report.share <= 0.55
    assert report.missing == ("+z",)
    text = " ".join(report.summary())
    assert "No samples with the field along the sensor +z axis" in text


def test_offset_sigma_matches_spread_over_repeated_simulations() -> None:
    scenario = magfit.scenario("ellipse2a", "smartphone")
    offsets, sigmas, headings = [], [], []
    for seed in range(40):
        sim = scenario.simulate(1000, seed=seed)
        cal = magfit.fit(sim.samples, "ellipsoid", diagnostics=False)
        offsets.append(cal.offset)
        if seed < 5:
            uncertainty = diagnose(cal, sim.samples, held_out=False).uncertainty
            assert uncertainty is not None and uncertainty.offset_sigma is not None
            sigmas.append(uncertainty.offset_sigma)
            headings.append(uncertainty.heading_sigma_deg)
    spread = np.std(np.array(offsets), axis=0, ddof=1)
    predicted = np.mean(np.array(sigmas), axis=0)
    # 40 draws estimate a standard deviation within about ±25 % (2 sd): a factor 1.5 is the brief's bar.
    ratio = predicted / spread
    assert np.all((ratio > 1 / 1.5) & (ratio < 1.5)), (predicted, spread)
    assert all(0 < h < 1.0 for h in headings)


def test_restricted_attitudes_name_the_vertical_direction() -> None:
    sim = magfit.scenario("mpu9250", "smartphone").simulate(3000, seed=4, orientations="restricted")
    # ±20° of tilt: the full model's vertical scale and offset trade off, the level heading is pinned (±0.5°)
    report = magfit.fit(sim.samples, "als").diagnostics
    assert report is not None and report.support is not None and report.support.verdict == "weak"
    assert any("do not determine the scale along z together with the offset" in w for w in report.warnings)
    assert report is not None and report.observability is not None and report.coverage is not None
    descriptions = [w.description for w in report.observability.weak]
    assert any("offset along z" in d and "scale along z" in d for d in descriptions), descriptions
    assert "−z" in report.coverage.missing
    assert report.coverage.share < 0.5
    assert any("cover only" in w for w in report.warnings)


def test_full_tumble_is_well_observed_and_goodness_matches_the_noise() -> None:
    scenario = magfit.scenario("ellipse2a", "none")
    sim = scenario.simulate(4000, seed=5)
    report = magfit.fit(sim.samples, "ellipsoid").diagnostics
    assert report is not None and report.observability is not None and report.goodness is not None
    assert report.observability.weak == ()
    assert report.observability.condition is not None and report.observability.condition < 5
    # Sphere distance std ≈ noise / field strength (0.0108) on fitted and on held-out samples.
    assert report.goodness.fitted.std == pytest.approx(0.0108, rel=0.1)
    assert report.goodness.held_out is not None and report.goodness.folds == 5
    assert report.goodness.fitted.std <= report.goodness.held_out.std <= 1.1 * report.goodness.fitted.std
    assert report.ok


def test_diagnostics_round_trip_and_summary() -> None:
    sim = magfit.scenario("mpu9250", "none").simulate(1500, seed=6, orientations="restricted")
    cal = magfit.fit(sim.samples, "sphere")
    report = cal.diagnostics
    assert isinstance(report, Diagnostics)
    assert Diagnostics.from_dict(json.loads(json.dumps(report.to_dict()))) == report
    assert magfit.Calibration.from_json(cal.to_json()).diagnostics == report
    lines = report.summary()
    assert lines and all(isinstance(line, str) and line for line in lines)
    assert lines[0].startswith("WARNING")
    with pytest.raises(magfit.MagfitError, match="schema version"):
        Diagnostics.from_dict({**report.to_dict(), "schema_version": 99})


def test_fit_can_skip_diagnostics_and_statistics_get_a_note() -> None:
    sim = magfit.simulate(500, hard_iron=[1.0, 2.0, 3.0], noise=0.01, seed=7)
    assert "diagnostics" not in magfit.fit(sim.samples, "sphere", diagnostics=False).details
    from_statistics = magfit.fit(magfit.Statistics.from_samples(sim.samples), "sphere").diagnostics
    assert from_statistics is not None
    assert from_statistics.coverage is None and from_statistics.n_samples == 500
    assert "need the samples" in from_statistics.notes[0]


def test_even_subsample_caps_weights_and_evens_out_directions() -> None:
    # 90 % of the directions crowd into the +z cap; the subsample must even them out.
    directions = _unit_vectors(60_000, 8)
    crowd = np.zeros((540_000, 3))
    crowd[:, 2] = 1.0
    crowd[:, :2] = np.random.default_rng(9).normal(0, 0.05, (540_000, 2))
    everything = np.vstack([directions, crowd])
    indices, weights = weighted_even_subsample(everything, cap=20_000)
    assert indices.size <= 20_000
    assert np.all(np.diff(indices) > 0)
    assert weights.sum() == pytest.approx(everything.shape[0])
    share_crowd = np.mean(indices >= 60_000)
    assert share_crowd < 0.2  # the crowd is 90 % of the input
    assert coverage(everything[indices]).share == 1.0


def test_real_recordings_get_a_diagnosis_not_numbers(real_data_dir) -> None:
    mag = np.loadtxt(real_data_dir / "android_phone_kritiksoman" / "data_mag.txt", delimiter=",", skiprows=1)
    android = mag[:, :3]
    planar = np.loadtxt(real_data_dir / "hmc5883l_nliaudat_partial" / "mag_out_sample.txt", delimiter=",")
    for samples in (android, planar):
        with pytest.raises(magfit.CalibrationError, match="not an ellipsoid|do not outline"):
            magfit.fit(samples, "ellipsoid")
    # The planar log: a diag fit is refused, naming the axis the sensor only turned about.
    with pytest.raises(magfit.CalibrationError, match="only turned about z"):
        magfit.fit(planar, "diag")
    # diagnose() itself still reads the geometry of the planar log through a sphere about its centre.
    centre = planar.mean(axis=0)
    radius = float(np.median(np.linalg.norm(planar - centre, axis=1)))
    report = diagnose(magfit.Calibration("guess", centre, np.eye(3), radius), planar, held_out=False)
    assert report.coverage is not None and report.coverage.share < 0.6
    assert not report.ok


def test_consistency_exposes_a_biased_fit_and_clears_the_maximum_likelihood_one() -> None:
    # Restricted attitudes and 2.4 % noise: the algebraic ellipsoid drifts far along the vertical (bias), the
    # linearised uncertainty at its own solution looks small; the comparison with the maximum-likelihood fit
    # of the same model must say so. auto returns that maximum-likelihood fit: consistent by construction.
    sim = magfit.scenario("mpu9250", "smartphone").simulate(3000, seed=2, orientations="restricted")
    with pytest.raises(magfit.CalibrationError, match="biased .* in offset away from the maximum-likelihood"):
        magfit.fit(sim.samples, "ellipsoid")
    biased = magfit.fit(sim.samples, "ellipsoid", allow_undetermined=True).diagnostics
    assert biased is not None and biased.consistency is not None
    assert not biased.consistency.consistent
    assert abs(biased.consistency.offset_difference[2]) > 50  # counts; the truth is ~200 counts away
    assert any("biased" in warning for warning in biased.warnings)
    # auto returns the maximum-likelihood fit of the model it chose: there is nothing to compare it with.
    auto = magfit.fit(sim.samples, "auto").diagnostics
    assert auto is not None and auto.consistency is None and auto.support is not None
    assert not any("biased" in warning for warning in auto.warnings)


def test_a_subsample_can_stand_for_the_whole_recording() -> None:
    sim = magfit.scenario("ellipse2a", "none").simulate(8000, seed=12)
    cal = magfit.fit(sim.samples, "ellipsoid", diagnostics=False)
    every_fourth = sim.samples[::4]
    alone = diagnose(cal, every_fourth, held_out=False)
    scaled = diagnose(cal, every_fourth, held_out=False, represents=8000)
    assert alone.uncertainty is not None and scaled.uncertainty is not None
    assert alone.uncertainty.offset_sigma is not None and scaled.uncertainty.offset_sigma is not None
    # Four times the samples: half the one-sigma (independent samples).
    np.testing.assert_allclose(np.array(scaled.uncertainty.offset_sigma) * 2, alone.uncertainty.offset_sigma, rtol=0.01)
    assert scaled.n_samples == 8000
    with pytest.raises(magfit.SampleError, match="fewer than"):
        diagnose(cal, every_fourth, represents=10)


def test_robust_calibration_diagnosed_on_a_subsample_leaves_the_spikes_out() -> None:
    sim = magfit.scenario("ellipse2a", "none").simulate(4000, seed=13)
    spiked = sim.samples.copy()
    centre = spiked.mean(axis=0)
    spiked[::50] = centre + 3.0 * (spiked[::50] - centre)  # 2 % spikes
    cal = magfit.fit(spiked, "robust", diagnostics=False)
    report = diagnose(cal, spiked[::2], held_out=False)  # indices no longer match: the rule is applied again
    assert report.goodness is not None
    assert report.goodness.fitted.std == pytest.approx(0.0108, rel=0.15)
    assert any("beyond the robust fit's threshold" in note for note in report.notes)


def test_affine_design_transform_matches_the_design_matrix() -> None:
    from magfit.diagnostics.moments import affine_design_transform
    from magfit.statistics import design_matrix

    rng = np.random.default_rng(14)
    gain, shift, z = rng.normal(size=(3, 3)), rng.normal(size=3), rng.normal(size=(20, 3))
    expected = design_matrix(z @ gain.T + shift)
    np.testing.assert_allclose(design_matrix(z) @ affine_design_transform(gain, shift).T, expected, atol=1e-12)


def test_statistics_fit_names_the_weak_direction_without_numbers() -> None:
    sim = magfit.scenario("mpu9250", "smartphone").simulate(3000, seed=3, orientations="restricted")
    statistics = magfit.Statistics.from_samples(sim.samples)
    with pytest.raises(magfit.CalibrationError, match="do not determine .*offset along z"):
        magfit.fit(statistics, "als")
    report = magfit.fit(statistics, "als", allow_undetermined=True).diagnostics
    assert report is not None and report.observability is not None and report.uncertainty is None
    assert any("offset along z" in w.description and not w.determined for w in report.observability.weak)
    assert all(w.sigma is None for w in report.observability.weak)
    assert report.warnings and "do not determine" in report.warnings[0]
    full = magfit.fit(
        magfit.Statistics.from_samples(magfit.scenario("mpu9250", "steel").simulate(3000, seed=3).samples)
    )
    assert full.diagnostics is not None and full.diagnostics.observability is not None
    assert full.diagnostics.observability.weak == () and full.diagnostics.ok


# ---------------------------------------------------------------------- a restricted model against the full one


def test_the_f_test_p_value_is_the_f_distributions_survival_function() -> None:
    # Oracle: scipy.stats (which the library does not import: it pulls in scipy.optimize) on the same numbers.
    from scipy.special import betainc
    from scipy.stats import f

    for statistic, extra, dof in [(3.76, 5, 300), (0.5, 3, 50), (20.0, 5, 1000), (1.0, 6, 9)]:
        ours = betainc(dof / 2.0, extra / 2.0, dof / (dof + extra * statistic))
        assert ours == pytest.approx(f.sf(statistic, extra, dof), rel=1e-9)


def test_a_sphere_on_soft_iron_is_compared_with_the_full_ellipsoid_and_a_sphere_on_a_sphere_is_not_flagged() -> None:
    from magfit.diagnostics.uncertainty import compare_with_full

    def comparison(soft_iron: np.ndarray) -> object:
        sim = magfit.simulate(3000, soft_iron=soft_iron, hard_iron=[0.2, -0.1, 0.3], noise=0.01, seed=8)
        calibration = magfit.fit(sim.samples, "sphere", allow_undetermined=True)
        weights = np.ones(3000)
        report = diagnose(calibration, sim.samples, held_out=False)
        assert report.uncertainty is not None
        return compare_with_full(sim.samples, weights, "sphere", calibration, report.uncertainty, 60.0, sim.samples)

    clean = comparison(np.eye(3))
    assert clean is not None and not clean.significant and clean.rss_ratio < 1.01  # no soft iron: nothing to miss
    soft = comparison(np.diag([1.1, 1.0, 0.9]))
    assert soft is not None and soft.significant and soft.rss_ratio > 2.0
    assert soft.full_heading_sigma_deg < 0.5 and soft.heading_difference_deg > 1.0  # the full fit pins the heading


def test_covering_adds_the_known_biases_to_the_heading_one_sigma_in_quadrature() -> None:
    from magfit.diagnostics.uncertainty import ModelComparison, covering
    from magfit.findings import Consistency, Uncertainty

    stated = Uncertainty((0.01,) * 3, (0.01,) * 3, 0.01, 0.3, 0.4, 60.0, 0.01, 1000, 900.0)
    missing = ModelComparison("sphere", 2.0, 50.0, 1e-9, 3.0, 4.0)  # heading cost √(3² + 4²) = 5
    biased = Consistency((0.0, 0.0, 0.0), 5.0, 12.0, False)
    widened = covering(stated, missing, biased)
    assert widened.heading_sigma_deg == pytest.approx(np.sqrt(0.3**2 + 5.0**2 + 12.0**2))
    assert widened.heading_sigma_max_deg == pytest.approx(np.sqrt(0.4**2 + 25.0 + 144.0))
    assert widened.offset_sigma == stated.offset_sigma  # only the heading
    not_significant = ModelComparison("sphere", 1.0, 0.1, 0.9, 0.5, 4.0)  # within 2 of the stated one-sigmas
    assert covering(stated, not_significant, None) == stated
    # Not rejected, but 3° from the full fit where ±0.3° is stated: the test had no power to tell, so counted.
    unruled = ModelComparison("sphere", 1.0, 0.1, 0.9, 3.0, 4.0)
    assert covering(stated, unruled, None).heading_sigma_deg == pytest.approx(np.hypot(0.3, 3.0))


def test_clipped_rows_are_named_beside_a_refusal() -> None:
    # A vehicle tilted ±5° whose x axis also clipped: refused for what the tilts leave undetermined, and the
    # clipping named beside it (the rows it cut are the directions missing).
    sim = magfit.simulate(
        2000, orientations="restricted", max_tilt_deg=5, hard_iron=[1.2, 0.0, 0.0], noise=0.01, seed=2
    )
    samples = np.clip(sim.samples, -1.5, 1.5)
    assert np.any(sim.samples[:, 0] > 1.5)
    with pytest.raises(magfit.CalibrationError) as caught:
        magfit.fit(samples, "als")
    assert "saturated" in caught.value.codes and "undetermined" in caught.value.codes, caught.value.codes
