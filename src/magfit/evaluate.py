"""The paper's evaluation (section V): distance of the calibrated samples to the unit sphere."""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ._validation import as_samples
from .calibration import Calibration
from .findings import Evaluation

__all__ = ["Evaluation", "evaluate", "sphere_distances"]


#: Samples per slice of :func:`sphere_distances`: its scratch rows stay in cache.
_DISTANCE_SLICE = 1 << 16


def sphere_distances(calibration: Calibration, samples: ArrayLike) -> NDArray[np.float64]:
    """Signed distance ``|apply(x, normalized=True)| − 1`` of each sample to the unit sphere.

    Parameters
    ----------
    calibration : Calibration
    samples : array_like, shape (N, 3)
        Raw samples, in the calibration's input units.

    Returns
    -------
    ndarray, shape (N,)
        Dimensionless; positive outside the sphere. For a hard-iron-only calibration the corrected
        vector ``x − V`` is divided by the fitted B, as the paper's comparison requires.
    """
    return unchecked_sphere_distances(calibration, as_samples(samples))


def unchecked_sphere_distances(calibration: Calibration, samples: NDArray[Any]) -> NDArray[np.float64]:
    """:func:`sphere_distances` of samples already known to be (N, 3) finite numbers (any float dtype).

    For magfit's own loops (the score of a file, the robust fit, the diagnostics), which have checked
    their samples once.
    """
    n = samples.shape[0]
    # |W y| / B as sqrt(yᵀ Q y), Q = WᵀW / B², y = x − V (subtracted first: no cancellation of a large
    # offset): six products on contiguous rows of yᵀ, a slice at a time. Four times faster than the
    # (N, 3) @ (3, 3) product and the row norms, and no BLAS call, whose threads would compete with the
    # threads that score a file's pieces in parallel.
    quadratic = calibration.matrix.T @ calibration.matrix / calibration.field_strength**2
    terms = [(i, j, quadratic[i, j] * (1.0 if i == j else 2.0)) for i in range(3) for j in range(i, 3)]
    offset = np.asarray(calibration.offset)[:, None]
    distances = np.empty(n)
    scratch = np.empty((4, min(n, _DISTANCE_SLICE)))
    for start in range(0, n, _DISTANCE_SLICE):
        chunk = samples[start : start + _DISTANCE_SLICE]
        y, product = scratch[:3, : chunk.shape[0]], scratch[3, : chunk.shape[0]]
        np.subtract(chunk.T, offset, out=y)
        squared = distances[start : start + chunk.shape[0]]
        squared.fill(0.0)
        for i, j, weight in terms:
            np.multiply(y[i], y[j], out=product)
            product *= weight
            squared += product
        np.sqrt(squared, out=squared)
        squared -= 1.0
    return distances


def evaluate(calibration: Calibration, samples: ArrayLike) -> Evaluation:
    """The paper's goodness of fit: mean and std of :func:`sphere_distances`, plus robust extras."""
    distances = sphere_distances(calibration, samples)
    magnitude = np.abs(distances)
    return Evaluation(
        n=int(distances.size),
        mean=float(distances.mean()),
        std=float(distances.std()),
        mean_abs=float(magnitude.mean()),
        rms=float(np.sqrt(np.mean(distances**2))),
        max_abs=float(magnitude.max()),
    )
