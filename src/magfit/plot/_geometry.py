"""The numbers behind the pictures: directions, equal-area cells, an even subsample, ellipsoid outlines.

Pure NumPy, so the report and the tests use them without matplotlib.

Directions are binned on an equal-area grid: azimuth ``atan2(y, x)`` in equal steps and elevation in
equal steps of ``sin(elevation)``. A band of the sphere between two heights has an area proportional to
its height (Archimedes' hat-box theorem), so every cell covers the same solid angle, ``4π / cells``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..calibration import Calibration
from ..errors import OptionError

__all__ = [
    "Coverage",
    "coverage",
    "direction_cells",
    "ellipse_outline",
    "ellipsoid_wireframe",
    "even_subsample",
    "sphere_wireframe",
]

#: Default equal-area grid: 36 azimuth steps of 10° times 18 bands of equal height in sin(elevation).
AZIMUTH_BINS = 36
ELEVATION_BINS = 18


def _directions(vectors: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Azimuth in (−π, π] and sin(elevation) in [−1, 1] of each row of ``vectors`` (N, 3)."""
    norm = np.linalg.norm(vectors, axis=1)
    norm[norm == 0] = 1.0  # a zero vector has no direction; it lands on the equator at azimuth 0
    azimuth = np.arctan2(vectors[:, 1], vectors[:, 0])
    sin_elevation = np.clip(vectors[:, 2] / norm, -1.0, 1.0)
    return azimuth, sin_elevation


def direction_cells(
    vectors: ArrayLike, azimuth_bins: int = AZIMUTH_BINS, elevation_bins: int = ELEVATION_BINS
) -> NDArray[np.intp]:
    """Index of the equal-area cell each direction falls in.

    Parameters
    ----------
    vectors : array_like, shape (N, 3)
        Vectors whose directions are binned (any length; typically calibrated samples).
    azimuth_bins, elevation_bins : int
        Grid size; cell ``k = elevation_index * azimuth_bins + azimuth_index``.

    Returns
    -------
    ndarray of int, shape (N,)
        Cell index in ``[0, azimuth_bins * elevation_bins)``.
    """
    azimuth, sin_elevation = _directions(np.asarray(vectors, dtype=np.float64))
    column = np.floor((azimuth + np.pi) / (2 * np.pi) * azimuth_bins).astype(np.intp)
    row = np.floor((sin_elevation + 1.0) / 2.0 * elevation_bins).astype(np.intp)
    np.clip(column, 0, azimuth_bins - 1, out=column)
    np.clip(row, 0, elevation_bins - 1, out=row)
    return row * azimuth_bins + column


@dataclass(frozen=True)
class Coverage:
    """How many samples point into each equal-area cell of the sphere of directions.

    Attributes
    ----------
    counts : ndarray of int, shape (elevation_bins, azimuth_bins)
        Samples per cell; row 0 is the band nearest −z (elevation −90°).
    azimuth_edges : ndarray, shape (azimuth_bins + 1,)
        Cell edges in azimuth, radians, from −π to π.
    elevation_edges : ndarray, shape (elevation_bins + 1,)
        Cell edges in elevation, radians, from −π/2 to π/2 (equal steps of sin(elevation)).
    """

    counts: NDArray[np.int64]
    azimuth_edges: NDArray[np.float64]
    elevation_edges: NDArray[np.float64]

    @property
    def fraction_visited(self) -> float:
        """Share of the sphere of directions (= share of cells) holding at least one sample, in [0, 1]."""
        return float(np.count_nonzero(self.counts) / self.counts.size)

    @property
    def n_cells(self) -> int:
        return int(self.counts.size)


def coverage(vectors: ArrayLike, azimuth_bins: int = AZIMUTH_BINS, elevation_bins: int = ELEVATION_BINS) -> Coverage:
    """Count the directions of ``vectors`` (N, 3) in the equal-area cells (see :func:`direction_cells`)."""
    cells = direction_cells(vectors, azimuth_bins, elevation_bins)
    counts = np.bincount(cells, minlength=azimuth_bins * elevation_bins).reshape(elevation_bins, azimuth_bins)
    return Coverage(
        counts=counts.astype(np.int64),
        azimuth_edges=np.linspace(-np.pi, np.pi, azimuth_bins + 1),
        elevation_edges=np.arcsin(np.linspace(-1.0, 1.0, elevation_bins + 1)),
    )


def even_subsample(
    vectors: ArrayLike,
    max_points: int,
    *,
    seed: int | np.random.Generator | None = 0,
    azimuth_bins: int = AZIMUTH_BINS,
    elevation_bins: int = ELEVATION_BINS,
) -> NDArray[np.intp]:
    """Indices of at most ``max_points`` rows spread evenly over the directions of ``vectors``.

    Every equal-area cell gets the same quota ``q`` (cells with fewer samples keep them all), with ``q``
    the largest that fits in ``max_points`` ("water filling"); the few points left over go to random
    cells that still have samples. Dense regions of a long recording are thinned, sparse ones kept, so
    a plot of the subsample shows where the sensor pointed, not how long it stayed there. Runs in
    O(N) (one permutation and one radix sort of small cell indices): about a second for 10 million rows.

    Parameters
    ----------
    vectors : array_like, shape (N, 3)
        Vectors whose directions decide the spread (calibrated samples, or raw samples minus their centre).
    max_points : int
        Largest number of indices returned (at least 1).
    seed : int, numpy Generator or None
        Seed of the random choice inside each cell.

    Returns
    -------
    ndarray of int, shape (min(N, max_points),)
        Increasing row indices into ``vectors`` (the recording's order is kept).
    """
    if max_points < 1:
        raise OptionError(f"max_points must be at least 1, got {max_points}")
    array = np.asarray(vectors, dtype=np.float64)
    n = array.shape[0]
    if n <= max_points:
        return np.arange(n, dtype=np.intp)
    rng = np.random.default_rng(seed)
    n_cells = azimuth_bins * elevation_bins
    cells = direction_cells(array, azimuth_bins, elevation_bins)
    counts = np.bincount(cells, minlength=n_cells)
    quota = _water_fill(counts, max_points, rng)
    # Random order first, then a stable sort by cell: each cell's samples come out in random order, and
    # a sample's rank inside its cell decides whether it is kept. int16 cells let NumPy radix-sort.
    order = rng.permutation(n)
    cell_dtype = np.int16 if n_cells < np.iinfo(np.int16).max else np.int32
    by_cell = order[np.argsort(cells[order].astype(cell_dtype), kind="stable")]
    starts = np.concatenate(([0], np.cumsum(counts)[:-1]))
    sorted_cells = cells[by_cell]
    rank = np.arange(n) - starts[sorted_cells]
    keep = by_cell[rank < quota[sorted_cells]]
    return np.sort(keep)


def _water_fill(counts: NDArray[np.intp], total: int, rng: np.random.Generator) -> NDArray[np.intp]:
    """Per-cell quotas ``min(count, q)`` (+1 for a few cells) summing to exactly ``total`` <= counts.sum()."""
    levels = np.sort(counts)
    # kept(q) = Σ min(count, q) is increasing in q; find the largest integer q with kept(q) <= total.
    low, high = 0, int(levels[-1])
    while low < high:
        middle = (low + high + 1) // 2
        if int(np.minimum(counts, middle).sum()) <= total:
            low = middle
        else:
            high = middle - 1
    quota = np.minimum(counts, low)
    spare = total - int(quota.sum())
    if spare > 0:
        candidates = np.flatnonzero(counts > quota)
        quota[rng.choice(candidates, size=spare, replace=False)] += 1
    return quota


def sphere_wireframe(n_lines: int = 12, n_points: int = 61) -> list[NDArray[np.float64]]:
    """Meridians and parallels of the unit sphere, each an (n_points, 3) polyline."""
    t = np.linspace(0.0, 2 * np.pi, n_points)
    lines = []
    for longitude in np.linspace(0.0, np.pi, n_lines // 2, endpoint=False):  # great circles through the poles
        lines.append(np.column_stack([np.cos(t) * np.cos(longitude), np.cos(t) * np.sin(longitude), np.sin(t)]))
    for latitude in np.radians([-60.0, -30.0, 0.0, 30.0, 60.0]):
        lines.append(
            np.column_stack(
                [np.cos(latitude) * np.cos(t), np.cos(latitude) * np.sin(t), np.full_like(t, np.sin(latitude))]
            )
        )
    return lines


def ellipsoid_wireframe(calibration: Calibration, n_lines: int = 12, n_points: int = 61) -> list[NDArray[np.float64]]:
    """The fitted ellipsoid as polylines (n_points, 3), in input units.

    The ellipsoid is the image of the sphere of radius B under the inverse of the correction
    ``corrected = matrix @ (raw - offset)``: ``raw = offset + matrix⁻¹ (B u)`` for unit vectors u.
    """
    distort = np.linalg.inv(calibration.matrix) * calibration.field_strength
    return [line @ distort.T + calibration.offset for line in sphere_wireframe(n_lines, n_points)]


def ellipse_outline(calibration: Calibration, axes: tuple[int, int], n_points: int = 181) -> NDArray[np.float64]:
    """Outline of the fitted ellipsoid seen along the third axis (its shadow on a plane), shape (n_points, 2).

    The ellipsoid ``(x − V)ᵀ A (x − V) = 1`` (eq. 2, A = ``ellipsoid_matrix``) projects onto coordinates
    (i, j) as the ellipse of matrix ``((A⁻¹)_{ij})⁻¹``: the 2x2 block of A⁻¹ is the projection's "covariance".
    """
    block = np.linalg.inv(calibration.ellipsoid_matrix)[np.ix_(axes, axes)]
    root = np.linalg.cholesky(block)
    t = np.linspace(0.0, 2 * np.pi, n_points)
    circle = np.column_stack([np.cos(t), np.sin(t)])
    return circle @ root.T + calibration.offset[list(axes)]
