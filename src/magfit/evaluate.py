"""The paper's evaluation (section V): distance of the calibrated samples to the unit sphere."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ._validation import as_samples
from .calibration import Calibration

__all__ = ["Evaluation", "evaluate", "sphere_distances"]


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
    corrected = calibration.apply(as_samples(samples), normalized=True)
    return np.linalg.norm(corrected, axis=1) - 1.0


@dataclass(frozen=True)
class Evaluation:
    """Summary of the sphere distances (dimensionless, fractions of the field strength).

    ``mean`` and ``std`` are the paper's two columns (``std`` is the population standard deviation).
    """

    n: int
    mean: float
    std: float
    mean_abs: float
    rms: float
    max_abs: float

    def to_dict(self) -> dict[str, float | int]:
        return {
            "n": self.n,
            "mean": self.mean,
            "std": self.std,
            "mean_abs": self.mean_abs,
            "rms": self.rms,
            "max_abs": self.max_abs,
        }


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
