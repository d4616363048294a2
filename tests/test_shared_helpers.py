"""The helpers gyro, vector, alignment, robust and the diagnostics share (one copy each): the cross-product
matrix, polar decomposition, the 24 proper signed permutations, a direction in words, the robust scale and the
inclination check, each against a one-line oracle or its definition."""

from __future__ import annotations

import math

import numpy as np
import pytest

from magfit import align
from magfit._scale import robust_scale
from magfit._validation import check_inclination
from magfit.errors import OptionError
from magfit.geometry.frame import axis_words as frame_axis_words
from magfit.rotations import axis_words, polar_decomposition, signed_permutations, skew


def test_skew_is_the_cross_product_matrix_for_stacks_of_vectors() -> None:
    rng = np.random.default_rng(0)
    v, u = rng.normal(size=(5, 4, 3)), rng.normal(size=(5, 4, 3))
    assert skew(v).shape == (5, 4, 3, 3)
    assert np.allclose(np.einsum("...ij,...j->...i", skew(v), u), np.cross(v, u), atol=1e-15)
    assert np.array_equal(skew(v), -np.swapaxes(skew(v), -1, -2))


def test_polar_decomposition_recovers_a_rotation_and_a_symmetric_definite_factor() -> None:
    rng = np.random.default_rng(1)
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    q *= np.sign(np.linalg.det(q))
    s = np.array([[1.2, 0.1, 0.0], [0.1, 0.9, 0.05], [0.0, 0.05, 1.1]])
    rotation, symmetric = polar_decomposition(q @ s)
    assert np.allclose(rotation, q, atol=1e-12) and np.allclose(symmetric, s, atol=1e-12)


def test_the_24_signed_permutations_are_the_rotations_of_a_cube() -> None:
    found = signed_permutations()
    assert len(found) == 24
    assert len({p.tobytes() for p in found}) == 24
    for p in found:
        assert set(np.abs(p).sum(axis=0)) == {1.0} and np.isclose(np.linalg.det(p), 1.0)
    # Every rotation lies within 62.8° of one of them (the cube's covering radius).
    rng = np.random.default_rng(2)
    for _ in range(200):
        q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
        q *= np.sign(np.linalg.det(q))
        nearest = min(math.degrees(math.acos(np.clip((np.trace(p.T @ q) - 1) / 2, -1, 1))) for p in found)
        assert nearest <= 62.8 + 1e-9


def test_axis_words_names_an_axis_or_the_components() -> None:
    assert axis_words([0.0, 0.0, -2.0]) == "−z"
    assert axis_words([0.6, -0.8, 0.0]) == "−y+x"
    assert frame_axis_words(np.array([1.0, 0.0, 0.0])) == "+x"  # the diagnostics' import still works
    assert axis_words([0.05, 0.0, 1.0], "gyro") == "the gyro's z axis"
    assert axis_words([0.6, 0.8, 0.0], "gyro") == "the gyro direction (+0.60, +0.80, +0.00)"
    names = ("front", "right", "down")
    assert axis_words([0.0, -0.99, 0.1], "body", names=names, within_deg=20.0) == "right"
    assert axis_words([-0.6, -0.8, 0.0], "body", noun="axis", unsigned=True) == "the body axis (+0.60, +0.80, -0.00)"


def test_robust_scale_is_the_gaussian_sigma_from_the_median_absolute_deviation() -> None:
    rng = np.random.default_rng(3)
    r = rng.normal(2.0, 0.5, 200_001)
    r[:2_000] = 1e6  # a hundredth of outliers moves neither much
    centre, sigma = robust_scale(r)
    assert abs(centre - 2.0) < 0.01 and abs(sigma - 0.5) < 0.01
    assert sigma == 1.4826 * float(np.median(np.abs(r - np.median(r))))


@pytest.mark.parametrize("value", [90.0, -90.0, 95.0, float("nan"), "64°", None])
def test_check_inclination_refuses_a_vertical_field_and_what_is_not_a_dip(value: object) -> None:
    with pytest.raises(OptionError, match="inclination_deg must be the field's dip in degrees within ±90"):
        check_inclination(value)


def test_check_inclination_returns_the_dip_as_a_float() -> None:
    assert check_inclination(64) == 64.0 and check_inclination("-89.5") == -89.5


def test_align_and_gyro_refuse_a_vertical_field_alike() -> None:
    import magfit
    from magfit.vehicle import simulate_vehicle

    sim = simulate_vehicle(1200, "tumble", seed=1)
    with pytest.raises(OptionError, match="within ±90") as by_align:
        align(sim.samples, sim.accel, inclination_deg=90.0)
    with pytest.raises(OptionError, match="within ±90") as by_gyro:
        magfit.fit(sim.samples, method="gyro", gyro=sim.gyro, time_s=sim.time_s, accel=sim.accel, inclination_deg=90.0)
    assert str(by_align.value) == str(by_gyro.value)


def test_a_method_function_called_with_an_array_is_one_line() -> None:
    """fit_gyro and fit_vector are exported by their packages; called directly with samples they say which call to
    make (magfit.fit), instead of an AttributeError from the prepared input they expect."""
    import numpy as np
    import pytest

    from magfit.errors import OptionError
    from magfit.methods.gyro import fit_gyro
    from magfit.methods.vector import fit_vector

    samples = np.zeros((100, 3))
    with pytest.raises(OptionError, match=r"magfit.fit\(samples, method='gyro'"):
        fit_gyro(samples, gyro=samples, time_s=np.arange(100.0))  # type: ignore[arg-type]
    with pytest.raises(OptionError, match=r"magfit.fit\(samples, method='vector'"):
        fit_vector(samples, reference=samples)  # type: ignore[arg-type]
