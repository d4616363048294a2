"""Where and when a log was recorded, from its own GNSS fixes: a leaf the readers and the motion streams share."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

__all__ = ["Position", "median_position"]


@dataclass(frozen=True)
class Position:
    """Where and when a log was recorded, from its own GNSS fixes (for the World Magnetic Model).

    Attributes
    ----------
    lat_deg, lon_deg : float
        The median of the 3-D fixes, geodetic degrees.
    alt_km : float
        Their median altitude above mean sea level, km (the model's ellipsoid height differs by the geoid's
        tens of metres: nothing for the field).
    time_s : float
        UTC seconds since 1970 of the first fix with a time, NaN when the receiver gave none.
    n_fixes : int
        How many 3-D fixes the medians are taken over.
    """

    lat_deg: float
    lon_deg: float
    alt_km: float
    time_s: float
    n_fixes: int


def median_position(
    lat_deg: NDArray[np.float64], lon_deg: NDArray[np.float64], alt_m: NDArray[np.float64], time_s: NDArray[np.float64]
) -> Position | None:
    """The :class:`Position` of the fixes given (already the 3-D ones), or None when there is no finite one."""
    good = np.isfinite(lat_deg) & np.isfinite(lon_deg) & (np.abs(lat_deg) <= 90) & (np.abs(lon_deg) <= 180)
    good &= ~((lat_deg == 0) & (lon_deg == 0))  # a receiver without a fix reports 0, 0
    if not np.any(good):
        return None
    altitude = alt_m[good][np.isfinite(alt_m[good])]
    times = time_s[good][np.isfinite(time_s[good]) & (time_s[good] > 0)]
    return Position(
        lat_deg=float(np.median(lat_deg[good])),
        lon_deg=float(np.median(lon_deg[good])),
        alt_km=float(np.median(altitude)) / 1000 if len(altitude) else 0.0,
        time_s=float(times[0]) if len(times) else float("nan"),
        n_fixes=int(np.count_nonzero(good)),
    )
