"""Sufficient statistics: everything the linear methods need, accumulated in one pass.

The quadric of eq. (3)-(4) is linear in its ten coefficients, so every linear fit (the paper's
ellipsoid and sphere fits, the axis-aligned fit, the adjusted least squares of its reference [3]) only
needs the scatter ``S = Σ d(z) d(z)ᵀ`` of the design vector

    d(z) = (z₁², z₂², z₃², √2 z₁z₂, √2 z₁z₃, √2 z₂z₃, z₁, z₂, z₃, 1)

evaluated at the normalised samples ``z = (x − centre) / scale``. Its entries are all the moments of
the samples up to degree four. The √2 on the cross terms makes ``θᵀ d(z) = zᵀMz + bᵀz + d`` with
``|θ|² = |M|²_F + |b|² + d²``: the unit-norm constraint of the fit is then invariant under rotations
of the sensor frame. (The paper's eq. (4) writes the cross terms without their factor 2; M carries
each off-diagonal coefficient twice in ``zᵀMz``, which the weight accounts for.)

Normalising first keeps raw counts in the tens of thousands, or an offset of 1e4 field radii, at
full float64 precision. The samples are accumulated in a working frame (the mean and RMS spread of
the first chunk, widened whenever later samples spread twice as far); two :class:`Statistics` built in
different frames merge exactly, because the design vector in one frame is a linear map of the design
vector in another (``d(a z + t) = T d(z)``), so the scatter transforms as ``T S Tᵀ``. The fits read
the scatter in the canonical frame (centre = mean, unit = RMS distance from it), which depends on the
set of samples only: merged, chunked and whole-array statistics give the same fit to round-off.

Speed: one pass, the ten design rows of a chunk built in place in a (10, n) buffer small enough to stay
in a core's cache, and reduced by one general BLAS product of its first nine rows with all ten (the
tenth row of the scatter, the constant monomial's, is the ninth column read again); the per-axis
min/max doubles as the finiteness check. Faster than building the (n, 10) design matrix the obvious way
(docs/scaling.md has the figures).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ._validation import IDENTICAL_ULPS, MAX_MAGNITUDE, check_finite, check_magnitude, check_shape
from .errors import OptionError, SampleError

__all__ = ["DESIGN_EXPONENTS", "Statistics", "design_matrix"]

#: Exponents (of z₁, z₂, z₃) of the ten design monomials, in design-vector order.
DESIGN_EXPONENTS: tuple[tuple[int, int, int], ...] = (
    (2, 0, 0), (0, 2, 0), (0, 0, 2),
    (1, 1, 0), (1, 0, 1), (0, 1, 1),
    (1, 0, 0), (0, 1, 0), (0, 0, 1),
    (0, 0, 0),
)  # fmt: skip
_SQRT2 = math.sqrt(2.0)
#: Weight of each design monomial (√2 on the cross terms, see the module docstring).
DESIGN_WEIGHTS = np.array([1, 1, 1, _SQRT2, _SQRT2, _SQRT2, 1, 1, 1, 1], dtype=np.float64)
#: The weights of the scatter's first nine rows (the products of two monomials' weights).
_PARTIAL_WEIGHTS = np.outer(DESIGN_WEIGHTS[:9], DESIGN_WEIGHTS)

#: Samples per chunk: enough that the per-chunk bookkeeping is small beside the arithmetic, few enough that
#: the chunk's ten design rows (80 bytes a sample: 655 KB) stay in a core's L2 cache between the passes.
DEFAULT_CHUNK = 1 << 13
#: A chunk that reaches beyond this many frame units from the frame's centre makes the frame be checked.
_FRAME_REACH = 4.0
#: The frame moves when the samples spread this many times wider than its unit.
_REFRAME_GROWTH = 2.0
#: Smallest unit of the normalised frame: its inverse stays finite.
_MIN_SCALE = 1e-300


def design_matrix(z: NDArray[np.floating]) -> NDArray[np.float64]:
    """The design matrix of eq. (4), one row d(z) per normalised sample; shape (N, 10)."""
    z = np.asarray(z, dtype=np.float64)
    design = np.empty((z.shape[0], 10), dtype=np.float64)
    np.square(z, out=design[:, 0:3])
    np.multiply(z[:, 0], z[:, 1], out=design[:, 3])
    np.multiply(z[:, 0], z[:, 2], out=design[:, 4])
    np.multiply(z[:, 1], z[:, 2], out=design[:, 5])
    design[:, 3:6] *= _SQRT2
    design[:, 6:9] = z
    design[:, 9] = 1.0
    return design


def _identical_spread(mean: NDArray[np.float64]) -> float:
    """The largest spread that is round-off at the samples' magnitude (as :func:`check_support` judges)."""
    return IDENTICAL_ULPS * float(np.finfo(np.float64).eps) * float(np.max(np.abs(mean)))


def _rms(deviations: NDArray[np.float64]) -> float:
    """√(Σ over rows of the mean over columns of ``deviations`` (3, m) squared), without overflow or underflow."""
    largest = float(np.max(np.abs(deviations))) if deviations.size else 0.0
    if largest == 0.0:
        return 0.0
    scaled = deviations / largest
    return largest * math.sqrt(float(np.einsum("ij,ij->", scaled, scaled)) / deviations.shape[1])


def _polynomial_product(
    left: dict[tuple[int, int, int], float], right: dict[tuple[int, int, int], float]
) -> dict[tuple[int, int, int], float]:
    product: dict[tuple[int, int, int], float] = {}
    for exp_l, coef_l in left.items():
        for exp_r, coef_r in right.items():
            exp = (exp_l[0] + exp_r[0], exp_l[1] + exp_r[1], exp_l[2] + exp_r[2])
            product[exp] = product.get(exp, 0.0) + coef_l * coef_r
    return product


def design_transform(gain: float, shift: NDArray[np.float64]) -> NDArray[np.float64]:
    """The 10x10 matrix T with ``d(gain · z + shift) = T d(z)`` for every z."""
    unit_exponents = ((1, 0, 0), (0, 1, 0), (0, 0, 1))
    factors = [{unit_exponents[i]: gain, (0, 0, 0): float(shift[i])} for i in range(3)]
    index = {exp: j for j, exp in enumerate(DESIGN_EXPONENTS)}
    transform = np.zeros((10, 10))
    for k, exponent in enumerate(DESIGN_EXPONENTS):
        poly: dict[tuple[int, int, int], float] = {(0, 0, 0): 1.0}
        for axis, power in enumerate(exponent):
            for _ in range(power):
                poly = _polynomial_product(poly, factors[axis])
        for exp, coef in poly.items():
            j = index[exp]
            transform[k, j] += DESIGN_WEIGHTS[k] * coef / DESIGN_WEIGHTS[j]
    return transform


def _moment_locations() -> dict[tuple[int, int, int], tuple[int, int]]:
    """For each exponent of total degree <= 4, one entry (i, j) of the scatter that holds its moment."""
    locations: dict[tuple[int, int, int], tuple[int, int]] = {}
    for i, exp_i in enumerate(DESIGN_EXPONENTS):
        for j, exp_j in enumerate(DESIGN_EXPONENTS):
            exp = (exp_i[0] + exp_j[0], exp_i[1] + exp_j[1], exp_i[2] + exp_j[2])
            locations.setdefault(exp, (i, j))
    return locations


_MOMENT_LOCATIONS = _moment_locations()


class Statistics:
    """Mergeable sufficient statistics of a set of samples, for the linear calibration methods.

    Build it in one pass over chunks of any size (memory stays bounded by the chunk), merge the
    statistics of several parts (processes, machines, files), then fit::

        stats = magfit.Statistics()
        for chunk in chunks:              # each an (n, 3) array
            stats.update(chunk)
        cal = magfit.fit(stats, method="ellipsoid")

    ``magfit.fit(stats.merge(other))`` equals the fit of the concatenated samples to round-off, and so
    does ``sum(parts)`` or any tree of merges.

    The normalised frame follows the data: it starts as the mean and RMS spread of the first chunk and
    moves (by the exact transform ``T S Tᵀ``) whenever later samples spread at least twice as wide, so a
    first chunk recorded while the sensor sat still, or chunks of a single sample, do not leave the
    scatter in a frame where the ellipsoid is a speck or a far-away cap. Merges keep the frame of the
    wider part. Both moves only map a tight frame into a wider one, the direction without cancellation.

    Parameters
    ----------
    chunk_size : int
        Samples processed per BLAS call inside :meth:`update` (memory: 80 bytes per sample).
    """

    #: (lowest, highest) values per axis a chunk may hold and leave the frame as it is: set once the samples
    #: have a spread, cleared when the frame moves (a class default: a Statistics pickled before it existed
    #: loads without it).
    _window: tuple[list[float], list[float]] | None = None

    def __init__(self, chunk_size: int = DEFAULT_CHUNK) -> None:
        if isinstance(chunk_size, bool) or not isinstance(chunk_size, (int, np.integer)) or chunk_size < 1:
            raise OptionError(f"chunk_size must be a positive integer, got {chunk_size!r}")
        self.chunk_size = int(chunk_size)
        self._n = 0
        self._centre: NDArray[np.float64] | None = None
        self._scale = 1.0
        self._scatter = np.zeros((10, 10))
        self._minimum = np.full(3, np.inf)
        self._maximum = np.full(3, -np.inf)
        self._canonical_cache: tuple[NDArray[np.float64], float, NDArray[np.float64]] | None = None
        self._window = None

    @classmethod
    def from_samples(cls, samples: ArrayLike, chunk_size: int = DEFAULT_CHUNK) -> Statistics:
        """Statistics of an (N, 3) array, accumulated chunk by chunk."""
        return cls(chunk_size).update(samples)

    @classmethod
    def from_chunks(cls, chunks: Iterable[ArrayLike], chunk_size: int = DEFAULT_CHUNK) -> Statistics:
        """Statistics of a stream of (n, 3) arrays (e.g. a file read in chunks)."""
        statistics = cls(chunk_size)
        for chunk in chunks:
            statistics.update(chunk)
        return statistics

    # ------------------------------------------------------------------ accumulation

    def update(self, samples: ArrayLike) -> Statistics:
        """Add samples, shape (n, 3), any float or integer dtype; returns ``self`` so calls can be chained.

        The samples are converted to float64 one chunk at a time (float32 input is never copied whole).
        The update is all or nothing: when a row is not finite, or holds a value beyond ±1e150 (whose
        square float64 cannot hold), a :class:`SampleError` names it and the statistics are left as they were.
        Both are checked on every update, so whether a value is refused never depends on the chunking.
        """
        return self._update(samples, None)

    def _update(
        self, samples: ArrayLike, scan: Callable[[NDArray[np.float64], int], None] | None
    ) -> Statistics:
        """:meth:`update`, handing each chunk's columns (3, m), float64 and checked, with its first row to
        ``scan`` while they are in the cache (:func:`magfit.saturation.statistics_and_clipping`)."""
        array = check_shape(samples)
        total = array.shape[0]
        if total == 0:
            return self
        # Work on a copy of the state and commit at the end, so that a bad row changes nothing.
        work = self.copy()
        # The ten design rows of one chunk, one row per monomial: every operation below runs on
        # contiguous memory, which is 2-4x faster than the (n, 10) layout for the squares, the min/max and
        # the finiteness check.
        buffer = np.empty((10, min(self.chunk_size, total)))
        buffer[9] = 1.0  # the constant monomial, written once
        for start in range(0, total, self.chunk_size):
            chunk = array[start : start + self.chunk_size]
            rows = buffer[:, : chunk.shape[0]]
            work._accumulate(chunk, rows, start, scan)
        work._complete()
        self._adopt(work)
        return self

    def _accumulate(
        self,
        chunk: NDArray[np.generic],
        rows: NDArray[np.float64],
        first_row: int,
        scan: Callable[[NDArray[np.float64], int], None] | None = None,
    ) -> None:
        """Add one chunk, using ``rows`` (10, len(chunk)) as scratch space (its last row all ones).

        The scatter's last row (the constant monomial's) is left to :meth:`_complete`.
        """
        z = rows[6:9]
        z[...] = chunk.T  # float64 from here on, whatever the input dtype
        low, high = z.min(axis=1), z.max(axis=1)
        lows, highs = low.tolist(), high.tolist()  # (three numbers each: compared in Python, no array calls)
        if not all(math.isfinite(value) for value in lows + highs):  # NaN and inf reach the min or max
            check_finite(chunk, first_row=first_row)
        if max(-min(lows), max(highs)) > MAX_MAGNITUDE:  # whatever the chunking: refused here
            check_magnitude(chunk, first_row=first_row)
        if scan is not None:
            scan(z, first_row)
        window = self._window
        inside = window is not None and all(
            a <= low_value and high_value <= b
            for a, low_value, high_value, b in zip(window[0], lows, highs, window[1], strict=True)
        )
        if not inside:
            self._adapt_frame(z, low, high, first_row)
        assert self._centre is not None
        z -= self._centre[:, None]
        z *= 1.0 / self._scale
        # d(z) of eq. (4) row by row, without the √2 of the cross terms (applied to the sums below).
        np.multiply(z, z, out=rows[0:3])
        np.multiply(z[0], z[1], out=rows[3])
        np.multiply(z[0], z[2], out=rows[4])
        np.multiply(z[1], z[2], out=rows[5])
        # The one pass over the data that matters: nine rows of the scatter by a general BLAS product (gemm),
        # the tenth (the constant monomial's: the sums of the others, and m) read off the ninth column. The
        # symmetric product ``rows @ rows.T`` (syrk) computes fewer terms but ran 2-3x slower on these
        # shapes (ten rows, thousands of columns) with OpenBLAS.
        partial = rows[:9] @ rows.T
        if not math.isfinite(float(partial.sum())) and not np.isfinite(partial).all():
            raise SampleError(
                f"samples in rows {first_row}..{first_row + chunk.shape[0] - 1} overflow float64 once normalised "
                "(a few values far larger than the rest?); remove the outliers or rescale the samples"
            )
        partial *= _PARTIAL_WEIGHTS
        self._scatter[:9] += partial
        np.minimum(self._minimum, low, out=self._minimum)
        np.maximum(self._maximum, high, out=self._maximum)
        self._n += chunk.shape[0]

    def _complete(self) -> None:
        """Fill the scatter's last row from its last column and the count (what :meth:`_accumulate` leaves)."""
        self._scatter[9, :9] = self._scatter[:9, 9]
        self._scatter[9, 9] = self._n

    def _adapt_frame(
        self, chunk_t: NDArray[np.float64], low: NDArray[np.float64], high: NDArray[np.float64], first_row: int
    ) -> None:
        """Set or widen the normalised frame for a chunk given as rows (3, m), before it is added.

        A chunk within :attr:`_window` (the frame's centre ± its reach, once the samples have a spread) is
        not brought here: the usual case, nothing to compute.
        """
        known = self._n > 0 and self._spread() > 0
        if known:
            assert self._centre is not None
            reach = _FRAME_REACH * self._scale
            self._window = ((self._centre - reach).tolist(), (self._centre + reach).tolist())
            if np.all(low >= self._centre - reach) and np.all(high <= self._centre + reach):
                return
        m = chunk_t.shape[1]
        chunk_mean = chunk_t.mean(axis=1)
        # RMS values, each scaled by its largest term, never sums of squares: values up to MAX_MAGNITUDE do not
        # overflow, denormal ones do not underflow, whatever the number of samples.
        chunk_spread = _rms(chunk_t - chunk_mean[:, None])  # √(mean |x − mean|²), input units
        if self._n == 0:
            mean, spread = chunk_mean, chunk_spread
        else:
            own_mean, own_spread = self._stored_mean(), self._spread()
            n = self._n + m
            own_share, chunk_share = self._n / n, m / n
            mean = own_mean + chunk_share * (chunk_mean - own_mean)  # exact when equal, even for denormals
            own_shift, chunk_shift = _rms((own_mean - mean)[:, None]), _rms((chunk_mean - mean)[:, None])
            unit = max(own_spread, chunk_spread, own_shift, chunk_shift)
            spread = 0.0
            if unit > 0:
                spread = unit * math.sqrt(
                    own_share * ((own_spread / unit) ** 2 + (own_shift / unit) ** 2)
                    + chunk_share * ((chunk_spread / unit) ** 2 + (chunk_shift / unit) ** 2)
                )
        if spread <= _identical_spread(mean):
            spread = 0.0
        if self._n == 0 or (spread > 0 and (not known or spread > _REFRAME_GROWTH * self._scale)):
            self._move_frame(mean, spread)

    def _stored_mean(self) -> NDArray[np.float64]:
        """Mean of the samples from the stored frame, input units."""
        assert self._centre is not None
        return self._centre + self._scale * (self._scatter[6:9, 9] / self._n)

    def _spread(self) -> float:
        """RMS distance of the samples from their mean, input units (0 when empty or all identical)."""
        if self._n == 0:
            return 0.0
        first = self._scatter[6:9, 9] / self._n
        second = np.trace(self._scatter[6:9, 6:9]) / self._n
        spread = float(self._scale * math.sqrt(max(float(second - first @ first), 0.0)))
        # Round-off of identical samples is no spread: a frame scaled to it would blow the scatter up to NaN.
        return spread if spread > _identical_spread(self._stored_mean()) else 0.0

    def _move_frame(self, centre: NDArray[np.float64], spread: float) -> None:
        """Express the scatter in the frame (centre, spread); a zero spread keeps a placeholder unit."""
        scale = spread if spread > 0 else (float(np.max(np.abs(centre))) or 1.0)
        # A denormal unit would make 1 / scale infinite; such samples are refused by the fits anyway (SPREAD_RANGE).
        scale = max(scale, _MIN_SCALE)
        self._canonical_cache = None
        self._window = None
        if self._n > 0:
            assert self._centre is not None
            self._complete()  # (mid-update: the rows added so far)
            transform = design_transform(self._scale / scale, (self._centre - centre) / scale)
            moved = transform @ self._scatter @ transform.T
            self._scatter = 0.5 * (moved + moved.T)
        self._centre = np.array(centre, dtype=np.float64)
        self._scale = scale

    def _adopt(self, other: Statistics) -> None:
        self._canonical_cache = None
        self._window = other._window
        self._n = other._n
        self._centre = other._centre
        self._scale = other._scale
        self._scatter = other._scatter
        self._minimum = other._minimum
        self._maximum = other._maximum

    def merge(self, other: Statistics) -> Statistics:
        """The statistics of both sample sets together (neither input is changed).

        The result is expressed in the frame of the part whose samples spread wider; the other part is
        mapped into it exactly (``T S Tᵀ``, see the module docstring).
        """
        if not isinstance(other, Statistics):
            raise SampleError(
                f"merge() takes another Statistics, got {type(other).__name__}; to add samples use update()"
            )
        if other._n == 0:
            return self.copy()
        if self._n == 0:
            merged = other.copy()
            merged.chunk_size = self.chunk_size
            return merged
        wide, narrow = (other, self) if other._spread() > self._spread() else (self, other)
        merged = wide.copy()
        merged.chunk_size = self.chunk_size
        assert merged._centre is not None and narrow._centre is not None
        transform = design_transform(narrow._scale / merged._scale, (narrow._centre - merged._centre) / merged._scale)
        moved = transform @ narrow._scatter @ transform.T
        merged._scatter = merged._scatter + 0.5 * (moved + moved.T)
        merged._n += narrow._n
        merged._minimum = np.minimum(merged._minimum, narrow._minimum)
        merged._maximum = np.maximum(merged._maximum, narrow._maximum)
        # Two tight parts far apart (or two parts without spread): widen the frame to the union.
        spread = merged._spread()
        if spread > 0 and (wide._spread() == 0 or spread > _REFRAME_GROWTH * merged._scale):
            merged._move_frame(merged._stored_mean(), spread)
        return merged

    def __add__(self, other: object) -> Statistics:
        if not isinstance(other, Statistics):
            return NotImplemented
        return self.merge(other)

    def __radd__(self, other: object) -> Statistics:
        # sum(parts) starts from 0.
        if isinstance(other, int) and other == 0:
            return self.copy()
        return NotImplemented

    def copy(self) -> Statistics:
        """An independent duplicate."""
        duplicate = Statistics(self.chunk_size)
        duplicate._n = self._n
        duplicate._centre = None if self._centre is None else self._centre.copy()
        duplicate._scale = self._scale
        duplicate._scatter = self._scatter.copy()
        duplicate._minimum = self._minimum.copy()
        duplicate._maximum = self._maximum.copy()
        return duplicate

    def to_dict(self) -> dict[str, object]:
        """The statistics as plain numbers (JSON-serialisable), exactly: :meth:`from_dict` restores them."""
        self._require_samples()
        assert self._centre is not None
        return {
            "n": self._n,
            "centre": self._centre.tolist(),
            "scale": self._scale,
            "scatter": self._scatter.tolist(),
            "minimum": self._minimum.tolist(),
            "maximum": self._maximum.tolist(),
        }

    @classmethod
    def from_dict(cls, data: dict[str, object]) -> Statistics:
        """Statistics from :meth:`to_dict`'s numbers (a :class:`SampleError` naming what is malformed)."""
        try:
            n = int(data["n"])  # type: ignore[call-overload]
            centre = np.asarray(data["centre"], dtype=np.float64).reshape(3)
            scale = float(data["scale"])  # type: ignore[arg-type]
            scatter = np.asarray(data["scatter"], dtype=np.float64).reshape(10, 10)
            minimum = np.asarray(data["minimum"], dtype=np.float64).reshape(3)
            maximum = np.asarray(data["maximum"], dtype=np.float64).reshape(3)
        except (KeyError, TypeError, ValueError) as error:
            raise SampleError(f"not the numbers of a Statistics ({error}): expected Statistics.to_dict()'s") from None
        numbers = (centre, scatter, minimum, maximum, np.array([scale]))
        if n < 1 or not all(np.all(np.isfinite(a)) for a in numbers) or not scale > 0:
            raise SampleError("not the numbers of a Statistics: a count below 1, a non-finite value or a scale <= 0")
        statistics = cls()
        statistics._n = n
        statistics._centre = centre
        statistics._scale = scale
        statistics._scatter = 0.5 * (scatter + scatter.T)
        statistics._minimum = minimum
        statistics._maximum = maximum
        return statistics

    # ------------------------------------------------------------------ what the fits read
    #
    # The fits read the scatter in the canonical frame of the samples: centre = their mean, unit = their
    # RMS distance from it. It depends only on the set of samples, never on the order they came in or on
    # how they were split and merged; this matters because the algebraic fit (|θ| = 1) is not invariant
    # under a change of frame, so a frame that depended on the first chunk would make the fit depend on it
    # too (by about 1e-6 of the radius on the paper's noisy data, 1e-2 after a still start).

    def _canonical(self) -> tuple[NDArray[np.float64], float, NDArray[np.float64]]:
        """(centre, scale, scatter) of the canonical frame, computed once per state."""
        if self._canonical_cache is None:
            self._require_samples()
            assert self._centre is not None
            first = self._scatter[6:9, 9] / self._n
            centre = self._centre + self._scale * first
            spread = self._spread()
            scale = max(spread, _MIN_SCALE) if spread > 0 else self._scale  # identical samples: any unit will do
            transform = design_transform(self._scale / scale, (self._centre - centre) / scale)
            scatter = transform @ self._scatter @ transform.T
            self._canonical_cache = (centre, scale, 0.5 * (scatter + scatter.T))
        return self._canonical_cache

    @property
    def n(self) -> int:
        """Number of samples accumulated."""
        return self._n

    @property
    def centre(self) -> NDArray[np.float64]:
        """Origin of the normalised frame: the mean of the samples, input units, shape (3,)."""
        return self._canonical()[0].copy()

    @property
    def scale(self) -> float:
        """Unit length of the normalised frame: the RMS distance of the samples from their mean, input units."""
        return self._canonical()[1]

    @property
    def scatter(self) -> NDArray[np.float64]:
        """``Σ d(z) d(z)ᵀ`` over ``z = (x − centre) / scale``, shape (10, 10) (a copy)."""
        return self._canonical()[2].copy()

    @property
    def minimum(self) -> NDArray[np.float64]:
        """Per-axis minimum of the samples, input units."""
        self._require_samples()
        return self._minimum.copy()

    @property
    def maximum(self) -> NDArray[np.float64]:
        """Per-axis maximum of the samples, input units."""
        self._require_samples()
        return self._maximum.copy()

    def moment(self, exponent: tuple[int, int, int]) -> float:
        """``Σ z₁^a z₂^b z₃^c`` over the normalised samples, for a + b + c <= 4."""
        i, j = _MOMENT_LOCATIONS[tuple(exponent)]  # type: ignore[index]
        return float(self._canonical()[2][i, j] / (DESIGN_WEIGHTS[i] * DESIGN_WEIGHTS[j]))

    @property
    def mean(self) -> NDArray[np.float64]:
        """Mean of the samples, input units, shape (3,)."""
        return self.centre

    @property
    def covariance(self) -> NDArray[np.float64]:
        """Covariance of the samples (divided by n), input units², shape (3, 3)."""
        _, scale, scatter = self._canonical()
        first = scatter[6:9, 9] / self._n  # zero up to round-off in this frame
        return (scatter[6:9, 6:9] / self._n - np.outer(first, first)) * scale**2

    def _require_samples(self) -> None:
        if self._n == 0:
            raise SampleError("these Statistics hold no samples yet: call update() with an (n, 3) array first")

    def __repr__(self) -> str:
        return f"Statistics(n={self._n})"
