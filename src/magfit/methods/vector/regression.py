"""The alignment fit: (1) of :mod:`.method`, ``raw_k = G r_k + V``, by linear least squares on the design
``[r, 1]``, one regression per axis of ``raw`` (:func:`_solve`), refused when the reference does not change
along some direction (:func:`magfit.diagnostics.reference.design_singularity`) or G comes out singular.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from ...diagnostics.reference import (
    ADVICE,
    design_singularity,
)
from ...errors import CalibrationError
from .reference import _design


def _solve(raw: NDArray[np.float64], reference: NDArray[np.float64]) -> tuple[NDArray[Any], NDArray[Any]]:
    """G and V of ``raw = G r + V`` by least squares (one regression per axis of raw)."""
    coefficients, *_ = np.linalg.lstsq(_design(reference), raw, rcond=None)
    return coefficients[:3].T, coefficients[3]


def _relative_rms(raw: NDArray[np.float64], reference: NDArray[np.float64], g: NDArray[np.float64],
                  offset: NDArray[np.float64]) -> float:  # fmt: skip
    """The RMS of ``raw − G r − V`` over the field in the samples' unit (as the verdict's residual_rms)."""
    residuals = raw - reference @ g.T - offset
    scale = abs(float(np.linalg.det(g))) ** (1.0 / 3.0)
    return float(np.sqrt(np.mean(np.sum(residuals**2, axis=1)))) / scale


def _vertical(g: NDArray[np.float64]) -> NDArray[np.float64]:
    """The unit row z of ``M = G⁻¹``: which direction of the samples the calibration reads as the vehicle's vertical."""
    row = np.linalg.inv(g)[2]
    return np.asarray(row / np.linalg.norm(row), dtype=np.float64)


def _regression(raw: NDArray[np.float64], reference: NDArray[np.float64], field: float) -> tuple[NDArray[Any],
                NDArray[Any]]:  # fmt: skip
    """G and V of eq. (1) by least squares, or the refusal when the reference does not determine them."""
    singular = design_singularity(reference, field)
    if singular is not None:  # nothing to return even when forced: the least-squares solution is arbitrary
        raise CalibrationError(
            f"the samples do not support the vector calibration: {singular}; {ADVICE}",
            codes=("single_axis" if "hardly turned" in singular else "undetermined",),
        )
    g, offset = _solve(raw, reference)
    if not abs(float(np.linalg.det(g))) > 1e-12 * float(np.max(np.abs(g))) ** 3:
        raise CalibrationError(
            "the samples do not support the vector calibration: the fitted matrix is singular (the samples do not "
            "change with the reference along some direction: a magnetometer axis that is dead or saturated?)",
            codes=("undetermined",),
        )
    return g, offset
