"""The Earth's field offline: the World Magnetic Model (WMM) at a place and a date.

A calibration scales the corrected field to a sphere whose radius is the local field strength B of eq. (1).
The samples alone give B only in their own unit and only as well as the sensor's gain is known; the World
Magnetic Model (NOAA NCEI and the British Geological Survey) gives it from the position and the date, to
about 140 nT (0.3 % of a typical 50 µT field, the model's own global error figure) away from local
anomalies. magfit uses it to pin the fit's scale (``field_strength=``, ``--field-strength wmm``) and to
check a fit: a fitted field far from the model's is a unit mix-up, steel near the sensor or a wrong place.

The coefficients come with the ``pygeomag`` package (the ``wmm`` extra, pure Python, no download at run
time): WMM2025 for 2025.0-2030.0, and the earlier models for dates back to 2010, so that an old log is
checked against the model of its own time. The model is imported when first used.

The components follow the model's convention: north (X), east (Y) and down (Z) in nanotesla, inclination
positive downwards, declination positive east of true north.

>>> field = field_at(47.4, 8.5, alt_km=0.5, date="2026-06-01")   # doctest: +SKIP
>>> round(field.total_in("uT"), 2)                                # doctest: +SKIP
48.38
"""

from __future__ import annotations

import datetime as _dt
import functools
import math
import re
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .errors import OptionError
from .remedy import option
from .units import conversion_factor, get_unit

__all__ = ["Field", "decimal_year", "field_at", "parse_date", "parse_location"]

#: The install command of the extra that provides the model's coefficients.
INSTALL_HINT = "pip install 'magfit[wmm]'"
#: First year of each model the package ships; each is valid for five years from its epoch.
_MODEL_EPOCHS = (2010, 2015, 2020, 2025)
#: The model's altitude range (km above the WGS-84 ellipsoid), as its software accepts it.
MIN_ALT_KM, MAX_ALT_KM = -1.0, 850.0


@dataclass(frozen=True)
class Field:
    """The Earth's main field at one place and date, from the World Magnetic Model.

    Attributes
    ----------
    north, east, down : float
        The field's components X, Y, Z in nT (down positive: the field points into the ground in the
        northern hemisphere).
    total : float
        Its strength F in nT: what a calibrated magnetometer should read in every attitude.
    horizontal : float
        H in nT, the part a level compass uses.
    inclination_deg : float
        Dip below the horizontal, degrees (the paper's δ in eq. 1).
    declination_deg : float
        Angle of magnetic north east of true north, degrees.
    latitude, longitude, altitude_km : float
        The place (geodetic degrees; km above the WGS-84 ellipsoid).
    year : float
        The date as a decimal year (2026.41).
    model : str
        The model used, e.g. ``"WMM-2025"``.
    total_uncertainty : float or None
        The model's global one-sigma error of F in nT (138 for WMM2025), None when not published for it.
    """

    north: float
    east: float
    down: float
    total: float
    horizontal: float
    inclination_deg: float
    declination_deg: float
    latitude: float
    longitude: float
    altitude_km: float
    year: float
    model: str
    total_uncertainty: float | None = None

    def total_in(self, unit: str) -> float:
        """The field strength in ``unit`` (``"uT"``, ``"G"``, ``"mG"`` ...).

        Raises
        ------
        OptionError
            ``unit`` is unknown, or raw counts, whose scale the model cannot know.
        """
        return self.total * _factor_from_nt(unit)

    def vector_in(self, unit: str) -> NDArray[np.float64]:
        """(north, east, down) in ``unit``, shape (3,)."""
        return np.array([self.north, self.east, self.down]) * _factor_from_nt(unit)

    def describe(self) -> str:
        """``WMM-2025 at 47.4°, 8.5°, 0.5 km on 2026.41`` (for messages)."""
        return f"{self.model} at {self.latitude:g}°, {self.longitude:g}°, {self.altitude_km:g} km on {self.year:.2f}"


def _factor_from_nt(unit: str) -> float:
    """The factor from nT to ``unit``, refusing raw counts with the reason."""
    if not get_unit(unit).is_physical:
        raise OptionError(
            "the World Magnetic Model gives the field in physical units; samples in raw counts (unknown scale) "
            f"cannot be pinned to it: give the samples' unit ({option('unit', 'uT')}, G, mG ...) or a field "
            "strength in counts"
        )
    return conversion_factor("nT", unit)


def _pygeomag() -> Any:
    """The ``pygeomag`` module, or an ImportError whose message is the install command."""
    try:
        import pygeomag
    except ImportError:
        raise ImportError(
            f"the World Magnetic Model needs pygeomag, which is not installed (the wmm extra): {INSTALL_HINT}",
            name="pygeomag",
        ) from None
    return pygeomag


@functools.lru_cache(maxsize=len(_MODEL_EPOCHS))
def _model(epoch: int) -> Any:
    """The model valid from ``epoch`` (its coefficients are parsed once, on first use)."""
    geomag = _pygeomag()
    return geomag.GeoMag(base_year=epoch)


def decimal_year(date: _dt.date | _dt.datetime | float | str | None = None) -> float:
    """``date`` as a decimal year, the model's time argument; None is today (UTC).

    A date counts its days as the model's own software does (1 January is ``year + 0``, each day
    ``1 / 365`` or ``1 / 366``); a datetime adds the fraction of its day (UTC when it has a time zone).
    Numbers are taken as decimal years already; strings are ``YYYY-MM-DD`` (:func:`parse_date`).
    """
    if date is None:
        date = _dt.datetime.now(_dt.timezone.utc).date()
    if isinstance(date, str):
        date = parse_date(date)
    if isinstance(date, (int, float)) and not isinstance(date, bool):
        if not math.isfinite(date):
            raise OptionError(f"the date must be a finite decimal year, got {date!r}")
        return float(date)
    if not isinstance(date, _dt.date):
        raise OptionError(f"the date must be a date, a datetime, a decimal year or 'YYYY-MM-DD', got {date!r}")
    day_fraction = 0.0
    if isinstance(date, _dt.datetime):
        if date.tzinfo is not None:
            date = date.astimezone(_dt.timezone.utc)
        day_fraction = (date.hour * 3600 + date.minute * 60 + date.second + date.microsecond / 1e6) / 86400
    start = _dt.date(date.year, 1, 1)
    days_in_year = (_dt.date(date.year + 1, 1, 1) - start).days
    day_of_year = (_dt.date(date.year, date.month, date.day) - start).days
    return date.year + (day_of_year + day_fraction) / days_in_year


def parse_date(text: str) -> _dt.date:
    """``"2026-06-01"`` into a date; anything else is an OptionError that shows the expected form."""
    try:
        return _dt.date.fromisoformat(str(text).strip())
    except ValueError:
        raise OptionError(f"expected a date as YYYY-MM-DD (e.g. 2026-06-01), got {text!r}") from None


_ALTITUDE = re.compile(r"^\s*([-+]?[\d.]+(?:[eE][-+]?\d+)?)\s*(km|m)?\s*$")


def parse_location(text: str) -> tuple[float, float, float]:
    """``"LAT,LON[,ALT]"`` into (latitude, longitude, altitude in km).

    Latitude and longitude are decimal degrees (north and east positive); the altitude is in km above
    the WGS-84 ellipsoid, or in metres with an ``m`` suffix (``47.4,8.5,500m``); it defaults to 0.
    """
    items = [item.strip() for item in str(text).split(",")]
    if len(items) not in (2, 3) or not all(items):
        raise OptionError(
            f"expected a location as LAT,LON or LAT,LON,ALT (decimal degrees, altitude in km or with an m "
            f"suffix, e.g. 47.4,8.5,0.5), got {text!r}"
        )
    try:
        lat, lon = float(items[0]), float(items[1])
    except ValueError:
        raise OptionError(f"the latitude and longitude must be decimal degrees (e.g. 47.4,8.5), got {text!r}") from None
    alt_km = 0.0
    if len(items) == 3:
        match = _ALTITUDE.match(items[2])
        try:
            value = float(match.group(1)) if match else math.nan
        except ValueError:
            value = math.nan
        if not match or not math.isfinite(value):
            raise OptionError(f"the altitude must be a number of km, or of metres with an m suffix, got {items[2]!r}")
        alt_km = value / 1000.0 if match.group(2) == "m" else value
    _check_place(lat, lon, alt_km)
    return lat, lon, alt_km


def _check_place(lat: float, lon: float, alt_km: float) -> None:
    if not (math.isfinite(lat) and -90.0 <= lat <= 90.0):
        raise OptionError(f"the latitude must be between -90 and 90 degrees, got {lat!r}")
    if not (math.isfinite(lon) and -180.0 <= lon <= 360.0):
        raise OptionError(f"the longitude must be between -180 and 360 degrees, got {lon!r}")
    if not (math.isfinite(alt_km) and MIN_ALT_KM <= alt_km <= MAX_ALT_KM):
        raise OptionError(
            f"the altitude must be between {MIN_ALT_KM:g} and {MAX_ALT_KM:g} km (the model's range), got {alt_km!r} km"
            " (give metres with an m suffix: 500m)"
        )


def field_at(
    lat: float, lon: float, alt_km: float = 0.0, date: _dt.date | _dt.datetime | float | str | None = None
) -> Field:
    """The World Magnetic Model's field at a place and date (components in nT).

    Parameters
    ----------
    lat, lon : float
        Geodetic latitude and longitude, degrees (north and east positive; longitudes up to 360 accepted).
    alt_km : float
        Height above the WGS-84 ellipsoid, km (-1 to 850).
    date : date, datetime, float, str or None
        The date (a decimal year, or ``"YYYY-MM-DD"``); None is today (UTC). The model of that date is used:
        WMM2025 from 2025.0 to 2030.0, the earlier ones back to 2010.

    Raises
    ------
    OptionError
        A place outside the model's range, or a date no shipped model covers (naming the range).
    ImportError
        The ``wmm`` extra is not installed (the message is the install command).
    """
    lat, lon, alt_km = float(lat), float(lon), float(alt_km)
    _check_place(lat, lon, alt_km)
    year = decimal_year(date)
    epoch = max((e for e in _MODEL_EPOCHS if e <= year), default=None)
    if epoch is None or year >= _MODEL_EPOCHS[-1] + 5:
        first, last = _MODEL_EPOCHS[0], _MODEL_EPOCHS[-1] + 5
        raise OptionError(
            f"no World Magnetic Model covers {year:.2f}: the models shipped cover {first}.0 to {last}.0"
            + (" (a newer pygeomag may ship the next model); give the field strength instead" if year >= last else "")
        )
    model = _model(epoch)
    longitude = lon - 360.0 if lon > 180.0 else lon
    result = model.calculate(glat=lat, glon=longitude, alt=alt_km, time=year)
    try:
        uncertainty: float | None = float(result.calculate_uncertainty().f)
    except (ValueError, AttributeError):  # the older models have no published error figures in the package
        uncertainty = None
    return Field(
        north=float(result.x),
        east=float(result.y),
        down=float(result.z),
        total=float(result.f),
        horizontal=float(result.h),
        inclination_deg=float(result.i),
        declination_deg=float(result.d),
        latitude=lat,
        longitude=longitude,
        altitude_km=alt_km,
        year=year,
        model=str(model.model),
        total_uncertainty=uncertainty,
    )


#: A fitted field further than this (relative) from the model's is worth a warning: the model is good to
#: 0.3 %, local anomalies rarely reach a few %, so 10 % is something near the sensor or a wrong unit.
MODEL_TOLERANCE = 0.10


def compare_fitted(fitted: float, unit: str, field: Field, *, tolerance: float = MODEL_TOLERANCE) -> str | None:
    """None when a fitted field strength (in ``unit``) agrees with the model's; else why it may not.

    The likely causes are named: a unit that would make them agree (the samples in G labelled µT), steel or
    magnets near the sensor while recording, a sensor range or gain other than the one assumed, a wrong
    place or date.
    """
    expected = field.total_in(unit)
    ratio = fitted / expected
    if abs(ratio - 1.0) <= tolerance:
        return None
    how = f"{100 * (ratio - 1):+.0f} % off" if 0.5 < ratio < 2 else f"{ratio:.3g} times"
    text = (
        f"the fitted field {fitted:.4g} {unit} is {how} the World Magnetic Model's {expected:.4g} {unit} "
        f"({field.describe()}): "
    )
    for other in ("T", "mT", "uT", "nT", "G", "mG"):
        if other != get_unit(unit).name and abs(fitted / field.total_in(other) - 1.0) <= tolerance:
            return text + f"the samples look like {other}, not {unit} (check {option('unit', unit)})"
    return text + (
        "likely causes: steel or magnets near the sensor while recording (indoors, a vehicle, a desk), a sensor range "
        f"or gain other than the one assumed, or a wrong {option('location', 'LAT,LON')} or "
        f"{option('date', 'YYYY-MM-DD')}"
    )
