"""Pictures of a calibration: :func:`calibration_figure` and :func:`save_figure`.

Needs the ``plot`` extra (matplotlib), imported only when a figure is drawn: ``import magfit`` and
``import magfit.plot`` load neither matplotlib nor plotly.

>>> import magfit, magfit.plot
>>> sim = magfit.scenario("mpu9250", "steel").simulate(2000, seed=1)
>>> fits = [magfit.fit(sim.samples, method=m) for m in ("ellipsoid", "sphere", "minmax")]
>>> figure = magfit.plot.calibration_figure(sim.samples, fits, unit="counts", title="steel")
>>> [axes.get_label() for axes in figure.axes][:3]
['raw-3d', 'calibrated-3d', 'coverage']
"""

from __future__ import annotations

from ._figure import (
    DEFAULT_MAX_POINTS,
    METHOD_COLOURS,
    calibration_figure,
    figure_png,
    method_labels,
    save_figure,
    shown_caption,
)
from ._geometry import (
    Coverage,
    corrected_unit,
    coverage,
    coverage_share,
    direction_cells,
    ellipse_outline,
    ellipsoid_wireframe,
    scan,
    subsample_for_plot,
)

__all__ = [
    "DEFAULT_MAX_POINTS",
    "METHOD_COLOURS",
    "Coverage",
    "calibration_figure",
    "corrected_unit",
    "coverage",
    "coverage_share",
    "direction_cells",
    "ellipse_outline",
    "ellipsoid_wireframe",
    "figure_png",
    "method_labels",
    "save_figure",
    "scan",
    "shown_caption",
    "subsample_for_plot",
]
