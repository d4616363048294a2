"""Samples clipped at the sensor's full scale: found, counted and left out before any fit.

A magnetometer whose field plus hard-iron offset exceeds its full-scale range reports its largest (or
smallest) code on that axis, whatever the field does beyond it. Such a row does not lie on the
ellipsoid of eq. (2): one of its coordinates is the range's end, not the field. Kept, the rows pull
the fit towards a box (heading errors of several degrees, the verdict none the wiser, because the
clipped rows form a flat face that an ellipsoid near it fits to a few per cent); with most rows
clipped the fit is meaningless.

The signature of clipping, on one axis of the raw samples (``x`` one column):

- the extreme ``m = max(x)`` (or ``min(x)``) is repeated exactly on ``c`` rows, and
- ``c`` is much more than the rows at each of the next distinct values inwards. A field direction
  uniform on the sphere projects onto an axis uniformly (Archimedes' hat-box theorem), so on a quantised
  sensor every level near the end holds about as many rows as the next one, and on a float sensor every
  value is held once; a clipped end holds every row beyond it.
  The test: ``c ≥`` :data:`MIN_CLIPPED` and ``c ≥`` :data:`CLIP_RATIO` times the mean count of the
  :data:`NEIGHBOURS` values next to it. Samples held for several rows (sample-and-hold) repeat every value
  alike and pass.
- or ``m`` is an integer sensor's full-scale code (``2^(b−1) − 1`` or ``−2^(b−1)`` for b = 8, 12 to 16:
  ±127/−128, ±2047/−2048, −4096 of the HMC5883L's overflow, ±32767/−32768), the column holds integers and
  ``m`` is held at least twice: no field reading lands on the range's end by chance.

A row clipped on any axis is left out whole (its other two coordinates are right, but the row is no
point of the ellipsoid). :func:`find_clipped` runs on the samples only: a :class:`~magfit.Statistics`
holds no rows to find them in.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

__all__ = ["CLIP_RATIO", "MIN_CLIPPED", "Clipping", "find_clipped"]

#: Rows at one extreme needed before it can be called clipped.
MIN_CLIPPED = 4
#: An extreme is clipped when it holds this many times the mean count of its neighbouring values.
CLIP_RATIO = 4.0
#: How many distinct values next to the extreme its count is compared with.
NEIGHBOURS = 5
#: Full-scale codes of integer sensors (two's complement, 8 and 12 to 16 bits).
FULL_SCALE_CODES = frozenset(
    value for bits in (8, 12, 13, 14, 15, 16) for value in (2 ** (bits - 1) - 1, -(2 ** (bits - 1)))
)

_AXES = ("x", "y", "z")


@dataclass(frozen=True)
class Clipping:
    """Where the samples reached the sensor's full scale.

    Attributes
    ----------
    n_samples : int
        Rows examined.
    clipped : ndarray of bool, shape (n_samples,)
        The rows clipped on at least one axis.
    ends : tuple of (axis, value, rows)
        Each clipped end: the axis ("x", "y", "z"), the value it is held at (input units) and how many
        rows hold it.
    """

    n_samples: int
    clipped: NDArray[np.bool_]
    ends: tuple[tuple[str, float, int], ...]

    @property
    def n_clipped(self) -> int:
        """Rows clipped on at least one axis."""
        return int(self.clipped.sum())

    @property
    def n_kept(self) -> int:
        return self.n_samples - self.n_clipped

    def describe(self, unit: str | None = None) -> str:
        """The clipped ends in words: ``"x at +1.4 (212 rows), z at −1.4 (40 rows)"``."""
        label = f" {unit}" if unit else ""
        return ", ".join(f"{axis} at {value:+.6g}{label} ({rows} rows)" for axis, value, rows in self.ends)

    def to_dict(self) -> dict[str, object]:
        """What ``details["saturation"]`` records: the counts and the ends (not the row mask)."""
        return {
            "n_samples": self.n_samples,
            "n_clipped": self.n_clipped,
            "ends": [{"axis": axis, "value": value, "rows": rows} for axis, value, rows in self.ends],
        }


def _clipped_end(column: NDArray[np.generic], value: float, held: NDArray[np.bool_], upper: bool) -> bool:
    """Whether the extreme ``value`` of ``column``, held on the rows ``held``, is a clipped end."""
    count = int(held.sum())
    if count < 2:
        return False
    if value in FULL_SCALE_CODES and bool(np.all(np.equal(np.mod(column, 1), 0))):
        return True
    if count < MIN_CLIPPED:
        return False
    inner = np.asarray(column[~held], dtype=np.float64)
    inner = inner if upper else -inner
    if inner.size == 0:
        return True  # the axis never left its end
    # The NEIGHBOURS distinct values next to the end and how many rows hold each: the values above the
    # window's lowest are whole in it; when the window holds too few distinct values, count them all.
    window = min(inner.size, 50 * NEIGHBOURS)
    values, counts = np.unique(np.partition(inner, inner.size - window)[inner.size - window :], return_counts=True)
    if values.size <= NEIGHBOURS and window < inner.size:
        values, counts = np.unique(inner, return_counts=True)
    neighbours = counts[::-1][:NEIGHBOURS]
    return count >= CLIP_RATIO * float(np.mean(neighbours))


def find_clipped(samples: NDArray[np.generic]) -> Clipping:
    """The rows of ``samples`` (N, 3), any numeric dtype, clipped at the sensor's full scale (module docstring)."""
    n = samples.shape[0]
    clipped = np.zeros(n, dtype=bool)
    ends: list[tuple[str, float, int]] = []
    if n == 0:
        return Clipping(0, clipped, ())
    for axis in range(3):
        column = samples[:, axis]
        if column.max() == column.min():
            continue  # a constant axis is a dead axis or no motion: the support checks name that
        for upper in (True, False):
            extreme = column.max() if upper else column.min()
            held = column == extreme
            if _clipped_end(column, float(extreme), held, upper):
                clipped |= held
                ends.append((_AXES[axis], float(extreme), int(held.sum())))
    return Clipping(n, clipped, tuple(ends))
