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

Normalising first (the centre and scale of the first chunk fix the frame) keeps raw counts in the
tens of thousands and normalised units at full float64 precision. Two :class:`Statistics` built in
different frames merge exactly: the design vector in one frame is a linear map of the design vector
in another (``d(a z + t) = T d(z)``), so the scatter transforms as ``T S Tᵀ``.
"""

from __future__ import annotations

import math
from collections.abc import Iterable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ._validation import check_finite, check_shape

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

#: Samples per chunk: large enough for BLAS to run at full speed, small enough to bound memory (~5 MB).
DEFAULT_CHUNK = 1 << 16


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

    ``magfit.fit(stats.merge(other))`` equals the fit of the concatenated samples to round-off.

    Parameters
    ----------
    chunk_size : int
        Samples processed per BLAS call inside :meth:`update`.
    """

    def __init__(self, chunk_size: int = DEFAULT_CHUNK) -> None:
        if chunk_size < 1:
            raise ValueError("chunk_size must be at least 1")
        self.chunk_size = int(chunk_size)
        self._n = 0
        self._centre: NDArray[np.float64] | None = None
        self._scale = 1.0
        self._scatter = np.zeros((10, 10))
        self._minimum = np.full(3, np.inf)
        self._maximum = np.full(3, -np.inf)

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
        """Add samples, shape (n, 3), any float dtype; returns ``self`` so calls can be chained."""
        array = check_shape(samples)
        for start in range(0, array.shape[0], self.chunk_size):
            chunk = np.asarray(array[start : start + self.chunk_size], dtype=np.float64)
            check_finite(chunk, first_row=start)
            if self._centre is None:
                self._set_frame(chunk)
            assert self._centre is not None
            z = chunk - self._centre
            z /= self._scale
            design = design_matrix(z)
            self._scatter += design.T @ design
            self._minimum = np.minimum(self._minimum, chunk.min(axis=0))
            self._maximum = np.maximum(self._maximum, chunk.max(axis=0))
            self._n += chunk.shape[0]
        return self

    def _set_frame(self, chunk: NDArray[np.float64]) -> None:
        centre = chunk.mean(axis=0)
        spread = float(np.sqrt(np.mean(np.sum((chunk - centre) ** 2, axis=1))))
        if not spread > 0:
            spread = float(np.max(np.abs(centre))) or 1.0
        self._centre = centre
        self._scale = spread

    def merge(self, other: Statistics) -> Statistics:
        """The statistics of both sample sets together (neither input is changed)."""
        merged = self.copy()
        if other._n == 0:
            return merged
        if merged._centre is None:
            return other.copy()
        assert other._centre is not None
        transform = design_transform(other._scale / merged._scale, (other._centre - merged._centre) / merged._scale)
        merged._scatter = merged._scatter + transform @ other._scatter @ transform.T
        merged._n += other._n
        merged._minimum = np.minimum(merged._minimum, other._minimum)
        merged._maximum = np.maximum(merged._maximum, other._maximum)
        return merged

    def __add__(self, other: Statistics) -> Statistics:
        return self.merge(other)

    def copy(self) -> Statistics:
        duplicate = Statistics(self.chunk_size)
        duplicate._n = self._n
        duplicate._centre = None if self._centre is None else self._centre.copy()
        duplicate._scale = self._scale
        duplicate._scatter = self._scatter.copy()
        duplicate._minimum = self._minimum.copy()
        duplicate._maximum = self._maximum.copy()
        return duplicate

    # ------------------------------------------------------------------ what the fits read

    @property
    def n(self) -> int:
        """Number of samples accumulated."""
        return self._n

    @property
    def centre(self) -> NDArray[np.float64]:
        """Origin of the normalised frame, input units, shape (3,)."""
        self._require_samples()
        assert self._centre is not None
        return self._centre.copy()

    @property
    def scale(self) -> float:
        """Unit length of the normalised frame, input units."""
        return self._scale

    @property
    def scatter(self) -> NDArray[np.float64]:
        """``Σ d(z) d(z)ᵀ`` in the normalised frame, shape (10, 10) (a copy)."""
        return self._scatter.copy()

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
        return float(self._scatter[i, j] / (DESIGN_WEIGHTS[i] * DESIGN_WEIGHTS[j]))

    @property
    def mean(self) -> NDArray[np.float64]:
        """Mean of the samples, input units, shape (3,)."""
        self._require_samples()
        normalised = self._scatter[6:9, 9] / self._n
        return self.centre + self._scale * normalised

    @property
    def covariance(self) -> NDArray[np.float64]:
        """Covariance of the samples (divided by n), input units², shape (3, 3)."""
        self._require_samples()
        first = self._scatter[6:9, 9] / self._n
        second = self._scatter[6:9, 6:9] / self._n
        return (second - np.outer(first, first)) * self._scale**2

    def _require_samples(self) -> None:
        if self._n == 0:
            raise ValueError("these Statistics hold no samples yet: call update() first")

    def __repr__(self) -> str:
        return f"Statistics(n={self._n})"
