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
from functools import cached_property

import numpy as np
from numpy.typing import NDArray

from .statistics import Statistics

__all__ = ["CLIP_RATIO", "MIN_CLIPPED", "Clipping", "find_clipped", "statistics_and_clipping"]

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
        The rows clipped on at least one axis (read-only when none is).
    ends : tuple of (axis, value, rows)
        Each clipped end: the axis ("x", "y", "z"), the value it is held at (input units) and how many
        rows hold it.
    """

    n_samples: int
    clipped: NDArray[np.bool_]
    ends: tuple[tuple[str, float, int], ...]

    @cached_property
    def n_clipped(self) -> int:
        """Rows clipped on at least one axis (counted once; the mask holds them only where an end is clipped)."""
        return int(np.count_nonzero(self.clipped)) if self.ends else 0

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

    @classmethod
    def none(cls, n_samples: int) -> Clipping:
        """Nothing clipped among ``n_samples`` rows (its mask a read-only view: no memory)."""
        return cls(n_samples, np.broadcast_to(np.False_, (n_samples,)), ())


#: The threshold below each end is read off a regular stride of about this many rows (see :func:`find_clipped`).
_PROBE_ROWS = 5_000
#: Rows compared with the thresholds at a time (a block of three columns stays in the cache).
_CHUNK_ROWS = 1 << 14


def _clipped_end(held_count: int, value: float, integral: bool, neighbours: NDArray[np.int64], inner: int) -> bool:
    """Whether an extreme ``value`` held on ``held_count`` rows is a clipped end.

    ``integral``: the column holds integers only; ``neighbours``: how many rows hold each of the (at most)
    :data:`NEIGHBOURS` distinct values next to the end, nearest first; ``inner``: rows not at the end.
    """
    if held_count < 2:
        return False
    if value in FULL_SCALE_CODES and integral:
        return True
    if held_count < MIN_CLIPPED:
        return False
    if inner == 0:
        return True  # the axis never left its end
    return held_count >= CLIP_RATIO * float(np.mean(neighbours))


def _thresholds(probe: NDArray[np.generic]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Per axis, a value with at least NEIGHBOURS + 1 distinct values of ``probe`` at or above it (and below).

    ``probe`` is a subset of the rows, so the whole column holds at least as many distinct values beyond
    the same thresholds: every row beyond them holds the end and the NEIGHBOURS values next to it, whole.
    An axis with fewer distinct values than that in the probe gets ±inf (examined whole, below).
    """
    upper = np.full(3, np.inf)
    lower = np.full(3, -np.inf)
    for axis in range(3):
        values = np.unique(probe[:, axis])
        if values.size > NEIGHBOURS + 1:
            upper[axis] = float(values[-(NEIGHBOURS + 1)])
            lower[axis] = float(values[NEIGHBOURS])
    return upper, lower


def find_clipped(samples: NDArray[np.generic]) -> Clipping:
    """The rows of ``samples`` (N, 3), any numeric dtype, clipped at the sensor's full scale (module docstring).

    One pass over the rows: a regular stride of about :data:`_PROBE_ROWS` rows gives each axis a threshold
    near each end beyond which the column holds its end and at least :data:`NEIGHBOURS` more distinct
    values (:func:`_thresholds`); the rows beyond a threshold (a few per mille of a log) are gathered in
    blocks, and the ends, their counts and their neighbours' counts are exact on them. The result is that
    of the test on the whole columns; the memory, a few rows per end instead of a copy of a column.
    """
    n = samples.shape[0]
    if n == 0:
        return Clipping.none(0)
    upper, lower = _thresholds(samples[:: max(1, n // _PROBE_ROWS)])
    candidates = np.arange(n) if np.isinf(upper).all() else _beyond(samples, upper, lower)
    return _clipping(samples, upper, lower, candidates)


def statistics_and_clipping(samples: NDArray[np.generic]) -> tuple[Statistics, Clipping]:
    """``Statistics.from_samples(samples)`` and ``find_clipped(samples)`` in one pass over the rows.

    The thresholds come from the same probe; the rows beyond them are gathered from each chunk while the
    statistics' pass holds it in the cache (float64 there, which holds every integer and float32 value
    exactly, so the comparisons are those of :func:`find_clipped`), instead of a second pass over the
    samples. Both results equal the separate calls'. Raises as :meth:`Statistics.update` does.
    """
    n = samples.shape[0]
    if n == 0:
        return Statistics.from_samples(samples), Clipping.none(0)
    upper, lower = _thresholds(samples[:: max(1, n // _PROBE_ROWS)])
    if np.isinf(upper).all():
        return Statistics.from_samples(samples), _clipping(samples, upper, lower, np.arange(n))
    found = [np.zeros(0, dtype=np.int64)]
    highs, lows = upper[:, None], lower[:, None]

    def gather(columns: NDArray[np.float64], first_row: int) -> None:
        hit = columns >= highs
        hit |= columns <= lows
        rows = np.flatnonzero(hit.any(axis=0))
        if rows.size:
            found.append(rows + first_row)

    statistics = Statistics()._update(samples, gather)
    return statistics, _clipping(samples, upper, lower, np.concatenate(found))


def _clipping(
    samples: NDArray[np.generic], upper: NDArray[np.float64], lower: NDArray[np.float64], candidates: NDArray[np.int64]
) -> Clipping:
    """The ends test of :func:`find_clipped` on the ``candidates`` rows: every row at or beyond a threshold."""
    n = samples.shape[0]
    rows = samples[candidates]
    ends: list[tuple[str, float, int]] = []
    marked: list[NDArray[np.int64]] = []
    for axis in range(3):
        whole = bool(np.isinf(upper[axis]))  # few distinct values: the whole column is examined
        column = samples[:, axis] if whole else rows[:, axis]
        high, low = column.max(), column.min()
        if high == low:
            continue  # a constant axis is a dead axis or no motion: the support checks name that
        for upper_end in (True, False):
            extreme = high if upper_end else low
            # Beyond the threshold: every row there is a candidate, and the end's NEIGHBOURS values lie there.
            tail = column if whole else column[column >= upper[axis]] if upper_end else column[column <= lower[axis]]
            held = tail == extreme
            count = int(np.count_nonzero(held))
            if count < 2:
                continue
            # (the whole column is read for integers only where the end is a full-scale code)
            integral = float(extreme) in FULL_SCALE_CODES and bool(np.all(np.mod(samples[:, axis], 1) == 0))
            counts = np.unique(tail[~held], return_counts=True)[1]
            neighbours = (counts[::-1] if upper_end else counts)[:NEIGHBOURS]
            if _clipped_end(count, float(extreme), integral, neighbours, n - count):
                at_end = np.flatnonzero(column == extreme)
                marked.append(at_end if whole else candidates[at_end])
                ends.append((_AXES[axis], float(extreme), count))
    if not ends:
        return Clipping.none(n)
    clipped = np.zeros(n, dtype=bool)
    for at_end in marked:
        clipped[at_end] = True
    return Clipping(n, clipped, tuple(ends))


def _beyond(samples: NDArray[np.generic], upper: NDArray[np.float64], lower: NDArray[np.float64]) -> NDArray[np.int64]:
    """The rows with a value at or beyond its axis's threshold (``upper`` or ``lower``), in order.

    The rows are compared in blocks as one flat run of values against the thresholds repeated for each
    row (contiguous memory: measured 1.2-1.5x faster than three strided columns).
    """
    n = samples.shape[0]
    block_rows = min(n, _CHUNK_ROWS)
    highs, lows = np.tile(upper, block_rows), np.tile(lower, block_rows)
    hit, other = np.empty(3 * block_rows, dtype=bool), np.empty(3 * block_rows, dtype=bool)
    found = [np.zeros(0, dtype=np.int64)]
    for start in range(0, n, block_rows):
        values = samples[start : start + block_rows].reshape(-1)  # a view of C-ordered rows (else a copy)
        size = values.shape[0]
        np.greater_equal(values, highs[:size], out=hit[:size])
        hit[:size] |= np.less_equal(values, lows[:size], out=other[:size])
        positions = np.flatnonzero(hit[:size])
        if positions.size:
            row = positions // 3
            first = np.empty(row.size, dtype=bool)  # a row beyond on two axes once
            first[0] = True
            np.not_equal(row[1:], row[:-1], out=first[1:])
            found.append(row[first] + start)
    return np.concatenate(found)
