"""The known-field option (``field_strength``, e.g. from the World Magnetic Model) on every method that has it.

- ellipsoid, als, diag, ml: the fitted ellipsoid (offset, A) is unchanged; ``matrix`` is scaled so
  corrected samples have the given magnitude, and ``det(matrix)`` becomes ``(given / fitted)³``. (A
  general ellipsoid's size is fitted from the data; pinning it would assume ``det W = 1``.)
- sphere: the offset is refitted with the radius pinned (better on partial coverage).
"""

from __future__ import annotations

import numpy as np
import pytest

import magfit

SCALING_METHODS = ["ellipsoid", "als", "diag", "ml"]
ALL_METHODS = [*SCALING_METHODS, "sphere"]


@pytest.mark.parametrize("method", SCALING_METHODS)
def test_ellipsoid_type_fits_keep_the_ellipsoid_and_take_the_given_radius(method: str) -> None:
    scenario = magfit.scenario("mpu9250", "none")  # axis-aligned, so diag fits it too
    sim = scenario.simulate(3000, seed=1)
    free = magfit.fit(sim.samples, method=method)
    given = 300.0  # counts; the fit finds about 270
    pinned = magfit.fit(sim.samples, method=method, field_strength=given)
    np.testing.assert_allclose(pinned.offset, free.offset, rtol=1e-12)
    np.testing.assert_allclose(pinned.ellipsoid_matrix, free.ellipsoid_matrix, rtol=1e-10)
    assert pinned.field_strength == given
    assert np.linalg.det(pinned.matrix) == pytest.approx((given / free.field_strength) ** 3, rel=1e-10)
    radii = np.linalg.norm(pinned.apply(sim.samples), axis=1)
    assert np.mean(radii) == pytest.approx(given, rel=0.01)  # noise 2.4 % per sample, 3000 samples
    assert pinned.known_field is not None
    assert pinned.known_field.fitted == pytest.approx(free.field_strength, rel=1e-12)
    assert free.known_field is None


@pytest.mark.parametrize("tilt", [20.0, 45.0])
def test_pinned_radius_places_the_sphere_centre_on_partial_coverage(tilt: float) -> None:
    # A vehicle that only tilts ±tilt°: the samples form a band, and the free sphere fit trades the
    # vertical offset against the radius. With the radius known the offset is found to the noise level.
    truth_offset = np.array([20.0, -10.0, 5.0])
    sim = magfit.simulate(
        3000, hard_iron=truth_offset, field_strength=50.0, noise=1.0, orientations="restricted", max_tilt_deg=tilt,
        seed=2,
    )  # fmt: skip
    free = magfit.fit(sim.samples, method="sphere")
    pinned = magfit.fit(sim.samples, method="sphere", field_strength=50.0)
    # 1 µT noise over 3000 samples: about 0.02 µT per axis on a full sphere; a band costs a few times that.
    assert np.linalg.norm(pinned.offset - truth_offset) < 0.25
    assert np.linalg.norm(free.offset - truth_offset) > 2 * np.linalg.norm(pinned.offset - truth_offset)
    assert pinned.field_strength == 50.0 and np.array_equal(pinned.matrix, np.eye(3))
    assert pinned.known_field is not None
    assert pinned.known_field.fitted == pytest.approx(free.field_strength)


def test_pinned_sphere_from_statistics_equals_from_samples() -> None:
    sim = magfit.simulate(2000, hard_iron=[3.0, 1.0, -2.0], field_strength=50.0, noise=0.5, seed=3)
    from_samples = magfit.fit(sim.samples, method="sphere", field_strength=50.0)
    from_chunks = magfit.fit(
        magfit.Statistics.from_chunks(np.array_split(sim.samples, 4)), method="sphere", field_strength=50.0
    )
    np.testing.assert_allclose(from_chunks.offset, from_samples.offset, rtol=1e-9)
    np.testing.assert_allclose(from_samples.offset, [3.0, 1.0, -2.0], atol=0.1)


def test_pinned_sphere_with_exact_data_is_exact() -> None:
    sim = magfit.simulate(200, hard_iron=[3.0, 1.0, -2.0], field_strength=50.0, seed=4)
    cal = magfit.fit(sim.samples, method="sphere", field_strength=50.0)
    np.testing.assert_allclose(cal.offset, [3.0, 1.0, -2.0], atol=1e-9)


@pytest.mark.parametrize("method", ALL_METHODS)
@pytest.mark.parametrize("bad", [0.0, -50.0, float("nan"), float("inf"), "strong"])
def test_bad_field_strength_is_refused(method: str, bad: object) -> None:
    sim = magfit.scenario("mpu9250", "none").simulate(500, seed=7)
    with pytest.raises(magfit.OptionError, match="field_strength"):
        magfit.fit(sim.samples, method=method, field_strength=bad)


@pytest.mark.parametrize("method", ALL_METHODS)
def test_not_giving_the_field_changes_nothing(method: str) -> None:
    sim = magfit.scenario("mpu9250", "smartphone").simulate(1500, seed=8)
    assert magfit.fit(sim.samples, method=method) == magfit.fit(sim.samples, method=method, field_strength=None)
