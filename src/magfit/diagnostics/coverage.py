"""Which directions the samples reach: an equal-area partition of the unit sphere, as MotionCal does.

MotionCal (Paul Stoffregen) splits the sphere into 100 regions of equal area and reports the share
with no data as its "gaps" error. magfit builds the same kind of partition with Leopardi's recursive
zonal equal-area construction (P. Leopardi, "A partition of the unit sphere into regions of equal area
and small diameter", ETNA 25, 2006, pp. 309-327): two polar caps and collars of cells, every cell of
area 4π / n, so the share of cells reached is the share of directions covered.

The directions are those of the *calibrated*, normalised samples: the direction of the earth field
as seen in the sensor frame. A cell that no sample reaches is a field direction the sensor never saw.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

__all__ = ["AXIS_DIRECTIONS", "Coverage", "EqualAreaPartition", "coverage", "partition"]

#: The six sensor half-axes coverage is described by, with their unit vectors.
AXIS_DIRECTIONS: dict[str, tuple[float, float, float]] = {
    "+x": (1.0, 0.0, 0.0),
    "−x": (-1.0, 0.0, 0.0),
    "+y": (0.0, 1.0, 0.0),
    "−y": (0.0, -1.0, 0.0),
    "+z": (0.0, 0.0, 1.0),
    "−z": (0.0, 0.0, -1.0),
}
#: Cells whose centre lies within this angle of a half-axis describe that axis.
_CAP_DEG = 45.0
#: A half-axis is "missing" below this share of its cells reached, "sparse" below the second.
MISSING_SHARE = 0.25
SPARSE_SHARE = 0.75


@dataclass(frozen=True)
class EqualAreaPartition:
    """n cells of equal area: colatitude boundaries of each zone and the cells per zone."""

    n: int
    boundaries: NDArray[np.float64]  # colatitudes, radians, increasing from 0 to π (zones + 1 values)
    cells_per_zone: NDArray[np.int64]
    first_cell: NDArray[np.int64]  # index of the first cell of each zone

    def cell(self, directions: NDArray[np.float64]) -> NDArray[np.int64]:
        """The cell index of each direction, shape (N,) for (N, 3) vectors (any length > 0)."""
        norm = np.linalg.norm(directions, axis=1)
        cos_colatitude = np.clip(directions[:, 2] / np.where(norm > 0, norm, 1.0), -1.0, 1.0)
        colatitude = np.arccos(cos_colatitude)
        zone = np.clip(np.searchsorted(self.boundaries, colatitude, side="right") - 1, 0, len(self.cells_per_zone) - 1)
        longitude = np.mod(np.arctan2(directions[:, 1], directions[:, 0]), 2.0 * math.pi)
        count = self.cells_per_zone[zone]
        sector = np.minimum((longitude / (2.0 * math.pi) * count).astype(np.int64), count - 1)
        return np.asarray(self.first_cell[zone] + sector, dtype=np.int64)

    def centres(self) -> NDArray[np.float64]:
        """Unit vector at the centre of each cell, shape (n, 3)."""
        rows = []
        for zone, count in enumerate(self.cells_per_zone):
            top, bottom = self.boundaries[zone], self.boundaries[zone + 1]
            colatitude = 0.0 if zone == 0 else math.pi if zone == len(self.cells_per_zone) - 1 else 0.5 * (top + bottom)
            for sector in range(int(count)):
                longitude = (sector + 0.5) * 2.0 * math.pi / count
                rows.append(
                    (
                        math.sin(colatitude) * math.cos(longitude),
                        math.sin(colatitude) * math.sin(longitude),
                        math.cos(colatitude),
                    )
                )
        return np.array(rows)


@functools.lru_cache(maxsize=8)
def partition(n: int = 100) -> EqualAreaPartition:
    """Leopardi's equal-area partition of the sphere into ``n`` cells (n >= 3)."""
    cell_area = 4.0 * math.pi / n
    cap = 2.0 * math.asin(math.sqrt(1.0 / n))  # a polar cap of one cell: area 2π(1 − cos θ) = 4π / n
    ideal_angle = math.sqrt(cell_area)  # cells about as tall as they are wide
    n_collars = max(1, round((math.pi - 2.0 * cap) / ideal_angle))
    collar_angle = (math.pi - 2.0 * cap) / n_collars
    # Ideal (real) number of cells per collar, rounded with the remainder carried to the next collar.
    counts = [1]
    carry = 0.0
    for k in range(n_collars):
        top, bottom = cap + k * collar_angle, cap + (k + 1) * collar_angle
        ideal = 2.0 * math.pi * (math.cos(top) - math.cos(bottom)) / cell_area + carry
        counts.append(max(1, round(ideal)))
        carry = ideal - counts[-1]
    counts.append(1)
    counts[-2] += n - sum(counts)  # round-off: the total is exactly n
    # Boundaries so that each zone's area is exactly its cell count: cap of k cells at 2 asin(√(k/n)).
    cumulative = np.cumsum([0, *counts])
    boundaries = 2.0 * np.arcsin(np.sqrt(np.clip(cumulative / n, 0.0, 1.0)))
    return EqualAreaPartition(
        n=n,
        boundaries=boundaries,
        cells_per_zone=np.array(counts, dtype=np.int64),
        first_cell=np.asarray(cumulative[:-1], dtype=np.int64),
    )


@dataclass(frozen=True)
class Coverage:
    """How much of the sphere of field directions the calibrated samples reach.

    Attributes
    ----------
    cells : int
        Number of equal-area cells (100, as MotionCal).
    cells_reached : int
        Cells holding at least one sample.
    share : float
        ``cells_reached / cells``, 0 to 1.
    axis_shares : dict
        For each sensor half-axis ("+x", "−x", ... "−z"), the share of the cells within 45° of it that
        are reached.
    missing : tuple of str
        Half-axes with less than 25 % of their cells reached: directions the field was (almost) never
        seen along.
    sparse : tuple of str
        Half-axes with 25 % to 75 % of their cells reached.
    """

    cells: int
    cells_reached: int
    share: float
    axis_shares: dict[str, float]
    missing: tuple[str, ...]
    sparse: tuple[str, ...]

    @property
    def unseen_axes(self) -> tuple[str, ...]:
        """Sensor axes ("x", "y", "z") the samples form a band around: the field was seen at neither end of
        the axis (both half-axes missing) but along the four half-axes at right angles to it.

        Nothing in such samples fixes the offset or the scale along that axis, whatever a fit returns.
        (A cap of directions, as from a vehicle that only tilts a little, misses more than that and is
        left to the observability analysis.)
        """
        unseen = []
        for axis in "xyz":
            others = [f"{sign}{other}" for other in "xyz" if other != axis for sign in ("+", "−")]
            ends_missing = f"+{axis}" in self.missing and f"−{axis}" in self.missing
            if ends_missing and not any(half in self.missing for half in others):
                unseen.append(axis)
        return tuple(unseen)

    def to_dict(self) -> dict[str, Any]:
        return {
            "cells": self.cells,
            "cells_reached": self.cells_reached,
            "share": self.share,
            "axis_shares": dict(self.axis_shares),
            "missing": list(self.missing),
            "sparse": list(self.sparse),
        }

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> Coverage:
        return cls(
            cells=int(data["cells"]),
            cells_reached=int(data["cells_reached"]),
            share=float(data["share"]),
            axis_shares={str(k): float(v) for k, v in data["axis_shares"].items()},
            missing=tuple(data["missing"]),
            sparse=tuple(data["sparse"]),
        )

    def summary(self) -> list[str]:
        """Plain-language lines: the share reached and the directions missing."""
        lines = [
            f"Coverage: the samples reach {self.cells_reached} of {self.cells} equal-area directions "
            f"({100 * self.share:.0f} %)."
        ]
        for axis in self.missing:
            lines.append(
                f"No samples with the field along the sensor {axis} axis ({_pointing_words(axis)}): "
                f"only {100 * self.axis_shares[axis]:.0f} % of those directions were reached; turn the sensor "
                "so that this side faces the field."
            )
        for axis in self.sparse:
            lines.append(
                f"Few samples with the field along the sensor {axis} axis ({_pointing_words(axis)}): "
                f"{100 * self.axis_shares[axis]:.0f} % of those directions were reached."
            )
        return lines


def _pointing_words(axis: str) -> str:
    """Where that axis points when the field lies along it (the field dips down north of the equator)."""
    letter = axis[1]
    if axis[0] == "+":
        return f"the sensor {letter} axis pointing along the field: north and down, in the northern hemisphere"
    return f"the sensor {letter} axis pointing against the field: south and up, in the northern hemisphere"


def coverage(directions: NDArray[np.float64], n_cells: int = 100) -> Coverage:
    """Coverage of (N, 3) calibrated samples (any length; only their direction counts)."""
    cells = partition(n_cells)
    reached = np.zeros(n_cells, dtype=bool)
    if directions.shape[0]:
        reached[cells.cell(directions)] = True
    centres = cells.centres()
    cos_cap = math.cos(math.radians(_CAP_DEG))
    axis_shares: dict[str, float] = {}
    for name, vector in AXIS_DIRECTIONS.items():
        near = centres @ np.asarray(vector) >= cos_cap
        axis_shares[name] = float(reached[near].mean())
    missing = tuple(name for name, share in axis_shares.items() if share < MISSING_SHARE)
    sparse = tuple(name for name, share in axis_shares.items() if MISSING_SHARE <= share < SPARSE_SHARE)
    return Coverage(
        cells=n_cells,
        cells_reached=int(reached.sum()),
        share=float(reached.mean()),
        axis_shares=axis_shares,
        missing=missing,
        sparse=sparse,
    )
