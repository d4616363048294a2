"""The paper's hard- and soft-iron calibration (section II): algebraic least squares on eq. (4).

The ten coefficients θ of ``xᵀMx + bᵀx + d = 0`` minimise ``Σ (θᵀ d(z))²`` under ``|θ| = 1``: the
eigenvector of the scatter matrix with the smallest eigenvalue (the ordinary least-squares estimator of
the paper's reference [3]). This estimate is biased when the noise is not small; see ``als``.
"""

from __future__ import annotations

import numpy as np

from ..calibration import Calibration
from ..errors import CalibrationError
from ..geometry.quadric import calibration_from_ellipsoid, check_field_strength, ellipsoid_from_quadric
from .registry import FitInput, register


@register(
    "ellipsoid",
    min_samples=9,
    data="statistics",
    summary="hard + soft iron: algebraic least-squares ellipsoid fit (paper, section II)",
    model="full",
)
def fit_ellipsoid(data: FitInput, *, root: str = "sqrt", field_strength: float | None = None) -> Calibration:
    """Fit eq. (4) by least squares, then ``V = −½ M⁻¹ b``, ``A = M / (Vᵀ M V − d)``, ``W⁻¹ = A^½``.

    Parameters
    ----------
    root : {"sqrt", "cholesky"}
        Which square root of A becomes the correction matrix.
    field_strength : float, optional
        Known magnitude of the local field (e.g. from the World Magnetic Model), input units. The fitted
        ellipsoid is unchanged; ``matrix`` is scaled so that corrected samples have this magnitude
        (then ``det(matrix) != 1``).
    """
    known_field = check_field_strength(field_strength)
    statistics = data.statistics
    eigenvalues, eigenvectors = np.linalg.eigh(statistics.scatter / statistics.n)
    if not eigenvalues[1] > 1e-12 * eigenvalues[-1]:
        # A second quadric fits as well as the first: fewer distinct samples than the 9 parameters need.
        raise CalibrationError(
            "the samples do not single out one ellipsoid: several fit them exactly (too few distinct samples "
            "for the 9 parameters); record more samples while turning the sensor in all directions"
        )
    theta = eigenvectors[:, 0]  # argmin |Dθ|² subject to |θ| = 1
    offset, shape = ellipsoid_from_quadric(theta, statistics, "ellipsoid")
    return calibration_from_ellipsoid(
        "ellipsoid",
        offset,
        shape,
        root=root,
        n_samples=statistics.n,
        field_strength=known_field,
        # How sharply the data single out one quadric: near 1 means a second quadric fits almost as well.
        details={"eigenvalue_ratio": float(eigenvalues[0] / eigenvalues[1])},
    )
