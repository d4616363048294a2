"""The calibration figure: before and after, in 3-D and in projection, with the paper's metric.

matplotlib is imported inside the functions (it is an optional extra) and the figure is drawn on an
Agg canvas of its own, without pyplot: no global state, no display needed, safe in threads and tests.
"""

from __future__ import annotations

import io
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .._validation import as_samples
from ..calibration import Calibration
from ..errors import OptionError
from ._geometry import (
    Coverage,
    coverage_share,
    ellipse_outline,
    ellipsoid_wireframe,
    scan,
    sphere_wireframe,
    subsample_for_plot,
)

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

__all__ = [
    "DEFAULT_MAX_POINTS",
    "METHOD_COLOURS",
    "calibration_figure",
    "figure_png",
    "method_labels",
    "save_figure",
    "shown_caption",
]

#: Points drawn per scatter panel by default: enough to see the shape, few enough to draw in a blink.
DEFAULT_MAX_POINTS = 4000
#: One colour per calibration, in the order given (the first is the main one).
METHOD_COLOURS = ("#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e", "#8c564b", "#e377c2", "#17becf")
_RAW_COLOUR = "#555555"
_PLANES = ((0, 1), (0, 2), (1, 2))
_AXIS_NAMES = "xyz"
_MAX_POINTS_3D = 1500


@dataclass(frozen=True)
class _Prepared:
    """Everything the panels draw, computed once."""

    samples: NDArray[np.float64]
    calibrations: tuple[Calibration, ...]
    labels: tuple[str, ...]
    unit: str
    shown: NDArray[np.intp]
    distances: tuple[NDArray[np.float64], ...]
    coverage: Coverage
    coverage_share: float  # as the diagnostics count it (the CLI's number), not the map's grid


def method_labels(calibrations: Sequence[Calibration]) -> tuple[str, ...]:
    """A distinct display name per calibration: the method name, numbered when it repeats, marked ``(not
    supported)`` when the samples do not support it (a fit returned with ``allow_undetermined=True``)."""
    labels: list[str] = []
    for calibration in calibrations:
        label = calibration.method
        repeat = sum(1 for other in labels if other == label or other.startswith((f"{label} #", f"{label} (")))
        label = label if repeat == 0 else f"{label} #{repeat + 1}"
        refused = calibration.support is not None and calibration.support.verdict == "refused"
        labels.append(f"{label} (not supported)" if refused else label)
    return tuple(labels)


def _as_calibrations(calibrations: Calibration | Sequence[Calibration]) -> tuple[Calibration, ...]:
    items = (calibrations,) if isinstance(calibrations, Calibration) else tuple(calibrations)
    if not items:
        raise OptionError("give at least one calibration to plot, e.g. magfit.fit(samples)")
    for item in items:
        if not isinstance(item, Calibration):
            raise OptionError(f"calibrations must be magfit.Calibration objects, got {type(item).__name__}")
    return items


def _prepare(
    samples: ArrayLike,
    calibrations: Calibration | Sequence[Calibration],
    unit: str | None,
    max_points: int,
    seed: int | None,
) -> _Prepared:
    array = as_samples(samples)
    items = _as_calibrations(calibrations)
    # Spread the shown points evenly over the directions the main calibration sees (the field's direction).
    shown = subsample_for_plot(array, items[0], max_points, seed=seed)
    distances, cover = scan(array, items, *_grid_for(array.shape[0]))
    return _Prepared(
        samples=array,
        calibrations=items,
        labels=method_labels(items),
        unit=unit or items[0].unit or "raw units",
        shown=shown,
        distances=distances,
        coverage=cover,
        coverage_share=coverage_share(items[0], array),
    )


def shown_caption(n_shown: int, n_total: int) -> str:
    """The caption that says how many samples a plot shows."""
    if n_shown >= n_total:
        return f"All {n_total:,} samples shown."
    return f"{n_shown:,} of {n_total:,} samples shown, spread evenly over the directions visited."


def calibration_figure(
    samples: ArrayLike,
    calibrations: Calibration | Sequence[Calibration],
    *,
    unit: str | None = None,
    title: str | None = None,
    max_points: int = DEFAULT_MAX_POINTS,
    seed: int | None = 0,
    size: tuple[float, float] = (16.0, 12.0),
    dpi: float = 100.0,
) -> Figure:
    """Draw one figure that shows a calibration at work.

    Panels: the raw samples with the fitted ellipsoid (3-D); the calibrated samples on the unit sphere
    (3-D); a coverage map of the directions visited (equal-area Mollweide map); the XY, XZ and YZ
    projections before (raw, with each method's fitted outline) and after (divided by B, with the unit
    circle); a histogram of each method's distance to the unit sphere (the paper's section V metric); a
    table of the fitted offsets, semi-axes and field strengths. The title gives the field strength and
    each method's mean and standard deviation of the distance to the unit sphere.

    Parameters
    ----------
    samples : array_like, shape (N, 3)
        Raw samples, in input units.
    calibrations : Calibration or sequence of Calibration
        One or more fits of ``samples``; the first is the main one (3-D panels, coverage, subsample).
    unit : str, optional
        Name of the input unit for the axis labels; default ``calibrations[0].unit``, else "raw units".
    title : str, optional
        What the data are (a file name, a scenario); leads the figure title.
    max_points : int
        Largest number of samples drawn in each scatter panel; larger inputs are subsampled evenly over
        directions (the caption says "N of M samples shown"). Histogram, coverage and metrics use all samples.
    seed : int or None
        Seed of the subsample.
    size : (float, float)
        Figure size in inches; the PNG is ``size * dpi`` pixels.
    dpi : float
        Resolution of the figure, pixels per inch.

    Returns
    -------
    matplotlib.figure.Figure
        Drawn on an Agg canvas; save it with :func:`save_figure`. Each panel's ``Axes.get_label()`` names
        it: ``raw-3d``, ``calibrated-3d``, ``coverage``, ``before-xy`` ... ``after-yz``, ``histogram``,
        ``parameters``.
    """
    try:
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure
    except ImportError as error:  # the plot extra is optional: say how to get it, in one line
        raise ImportError(f"drawing figures needs matplotlib ({error}): pip install 'magfit[plot]'") from None

    prepared = _prepare(samples, calibrations, unit, max_points, seed)
    figure = Figure(figsize=size, dpi=dpi, layout="constrained")
    FigureCanvasAgg(figure)
    grid = figure.add_gridspec(3, 4)
    _draw_raw_3d(figure.add_subplot(grid[0, 0], projection="3d"), prepared)
    _draw_calibrated_3d(figure.add_subplot(grid[0, 1], projection="3d"), prepared)
    _draw_coverage(figure, figure.add_subplot(grid[0, 2:], projection="mollweide"), prepared)
    for column, plane in enumerate(_PLANES):
        _draw_before(figure.add_subplot(grid[1, column]), prepared, plane)
        _draw_after(figure.add_subplot(grid[2, column]), prepared, plane)
    _draw_histogram(figure.add_subplot(grid[1, 3]), prepared)
    _draw_parameters(figure.add_subplot(grid[2, 3]), prepared)
    figure.suptitle(_title(prepared, title), fontsize=13)
    caption = shown_caption(prepared.shown.size, prepared.samples.shape[0])
    step = _thin_3d(prepared)
    if step > 1:
        caption += f" The 3-D panels show one in {step} of them."
    figure.supxlabel(caption, fontsize=10)
    return figure


def _title(prepared: _Prepared, title: str | None) -> str:
    main = prepared.calibrations[0]
    n = prepared.samples.shape[0]
    head = f"{title}: " if title else ""
    first = (
        f"{head}{n:,} samples, field strength B = {main.field_strength:.4g} {prepared.unit} ({prepared.labels[0]} fit)"
    )
    scores = [
        f"{label} {distances.mean():+.4f} / {distances.std():.4f}"
        for label, distances in zip(prepared.labels, prepared.distances, strict=True)
    ]
    # Four methods per line keep the title inside the figure however many are compared.
    lines = ["   ".join(scores[start : start + 4]) for start in range(0, len(scores), 4)]
    lines[0] = f"Distance to the unit sphere, mean / std (paper, section V):   {lines[0]}"
    return "\n".join([first, *lines])


def _equal_3d_limits(axes: Any, points: NDArray[np.float64]) -> None:
    low, high = points.min(axis=0), points.max(axis=0)
    centre, half = (low + high) / 2, (high - low).max() / 2 * 1.05
    axes.set_xlim(centre[0] - half, centre[0] + half)
    axes.set_ylim(centre[1] - half, centre[1] + half)
    axes.set_zlim(centre[2] - half, centre[2] + half)
    axes.set_box_aspect((1, 1, 1))


def _marker_size(n_points: int) -> float:
    """Scatter marker area (points²): small for thousands of points, larger when there are few to see."""
    return float(np.clip(3000.0 / max(n_points, 1), 1.0, 9.0))


def _grid_for(n_samples: int) -> tuple[int, int]:
    """Coverage grid (azimuth bins, elevation bins) with about 8 samples per cell for a full tumble.

    A grid finer than the data can fill would call a well-turned sensor "half covered": 324 samples
    cannot reach 648 cells. Cells are 2k x k for k in 6, 9, 12, 18 (30° down to 10° in azimuth).
    """
    for k in (18, 12, 9):
        if 2 * k * k * 8 <= n_samples:
            return 2 * k, k
    return 12, 6


def _thin_3d(prepared: _Prepared) -> int:
    """Step through the shown samples in the 3-D panels: a cloud of more than ~1500 hides the wireframe."""
    return max(1, int(np.ceil(prepared.shown.size / _MAX_POINTS_3D)))


def _draw_raw_3d(axes: Any, prepared: _Prepared) -> None:
    main = prepared.calibrations[0]
    shown = prepared.samples[prepared.shown[:: _thin_3d(prepared)]]
    axes.set_label("raw-3d")
    size = _marker_size(shown.shape[0])
    axes.scatter(shown[:, 0], shown[:, 1], shown[:, 2], s=size, color=_RAW_COLOUR, alpha=0.35, depthshade=False)
    lines = ellipsoid_wireframe(main)
    for line in lines:  # drawn after the points so the fitted surface stays visible through them
        axes.plot(line[:, 0], line[:, 1], line[:, 2], color=METHOD_COLOURS[0], linewidth=1.0, alpha=0.9)
    _equal_3d_limits(axes, np.vstack([shown, *lines]))
    for name, setter in zip(_AXIS_NAMES, (axes.set_xlabel, axes.set_ylabel, axes.set_zlabel), strict=True):
        setter(f"{name} ({prepared.unit})")
    axes.set_title(f"Raw samples and the fitted ellipsoid\n({prepared.labels[0]})", fontsize=11)


def _draw_calibrated_3d(axes: Any, prepared: _Prepared) -> None:
    shown = prepared.calibrations[0].apply(prepared.samples[prepared.shown[:: _thin_3d(prepared)]], normalized=True)
    axes.set_label("calibrated-3d")
    for line in sphere_wireframe():
        axes.plot(line[:, 0], line[:, 1], line[:, 2], color="#999999", linewidth=0.5, alpha=0.6)
    size = _marker_size(shown.shape[0])
    axes.scatter(shown[:, 0], shown[:, 1], shown[:, 2], s=size, color=METHOD_COLOURS[0], alpha=0.7, depthshade=False)
    limit = max(1.05, float(np.abs(shown).max()) * 1.02)
    for setter in (axes.set_xlim, axes.set_ylim, axes.set_zlim):
        setter(-limit, limit)
    axes.set_box_aspect((1, 1, 1))
    for name, setter in zip(_AXIS_NAMES, (axes.set_xlabel, axes.set_ylabel, axes.set_zlabel), strict=True):
        setter(f"{name} / B")
    axes.set_title(f"Calibrated by {prepared.labels[0]}\non the unit sphere", fontsize=11)


def _draw_coverage(figure: Figure, axes: Axes, prepared: _Prepared) -> None:
    from matplotlib.colors import LogNorm

    cover = prepared.coverage
    counts = np.ma.masked_equal(cover.counts, 0)
    axes.set_label("coverage")
    axes.set_facecolor("#f6c9c4")  # cells never visited show this pale red through the masked mesh
    mesh = axes.pcolormesh(
        cover.azimuth_edges,
        cover.elevation_edges,
        counts,
        cmap="viridis",
        norm=LogNorm(vmin=1, vmax=max(2, int(cover.counts.max()))),
        shading="flat",
    )
    axes.grid(True, color="white", linewidth=0.4, alpha=0.7)
    axes.tick_params(labelsize=8)
    axes.set_xlabel("azimuth of the calibrated field in the sensor frame, atan2(y, x)")
    axes.set_ylabel("elevation, asin(z / |m|)")
    axes.set_title(
        f"Directions visited: {prepared.coverage_share:.0%} of the sphere (the diagnostics' 100 equal-area regions)\n"
        f"map: {np.count_nonzero(cover.counts)} of {cover.n_cells} cells {360 // cover.counts.shape[1]}° wide reached; "
        "pale red: never visited",
        fontsize=11,
    )
    colorbar = figure.colorbar(mesh, ax=axes, shrink=0.8, pad=0.02)
    colorbar.set_label("samples per cell")


def _draw_before(axes: Axes, prepared: _Prepared, plane: tuple[int, int]) -> None:
    i, j = plane
    shown = prepared.samples[prepared.shown]
    name = f"{_AXIS_NAMES[i]}{_AXIS_NAMES[j]}".upper()
    axes.set_label(f"before-{name.lower()}")
    size = _marker_size(shown.shape[0])
    axes.scatter(shown[:, i], shown[:, j], s=size, color=_RAW_COLOUR, alpha=0.5, linewidths=0, label="raw samples")
    for index in reversed(range(len(prepared.calibrations))):
        outline = ellipse_outline(prepared.calibrations[index], plane)
        axes.plot(outline[:, 0], outline[:, 1], color=METHOD_COLOURS[index % len(METHOD_COLOURS)], linewidth=1.2)
    axes.set_aspect("equal", adjustable="datalim")
    axes.set_xlabel(f"{_AXIS_NAMES[i]} ({prepared.unit})")
    axes.set_ylabel(f"{_AXIS_NAMES[j]} ({prepared.unit})")
    axes.set_title(f"Before, {name}: raw samples, fitted outlines", fontsize=10)
    axes.grid(True, linewidth=0.3)


def _draw_after(axes: Axes, prepared: _Prepared, plane: tuple[int, int]) -> None:
    i, j = plane
    raw = prepared.samples[prepared.shown]
    name = f"{_AXIS_NAMES[i]}{_AXIS_NAMES[j]}".upper()
    axes.set_label(f"after-{name.lower()}")
    largest = 1.0
    # The main calibration is drawn last, on top of the others.
    for index in reversed(range(len(prepared.calibrations))):
        corrected = prepared.calibrations[index].apply(raw, normalized=True)
        largest = max(largest, float(np.abs(corrected[:, [i, j]]).max()))
        axes.scatter(
            corrected[:, i],
            corrected[:, j],
            s=_marker_size(raw.shape[0]),
            color=METHOD_COLOURS[index % len(METHOD_COLOURS)],
            alpha=0.45,
            linewidths=0,
            label=prepared.labels[index],
        )
    t = np.linspace(0.0, 2 * np.pi, 181)
    axes.plot(np.cos(t), np.sin(t), color="black", linewidth=0.8, linestyle="--")
    limit = min(largest, 3.0) * 1.08
    axes.set_xlim(-limit, limit)
    axes.set_ylim(-limit, limit)
    axes.set_aspect("equal")
    axes.set_xlabel(f"{_AXIS_NAMES[i]} / B (calibrated)")
    axes.set_ylabel(f"{_AXIS_NAMES[j]} / B (calibrated)")
    axes.set_title(f"After, {name}: calibrated ÷ B, unit circle", fontsize=10)
    axes.grid(True, linewidth=0.3)


def _draw_histogram(axes: Axes, prepared: _Prepared) -> None:
    # The range from at most ~1 million of the distances: quantiles of a regular stride are as good.
    stride = max(1, prepared.samples.shape[0] // 1_000_000)
    low, high = np.percentile(np.concatenate([d[::stride] for d in prepared.distances]), [0.5, 99.5])
    span = max(high - low, 1e-9)
    low, high = low - 0.05 * span, high + 0.05 * span
    axes.set_label("histogram")
    for index, (label, distances) in enumerate(zip(prepared.labels, prepared.distances, strict=True)):
        counts, edges = np.histogram(distances, bins=80, range=(low, high))  # equal bins: NumPy's fast path
        outside = int(np.count_nonzero((distances < low) | (distances > high)))
        note = f", {outside:,} outside" if outside else ""
        axes.stairs(
            counts,
            edges,
            color=METHOD_COLOURS[index % len(METHOD_COLOURS)],
            linewidth=1.5,
            label=f"{label}: mean {distances.mean():+.4f}, std {distances.std():.4f}{note}",
        )
    axes.axvline(0.0, color="black", linewidth=0.6)
    axes.set_xlabel("distance to the unit sphere, |calibrated| / B − 1 (dimensionless)")
    axes.set_ylabel("samples per bin")
    axes.set_title("Distance to the unit sphere per method", fontsize=10)
    axes.legend(fontsize=8, loc="upper left", frameon=False)
    axes.set_ylim(top=axes.get_ylim()[1] * (1.0 + 0.12 * len(prepared.labels)))  # room for the legend
    axes.grid(True, linewidth=0.3)


def _draw_parameters(axes: Axes, prepared: _Prepared) -> None:
    axes.set_label("parameters")
    axes.axis("off")
    rows = [
        [
            label,
            f"{calibration.field_strength:.4g}",
            "(" + ", ".join(f"{value:.4g}" for value in calibration.offset) + ")",
            "(" + ", ".join(f"{value:.4g}" for value in calibration.semi_axes) + ")",
        ]
        for label, calibration in zip(prepared.labels, prepared.calibrations, strict=True)
    ]
    table = axes.table(
        cellText=rows,
        colLabels=["method", "B", "offset V (x, y, z)", "semi-axes (x, y, z)"],
        loc="upper center",
        cellLoc="center",
    )
    table.auto_set_font_size(False)
    table.set_fontsize(8.5)
    table.auto_set_column_width(list(range(4)))
    table.scale(1.0, 1.6)
    for index in range(len(rows)):
        table[index + 1, 0].get_text().set_color(METHOD_COLOURS[index % len(METHOD_COLOURS)])
    axes.set_title(f"Fitted parameters ({prepared.unit})", fontsize=10)


def save_figure(figure: Figure, path: str | Path, *, dpi: float | None = None) -> Path:
    """Write ``figure`` to ``path``; the format follows the extension (.png, .svg, .pdf ...).

    Returns
    -------
    Path
        The path written.
    """
    target = Path(path)
    supported = figure.canvas.get_supported_filetypes()
    extension = target.suffix.lower().lstrip(".")
    if extension not in supported:
        raise OptionError(
            f"cannot save a figure as {target.name!r}: use one of the extensions {', '.join(sorted(supported))}"
        )
    if not target.parent.is_dir():
        raise OptionError(f"cannot save {target}: the folder {target.parent} does not exist")
    figure.savefig(target, dpi=dpi if dpi is not None else "figure")
    return target


def figure_png(figure: Figure, *, dpi: float | None = None) -> bytes:
    """The figure as PNG bytes (for embedding in HTML)."""
    buffer = io.BytesIO()
    figure.savefig(buffer, format="png", dpi=dpi if dpi is not None else "figure")
    return buffer.getvalue()
