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

import math

import numpy as np
from numpy.typing import NDArray

from ..findings import AXIS_DIRECTIONS, Coverage
from ..geometry.cells import EqualAreaPartition, partition

__all__ = ["AXIS_DIRECTIONS", "Coverage", "EqualAreaPartition", "coverage", "partition"]

#: Cells whose centre lies within this angle of a half-axis describe that axis.
_CAP_DEG = 45.0
#: A half-axis is "missing" below this share of its cells reached, "sparse" below the second.
MISSING_SHARE = 0.25
SPARSE_SHARE = 0.75


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
