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

__all__ = ["UNITS", "Unit", "canonical_name", "conversion_factor", "get_unit"]


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
