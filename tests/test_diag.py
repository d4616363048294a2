"""The axis-aligned fit (``diag``: offset + one scale per axis) against ground truth.

It is exact when the soft iron stretches the sensor axes only, and biased (by the rotation it cannot
represent, whatever the number of samples) when the iron's axes are turned.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from scipy.spatial.transform import Rotation

import magfit
from magfit import Calibration

MAGNETO_OFFSET = np.array([28.557458, -39.981060, -27.428035])
AXIS_SCALES = np.diag([1.3, 0.8, 1.1])
HARD_IRON = [0.3, -0.2, 0.1]


def shape_error(fitted: Calibration, truth: Calibration) -> float:
    a, a_true = fitted.ellipsoid_matrix, truth.ellipsoid_matrix
    return float(np.linalg.norm(a - a_true) / np.linalg.norm(a_true))


def test_exact_on_axis_aligned_distortion() -> None:
    sim = magfit.simulate(300, soft_iron=AXIS_SCALES, hard_iron=HARD_IRON, field_strength=48.0, seed=1)
    cal = magfit.fit(sim.samples, method="diag")
    np.testing.assert_allclose(cal.offset, HARD_IRON, atol=1e-9)
    np.testing.assert_allclose(cal.ellipsoid_matrix, sim.truth.ellipsoid_matrix, rtol=1e-9)
    np.testing.assert_allclose(cal.semi_axes, 48.0 * np.diag(AXIS_SCALES), rtol=1e-9)
    assert np.count_nonzero(cal.matrix - np.diag(np.diag(cal.matrix))) == 0  # exactly diagonal
    assert np.linalg.det(cal.matrix) == pytest.approx(1.0)
    np.testing.assert_allclose(np.linalg.norm(cal.apply(sim.samples), axis=1), cal.field_strength, rtol=1e-9)


def test_noisy_axis_aligned_distortion_within_the_noise() -> None:
    n, noise = 5000, 0.02
    sim = magfit.simulate(n, soft_iron=AXIS_SCALES, hard_iron=HARD_IRON, noise=noise, seed=2)
    cal = magfit.fit(sim.samples, method="diag")
    relative = noise / 0.8  # smallest semi-axis
    tol = 20 * relative / np.sqrt(n) + 3 * relative**2  # as for the paper's algebraic fit
    assert np.linalg.norm(cal.offset - sim.truth.offset) < tol
    assert shape_error(cal, sim.truth) < 3 * tol


def test_biased_on_rotated_distortion_where_the_full_ellipsoid_is_exact() -> None:
    turn = Rotation.from_euler("z", 30, degrees=True).as_matrix()
    sim = magfit.simulate(2000, soft_iron=turn @ AXIS_SCALES @ turn.T, hard_iron=HARD_IRON, seed=3)
    diag = magfit.fit(sim.samples, method="diag", allow_undetermined=True)
    full = magfit.fit(sim.samples, method="ellipsoid")
    # The verdict knows: the full ellipsoid leaves far less on the same samples (F test) and turns the heading.
    assert diag.support.verdict == "refused"
    assert "model_inadequate" in diag.support.to_dict()["refusal_codes"]
    assert shape_error(full, sim.truth) < 1e-9
    assert shape_error(diag, sim.truth) > 0.1  # a 30° turn of a 1.3 : 0.8 stretch cannot be diagonal
    assert np.count_nonzero(diag.matrix - np.diag(np.diag(diag.matrix))) == 0


def test_statistics_in_chunks_give_the_same_fit() -> None:
    sim = magfit.scenario("ellipse2a", "smartphone").simulate(3000, seed=4)
    from_chunks = magfit.fit(magfit.Statistics.from_chunks(np.array_split(sim.samples, 5)), method="diag")
    whole = magfit.fit(sim.samples, method="diag")
    np.testing.assert_allclose(from_chunks.offset, whole.offset, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(from_chunks.matrix, whole.matrix, rtol=1e-9)
    assert from_chunks.method == "diag" and whole.n_samples == 3000


def test_scenario_without_turned_iron_is_recovered() -> None:
    scenario = magfit.scenario("mpu9250", "none")  # the paper's undisturbed case: no axis rotation
    n = 5000
    sim = scenario.simulate(n, seed=5)
    cal = magfit.fit(sim.samples, method="diag")
    relative = scenario.noise / min(scenario.semi_axes)
    tol = 20 * relative / np.sqrt(n) + 3 * relative**2
    assert np.linalg.norm(cal.offset - sim.truth.offset) / scenario.field_strength < tol
    np.testing.assert_allclose(cal.semi_axes, scenario.semi_axes, rtol=3 * tol)


def test_json_round_trip() -> None:
    cal = magfit.fit(magfit.scenario("mpu9250", "none").simulate(800, seed=6).samples, method="diag")
    assert Calibration.from_json(cal.to_json()) == cal


def test_fxos8700_offset_near_magneto(real_data_dir: Path) -> None:
    samples = np.loadtxt(real_data_dir / "fxos8700_magneto" / "mag-readings.txt")
    cal = magfit.fit(samples, method="diag")
    # Magneto's correction is nearly diagonal (off-diagonal terms 0.02), so the axis-aligned fit lands close.
    assert np.linalg.norm(cal.offset - MAGNETO_OFFSET) < 0.5


def test_tilting_only_recording_is_refused(real_data_dir: Path) -> None:
    samples = pd.read_csv(real_data_dir / "android_phone_kritiksoman" / "data_mag.txt")[["x", "y", "z"]]
    with pytest.raises(magfit.CalibrationError):
        magfit.fit(samples.to_numpy(), method="diag")


def test_strongly_turned_iron_is_refused_with_the_model_named() -> None:
    # The paper's steel case: semi-axes 193 : 1362 turned 20° off the axes. No axis-aligned ellipsoid
    # fits; the best 7-term quadric is a hyperboloid, and the message points to the full model.
    sim = magfit.scenario("mpu9250", "steel").simulate(5000, seed=7)
    with pytest.raises(magfit.CalibrationError, match="turned off the sensor axes.*method='als'"):
        magfit.fit(sim.samples, method="diag")
