"""Units of magnetic flux density: names, aliases and exact conversion factors.

magfit works in whatever unit the samples come in (paper, eq. 1 holds in any unit) and records that
unit's name in :attr:`magfit.Calibration.unit`. Firmware exports need a fixed unit (ArduPilot reads
milligauss, PX4 gauss), so they convert with the factors below::

    1 T = 10⁴ G        1 G = 100 µT = 10⁵ nT        1 mG = 0.1 µT = 100 nT

Every unit is stored as a power of ten of the tesla, so every factor is an exact power of ten
(``10.0 ** k`` is correctly rounded) and converting back and forth is lossless to float precision.

``"counts"`` (raw ADC counts, LSB) is a unit of unknown scale: it can label a calibration but it
cannot be converted to anything physical; give the samples' physical unit instead.

>>> conversion_factor("uT", "mG")
10.0
>>> get_unit("µT").name, get_unit("gauss").name, get_unit("LSB").name
('uT', 'G', 'counts')
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from types import MappingProxyType

from .errors import OptionError
from .findings import Reason
from .remedy import option

__all__ = [
    "EARTH_FIELD_UT",
    "PLAUSIBLE_FIELD_UT",
    "UNITS",
    "Unit",
    "canonical_name",
    "conversion_factor",
    "field_unit_reason",
    "get_unit",
]


@dataclass(frozen=True)
class Unit:
    """A unit of magnetic flux density.

    Parameters
    ----------
    name : str
        Canonical ASCII symbol (``"uT"``, ``"G"``, ``"counts"`` ...): what magfit writes in files.
    description : str
        Spelled-out name, for messages (``"microtesla"``).
    exponent : int or None
        One unit is ``10 ** exponent`` tesla; None when the scale is unknown (raw counts).
    aliases : tuple of str
        Other spellings accepted by :func:`get_unit` (matched case-insensitively).
    """

    name: str
    description: str
    exponent: int | None
    aliases: tuple[str, ...] = ()

    @property
    def is_physical(self) -> bool:
        """True when the unit has a known scale (it is not raw counts)."""
        return self.exponent is not None

    @property
    def tesla(self) -> float | None:
        """Value of one unit in tesla, or None for raw counts."""
        return None if self.exponent is None else 10.0**self.exponent

    @property
    def gauss(self) -> float | None:
        """Value of one unit in gauss, or None for raw counts."""
        return None if self.exponent is None else 10.0 ** (self.exponent + 4)


_ALL = (
    Unit("T", "tesla", 0, ("tesla", "teslas")),
    Unit("mT", "millitesla", -3, ("millitesla", "milli-tesla")),
    # The micro sign (U+00B5) and the Greek mu (U+03BC) both casefold to the Greek mu.
    Unit("uT", "microtesla", -6, ("µT", "μT", "microtesla", "micro-tesla")),
    Unit("nT", "nanotesla", -9, ("nanotesla", "nano-tesla")),
    Unit("G", "gauss", -4, ("gauss", "Ga", "Gs")),
    Unit("mG", "milligauss", -7, ("milligauss", "milli-gauss", "mGauss", "mGa")),
    Unit("counts", "raw counts (unknown scale)", None, ("count", "LSB", "raw")),
)

#: The known units by canonical name.
UNITS: Mapping[str, Unit] = MappingProxyType({unit.name: unit for unit in _ALL})

_LOOKUP = {alias.casefold(): unit for unit in _ALL for alias in (unit.name, *unit.aliases)}


def get_unit(name: str) -> Unit:
    """The unit called ``name`` (canonical symbol or alias, case-insensitive, e.g. ``"µT"``).

    Raises
    ------
    OptionError
        ``name`` is not a unit magfit knows; the message lists the valid names.
    """
    unit = _LOOKUP.get(str(name).strip().casefold()) if isinstance(name, str) else None
    if unit is None:
        valid = ", ".join(f"{u.name} ({u.description})" for u in _ALL)
        raise OptionError(f"unknown unit {name!r}; valid units: {valid}")
    return unit


def canonical_name(name: str) -> str:
    """The canonical ASCII symbol of ``name`` (``"µT"`` -> ``"uT"``, ``"gauss"`` -> ``"G"``)."""
    return get_unit(name).name


def conversion_factor(source: str, target: str) -> float:
    """The factor that converts values in ``source`` units to ``target`` units (``x_target = f * x_source``).

    Raises
    ------
    OptionError
        A name is unknown, or one of the units is raw counts, whose scale is unknown.
    """
    src, dst = get_unit(source), get_unit(target)
    if src.exponent is None or dst.exponent is None:
        raise OptionError(
            f"cannot convert {src.name!r} to {dst.name!r}: raw counts have no known scale; "
            "give the physical unit of the samples (e.g. 'uT', 'nT', 'G')"
        )
    return 10.0 ** (src.exponent - dst.exponent)


#: The Earth's main field at its surface, µT: about 22 (the South Atlantic anomaly) to 67 (near the magnetic
#: poles) in the World Magnetic Model.
EARTH_FIELD_UT = (22.0, 67.0)

#: The field strengths (µT) a calibration may fit and still be the Earth's field in the declared unit: the
#: surface range widened for altitude (the dipole field falls as 1/r³: about 3 % lower 100 km up) and for
#: the steel of buildings and vehicles, which can change the local field by tens of percent.
PLAUSIBLE_FIELD_UT = (15.0, 100.0)


#: How far outside the surface range a value may lie in another unit for that unit to be named as the likely
#: one (a factor: 18-80 uT); a value further out is more likely raw counts than a field in that unit.
LIKELY_MARGIN = 1.2


def field_unit_reason(field_strength: float, unit: str | None) -> Reason | None:
    """None when ``field_strength`` in ``unit`` can be the Earth's field, else why not and the likely unit.

    A calibration's field strength is the radius of its corrected sphere (the Earth's field B of paper
    eq. 1, in the samples' unit). Anywhere on Earth B lies in :data:`EARTH_FIELD_UT`; a value outside
    :data:`PLAUSIBLE_FIELD_UT` once converted to µT means the declared unit is not the samples' unit.
    Physical units are powers of ten apart by at least 10, wider than the surface range widened by
    :data:`LIKELY_MARGIN` (18-80 µT, 4.4x), so at most one unit puts the value there: that one is named.
    When none does, the samples are most likely raw counts of the sensor's ADC, whose scale only its
    sensitivity gives.

    Parameters
    ----------
    field_strength : float
        The fitted field strength, in ``unit``.
    unit : str or None
        The declared unit of the samples (any name :func:`get_unit` takes). None, raw counts and names
        magfit does not know cannot be checked: None is returned.

    Returns
    -------
    Reason or None
        A :class:`magfit.findings.Reason` with code ``"unit_mismatch"`` and, as its remedy, the likely
        unit (``("unit", "T")``, or ``("unit", "counts")`` for raw counts); None when the value is plausible
        or cannot be checked.

    >>> field_unit_reason(48.0, "uT") is None
    True
    >>> field_unit_reason(6.6e-05, "uT").remedy
    (('unit', 'T'),)
    """
    if unit is None:
        return None
    try:
        declared = get_unit(unit)
    except OptionError:
        return None
    value = float(field_strength)
    if declared.exponent is None or not value > 0 or value == float("inf"):
        return None
    in_ut = value * 10.0 ** (declared.exponent + 6)
    low, high = PLAUSIBLE_FIELD_UT
    if low <= in_ut <= high:
        return None
    converted = "" if declared.name == "uT" else f" ({in_ut:.3g} uT)"
    earth = (
        f"the fitted field strength, {value:.6g} {declared.name}{converted}, is not the Earth's field, which "
        f"is {EARTH_FIELD_UT[0]:.0f}-{EARTH_FIELD_UT[1]:.0f} uT on the surface ({low:.0f}-{high:.0f} uT allowed for "
        "altitude and nearby steel)"
    )
    for candidate in UNITS.values():
        if candidate.exponent is None or candidate is declared:
            continue
        as_candidate = value * 10.0 ** (candidate.exponent + 6)
        if EARTH_FIELD_UT[0] / LIKELY_MARGIN <= as_candidate <= EARTH_FIELD_UT[1] * LIKELY_MARGIN:
            return Reason(
                f"{earth}: the samples look like {candidate.description} ({value:.6g} {candidate.name} = "
                f"{as_candidate:.3g} uT), not {declared.description}; declare {option('unit', candidate.name)}",
                "unit_mismatch",
                (("unit", candidate.name),),
            )
    return Reason(
        f"{earth}, nor in any other unit: the samples are most likely the sensor's raw counts (or the sensor "
        f"sits in steel); declare {option('unit', 'counts')}, or convert the counts with the sensor's sensitivity "
        "(counts per gauss) before fitting",
        "unit_mismatch",
        (("unit", "counts"),),
    )
