"""Units of magnetic flux density: names, aliases, exact factors, and refusals."""

from __future__ import annotations

import itertools

import pytest

from magfit.errors import OptionError
from magfit.units import UNITS, canonical_name, conversion_factor, get_unit

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
