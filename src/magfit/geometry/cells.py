"""An equal-area partition of the unit sphere into direction cells, as MotionCal's coverage uses.

MotionCal (Paul Stoffregen) splits the sphere into 100 regions of equal area and reports the share
with no data as its "gaps" error. magfit builds the same kind of partition with Leopardi's recursive
zonal equal-area construction (P. Leopardi, "A partition of the unit sphere into regions of equal area
and small diameter", ETNA 25, 2006, pp. 309-327): two polar caps and collars of cells, every cell of
area 4π / n, so the share of cells reached is the share of directions covered. Used by the coverage
diagnostics, the even subsamples and the plots.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

__all__ = ["EqualAreaPartition", "partition"]

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
