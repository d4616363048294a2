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
    "corrected_unit",
    "coverage",
    "coverage_share",
    "direction_cells",
    "ellipse_outline",
    "ellipsoid_wireframe",
    "scan",
    "sphere_wireframe",
    "subsample_for_plot",
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


#: Rows per block when a pass over every sample is made (bounded memory on long logs: ~24 MB a block).
CHUNK_ROWS = 1 << 20


def corrected_unit(calibration: Calibration, samples: NDArray[np.float64]) -> NDArray[np.float64]:
    """``calibration.apply(samples, normalized=True)``: the calibrated samples on the unit sphere, (N, 3)."""
    return calibration.apply(samples, normalized=True)


def scan(
    samples: NDArray[np.float64],
    calibrations: tuple[Calibration, ...],
    azimuth_bins: int = AZIMUTH_BINS,
    elevation_bins: int = ELEVATION_BINS,
) -> tuple[tuple[NDArray[np.float64], ...], Coverage]:
    """One pass over every sample, in blocks: each calibration's sphere distances and the first one's coverage.

    Returns
    -------
    distances : tuple of ndarray, each shape (N,)
        ``|apply(x, normalized=True)| − 1`` per calibration (the paper's section V metric), dimensionless.
    coverage : Coverage
        Directions of the first calibration's corrected samples on the equal-area grid.
    """
    n = samples.shape[0]
    distances = tuple(np.empty(n) for _ in calibrations)
    counts = np.zeros(azimuth_bins * elevation_bins, dtype=np.int64)
    for start in range(0, n, CHUNK_ROWS):
        block = samples[start : start + CHUNK_ROWS]
        for index, calibration in enumerate(calibrations):
            corrected = corrected_unit(calibration, block)
            distances[index][start : start + block.shape[0]] = np.sqrt(np.einsum("ni,ni->n", corrected, corrected)) - 1
            if index == 0:
                cells = direction_cells(corrected, azimuth_bins, elevation_bins)
                counts += np.bincount(cells, minlength=counts.size)
    return distances, _coverage_from_counts(counts, azimuth_bins, elevation_bins)


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
    counts = np.bincount(cells, minlength=azimuth_bins * elevation_bins)
    return _coverage_from_counts(counts, azimuth_bins, elevation_bins)


def _coverage_from_counts(counts: NDArray[np.intp], azimuth_bins: int, elevation_bins: int) -> Coverage:
    return Coverage(
        counts=counts.reshape(elevation_bins, azimuth_bins).astype(np.int64),
        azimuth_edges=np.linspace(-np.pi, np.pi, azimuth_bins + 1),
        elevation_edges=np.arcsin(np.linspace(-1.0, 1.0, elevation_bins + 1)),
    )


def coverage_share(calibration: Calibration, samples: NDArray[np.float64]) -> float:
    """The share of directions covered, as the diagnostics count it, so that a figure and the CLI agree.

    The diagnostics' own number (``calibration.diagnostics.coverage.share``: MotionCal's 100 equal-area
    regions, on the samples the diagnostics analysed) when the fit carries it; otherwise the same
    partition counted on ``samples``. The map's finer grid shows where, not how much: its share of cells
    is lower for the same samples (324 samples cannot reach 648 cells).
    """
    diagnostics = calibration.diagnostics
    if diagnostics is not None and diagnostics.coverage is not None:
        return float(diagnostics.coverage.share)
    from ..diagnostics.coverage import coverage as diagnostics_coverage

    return float(diagnostics_coverage(corrected_unit(calibration, samples)).share)


#: Long recordings are first cut to this many candidates per point drawn, by a regular stride in time,
#: so that the even subsample of a 10-million-sample log takes a fraction of a second. A direction the
#: sensor held for fewer than ``N / (CANDIDATES_PER_POINT * max_points)`` consecutive samples can be
#: missed by the picture (never by the coverage map or the metrics, which use every sample).
CANDIDATES_PER_POINT = 50


def subsample_for_plot(
    samples: ArrayLike, calibration: Calibration, max_points: int, *, seed: int | np.random.Generator | None = 0
) -> NDArray[np.intp]:
    """Indices of at most ``max_points`` samples spread evenly over the directions of the calibrated field.

    Uses :func:`magfit.sampling.even_subsample` (equal-area direction cells, each capped at the same
    count) in the frame of ``calibration``, so that a plot shows where the sensor pointed, not how long it
    stayed there. Recordings longer than ``CANDIDATES_PER_POINT * max_points`` are first thinned by a
    regular stride.

    Parameters
    ----------
    samples : array_like, shape (N, 3)
        Raw samples, input units.
    calibration : Calibration
        Its offset and matrix define the directions (``matrix @ (raw - offset)``).
    max_points : int
        Largest number of indices returned (at least 1).
    seed : int, numpy Generator or None
        Seed of the random choice inside each cell.

    Returns
    -------
    ndarray of int, shape (m,), m <= min(N, max_points)
        Increasing row indices into ``samples`` (the recording's order is kept).
    """
    from ..sampling import DEFAULT_CELLS
    from ..sampling import even_subsample as sample_evenly

    if max_points < 1:
        raise OptionError(f"max_points must be at least 1, got {max_points}")
    array = np.asarray(samples, dtype=np.float64)
    n = array.shape[0]
    if n <= max_points:
        return np.arange(n, dtype=np.intp)
    stride = max(1, n // (CANDIDATES_PER_POINT * max_points))
    candidates = np.arange(0, n, stride, dtype=np.intp)
    # About four points per cell: the sampler caps every cell at the same whole count, so with more
    # cells than points it could keep nothing, and with one point per cell it would waste the budget.
    cells = int(np.clip(max_points // 4, 2, DEFAULT_CELLS))
    chosen = sample_evenly(
        array[candidates],
        max_samples=max_points,
        cells=cells,
        centre=calibration.offset,
        shape=calibration.matrix,
        seed=seed,
    )
    if chosen.size == 0:  # a budget of a handful of points: a regular stride is as good as anything
        return np.linspace(0, n - 1, max_points).round().astype(np.intp)
    return candidates[chosen]


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
