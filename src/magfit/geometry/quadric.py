"""From fitted quadric coefficients to a calibration (paper, section II.B).

Shared by every ellipsoid method: the coefficients θ of eq. (4) in the normalised frame of a
:class:`~magfit.Statistics` give the centre V and shape A of the ellipsoid (eq. 5 of the paper's
reference [3]), then the correction ``W⁻¹ = A^½`` (reference [1], eq. 20) or a Cholesky factor.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .._validation import check_choice
from ..calibration import Calibration
from ..errors import CalibrationError, OptionError
from ..remedy import option
from ..statistics import Statistics

ROOTS = ("sqrt", "cholesky")
_SIGN = {True: "+", False: "-"}


def quadric_matrix(theta: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64], float]:
    """Split θ (design order, see :mod:`magfit.statistics`) into M (3x3), b (3,) and d of eq. (3)."""
    r = 1.0 / math.sqrt(2.0)
    m = np.array(
        [
            [theta[0], r * theta[3], r * theta[4]],
            [r * theta[3], theta[1], r * theta[5]],
            [r * theta[4], r * theta[5], theta[2]],
        ]
    )
    return m, np.asarray(theta[6:9], dtype=np.float64), float(theta[9])


def quadric_ellipsoid(
    theta: NDArray[np.float64], statistics: Statistics
) -> tuple[NDArray[np.float64], NDArray[np.float64]] | str:
    """Centre V and unit-sphere shape A (input units) of the quadric θ fitted in the normalised frame.

    Returns the reason, in words, when the quadric is not a real ellipsoid: never ``abs()`` of an
    eigenvalue, never a NaN.
    """
    m, b, d = quadric_matrix(theta)
    if np.trace(m) < 0:  # θ and −θ are the same quadric
        m, b, d = -m, -b, -d
    eigenvalues = np.linalg.eigvalsh(m)
    if not eigenvalues[0] > 1e-12 * abs(eigenvalues[-1]):
        signs = " ".join(_SIGN[bool(value > 0)] for value in eigenvalues[::-1])
        kind = "a hyperboloid" if eigenvalues[0] < 0 < eigenvalues[-1] else "degenerate"
        return f"the fitted quadric is {kind}, not an ellipsoid (eigenvalue signs of M: {signs})"
    centre_z = -0.5 * np.linalg.solve(m, b)  # V = −½ M⁻¹ b   (section II.B)
    level = float(centre_z @ m @ centre_z - d)  # Vᵀ M V − d
    if not level > 0:
        return f"the fitted quadric is an imaginary ellipsoid (Vᵀ M V − d = {level:.3g} <= 0)"
    shape_z = m / level  # A = M / (Vᵀ M V − d)
    # Back from the normalised frame z = (x − centre) / scale.
    offset = statistics.centre + statistics.scale * centre_z
    shape = shape_z / statistics.scale**2
    return offset, shape


def algebraic_ellipsoid(statistics: Statistics) -> tuple[NDArray[np.float64], NDArray[np.float64]] | str:
    """The paper's least-squares ellipsoid (eq. 4 under |θ| = 1) of ``statistics``: centre and shape, or why none.

    The smallest eigenvector of the scatter ``DᵀD`` minimises ``|Dθ|²`` subject to ``|θ| = 1``; see
    :func:`quadric_ellipsoid` for the rest and :mod:`magfit.methods.ellipsoid` for the method.
    """
    eigenvectors = np.linalg.eigh(statistics.scatter / statistics.n)[1]  # as the ellipsoid method scales it
    return quadric_ellipsoid(eigenvectors[:, 0], statistics)


def ellipsoid_from_quadric(
    theta: NDArray[np.float64], statistics: Statistics, method: str
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """:func:`quadric_ellipsoid`, raising :class:`CalibrationError` with a remedy when it is none."""
    result = quadric_ellipsoid(theta, statistics)
    if isinstance(result, str):
        raise CalibrationError(
            f"the {method} fit failed: {result}; the samples probably cover too few directions: rotate the "
            f"sensor through more attitudes, or use {option('method', 'sphere')} (hard iron only), which needs less "
            "coverage",
            codes=("no_ellipsoid",),
            remedy=(("method", "sphere"),),
        )
    return result


def check_field_strength(field_strength: float | None) -> float | None:
    """Validate the known-field option: ``None`` or a positive finite number (input units)."""
    if field_strength is None:
        return None
    try:
        value = float(field_strength)
    except (TypeError, ValueError):
        raise OptionError(f"field_strength must be a number (input units) or None, got {field_strength!r}") from None
    if not (math.isfinite(value) and value > 0):
        raise OptionError(f"field_strength must be a positive finite number (input units), got {field_strength!r}")
    return value


def calibration_from_ellipsoid(
    method: str,
    offset: NDArray[np.float64],
    shape: NDArray[np.float64],
    *,
    root: str = "sqrt",
    n_samples: int | None = None,
    details: Mapping[str, Any] | None = None,
    field_strength: float | None = None,
) -> Calibration:
    """The calibration of the ellipsoid ``(x − offset)ᵀ shape (x − offset) = 1``.

    ``W⁻¹`` is the symmetric square root of ``shape`` (``root="sqrt"``) or the transpose of its lower
    Cholesky factor (``root="cholesky"``, the alternative the paper mentions); both satisfy
    ``W⁻ᵀ W⁻¹ = shape`` and differ by a rotation. The field strength is the geometric mean of the
    semi-axes, so that ``det(matrix) = 1``.

    A known ``field_strength`` (input units; e.g. from the World Magnetic Model) leaves the ellipsoid
    as fitted but scales ``matrix`` so that corrected samples have that magnitude: then
    ``det(matrix) = (field_strength / fitted)³`` and the fitted value is kept in ``details``.
    """
    check_choice("root", root, ROOTS)
    shape = 0.5 * (shape + shape.T)
    eigenvalues, eigenvectors = np.linalg.eigh(shape)
    if root == "sqrt":
        unit_map = (eigenvectors * np.sqrt(eigenvalues)) @ eigenvectors.T
    else:
        unit_map = np.linalg.cholesky(shape).T
    strength = float(np.prod(eigenvalues) ** (-1.0 / 6.0))
    fitted = Calibration(
        method=method,
        offset=offset,
        matrix=strength * unit_map,
        field_strength=strength,
        n_samples=n_samples,
        details={"root": root, **(details or {})},
    )
    return pin_field_strength(fitted, field_strength)


def pin_field_strength(calibration: Calibration, field_strength: float | None) -> Calibration:
    """``calibration`` with its corrected sphere scaled to a known ``field_strength`` (input units).

    The fitted ellipsoid is kept; ``matrix`` is scaled so that corrected samples have the given
    magnitude (then ``det(matrix) = (field_strength / fitted)³``) and the fitted value is kept in
    ``details["fitted_field_strength"]``. ``None`` returns the calibration unchanged.
    """
    if field_strength is None:
        return calibration
    return replace(
        calibration,
        matrix=calibration.matrix * (field_strength / calibration.field_strength),
        field_strength=field_strength,
        details={
            **calibration.details,
            "field_strength_given": True,
            "fitted_field_strength": calibration.field_strength,
        },
    )
