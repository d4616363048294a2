"""The paper's pseudo-calibration (section IV): per-axis min/max scaling.

Each axis is mapped by ``2 (x − centre) / (max − min)`` (the paper's z row divides by ``y_mean``, a
typo for ``z_max − z_min``). The paper centres on the dataset mean; the common min/max method (and
most firmware) centres on the mid-range ``(max + min) / 2``. Both ignore any rotation of the soft-iron
distortion: when the ellipsoid's axes are not aligned with the sensor axes the result is biased.
"""

from __future__ import annotations

import numpy as np

from ..calibration import Calibration
from ..errors import CalibrationError
from .registry import FitInput, check_choice, register
from .support import check_outlines_ellipsoid

CENTRES = ("mean", "midrange")


@register(
    "minmax",
    checks=(check_outlines_ellipsoid,),
    min_samples=4,
    data="statistics",
    summary="pseudo-calibration: per-axis min/max scaling (paper, section IV)",
)
def fit_minmax(data: FitInput, *, centre: str = "mean") -> Calibration:
    """Scale each axis by its half-range around its mean (as published) or its mid-range.

    Parameters
    ----------
    centre : {"mean", "midrange"}
        ``"mean"``: the dataset mean, as in the paper. ``"midrange"``: ``(max + min) / 2``.
    """
    check_choice("centre", centre, CENTRES)
    statistics = data.statistics
    low, high = statistics.minimum, statistics.maximum
    half_range = 0.5 * (high - low)
    if not np.all(half_range > 0):
        axis = "xyz"[int(np.argmin(half_range))]
        raise CalibrationError(f"the {axis} axis never changes: min/max scaling needs every axis to vary")
    offset = statistics.mean if centre == "mean" else 0.5 * (high + low)
    # B_cal = 2 (x − centre) / (max − min) on the unit sphere; scaled so that det(matrix) = 1.
    field_strength = float(np.prod(half_range) ** (1.0 / 3.0))
    return Calibration(
        method="minmax",
        offset=offset,
        matrix=np.diag(field_strength / half_range),
        field_strength=field_strength,
        n_samples=statistics.n,
        details={"centre": centre},
    )
