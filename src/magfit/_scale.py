"""A robust scale: the median and σ = 1.4826 · MAD of residuals, in one place.

For Gaussian errors the median absolute deviation from the median is ``Φ⁻¹(3/4) σ = 0.6745 σ``, so
``1.4826 MAD`` estimates σ while up to half of the residuals may be outliers (Hampel, JASA 69, 1974).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

__all__ = ["MAD_TO_SIGMA", "robust_scale"]

#: 1 / Φ⁻¹(3/4): the MAD of a Gaussian times this is its standard deviation.
MAD_TO_SIGMA = 1.4826


def robust_scale(residuals: ArrayLike) -> tuple[float, float]:
    """Median and σ = 1.4826 MAD of the residuals (a Gaussian's standard deviation, robustly)."""
    r = np.asarray(residuals, dtype=np.float64)
    centre = float(np.median(r))
    return centre, MAD_TO_SIGMA * float(np.median(np.abs(r - centre)))
