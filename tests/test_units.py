"""Units of magnetic flux density: names, aliases, exact factors, and refusals."""

from __future__ import annotations

import itertools

import pytest

from magfit.errors import OptionError
from magfit.units import EARTH_FIELD_UT, UNITS, canonical_name, conversion_factor, field_unit_reason, get_unit

PHYSICAL = [name for name, unit in UNITS.items() if unit.is_physical]


@pytest.mark.parametrize(
    ("source", "target", "expected"),
    [
        # SI definitions: 1 G = 1e-4 T exactly, hence 1 G = 100 µT = 1e5 nT and 1 mG = 0.1 µT.
        ("uT", "mG", 10.0),
        ("mG", "uT", 0.1),
        ("G", "uT", 100.0),
        ("uT", "G", 0.01),
        ("nT", "G", 1e-5),
        ("G", "nT", 1e5),
        ("T", "G", 1e4),
        ("mT", "G", 10.0),
        ("G", "mG", 1000.0),
        ("mG", "nT", 100.0),
        ("uT", "nT", 1000.0),
        ("uT", "uT", 1.0),
    ],
)
def test_conversion_factors_are_the_si_definitions(source: str, target: str, expected: float) -> None:
    # Each factor is a correctly rounded power of ten, so equality is exact.
    assert conversion_factor(source, target) == expected


@pytest.mark.parametrize(("a", "b"), list(itertools.permutations(PHYSICAL, 2)))
def test_factors_invert_and_compose(a: str, b: str) -> None:
    # Products of two correctly rounded powers of ten are within 2 ulp of the exact value.
    assert conversion_factor(a, b) * conversion_factor(b, a) == pytest.approx(1.0, rel=4e-16)
    for c in PHYSICAL:
        assert conversion_factor(a, b) * conversion_factor(b, c) == pytest.approx(conversion_factor(a, c), rel=4e-16)


@pytest.mark.parametrize(
    ("alias", "name"),
    [
        ("µT", "uT"),  # micro sign U+00B5
        ("μT", "uT"),  # Greek small mu U+03BC
        ("microtesla", "uT"),
        ("UT", "uT"),
        (" uT ", "uT"),
        ("nanotesla", "nT"),
        ("millitesla", "mT"),
        ("tesla", "T"),
        ("gauss", "G"),
        ("Gauss", "G"),
        ("Ga", "G"),
        ("milligauss", "mG"),
        ("mGauss", "mG"),
        ("counts", "counts"),
        ("LSB", "counts"),
        ("raw", "counts"),
    ],
)
def test_aliases_resolve_to_the_canonical_name(alias: str, name: str) -> None:
    assert canonical_name(alias) == name
    assert get_unit(alias) is UNITS[name]


def test_unit_scales() -> None:
    assert UNITS["uT"].tesla == 1e-6
    assert UNITS["uT"].gauss == 0.01
    assert UNITS["mG"].gauss == 1e-3
    assert UNITS["G"].tesla == 1e-4
    counts = UNITS["counts"]
    assert not counts.is_physical
    assert counts.tesla is None and counts.gauss is None


@pytest.mark.parametrize("bad", ["furlong", "", "uT/s", None, 3])
def test_unknown_unit_lists_the_valid_ones(bad: object) -> None:
    with pytest.raises(OptionError, match=r"unknown unit .*valid units: T \(tesla\).*uT \(microtesla\)"):
        get_unit(bad)  # type: ignore[arg-type]


@pytest.mark.parametrize(("source", "target"), [("counts", "mG"), ("uT", "counts"), ("LSB", "G")])
def test_counts_cannot_be_converted(source: str, target: str) -> None:
    with pytest.raises(OptionError, match="raw counts have no known scale"):
        conversion_factor(source, target)


# ---------------------------------------------------------------------- the declared unit against the Earth's field


@pytest.mark.parametrize("field_ut", [22.0, 38.0, 48.0, 67.0])
@pytest.mark.parametrize("true_unit", PHYSICAL)
def test_a_field_in_its_own_unit_passes_and_in_another_names_its_unit(field_ut: float, true_unit: str) -> None:
    # Ground truth: the Earth's field (22-67 uT anywhere on the surface) written in the samples' true unit.
    value = field_ut * conversion_factor("uT", true_unit)
    assert field_unit_reason(value, true_unit) is None
    for declared in PHYSICAL:
        if declared == true_unit:
            continue
        reason = field_unit_reason(value, declared)
        assert reason is not None and reason.code == "unit_mismatch"
        assert reason.remedy == (("unit", true_unit),), (value, declared)


@pytest.mark.parametrize(
    ("value", "declared", "likely"),
    [
        (1078.39, "uT", "counts"),  # a QMC5883L's raw counts declared uT
        (6.6e-05, "uT", "T"),  # a recording in tesla declared uT
        (500.0, "G", "mG"),  # milligauss declared gauss
        (0.5, "mG", "G"),  # gauss declared milligauss
        (50000.0, "uT", "nT"),  # nanotesla declared microtesla
        (1400.0, "G", "counts"),
    ],
)
def test_the_likely_unit_is_named(value: float, declared: str, likely: str) -> None:
    reason = field_unit_reason(value, declared)
    assert reason is not None and reason.code == "unit_mismatch" and reason.remedy == (("unit", likely),)


@pytest.mark.parametrize(
    ("value", "unit"),
    [(15.0, "uT"), (100.0, "uT"), (0.2, "G"), (250.0, "mG"), (1400.0, "counts"), (1.0, None), (50.0, "furlongs"),
     (0.0, "uT"), (float("nan"), "uT"), (-48.0, "uT")],
)  # fmt: skip
def test_plausible_or_uncheckable_fields_give_no_reason(value: float, unit: str | None) -> None:
    # 15-100 uT is accepted (altitude, nearby steel); counts, no unit and unknown names cannot be checked.
    assert field_unit_reason(value, unit) is None


def test_the_surface_range_is_the_world_magnetic_models() -> None:
    # WMM2025 total intensity extremes: about 22 uT (South Atlantic anomaly) and 67 uT (south magnetic pole area).
    assert EARTH_FIELD_UT == (22.0, 67.0)
    assert field_unit_reason(14.9, "uT") is not None and field_unit_reason(100.1, "uT") is not None
