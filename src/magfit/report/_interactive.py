"""The interactive 3-D view of a report section: raw samples with the fitted ellipsoid, calibrated samples
on the unit sphere, turned with the mouse (plotly ``scatter3d``). plotly is imported inside the function."""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from ..calibration import Calibration
from ..plot._figure import METHOD_COLOURS
from ..plot._geometry import ellipsoid_wireframe, sphere_wireframe

if TYPE_CHECKING:
    import plotly.graph_objects as go

__all__ = ["interactive_figure", "raw_figure"]


def _polyline(lines: Sequence[NDArray[np.float64]]) -> NDArray[np.float32]:
    """Join polylines into one (M, 3) array with NaN rows between them (plotly breaks lines at gaps)."""
    gap = np.full((1, 3), np.nan)
    return np.vstack([part for line in lines for part in (line, gap)]).astype(np.float32)


def interactive_figure(
    samples: NDArray[np.float64],
    calibrations: Sequence[Calibration],
    labels: Sequence[str],
    *,
    unit: str,
    height: int = 520,
) -> go.Figure:
    """Two 3-D scenes side by side: raw samples + fitted ellipsoid, calibrated samples + unit sphere.

    Parameters
    ----------
    samples : ndarray, shape (N, 3)
        The raw samples to draw (already subsampled by the caller), input units.
    calibrations : sequence of Calibration
        The fits; the first is shown by default, the others can be switched on in the legend.
    labels : sequence of str
        Display name of each calibration.
    unit : str
        Input unit, for the axis titles.
    height : int
        Height of the view in CSS pixels.
    """
    import plotly.graph_objects as go
    from plotly.subplots import make_subplots

    figure = make_subplots(
        rows=1,
        cols=2,
        specs=[[{"type": "scene"}, {"type": "scene"}]],
        subplot_titles=(
            f"Raw samples ({unit}) and the fitted ellipsoid ({labels[0]})",
            "Calibrated samples ÷ B on the unit sphere",
        ),
        horizontal_spacing=0.02,
    )
    raw = samples.astype(np.float32)  # float32 halves the embedded data; 7 digits is plenty for a picture
    marker = {"size": 1.8, "opacity": 0.7}
    figure.add_trace(
        go.Scatter3d(
            x=raw[:, 0], y=raw[:, 1], z=raw[:, 2], mode="markers", name="raw samples",
            marker={**marker, "color": "#555555"}, legendgroup="raw",
        ),
        row=1, col=1,
    )  # fmt: skip
    wire = _polyline(ellipsoid_wireframe(calibrations[0], n_lines=10, n_points=49))
    figure.add_trace(
        go.Scatter3d(
            x=wire[:, 0], y=wire[:, 1], z=wire[:, 2], mode="lines", name=f"fitted ellipsoid ({labels[0]})",
            line={"color": METHOD_COLOURS[0], "width": 2}, hoverinfo="skip",
        ),
        row=1, col=1,
    )  # fmt: skip
    sphere = _polyline(sphere_wireframe(n_lines=10, n_points=49))
    figure.add_trace(
        go.Scatter3d(
            x=sphere[:, 0], y=sphere[:, 1], z=sphere[:, 2], mode="lines", name="unit sphere",
            line={"color": "#aaaaaa", "width": 1}, hoverinfo="skip",
        ),
        row=1, col=2,
    )  # fmt: skip
    for index, (calibration, label) in enumerate(zip(calibrations, labels, strict=True)):
        corrected = calibration.apply(samples, normalized=True).astype(np.float32)
        figure.add_trace(
            go.Scatter3d(
                x=corrected[:, 0], y=corrected[:, 1], z=corrected[:, 2], mode="markers",
                name=f"calibrated by {label}", visible=True if index == 0 else "legendonly",
                marker={**marker, "color": METHOD_COLOURS[index % len(METHOD_COLOURS)]},
            ),
            row=1, col=2,
        )  # fmt: skip
    axis_titles = {name: f"{name} ({unit})" for name in "xyz"}
    figure.update_layout(
        template="none",
        height=height,
        margin={"l": 0, "r": 0, "t": 40, "b": 0},
        legend={"orientation": "h", "y": -0.02},
        scene={
            "aspectmode": "data",
            "xaxis_title": axis_titles["x"],
            "yaxis_title": axis_titles["y"],
            "zaxis_title": axis_titles["z"],
        },
        scene2={
            "aspectmode": "cube",
            "xaxis_title": "x / B",
            "yaxis_title": "y / B",
            "zaxis_title": "z / B",
        },
    )
    return figure


def raw_figure(samples: NDArray[np.float64], *, unit: str, height: int = 520) -> go.Figure:
    """One 3-D scene of the raw samples alone: what there is to see when no method could fit them.

    Parameters
    ----------
    samples : ndarray, shape (N, 3)
        The raw samples to draw (already subsampled by the caller), input units.
    unit : str
        Input unit, for the axis titles.
    height : int
        Height of the view in CSS pixels.
    """
    import plotly.graph_objects as go

    raw = samples.astype(np.float32)
    figure = go.Figure(
        go.Scatter3d(
            x=raw[:, 0], y=raw[:, 1], z=raw[:, 2], mode="markers", name="raw samples",
            marker={"size": 1.8, "opacity": 0.7, "color": "#555555"},
        )
    )  # fmt: skip
    figure.update_layout(
        template="none",
        height=height,
        margin={"l": 0, "r": 0, "t": 40, "b": 0},
        title={"text": f"Raw samples ({unit}): a full tumble would outline an ellipsoid", "x": 0.5},
        scene={
            "aspectmode": "data",
            "xaxis_title": f"x ({unit})",
            "yaxis_title": f"y ({unit})",
            "zaxis_title": f"z ({unit})",
        },
    )
    return figure
