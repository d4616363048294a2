"""Even sampling: thin the samples so that every direction of the field weighs the same.

A least-squares fit weighs each sample equally, so a recording that stays long in one attitude (the
vehicle parked before take-off, the phone lying on the desk) weighs that one direction like thousands
of others, and any error there (noise bias, a slightly disturbed field, soft iron that a sphere fit
does not model) pulls the whole fit. That pull is the most cited complaint about the compass
calibrations of PX4, ArduPilot and phone apps. Thinning first removes it.

The direction of each sample from a centre (``u = shape (x − centre) / |...|``) is binned on ``cells``
cells of equal area on the unit sphere, and every cell keeps at most ``cap`` of its samples, drawn at
random. The cells are the zonal equal-area partition of the coverage diagnostics (Leopardi, "A
partition of the unit sphere into regions of equal area and small diameter", ETNA 25, 2006): bands of
latitude whose areas are whole multiples of the cell area, each split into equal longitude sectors.

Within a cell the kept samples are those with the smallest of independent uniform random keys (a
bottom-k sample). That choice makes the sampler streamable and exact: :class:`EvenSampler` fed chunk
by chunk keeps precisely the samples :func:`even_subsample` keeps from the whole array with the same
seed, while holding at most twice ``max_samples`` of them.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ._validation import as_samples, check_support
from .errors import CalibrationError, OptionError, SampleError
from .geometry.cells import partition
from .geometry.quadric import algebraic_ellipsoid, calibration_from_ellipsoid
from .remedy import option

if TYPE_CHECKING:
    from .statistics import Statistics

__all__ = [
    "DEFAULT_CELLS",
    "MAX_ANALYSED",
    "EvenSampler",
    "SphereCells",
    "direction_frame",
    "even_subsample",
    "even_subsample_chunks",
    "thin",
    "weighted_even_subsample",
]

#: Cells of about 10 degrees across (4π / 400 sr each): fine enough to separate attitudes a calibration
#: needs apart, coarse enough that a few thousand samples fill them.
DEFAULT_CELLS = 400
#: When the samples support no ellipsoid, the directions start from the mid-point of these per-axis
#: quantiles, each axis scaled by their half-distance: a few outliers do not move them, and neither does
#: the time spent in any one attitude.
_CENTRE_QUANTILES = (0.001, 0.999)
#: In that fallback frame, no axis is scaled up by more than 1 / (2 · this) relative to the widest.
_FLAT_AXIS = 0.05


@dataclass(frozen=True)
class SphereCells:
    """The unit sphere cut into ``count`` cells of equal area, as the coverage diagnostics cut it.

    The partition is Leopardi's (:func:`magfit.geometry.cells.partition`): two polar caps of one
    cell and bands of latitude split into equal sectors, each band's area a whole number of cells.

    Attributes
    ----------
    z_edges : ndarray, shape (bands + 1,)
        Heights ``z = cos(colatitude)`` of the band edges, from 1 (north pole) down to -1.
    sectors : ndarray, shape (bands,)
        Number of longitude sectors of each band (1 for the polar caps).
    first : ndarray, shape (bands,)
        Index of each band's first cell.
    """

    z_edges: NDArray[np.float64]
    sectors: NDArray[np.int64]
    first: NDArray[np.int64]
    _cell: Callable[[NDArray[np.float64]], NDArray[np.int64]] = field(repr=False, compare=False)

    @classmethod
    def make(cls, count: int) -> SphereCells:
        """The partition into ``count`` cells (``count`` >= 3), as square as the count allows."""
        if isinstance(count, bool) or not isinstance(count, (int, np.integer)) or count < 3:
            raise OptionError(f"cells must be an integer >= 3, got {count!r}")

        cells = partition(int(count))
        return cls(np.cos(cells.boundaries), cells.cells_per_zone, cells.first_cell, cells.cell)

    @property
    def count(self) -> int:
        """Number of cells."""
        return int(self.sectors.sum())

    def index(self, directions: NDArray[np.float64]) -> NDArray[np.int64]:
        """Cell of each direction, shape (N,); rows of ``directions`` (N, 3) need not be unit length."""
        return self._cell(directions)


def _water_level(counts: NDArray[np.int64], budget: int) -> int:
    """The largest cap with ``Σ min(counts, cap) <= budget`` (``budget`` itself when every count fits)."""
    if counts.sum() <= budget:
        return budget
    ordered = np.sort(counts[counts > 0])
    below = np.concatenate([[0], np.cumsum(ordered)[:-1]])  # Σ of the counts smaller than ordered[i]
    # With the cap at ordered[i], the total kept is below[i] + cap · (number of cells from i on).
    remaining = ordered.size - np.arange(ordered.size)
    fits = below + ordered * remaining <= budget  # true, then false from some i on (the top never fits)
    i = int(np.argmin(fits))
    # The cap lies between ordered[i - 1] (fits) and ordered[i] (does not): share what is left equally.
    return int((budget - below[i]) // remaining[i])


class EvenSampler:
    """Stream samples through an even thinning, keeping at most ``max_samples`` of them.

    Feed chunks with :meth:`update`; :attr:`samples` and :attr:`indices` hold the kept samples and
    their row numbers in the stream. The result equals :func:`even_subsample` on the whole array with
    the same ``centre``, ``shape``, ``cells`` and ``seed``. While streaming it holds at most twice
    ``max_samples`` samples (a cell is cut back to its cap once it holds twice as many, so that each
    sample costs O(1) however long the stream).

    Parameters
    ----------
    max_samples : int
        The most samples kept; each cell keeps at most ``cap`` of its own, the largest cap that fits.
    centre : array_like, shape (3,)
        Where the directions start, input units: the hard-iron offset, or an estimate of it (a first
        fit, or the mid-range of the samples).
    shape : array_like, shape (3, 3), optional
        Applied to ``x − centre`` before taking directions, e.g. ``Calibration.matrix`` so that the
        cells are equal areas of the corrected sphere rather than of the distorted ellipsoid.
    cells : int
        Number of equal-area cells on the sphere.
    seed : int or numpy Generator or None
        Seed of the random keys that choose which samples of a full cell are kept.
    """

    def __init__(
        self,
        max_samples: int,
        *,
        centre: ArrayLike,
        shape: ArrayLike | None = None,
        cells: int = DEFAULT_CELLS,
        seed: int | np.random.Generator | None = 0,
    ) -> None:
        if isinstance(max_samples, bool) or not isinstance(max_samples, (int, np.integer)) or max_samples < 1:
            raise OptionError(f"max_samples must be a positive integer, got {max_samples!r}")
        self.max_samples = int(max_samples)
        self.centre = _vector(centre, "centre")
        self.shape = None if shape is None else _matrix(shape)
        self.cells = SphereCells.make(cells)
        self._rng = np.random.default_rng(seed)
        self._seen = 0
        self._counts = np.zeros(self.cells.count, dtype=np.int64)  # samples offered, per cell
        self._cap = self.max_samples
        # Per cell: blocks of (keys, row numbers, samples) held, their total, and the key above which a
        # newcomer can never be kept (the cap-th smallest key held when the cell was last cut back).
        self._held: list[list[tuple[NDArray[np.float64], NDArray[np.int64], NDArray[np.float64]]]] = [
            [] for _ in range(self.cells.count)
        ]
        self._held_count = np.zeros(self.cells.count, dtype=np.int64)
        self._threshold = np.full(self.cells.count, np.inf)
        self._result: tuple[NDArray[np.float64], NDArray[np.int64]] | None = None

    def update(self, chunk: ArrayLike) -> EvenSampler:
        """Offer the next (n, 3) samples of the stream; returns ``self``."""
        array = as_samples(chunk)
        keys = np.asarray(self._rng.random(array.shape[0]))  # one per row: the keys never depend on chunking
        cell = self.cells.index(self._directions(array))
        return self._offer(array, cell, keys)

    def _offer(self, array: NDArray[np.float64], cell: NDArray[np.int64], keys: NDArray[np.float64]) -> EvenSampler:
        n = array.shape[0]
        self._result = None
        self._counts += np.bincount(cell, minlength=self.cells.count)
        self._cap = min(self._cap, _water_level(self._counts, self.max_samples))
        rows = np.arange(self._seen, self._seen + n, dtype=np.int64)
        self._seen += n
        # A newcomer whose key exceeds what its cell was cut back to can never be kept (the cap only
        # shrinks): most of a long stream stops here.
        candidate = keys < self._threshold[cell]
        if candidate.any():
            cell, keys, rows, array = cell[candidate], keys[candidate], rows[candidate], array[candidate]
            order = np.argsort(cell.astype(np.uint16 if self.cells.count <= 1 << 16 else np.int64), kind="stable")
            cell, keys, rows, array = cell[order], keys[order], rows[order], array[order]
            bounds = np.searchsorted(cell, np.arange(self.cells.count + 1))
            for c in np.flatnonzero(np.diff(bounds)):
                lo, hi = bounds[c], bounds[c + 1]
                self._held[c].append((keys[lo:hi], rows[lo:hi], array[lo:hi]))
                self._held_count[c] += hi - lo
        for c in np.flatnonzero(self._held_count > 2 * self._cap):
            self._cut(int(c))
        return self

    def _cut(self, c: int) -> None:
        """Keep, in cell ``c``, the ``cap`` samples with the smallest keys (a bottom-k sample)."""
        keys = np.concatenate([block[0] for block in self._held[c]])
        rows = np.concatenate([block[1] for block in self._held[c]])
        array = np.concatenate([block[2] for block in self._held[c]])
        if keys.size > self._cap:
            kept = np.argpartition(keys, self._cap - 1)[: self._cap] if self._cap else np.empty(0, dtype=np.int64)
            keys, rows, array = keys[kept], rows[kept], array[kept]
            self._threshold[c] = keys.max(initial=-np.inf)  # a cap of 0 (a tiny budget) admits nothing
        self._held[c] = [(keys, rows, array)]
        self._held_count[c] = keys.size

    def _finish(self) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
        """Every cell cut back to the cap; the kept samples and rows in stream order."""
        if self._result is None:
            for c in np.flatnonzero(self._held_count > self._cap):
                self._cut(int(c))
            blocks = [block for held in self._held for block in held]
            rows = np.concatenate([block[1] for block in blocks]) if blocks else np.empty(0, dtype=np.int64)
            array = np.concatenate([block[2] for block in blocks]) if blocks else np.empty((0, 3))
            order = np.argsort(rows)
            self._result = (array[order], rows[order])
        return self._result

    def _directions(self, array: NDArray[np.float64]) -> NDArray[np.float64]:
        offset_free = array - self.centre
        return offset_free if self.shape is None else offset_free @ self.shape.T

    @property
    def samples(self) -> NDArray[np.float64]:
        """The kept samples, in stream order, shape (m, 3), input units."""
        return self._finish()[0].copy()

    @property
    def indices(self) -> NDArray[np.int64]:
        """Row numbers of the kept samples in the stream (0-based, increasing), shape (m,)."""
        return self._finish()[1].copy()

    @property
    def seen(self) -> int:
        """Number of samples offered so far."""
        return self._seen

    @property
    def cap(self) -> int:
        """The most samples any cell keeps (so far)."""
        return self._cap

    @property
    def occupied_cells(self) -> int:
        """Number of cells that received at least one sample."""
        return int(np.count_nonzero(self._counts))


def even_subsample(
    samples: ArrayLike,
    *,
    max_samples: int | None = None,
    cells: int = DEFAULT_CELLS,
    centre: ArrayLike | None = None,
    shape: ArrayLike | None = None,
    seed: int | np.random.Generator | None = 0,
) -> NDArray[np.int64]:
    """Indices of a subsample in which every direction weighs (about) the same.

    Use it before any fit: ``magfit.fit(samples[even_subsample(samples)])``.

    Parameters
    ----------
    samples : array_like, shape (N, 3)
        Raw samples, any unit.
    max_samples : int, optional
        Keep at most this many: every cell keeps at most ``cap`` samples, the largest cap that fits.
        By default ``cap`` is the median number of samples of the cells that have any, so a cell
        visited for a long time is cut down to a typical cell while the rest are kept as they are.
    cells : int
        Number of equal-area cells of the sphere of directions (default 400, about 10° across).
    centre : array_like, shape (3,), optional
        Where directions start, input units. By default the offset of a first ellipsoid fit, whose
        ``matrix`` is then also the default ``shape``; when the samples support no ellipsoid, the
        mid-point of each axis's 0.1 % and 99.9 % quantiles (unmoved by how long the sensor stayed
        anywhere), with each axis divided by their half-distance (at least a tenth of the widest one).
    shape : array_like, shape (3, 3), optional
        Applied to ``x − centre`` before taking directions (identity when only ``centre`` is given),
        e.g. ``calibration.matrix`` so that the cells are equal areas of the corrected sphere.
    seed : int or numpy Generator or None
        Seed of the random choice of the samples kept in a full cell (default 0: repeatable).

    Returns
    -------
    ndarray of int, shape (m,)
        Increasing row numbers into ``samples``.
    """
    array = as_samples(samples)
    if array.shape[0] == 0:
        raise SampleError("samples must hold at least one row, got shape (0, 3)")
    if centre is None:
        centre, shape = _default_frame(array)
    # The sampler is built with a provisional budget so that it validates the options and holds the cells.
    sampler = EvenSampler(1 if max_samples is None else max_samples, centre=centre, shape=shape, cells=cells, seed=seed)
    cell = sampler.cells.index(sampler._directions(array))
    if max_samples is None:
        counts = np.bincount(cell, minlength=sampler.cells.count)
        median = math.ceil(float(np.median(counts[counts > 0])))
        sampler.max_samples = sampler._cap = int(np.minimum(counts, median).sum())
    return _kept(sampler._offer(array, cell, np.asarray(sampler._rng.random(array.shape[0])))).indices


def _kept(sampler: EvenSampler) -> EvenSampler:
    """``sampler``, unless its budget was below the cells of directions the samples fill: an even subsample keeps
    as many from every such cell, at least one, and with fewer it would keep none."""
    filled = int(np.count_nonzero(sampler._counts))
    if filled and sampler._cap < 1:
        raise OptionError(
            f"{option('max_samples', sampler.max_samples)} is fewer than the {filled} cells of directions the samples "
            f"fill, from each of which an even subsample keeps at least one: give at least "
            f"{option('max_samples', filled)}"
        )
    return sampler


def even_subsample_chunks(
    chunks: Callable[[], Iterable[ArrayLike]],
    *,
    centre: ArrayLike,
    shape: ArrayLike | None = None,
    max_samples: int | None = None,
    cap_at_median: bool = True,
    cells: int = DEFAULT_CELLS,
    seed: int | np.random.Generator | None = 0,
) -> EvenSampler:
    """:func:`even_subsample` of a stream too large for memory: it keeps at most ``max_samples`` samples.

    Parameters
    ----------
    chunks : callable
        Returns a fresh iterable of (n, 3) arrays each time it is called (e.g. a file read in chunks); it
        is called twice when ``cap_at_median`` is true (once to count the cells, once to sample), else once.
    centre, shape, cells, seed
        As in :func:`even_subsample`; here ``centre`` is required (e.g. the offset of a first fit of the
        stream's :class:`~magfit.Statistics`).
    max_samples : int, optional
        The most samples kept (memory while streaming: up to twice that many, at about 40 bytes each);
        required without ``cap_at_median``.
    cap_at_median : bool
        Also cap every cell at the median count of the cells that have samples (what :func:`even_subsample`
        does by default). Without it, cells are capped only as far as ``max_samples`` requires: the
        densest cells lose samples first, and a stream that fits keeps every sample.

    Returns
    -------
    EvenSampler
        Its ``samples`` and ``indices`` (row numbers in the stream) are the subsample; ``seen`` the rows read.
    """
    if not cap_at_median and max_samples is None:
        raise OptionError("max_samples is required when cap_at_median is false")
    sampler = EvenSampler(max_samples or 1, centre=centre, shape=shape, cells=cells, seed=seed)
    if cap_at_median:
        counts = np.zeros(sampler.cells.count, dtype=np.int64)
        for chunk in chunks():
            array = as_samples(chunk)
            counts += np.bincount(sampler.cells.index(sampler._directions(array)), minlength=sampler.cells.count)
        if not counts.any():
            raise SampleError("the stream holds no samples")
        median = math.ceil(float(np.median(counts[counts > 0])))
        budget = int(np.minimum(counts, median).sum())
        sampler.max_samples = sampler._cap = budget if max_samples is None else min(budget, max_samples)
    for chunk in chunks():
        sampler.update(chunk)
    return _kept(sampler)


def direction_frame(statistics: Statistics) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """A centre and shape for :class:`EvenSampler` from the :class:`~magfit.Statistics` of a stream.

    The offset and matrix of the stream's ellipsoid fit; when the samples support no ellipsoid, the
    mid-range of each axis with each axis divided by its half-range (at least a tenth of the widest one).

    Returns
    -------
    centre : ndarray, shape (3,)
        Input units.
    shape : ndarray, shape (3, 3)
        Dimensionless up to a common scale (only directions matter).
    """
    ellipsoid = _ellipsoid_frame(statistics)
    return ellipsoid if ellipsoid is not None else _box_frame(statistics.minimum, statistics.maximum)


def _ellipsoid_frame(statistics: Statistics) -> tuple[NDArray[np.float64], NDArray[np.float64]] | None:
    """Centre and shape of the paper's algebraic ellipsoid (section II), or None when there is none."""
    try:
        check_support(statistics, "ellipsoid", 9)  # enough samples, spread over three dimensions
    except CalibrationError:
        return None
    found = algebraic_ellipsoid(statistics)
    if isinstance(found, str):
        return None
    calibration = calibration_from_ellipsoid("ellipsoid", *found)
    return calibration.offset, calibration.matrix


def _box_frame(low: NDArray[np.float64], high: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    # An axis that hardly varies (level turns only) must not let its noise pick the cells: floor it.
    half = np.maximum(0.5 * (high - low), _FLAT_AXIS * float(np.max(high - low)))
    return 0.5 * (low + high), np.diag(1.0 / np.where(half > 0, half, 1.0))


def _default_frame(array: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Centre and shape for the directions: a first ellipsoid fit, or the quantile box when that fails.

    The fit is pulled by a long stay, but only by a fraction of the radius: directions from its centre,
    through its matrix, are those of the corrected sphere to within a few degrees, so its cells cover
    equal areas of the true field sphere, not of the distorted ellipsoid.
    """
    from .statistics import Statistics

    ellipsoid = _ellipsoid_frame(Statistics.from_samples(array)) if array.shape[0] >= 9 else None
    if ellipsoid is not None:
        return ellipsoid
    low, high = np.quantile(array, _CENTRE_QUANTILES, axis=0)
    return _box_frame(low, high)


def _vector(value: ArrayLike, name: str) -> NDArray[np.float64]:
    vector = np.asarray(value, dtype=np.float64)
    if vector.shape != (3,) or not np.all(np.isfinite(vector)):
        raise OptionError(f"{name} must be 3 finite numbers (x, y, z), got {np.asarray(value).tolist()!r}")
    return vector


def _matrix(value: ArrayLike) -> NDArray[np.float64]:
    matrix = np.asarray(value, dtype=np.float64)
    if matrix.shape != (3, 3) or not np.all(np.isfinite(matrix)) or abs(np.linalg.det(matrix)) == 0:
        raise OptionError(f"shape must be an invertible, finite 3x3 matrix, got shape {matrix.shape}")
    return matrix


#: The diagnostics and the model choice analyse at most this many samples (see :func:`thin`).
MAX_ANALYSED = 20_000


def thin(n: int, cap: int = MAX_ANALYSED) -> NDArray[np.int64]:
    """At most ``10 cap`` of ``n`` row indices, by a regular stride (cheap on 10⁷ samples)."""
    return np.arange(0, n, max(1, math.ceil(n / (10 * cap))), dtype=np.int64)


def weighted_even_subsample(
    directions: NDArray[np.float64], cap: int = MAX_ANALYSED, total: int | None = None
) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
    """Indices of at most ``cap`` rows spread evenly over directions, and the weight of each.

    The rows (already thinned with :func:`thin` when there are many) are binned into 400 equal-area
    direction cells; every cell gives the same number q of its rows, spread in time (all of them when it
    has fewer), with q as large as the cap allows. The weight of a row is the number of original rows it
    stands for: its cell's count over the rows taken there, times ``total / len(directions)``, so the
    weights sum to ``total`` (default: the number of rows).
    """
    m = directions.shape[0]
    factor = 1.0 if total is None else total / max(m, 1)
    if m <= cap:
        return np.arange(m, dtype=np.int64), np.full(m, factor)
    cells = partition(400).cell(directions)
    order = np.argsort(cells, kind="stable")  # by cell, in time order within a cell
    counts = np.bincount(cells, minlength=400)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    low, high = 1, int(counts.max())
    while low < high:  # the largest q with Σ min(count, q) <= cap
        middle = (low + high + 1) // 2
        if int(np.minimum(counts, middle).sum()) <= cap:
            low = middle
        else:
            high = middle - 1
    taken = np.minimum(counts, low)
    occupied = np.flatnonzero(counts)
    positions = np.concatenate(
        [starts[cell] + np.arange(taken[cell]) * counts[cell] // taken[cell] for cell in occupied]
    )
    indices = order[positions]
    chosen_cells = cells[indices]
    weights = counts[chosen_cells] / taken[chosen_cells] * factor
    sort = np.argsort(indices)
    return np.asarray(indices[sort], dtype=np.int64), np.asarray(weights[sort], dtype=np.float64)
