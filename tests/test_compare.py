"""magfit.compare (several methods on the same samples) and magfit.experiment (the paper's section V)."""

from __future__ import annotations

import itertools
import json

import numpy as np
import pytest

import magfit
from magfit.compare import PAPER_METHODS, compare, evaluate_chunks
from magfit.experiment import PAPER_DISTANCES, findings, run_experiment
from magfit.methods import FitInput, MethodSpec


@pytest.fixture(scope="module")
def steel() -> magfit.Simulation:
    """The paper's MPU-9250 with a piece of steel: strong, rotated soft iron (semi-axes 193, 714, 1362 counts)."""
    return magfit.scenario("mpu9250", "steel").simulate(4000, seed=11)


def test_compare_runs_each_method_and_scores_it_as_evaluate_does(steel: magfit.Simulation) -> None:
    comparison = compare(steel.samples, allow_undetermined=True)  # every method scored, as in the paper
    assert comparison.methods == PAPER_METHODS
    assert comparison.n_samples == 4000
    assert comparison.any_succeeded
    for result in comparison:
        assert result.ok and result.error is None
        assert result.calibration is not None and result.calibration.method == result.method
        # The score is exactly magfit.evaluate of the same calibration on the same samples.
        expected = magfit.evaluate(result.calibration, steel.samples)
        assert result.evaluation == expected
        assert result.seconds >= 0


def test_compare_refuses_what_the_samples_do_not_support(steel: magfit.Simulation) -> None:
    # Strong soft iron: a sphere, and min/max, leave residuals many times the full ellipsoid's.
    comparison = compare(steel.samples)
    assert comparison["ellipsoid"].ok
    for method in ("sphere", "minmax"):
        assert not comparison[method].ok
        assert "cannot describe these samples" in str(comparison[method].error)


def test_compare_ellipsoid_recovers_the_truth_and_the_paper_finding(steel: magfit.Simulation) -> None:
    comparison = compare(steel.samples, allow_undetermined=True)
    ellipsoid = comparison["ellipsoid"].calibration
    assert ellipsoid is not None
    # Noise is 6.4 counts per axis over 4000 samples: the semi-axes come out within a fraction of a
    # count of the truth; 1 % (2 to 14 counts) leaves a wide margin while catching any axis mix-up.
    np.testing.assert_allclose(ellipsoid.semi_axes, steel.truth.semi_axes, rtol=0.01)
    np.testing.assert_allclose(ellipsoid.offset, steel.truth.offset, atol=3.0)
    # Paper, section V: with the steel, the full fit's spread is several times below the other two.
    stds = {result.method: result.evaluation.std for result in comparison if result.evaluation is not None}
    assert stds["sphere"] > 5 * stds["ellipsoid"]
    assert stds["minmax"] > 5 * stds["ellipsoid"]


def _always_fails(data: FitInput) -> magfit.Calibration:
    raise magfit.CalibrationError("this method never fits (test double)")


def test_a_failing_method_keeps_its_reason_and_the_others_still_run(
    steel: magfit.Simulation, monkeypatch: pytest.MonkeyPatch
) -> None:
    spec = MethodSpec("always_fails", _always_fails, 4, "statistics", "test double that always fails")
    monkeypatch.setitem(magfit.METHODS, "always_fails", spec)
    comparison = compare(steel.samples, ["sphere", "always_fails", "ellipsoid"], allow_undetermined=True)
    failed = comparison["always_fails"]
    assert not failed.ok and failed.calibration is None and failed.evaluation is None
    assert failed.error == "this method never fits (test double)"
    assert comparison["sphere"].ok and comparison["ellipsoid"].ok  # the methods after it ran too
    assert comparison.any_succeeded


def test_compare_reports_when_every_method_failed() -> None:
    comparison = compare([[1.0, 2.0, 3.0], [2.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    assert not comparison.any_succeeded
    assert all("needs at least" in str(result.error) for result in comparison)


def test_compare_passes_options_to_their_method(steel: magfit.Simulation) -> None:
    comparison = compare(
        steel.samples, ["minmax"], options={"minmax": {"centre": "midrange"}}, allow_undetermined=True
    )
    calibration = comparison["minmax"].calibration
    assert calibration is not None
    low, high = steel.samples.min(axis=0), steel.samples.max(axis=0)
    np.testing.assert_allclose(calibration.offset, (low + high) / 2, rtol=1e-12)


@pytest.mark.parametrize(
    ("methods", "options", "message"),
    [
        (["ellipsoid", "nope"], None, "unknown method 'nope'; valid methods: .*ellipsoid"),
        (["sphere", "sphere"], None, "methods listed more than once: sphere"),
        ([], None, r"compare\(\) needs at least one method"),
        (["sphere"], {"minmax": {"centre": "mean"}}, "options given for methods not compared: minmax"),
        (["minmax"], {"minmax": {"center": "mean"}}, "method 'minmax' has no option 'center'; valid options: .*centre"),
    ],
)
def test_compare_refuses_bad_requests_before_fitting(methods: list[str], options: dict | None, message: str) -> None:
    with pytest.raises(magfit.OptionError, match="^" + message):
        compare(np.eye(3), methods, options=options)


def test_compare_refuses_malformed_samples() -> None:
    with pytest.raises(magfit.SampleError, match="NaN or inf"):
        compare([[1.0, 2.0, np.nan]] * 20)
    with pytest.raises(magfit.SampleError, match=r"shape \(3, 20\)"):
        compare(np.ones((3, 20)))


def test_comparison_lookup_and_json(steel: magfit.Simulation) -> None:
    comparison = compare(steel.samples[:500], ["sphere", "ellipsoid"])
    assert len(comparison) == 2 and comparison.methods == ("sphere", "ellipsoid")
    with pytest.raises(KeyError, match="'minmax' is not in this comparison; it holds: sphere, ellipsoid"):
        comparison["minmax"]
    document = json.loads(json.dumps(comparison.to_dict()))
    assert document["n_samples"] == 500
    entry = document["results"][1]
    restored = magfit.Calibration.from_dict(entry["calibration"])
    assert restored == comparison["ellipsoid"].calibration
    assert entry["evaluation"]["std"] == comparison["ellipsoid"].evaluation.std
    failed = compare(np.eye(3) + 1, ["sphere"]).to_dict()["results"][0]
    assert failed["ok"] is False and "needs at least" in failed["error"]


def test_evaluate_chunks_equals_evaluate_on_the_whole_stream(steel: magfit.Simulation) -> None:
    calibration = magfit.fit(steel.samples, method="sphere", allow_undetermined=True)  # large mean and spread
    bounds = [0, 1, 1, 700, 701, 2500, 4000]  # uneven chunks, one of a single sample, one empty
    chunks = [steel.samples[a:b] for a, b in itertools.pairwise(bounds)]
    streamed = evaluate_chunks(calibration, chunks)
    whole = magfit.evaluate(calibration, steel.samples)
    assert streamed.n == whole.n == 4000
    for name in ("mean", "std", "mean_abs", "rms", "max_abs"):
        assert getattr(streamed, name) == pytest.approx(getattr(whole, name), rel=1e-12, abs=1e-15), name


def test_evaluate_chunks_refuses_an_empty_stream() -> None:
    with pytest.raises(magfit.SampleError, match="no samples"):
        evaluate_chunks(magfit.Calibration.identity(), [np.empty((0, 3))])


# ---------------------------------------------------------------------- the paper's experiment


@pytest.fixture(scope="module")
def experiment() -> magfit.experiment.Experiment:
    return run_experiment(3000, seed=5)


@pytest.mark.slow
def test_experiment_fits_match_each_scenario_truth(experiment: magfit.experiment.Experiment) -> None:
    assert len(experiment.cases) == len(magfit.SENSORS) * len(magfit.DISTURBANCES)
    for case in experiment.cases:
        truth = case.simulation.truth
        # The truth is the paper's own table of semi-axes and offsets.
        np.testing.assert_allclose(np.sort(truth.semi_axes), np.sort(case.scenario.semi_axes), rtol=1e-12)
        calibration = case.comparison["ellipsoid"].calibration
        assert calibration is not None, case.scenario.name
        np.testing.assert_allclose(
            calibration.ellipsoid_matrix,
            truth.ellipsoid_matrix,
            rtol=0.03,
            atol=0.01 * np.max(np.abs(truth.ellipsoid_matrix)),
        )
        # Offset error ~ noise / sqrt(n) amplified by the axis ratio (up to 7 for the steel): 1 % of the
        # longest semi-axis is about ten standard errors.
        np.testing.assert_allclose(calibration.offset, truth.offset, atol=0.01 * max(truth.semi_axes))
        # The full fit leaves only the simulated noise σ. A sample in calibrated direction u moves off the
        # unit sphere by uᵀ diag(1/a) Qᵀ ε, whose variance averaged over uniform u is σ² mean(1/a²).
        # Sampling error of a std over 3000 samples is ~2 %; the MPU's rounding to counts adds ~0.5 %.
        inverse_axes = 1.0 / np.asarray(case.scenario.semi_axes)
        expected_std = case.scenario.noise * float(np.sqrt(np.mean(inverse_axes**2)))
        evaluation = case.comparison["ellipsoid"].evaluation
        assert evaluation is not None
        assert evaluation.std == pytest.approx(expected_std, rel=0.08), case.scenario.name


def test_experiment_is_repeatable_and_seeded(experiment: magfit.experiment.Experiment) -> None:
    again = run_experiment(3000, seed=5, sensors=("ellipse2a",), disturbances=("steel",))
    same = experiment.case("ellipse2a", "steel")
    np.testing.assert_array_equal(again.cases[0].simulation.samples, same.simulation.samples)
    other = run_experiment(3000, seed=6, sensors=("ellipse2a",), disturbances=("steel",))
    assert not np.array_equal(other.cases[0].simulation.samples, same.simulation.samples)
    with pytest.raises(KeyError, match="no case"):
        again.case("mpu9250", "none")


def test_experiment_reproduces_the_papers_findings(experiment: magfit.experiment.Experiment) -> None:
    checked = findings(experiment)
    assert len(checked) == 2 * 5  # per sensor: steel, and two checks for each of none and smartphone
    failed = [f"{finding.statement}: {finding.evidence}" for finding in checked if not finding.holds]
    assert not failed


def test_findings_can_fail() -> None:
    # An experiment without the steel's soft iron cannot show the full fit's advantage: the same check
    # with a demanding factor must report that it does not hold.
    run = run_experiment(1000, seed=2, disturbances=("steel",))
    verdicts = findings(run, soft_iron_factor=1000.0)
    assert [finding.holds for finding in verdicts] == [False, False]


def test_paper_table_is_complete() -> None:
    keys = {(d, m, s) for d in magfit.DISTURBANCES for m in PAPER_METHODS for s in magfit.SENSORS}
    assert set(PAPER_DISTANCES) == keys
    # Spot values from the paper's section V.
    assert PAPER_DISTANCES["steel", "sphere", "ellipse2a"] == (0.0251, 0.2228)
    assert PAPER_DISTANCES["none", "ellipsoid", "mpu9250"] == (0.0028, 0.0236)


@pytest.mark.slow
def test_methods_that_need_more_than_the_samples_run_where_it_is_given_and_say_why_not_otherwise() -> None:
    from scipy.spatial.transform import Rotation

    from magfit.compare import compare
    from magfit.vehicle import simulate_vehicle

    mounting = Rotation.from_euler("x", 20, degrees=True).as_matrix()
    sim = simulate_vehicle(3000, "tumble", hard_iron=[0.2, 0.1, -0.3], mounting=mounting, noise=0.01, seed=1)
    alone = compare(sim.samples, ["auto", "vector", "gyro"])
    assert alone["auto"].ok and not alone["vector"].ok and not alone["gyro"].ok
    assert alone["vector"].error.startswith("not run: the vector method needs the field expected at each sample")
    assert "gyroscope" in alone["gyro"].error and "time stamps" in alone["gyro"].error
    streams = {"reference": sim.reference, "gyro": sim.gyro, "time_s": sim.time_s}
    both = compare(sim.samples, ["auto", "vector", "gyro"], streams=streams)
    assert all(result.ok for result in both)
    np.testing.assert_allclose(both["vector"].calibration.matrix, sim.truth.matrix, atol=0.01)  # aligned too
