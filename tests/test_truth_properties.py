"""Every returned calibration is within its stated uncertainty of the simulated truth, or refused.

The kinds of data the second fuzz campaign found weak-but-wrong or supported-but-wrong fits on
(``benchmarks/campaign.py``: clipped at full scale, half a sphere with soft iron, clusters of attitudes,
tilt cones, coarse integer counts, level flight; level turns with strong soft iron, tilt within ±5-10°, flight
with a drifting field and eddy currents, caps of 10 % of the directions), each with a known truth. For every
magnitude-only method, a fit that comes back "supported" or "weak" must have a true level-heading error within
``campaign.COVER`` (3) times its stated heading one-sigma (or below ``campaign.FLOOR_DEG``, 0.1°).
The seed of a failing trial is in the assertion message (and hypothesis prints how to replay it).
"""

from __future__ import annotations

import importlib
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import magfit
from magfit import CalibrationError

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
campaign = importlib.import_module("campaign")
fleet = importlib.import_module("fleet")
accuracy = importlib.import_module("accuracy")


def _check(kind: str, seed: int, methods: tuple[str, ...] = campaign.METHODS) -> None:
    sim, samples = campaign.trial(kind, seed)
    for method in methods:
        outcome = campaign.score(kind, seed, method, sim, samples)
        assert not outcome.exceeds, (
            f"{kind}, seed {seed}, {method}: {outcome.verdict} {outcome.codes}, true heading error "
            f"{outcome.error_deg:.3g}° against a stated one-sigma of ±{outcome.stated_deg}° "
            f"(rerun: python benchmarks/campaign.py --kinds '{kind}' --methods {method} --seed {seed} --trials 1)"
        )


@pytest.mark.parametrize(("kind", "seed"), [("hemisphere", 0), ("saturated", 1)])
def test_the_campaign_reproducers_are_refused_or_covered(kind: str, seed: int) -> None:
    # Before: a sphere on half a sphere with soft iron came back weak 5.8° off stating ±0.47°; diag and sphere on
    # a clipped sensor 4.8-6.8° off stating ±0.2-0.4°.
    _check(kind, seed, ("sphere", "diag", "minmax", "ellipsoid"))


@pytest.mark.parametrize(("kind", "seed"), [("drifting flight", 5), ("level turns", 0), ("shallow tilt", 1)])
@pytest.mark.slow
def test_the_new_campaign_kinds_are_refused_or_covered_by_auto_and_sphere(kind: str, seed: int) -> None:
    # Before: on a flight whose field drifts 1.8 % the sphere (and auto's sphere) came back weak 1.9° off stating
    # ±0.39°: the F test against the full model had some hundred effective samples and did not reject it.
    _check(kind, seed, ("auto", "sphere"))


@pytest.mark.parametrize("seed", [1])
@pytest.mark.slow
def test_a_full_fit_that_follows_a_drifting_field_is_refused_or_covered(seed: int) -> None:
    # Before: als, ml and robust on a flight whose field drifted came back weak (restricted_attitude) 9.3-9.9° off
    # stating ±2.7-2.9°: the combination the samples do not determine followed the drift.
    _check("drifting flight", seed, ("als", "ml", "robust"))


def _covered_or_refused(sim: magfit.Simulation, samples: np.ndarray, method: str = "auto") -> str:
    """The verdict of ``method`` on ``samples``; when returned, its true heading error within COVER stated sigmas."""
    try:
        calibration = magfit.fit(samples, method=method)
    except CalibrationError as error:
        return "refused:" + ",".join(error.codes)
    report = calibration.diagnostics
    assert report is not None and report.uncertainty is not None
    stated = report.uncertainty.heading_sigma_deg
    error = campaign.heading_error_deg(calibration, sim)
    assert stated is not None and (error <= campaign.COVER * stated or error <= campaign.FLOOR_DEG), (error, stated)
    return str(calibration.support.verdict)


@pytest.mark.parametrize("seed", [200582])
def test_level_turns_with_strong_horizontal_soft_iron_state_the_soft_iron(seed: int) -> None:
    # Before: auto returned the sphere, weak, ±0.47° stated, 6.2° true: samples in a plane flatten every richer
    # ellipsoid, so nothing witnessed the 37 % of soft iron the ellipse in their plane shows.
    sim = magfit.simulate(
        5000, soft_iron=np.diag([1.004, 1.367, 0.927]), hard_iron=[2.942, -0.938, -2.973], inclination_deg=-39.2,
        noise=0.01, orientations="yaw", seed=seed,
    )  # fmt: skip
    verdict = _covered_or_refused(sim, sim.samples)
    if verdict == "weak":
        codes = magfit.fit(sim.samples, method="auto").support.to_dict()["weakness_codes"]
        assert "model_inadequate" in codes


@pytest.mark.parametrize("seed", [901])
def test_a_useless_heading_bound_is_refused(seed: int) -> None:
    # Before: auto on a cap of 10 % of the directions returned the sphere, weak, stating ±50°.
    samples = fleet.partial_flight(2000, np.array([0.0, 1.0, 0.0]), 0.1, 2.5, seed)
    with pytest.raises(CalibrationError) as caught:
        magfit.fit(samples, method="auto")
    assert "undetermined" in caught.value.codes


def test_the_verdict_refuses_beyond_the_useless_bound() -> None:
    from magfit.diagnostics.verdict import USELESS_BOUND_DEG
    from magfit.methods import auto

    assert auto.USELESS_BOUND_DEG is USELESS_BOUND_DEG  # one bound, the verdict's


def _flight(seed: int, **options: object) -> magfit.Simulation:
    return magfit.simulate(
        4000, soft_iron=np.eye(3), hard_iron=[0.2, -0.1, 0.3], noise=0.005, orientations="flight", seed=seed,
        **options,  # type: ignore[arg-type]
    )  # fmt: skip


@pytest.mark.parametrize(
    ("name", "seed"), [("flight ±60°, drift 2 %", 200100), ("aircraft, eddy currents", 200210), ("tilt ±10°", 101083)]
)
def test_the_flight_reproducers_are_refused_or_covered(name: str, seed: int) -> None:
    if name.startswith("flight"):
        sim = _flight(seed, max_tilt_deg=60.0, field_drift=0.02)
    elif name.startswith("aircraft"):
        soft_iron, hard_iron, eddy = accuracy.aircraft_distortion(np.random.default_rng(seed))
        sim = magfit.simulate(
            10_000, soft_iron=soft_iron, hard_iron=hard_iron, noise=0.005, orientations="flight", max_tilt_deg=20.0,
            field_drift=0.005, eddy_current=eddy, seed=seed,
        )  # fmt: skip
    else:
        sim = magfit.simulate(
            1500, soft_iron=np.diag([1.05, 0.95, 1.0]), hard_iron=[0.3, -0.2, 0.1], noise=0.01,
            orientations="restricted", max_tilt_deg=10.0, seed=seed,
        )  # fmt: skip
    _covered_or_refused(sim, sim.samples)


@pytest.mark.slow
@pytest.mark.parametrize("kind", list(campaign.KINDS))
# derandomize: the same seeds on every run, so that CI's verdict does not depend on the draw; a counterexample a
# random run finds is kept as a test of its own (below), not left to chance.
@settings(
    max_examples=2, deadline=None, print_blob=True, derandomize=True, suppress_health_check=[HealthCheck.too_slow]
)
@given(seed=st.integers(100, 10_000))
def test_returned_calibrations_cover_their_true_heading_error(kind: str, seed: int) -> None:
    _check(kind, seed)


@pytest.mark.parametrize(("kind", "seed"), [("flight", 1564), ("drifting flight", 5)])
def test_a_full_fit_that_follows_a_drifting_field_states_it(kind: str, seed: int) -> None:
    # Before: on a level flight whose field drifted 0.25 % (seed 1564, found by a random run of the property
    # below) als came back weak 1.98° off stating ±0.48° (4.2x); on a drifting flight (seed 5) als and ml 3.6-3.9°
    # off stating ±1.2° (3.1-3.3x). The full ellipsoid bent its soft iron to follow the drift; the fit that allows
    # for a field changing along the recording is 0.1-0.9° off, and the difference is now stated.
    sim, samples = campaign.trial(kind, seed)
    for method in ("als", "ml"):
        outcome = campaign.score(kind, seed, method, sim, samples)
        assert not outcome.exceeds, outcome
        assert outcome.verdict == "refused" or "field_drift" in outcome.codes, outcome


@pytest.mark.parametrize(("seed", "method"), [(1062, "als"), (1062, "robust"), (1046, "ellipsoid")])
def test_flights_a_random_run_found_are_covered(seed: int, method: str) -> None:
    # Found by running the campaign's flight kind over fresh seeds: seed 1062, als and robust 1.4° off stating
    # ±0.36-0.47° (a drift 0.70° of heading away, under the 2 one-sigmas that name it); seed 1046, the algebraic
    # ellipsoid 0.50° off stating ±0.16° (0.20° from its model's maximum-likelihood fit, within 3 one-sigmas of
    # offset). Both differences are now in the heading one-sigma.
    _check("flight", seed, (method,))


@pytest.mark.xfail(
    reason="known gap, found by the campaign on fresh seeds (100-111): a drifting flight whose eddy currents, not a "
    "drift, move the full fit (seed 106): als, robust, ml and auto 1.1° off stating ±0.25-0.28° (3.8-4.6x); the drift "
    "model does not hold an eddy-current field, and one that adds its nine terms masks the drift on other flights",
    strict=True,
)
def test_a_drifting_flight_whose_eddy_currents_move_the_full_fit() -> None:
    _check("drifting flight", 106, ("ml",))


def test_a_drift_the_samples_do_not_show_changes_nothing() -> None:
    # The same flight without the drift: the drift model's F test does not count, nothing is widened or named.
    sim = magfit.simulate(
        4000, soft_iron=campaign.mild_soft_iron(np.random.default_rng(3), 0.05), hard_iron=[0.2, -0.1, 0.3],
        noise=0.005, orientations="flight", max_tilt_deg=25.0, seed=3,
    )  # fmt: skip
    calibration = magfit.fit(sim.samples, "ml")
    assert calibration.support is not None and "field_drift" not in calibration.support.codes
    report = calibration.diagnostics
    assert report is not None and report.uncertainty is not None and report.uncertainty.heading_sigma_deg
    assert campaign.heading_error_deg(calibration, sim) <= campaign.COVER * report.uncertainty.heading_sigma_deg


def test_a_restricted_model_whose_full_model_is_undetermined_is_refused_when_it_misses_soft_iron() -> None:
    # Before: diag on a cap of 10 % of the directions (seed 0) came back weak 16.4° off stating ±3.1°: the full
    # ellipsoid fits significantly better (F test, p = 2e-6) but the cap does not determine it, so nothing bounded
    # what the cross-coupling diag leaves out costs the heading.
    _, samples = campaign.trial("cap 10 %", 0)
    with pytest.raises(CalibrationError) as caught:
        magfit.fit(samples, "diag")
    assert "model_inadequate" in caught.value.codes


def test_the_heading_error_metric_sees_a_wrong_calibration() -> None:
    # The property cannot pass vacuously: the truth scores 0, a calibration off by a tenth of the field in
    # offset scores degrees, and that is what the campaign counts against a stated one-sigma.
    sim, _ = campaign.trial("hemisphere", 0)
    assert campaign.heading_error_deg(sim.truth, sim) < 1e-9
    wrong = magfit.Calibration("wrong", sim.truth.offset + np.array([0.1, 0.0, 0.0]), sim.truth.matrix, 1.0)
    assert campaign.heading_error_deg(wrong, sim) > 3.0
    assert campaign.Outcome("hemisphere", 0, "sphere", "weak", (), error_deg=4.0, stated_deg=1.0).exceeds
    assert not campaign.Outcome("hemisphere", 0, "sphere", "refused", (), error_deg=40.0).exceeds


@pytest.mark.slow
def test_the_campaign_runs_and_writes_its_table(tmp_path: Path) -> None:
    output = tmp_path / "campaign.md"
    status = campaign.main(["--trials", "1", "--kinds", "hemisphere,quantised", "--output", str(output)])
    text = output.read_text(encoding="utf-8")
    assert "| hemisphere |" in text and "| quantised |" in text and "accepted fits exceed" in text
    assert status == 0, text
