"""The paper's pseudo-calibration (section IV): per-axis min/max scaling.

Each axis is mapped by ``2 (x − centre) / (max − min)`` (the paper's z row divides by ``y_mean``, a
typo for ``z_max − z_min``). The paper centres on the dataset mean; the common min/max method (and
most firmware) centres on the mid-range ``(max + min) / 2``. Both ignore any rotation of the soft-iron
distortion: when the ellipsoid's axes are not aligned with the sensor axes the result is biased.
"""

from __future__ import annotations

import numpy as np

from .._validation import check_choice
from ..calibration import Calibration
from ..errors import CalibrationError
from .registry import FitInput, register
from .support import check_outlines_ellipsoid

CENTRES = ("mean", "midrange")
#: An axis whose range is below this share of the widest one was not turned along the field. The paper's
#: steel case, the strongest soft iron it measured, has 0.14 (semi-axes 193 and 1362 counts).
MIN_RANGE_RATIO = 0.1


@register(
    "minmax",
    checks=(check_outlines_ellipsoid,),
    min_samples=4,
    data="statistics",
    summary="pseudo-calibration: per-axis min/max scaling (paper, section IV)",
    model="diag",
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
        raise CalibrationError(
            f"the {axis} axis never changes: min/max scaling needs every axis to vary", codes=("single_axis",)
        )
    narrow = int(np.argmin(half_range))
    if half_range[narrow] < MIN_RANGE_RATIO * half_range.max():
        # A sensor that never pointed an axis along the field: its range there is the tilt or the noise, and
        # scaling it up to the others' would blow the noise up to the field strength.
        axis = "xyz"[narrow]
        raise CalibrationError(
            f"the samples hardly vary along {axis} ({100 * half_range[narrow] / half_range.max():.0f} % of the widest "
            f"axis's range): min/max cannot scale an axis the sensor was never turned along; tilt the sensor so both "
            f"ends of {axis} face the field in turn",
            codes=("single_axis",),
        )
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
