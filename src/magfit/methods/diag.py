"""Hard iron plus an axis-aligned scale per axis: the quadric of eq. (4) without its cross terms.

The model of MATLAB's ``magcal(..., 'diag')`` and of MotionCal's 7-element fit: the soft iron only
stretches each sensor axis, ``W = diag(w₁, w₂, w₃)``, so eq. (2) becomes
``Σ_k a_k (x_k − V_k)² = 1``, i.e. eq. (4) with ``m₂ = m₃ = m₅ = 0``::

    m₁x₁² + m₄x₂² + m₆x₃² + b₁x₁ + b₂x₂ + b₃x₃ + d = 0

Seven coefficients, fitted like the paper's ellipsoid (section II.B): the eigenvector of the smallest
eigenvalue of the scatter restricted to the design monomials ``x₁², x₂², x₃², x₁, x₂, x₃, 1``. Then
``V = −½ M⁻¹ b`` and ``A = M / (Vᵀ M V − d)`` as in the paper; A and the correction are diagonal.

It needs less coverage than the full ellipsoid (6 parameters besides the scale instead of 9) and is
exact when the distortion is axis-aligned; a rotated soft iron (iron off the sensor axes) biases it.
"""

from __future__ import annotations

import numpy as np

from ..calibration import Calibration
from ..errors import CalibrationError
from ..geometry.quadric import calibration_from_ellipsoid, check_field_strength, quadric_ellipsoid
from ..remedy import option
from .registry import FitInput, register

__all__ = ["DIAGONAL_TERMS", "fit_diag"]

#: Design-vector indices (see :mod:`magfit.statistics`) of x₁², x₂², x₃², x₁, x₂, x₃, 1.
DIAGONAL_TERMS = (0, 1, 2, 6, 7, 8, 9)


@register(
    "diag",
    min_samples=7,
    data="statistics",
    summary="hard iron + per-axis scale: axis-aligned ellipsoid fit (magcal 'diag', MotionCal 7 elements)",
    model="diag",
)
def fit_diag(data: FitInput, *, field_strength: float | None = None) -> Calibration:
    """Fit eq. (4) without cross terms by least squares: offset and a diagonal correction matrix.

    Parameters
    ----------
    field_strength : float, optional
        Known magnitude of the local field (e.g. from the World Magnetic Model), input units. The fitted
        ellipsoid is unchanged; ``matrix`` is scaled so that corrected samples have this magnitude
        (then ``det(matrix) != 1``).
    """
    known_field = check_field_strength(field_strength)
    statistics = data.statistics
    terms = np.array(DIAGONAL_TERMS)
    scatter = statistics.scatter[np.ix_(terms, terms)] / statistics.n
    eigenvalues, eigenvectors = np.linalg.eigh(scatter)
    theta = np.zeros(10)
    theta[terms] = eigenvectors[:, 0]  # argmin |Dθ|² over the 7 terms, |θ| = 1; cross terms m₂ = m₃ = m₅ = 0
    ellipsoid = quadric_ellipsoid(theta, statistics)  # V = −½ M⁻¹ b, A = M / (Vᵀ M V − d), or the reason
    if isinstance(ellipsoid, str):
        raise CalibrationError(
            f"the diag fit failed: {ellipsoid}; either the soft iron is turned off the sensor axes, which the "
            f"axis-aligned model cannot represent (use {option('method', 'als')}), or the samples cover too few "
            "directions (rotate the sensor through more attitudes)",
            codes=("no_ellipsoid",),
        )
    offset, shape = ellipsoid
    shape = np.diag(np.diag(shape))  # exactly diagonal (the off-diagonal entries are zeros already)
    return calibration_from_ellipsoid(
        "diag",
        offset,
        shape,
        n_samples=statistics.n,
        field_strength=known_field,
        details={"eigenvalue_ratio": float(eigenvalues[0] / eigenvalues[1])},
    )
