"""The maximum-likelihood (orthogonal-distance) fit ``ml`` against ground truth, ``als`` and its own claims.

Tolerances: a consistent, efficient estimator recovers A and V to about σ/(a√N) (a the smallest
semi-axis); we allow 20 σ/(a√N) as for the other methods.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

import magfit
from magfit import Calibration, Simulation
from magfit.methods.ml import COVARIANCE_PARAMETERS, orthogonal_distances

SCENARIOS = [(sensor, disturbance) for sensor in magfit.SENSORS for disturbance in magfit.DISTURBANCES]
MAGNETO_OFFSET = np.array([28.557458, -39.981060, -27.428035])
SOFT_IRON = np.array([[1.3, 0.2, 0.1], [0.2, 0.8, -0.15], [0.1, -0.15, 1.0]])
A_INDEX = ([0, 1, 2, 0, 0, 1], [0, 1, 2, 1, 2, 2])  # the A entries of COVARIANCE_PARAMETERS


def shape_error(fitted: Calibration, truth: Calibration) -> float:
    a, a_true = fitted.ellipsoid_matrix, truth.ellipsoid_matrix
    return float(np.linalg.norm(a - a_true) / np.linalg.norm(a_true))


def offset_error(fitted: Calibration, sim: Simulation) -> float:
    return float(np.linalg.norm(fitted.offset - sim.truth.offset) / sim.field_strength)


def test_orthogonal_distances_of_points_placed_along_the_normals() -> None:
    # Oracle: x = p + d n with p on the ellipsoid and n its unit normal is at signed distance d, as long
    # as |d| stays below the smallest radius of curvature (a_min² / a_max).
    truth = magfit.simulate(1, soft_iron=SOFT_IRON, hard_iron=[1.0, 2.0, -3.0], field_strength=40.0).truth
    rng = np.random.default_rng(0)
    directions = rng.normal(size=(500, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    on_surface = truth.offset + directions @ np.linalg.inv(truth.matrix).T * truth.field_strength
    normals = (on_surface - truth.offset) @ truth.ellipsoid_matrix
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    axes = truth.semi_axes
    distances = rng.uniform(-0.5, 0.5, 500) * axes.min() ** 2 / axes.max()
    measured = orthogonal_distances(truth, on_surface + distances[:, None] * normals)
    np.testing.assert_allclose(measured, distances, atol=1e-9 * truth.field_strength)


def test_noise_free_samples_give_the_exact_ellipsoid() -> None:
    sim = magfit.simulate(400, soft_iron=SOFT_IRON, hard_iron=[0.5, -0.3, 0.2], seed=1)
    cal = magfit.fit(sim.samples, method="ml")
    np.testing.assert_allclose(cal.offset, sim.truth.offset, atol=1e-8)
    np.testing.assert_allclose(cal.ellipsoid_matrix, sim.truth.ellipsoid_matrix, atol=1e-8)
    assert np.linalg.det(cal.matrix) == pytest.approx(1.0)


@pytest.mark.parametrize(("sensor", "disturbance"), SCENARIOS)
@pytest.mark.slow
def test_ml_recovers_every_scenario(sensor: str, disturbance: str) -> None:
    scenario = magfit.scenario(sensor, disturbance)
    n = 3000
    sim = scenario.simulate(n, seed=31)
    cal = magfit.fit(sim.samples, method="ml")
    tol = 20 * scenario.noise / min(scenario.semi_axes) / np.sqrt(n)
    assert offset_error(cal, sim) < tol * max(scenario.semi_axes) / scenario.field_strength
    assert shape_error(cal, sim.truth) < 3 * tol
    assert cal.details["status"] in (1, 2, 3) and cal.details["start"] == "als"


def test_ml_is_at_least_as_good_as_als_at_the_sensors_noise() -> None:
    # RMS errors over repeated recordings of the paper's steel case (semi-axes 193 : 1362 counts).
    scenario = magfit.scenario("mpu9250", "steel")
    errors: dict[str, list[tuple[float, float]]] = {"als": [], "ml": []}
    for seed in range(8):
        sim = scenario.simulate(2000, seed=100 + seed)
        for method, found in errors.items():
            cal = magfit.fit(sim.samples, method=method, diagnostics=False)  # tested elsewhere
            found.append((shape_error(cal, sim.truth), offset_error(cal, sim)))
    rms = {method: np.sqrt(np.mean(np.square(found), axis=0)) for method, found in errors.items()}
    assert rms["ml"][0] <= 1.05 * rms["als"][0]  # shape
    assert rms["ml"][1] <= 1.05 * rms["als"][1]  # offset


def test_bias_correction_removes_most_of_the_geometric_fits_bias() -> None:
    # At 10 % noise the plain orthogonal-distance fit grows the ellipsoid by about σ²/B (~1 % in A).
    n, noise = 50_000, 0.1
    sim = magfit.simulate(n, soft_iron=SOFT_IRON, hard_iron=[0.5, -0.3, 0.2], noise=noise, seed=2)
    corrected = magfit.fit(sim.samples, method="ml", diagnostics=False)
    plain = magfit.fit(sim.samples, method="ml", bias_correction=False, diagnostics=False)
    tol = 20 * noise / 0.7 / np.sqrt(n)  # 0.7: the smallest semi-axis of SOFT_IRON, rounded down
    assert shape_error(corrected, sim.truth) < tol
    assert shape_error(plain, sim.truth) > 1.5 * shape_error(corrected, sim.truth)
    assert offset_error(corrected, sim) < tol
    assert corrected.details["bias_correction"] and not plain.details["bias_correction"]


def test_details_report_the_solver_and_a_calibrated_covariance() -> None:
    scenario = magfit.scenario("mpu9250", "steel")
    squared_z_scores = []
    for seed in range(10):
        sim = scenario.simulate(2000, seed=200 + seed)
        cal = magfit.fit(sim.samples, method="ml", diagnostics=False)
        covariance = np.array(cal.details["covariance"])
        assert covariance.shape == (9, 9) and cal.details["covariance_parameters"] == list(COVARIANCE_PARAMETERS)
        np.testing.assert_allclose(covariance, covariance.T, rtol=1e-9, atol=1e-30)
        assert np.all(np.linalg.eigvalsh(covariance) > -1e-12 * np.abs(covariance).max())
        error = np.concatenate(
            [cal.offset - sim.truth.offset, (cal.ellipsoid_matrix - sim.truth.ellipsoid_matrix)[A_INDEX]]
        )
        squared_z_scores.append(error**2 / np.diag(covariance))
    # If (JᵀJ)⁻¹σ² is the estimator's covariance, squared z-scores average 1 (90 values: 0.5..2 is generous).
    assert 0.5 < float(np.mean(squared_z_scores)) < 2.0
    assert cal.details["noise_std"] == pytest.approx(scenario.noise, rel=0.1)
    assert isinstance(cal.details["message"], str) and cal.solver.iterations >= 1 and cal.details["cost"] > 0
    json.dumps(dict(cal.details))  # JSON-serialisable
    assert Calibration.from_json(cal.to_json()) == cal


def test_iteration_limit_is_an_error_not_a_result() -> None:
    sim = magfit.scenario("mpu9250", "steel").simulate(2000, seed=1)
    with pytest.raises(magfit.CalibrationError, match="did not converge"):
        magfit.fit(sim.samples, method="ml", max_iterations=1)


@pytest.mark.parametrize(
    ("option", "value"),
    [("bias_correction", "yes"), ("max_iterations", 0), ("max_iterations", 2.5), ("root", "cube")],
)
def test_bad_options_are_refused(option: str, value: object) -> None:
    sim = magfit.scenario("mpu9250", "none").simulate(500, seed=3)
    with pytest.raises(magfit.OptionError, match=option):
        magfit.fit(sim.samples, method="ml", **{option: value})


def test_statistics_are_not_enough() -> None:
    statistics = magfit.Statistics.from_samples(magfit.scenario("mpu9250", "none").simulate(500, seed=4).samples)
    with pytest.raises(magfit.OptionError, match="needs the samples"):
        magfit.fit(statistics, method="ml")


def test_fxos8700_agrees_with_magneto(real_data_dir: Path) -> None:
    samples = np.loadtxt(real_data_dir / "fxos8700_magneto" / "mag-readings.txt")
    cal = magfit.fit(samples, method="ml")
    assert np.linalg.norm(cal.offset - MAGNETO_OFFSET) < 0.5


def test_tilting_only_recording_is_refused(real_data_dir: Path) -> None:
    samples = pd.read_csv(real_data_dir / "android_phone_kritiksoman" / "data_mag.txt")[["x", "y", "z"]]
    with pytest.raises(magfit.CalibrationError):
        magfit.fit(samples.to_numpy(), method="ml")


def test_falls_back_to_the_algebraic_start_when_als_has_no_ellipsoid(monkeypatch: pytest.MonkeyPatch) -> None:
    from magfit.methods import ml

    def no_als(*args: object, **kwargs: object) -> None:
        raise magfit.CalibrationError("the als fit failed: stand-in for a hyperboloid")

    monkeypatch.setattr(ml, "als_theta", no_als)
    scenario = magfit.scenario("ellipse2a", "steel")
    n = 3000
    sim = scenario.simulate(n, seed=40)
    cal = magfit.fit(sim.samples, method="ml", diagnostics=False)
    assert cal.details["start"] == "ellipsoid"
    tol = 20 * scenario.noise / min(scenario.semi_axes) / np.sqrt(n)
    assert shape_error(cal, sim.truth) < 3 * tol
    assert offset_error(cal, sim) < tol


@settings(max_examples=5, deadline=None)
@given(angles=st.tuples(*[st.floats(-180.0, 180.0)] * 3), shift=st.tuples(*[st.floats(-100.0, 100.0)] * 3))
def test_ml_is_equivariant_under_rotation_and_translation_of_the_input(
    angles: tuple[float, float, float], shift: tuple[float, float, float]
) -> None:
    samples = magfit.scenario("ellipse2a", "smartphone").simulate(1500, seed=41).samples
    rotation = Rotation.from_euler("xyz", angles, degrees=True).as_matrix()
    base = magfit.fit(samples, method="ml", diagnostics=False)
    turned = magfit.fit(samples @ rotation.T + np.asarray(shift), method="ml", diagnostics=False)
    # Both stop within 1e-3 standard errors of the same optimum, so they agree far inside the noise.
    scale = np.linalg.norm(base.ellipsoid_matrix)
    np.testing.assert_allclose(turned.offset, rotation @ base.offset + shift, atol=1e-5 + 1e-9 * max(map(abs, shift)))
    np.testing.assert_allclose(
        turned.ellipsoid_matrix, rotation @ base.ellipsoid_matrix @ rotation.T, atol=1e-5 * scale
    )


def test_gauss_newton_polish_reaches_the_bias_corrected_solution_from_the_plain_one() -> None:
    # The polish that guards Levenberg–Marquardt's stop: started from the plain geometric optimum (about
    # σ²/B away), it must land where the full bias-corrected fit lands.
    from magfit.methods import ml

    sim = magfit.simulate(20_000, soft_iron=SOFT_IRON, hard_iron=[0.5, -0.3, 0.2], noise=0.1, seed=5)
    statistics = magfit.Statistics.from_samples(sim.samples)
    zt = (sim.samples.T - statistics.centre[:, None]) / statistics.scale
    _, centre, shape, variance = ml._start(statistics)
    assert variance is not None
    from magfit._optimize import Solution, levenberg_marquardt

    plain_model = ml._Model(zt, 0.0)
    start_params = plain_model.pack(centre, np.linalg.cholesky(shape))
    plain = levenberg_marquardt(plain_model.evaluate, start_params, n_residuals=zt.shape[1], max_iterations=200)
    corrected_model = ml._Model(zt, variance)
    start = Solution(plain.params, corrected_model.evaluate(plain.params), plain.status, "", plain.iterations)
    polished = ml._solve_estimating_equation(corrected_model, start, 50)
    assert polished.status > 0 and polished.iterations > plain.iterations
    full = magfit.fit(sim.samples, method="ml", diagnostics=False)
    centre_z, lower = corrected_model.unpack(polished.params)
    np.testing.assert_allclose(statistics.centre + statistics.scale * centre_z, full.offset, atol=1e-5)
    np.testing.assert_allclose(lower @ lower.T / statistics.scale**2, full.ellipsoid_matrix, rtol=1e-4)


def _few_directions(seed: int) -> np.ndarray:
    """12-60 samples of a tilted soft-iron ellipsoid, some seeds confined near a plane: degenerate for ml."""
    rng = np.random.default_rng(seed)
    n = int(rng.integers(12, 60))
    b = rng.normal(size=(3, 3)) * 0.3 + np.eye(3)
    u = rng.normal(size=(n, 3))
    if seed % 3 == 0:
        u[:, 2] = np.abs(u[:, 2]) * rng.uniform(0.05, 1)
    if seed % 3 == 1:
        u[:, 2] *= rng.uniform(0.01, 0.3)
    u /= np.linalg.norm(u, axis=1)[:, None]
    shape = np.linalg.cholesky(b @ b.T)
    return u @ shape.T * 400 + rng.normal(size=3) * 300 + rng.normal(size=(n, 3)) * rng.choice([0, 0.1, 5, 40])


@pytest.mark.parametrize("seed", [4, 46, 55])
@pytest.mark.slow
def test_samples_that_do_not_fix_the_ellipsoid_are_a_calibration_error_not_a_crash(seed: int) -> None:
    # Found by fuzzing: a singular JᵀJ (LinAlgError) and a trial step whose ellipsoid lost positive
    # definiteness (math domain error) escaped ml as tracebacks, and through it auto's final refinement.
    samples = _few_directions(seed)
    with pytest.raises(magfit.CalibrationError, match="cannot determine the ellipsoid|no starting ellipsoid"):
        magfit.fit(samples, method="ml")
    try:
        calibration = magfit.fit(samples, method="auto")
    except magfit.CalibrationError:
        return  # auto may refuse too; what it must not do is crash
    assert np.all(np.isfinite(calibration.offset)) and np.all(np.isfinite(calibration.matrix))


def test_an_unconverged_fit_is_refused_by_the_verdict_in_the_solvers_words() -> None:
    sim = magfit.simulate(2000, soft_iron=np.diag([1.3, 1.0, 0.8]), hard_iron=[0.4, -0.2, 0.3], noise=0.02, seed=3)
    with pytest.raises(magfit.CalibrationError, match="the ml fit did not converge"):
        magfit.fit(sim.samples, "ml", max_iterations=1)
    forced = magfit.fit(sim.samples, "ml", max_iterations=1, allow_undetermined=True)
    assert forced.solver.converged is False and forced.support.verdict == "refused"
    assert magfit.fit(sim.samples, "ml").solver.converged is True
