"""The outlier rule of the robust fits, in one place: below :mod:`magfit.methods` and :mod:`magfit.diagnostics`.

A sample is an outlier when its sphere distance ``r`` lies farther than ``threshold`` robust standard
deviations from the median, ``|r − median(r)| > threshold · σ`` with ``σ = 1.4826 MAD(r)`` (a Gaussian's
standard deviation, estimated robustly: Huber & Ronchetti, *Robust Statistics*, 2nd ed., 2009, section 5.1;
:func:`magfit._scale.robust_scale`).
:mod:`magfit.methods.robust` fits by it; the diagnostics leave out the samples it rejected
(:func:`inlier_mask`).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from ._scale import MAD_TO_SIGMA, robust_scale
from .evaluate import unchecked_sphere_distances
from .statistics import Statistics

if TYPE_CHECKING:
    from .calibration import Calibration

__all__ = ["DEFAULT_THRESHOLD", "MAD_TO_SIGMA", "inlier_mask", "kept_statistics", "robust_scale"]

#: Cut-off c of the loss, in units of σ: a Gaussian inlier is rejected with probability 5e-4.
DEFAULT_THRESHOLD = 3.5


def inlier_mask(calibration: Calibration, samples: NDArray[Any]) -> tuple[NDArray[np.bool_] | None, str]:
    """The samples a robust fit kept (None: all, or no robust fit), and how they were found.

    The recorded runs (:attr:`Calibration.rejected`) when they refer to these samples; otherwise (a subsample,
    a truncated list) the rule applied again with the fit's threshold.
    """
    stored = calibration.rejected
    if stored is None:
        return None, ""
    n = samples.shape[0]
    if not stored.truncated and calibration.n_samples == n:
        mask = np.ones(n, dtype=bool)
        for start, stop in stored.runs:
            mask[start:stop] = False
        return mask, "the robust fit rejected"
    residuals = unchecked_sphere_distances(calibration, samples)
    centre, sigma = robust_scale(residuals)
    threshold = DEFAULT_THRESHOLD if stored.threshold is None else stored.threshold
    return np.abs(residuals - centre) <= threshold * max(sigma, 1e-12), "lie beyond the robust fit's threshold"


def kept_statistics(calibration: Calibration | None, samples: NDArray[Any]) -> Statistics:
    """The statistics of ``samples`` less those ``calibration``'s robust fit rejected (:func:`inlier_mask`): what
    recordings of one compass merge by. All of them without a calibration or a robust fit."""
    mask = None if calibration is None else inlier_mask(calibration, samples)[0]
    return Statistics.from_samples(samples if mask is None else samples[mask])
