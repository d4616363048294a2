"""Observability and uncertainty from :class:`~magfit.Statistics` alone (no samples).

A fit from statistics (chunked or merged) keeps only the scatter ``S = Σ d(z) d(z)ᵀ`` of the design vector
of eq. (4), i.e. every moment of the samples up to degree four. That is enough for a Gauss-Newton analysis
of the *algebraic* residual: near the fitted ellipsoid, in the calibration's corrected frame
``c = L (x − V)`` (L the symmetric unit map), the residual is

    r = |c| − 1 ≈ (|c|² − 1) / 2                                            (first order in r)

and its derivatives with respect to the parameters (v, L) at (0, I) — ``−c_i`` along the offset,
``c_j²`` along a diagonal entry of L, ``2 c_j c_k`` along an off-diagonal one, ``|c|²`` along a sphere's
scale — are quadratic polynomials in c. Any two quadratic polynomials ``θ_aᵀ d(c)`` and ``θ_bᵀ d(c)`` have
``Σ (θ_aᵀ d)(θ_bᵀ d) = θ_aᵀ S_c θ_b`` with ``S_c`` the scatter in the corrected frame, an exact linear
transform of the stored one (``d(G z + h) = T d(z)``). So JᵀJ, the residual sum of squares and the residual
mean are read off the statistics.

The approximation is the algebraic one: it weights the samples by the local stretch of the correction, so
for strongly eccentric ellipsoids the one-sigmas are rougher than those :func:`magfit.diagnose` computes
from the samples (measured within a factor of about 2). Coverage and held-out goodness need the samples.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from ..calibration import Calibration
from ..geometry.frame import symmetric_unit_map
from ..statistics import DESIGN_EXPONENTS, DESIGN_WEIGHTS, Statistics
from .uncertainty import Observability, WeakDirection, _weak_directions

#: Without the samples, a direction is called not determined below this share of a full tumble's information.
UNDETERMINED_INFORMATION = 1e-3

__all__ = ["affine_design_transform", "analyse_statistics"]

_OFF_DIAGONAL = ((0, 1), (0, 2), (1, 2))
_INDEX = {exponent: j for j, exponent in enumerate(DESIGN_EXPONENTS)}


def affine_design_transform(gain: NDArray[np.float64], shift: NDArray[np.float64]) -> NDArray[np.float64]:
    """The 10x10 matrix T with ``d(G z + h) = T d(z)`` for every z (G = ``gain``, 3x3; h = ``shift``)."""
    transform = np.zeros((10, 10))
    # Each coordinate of G z + h as a polynomial in z: {exponent: coefficient}.
    linear = [
        {**{DESIGN_EXPONENTS[6 + a]: float(gain[i, a]) for a in range(3)}, (0, 0, 0): float(shift[i])} for i in range(3)
    ]
    for k, exponent in enumerate(DESIGN_EXPONENTS):
        polynomial: dict[tuple[int, int, int], float] = {(0, 0, 0): 1.0}
        for axis, power in enumerate(exponent):
            for _ in range(power):
                product: dict[tuple[int, int, int], float] = {}
                for left, left_coefficient in polynomial.items():
                    for right, right_coefficient in linear[axis].items():
                        key = (left[0] + right[0], left[1] + right[1], left[2] + right[2])
                        product[key] = product.get(key, 0.0) + left_coefficient * right_coefficient
                polynomial = product
        for key, coefficient in polynomial.items():
            j = _INDEX[key]
            transform[k, j] += DESIGN_WEIGHTS[k] * coefficient / DESIGN_WEIGHTS[j]
    return transform


def _residual_and_jacobian(kind: str) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """θ of r ≈ (|c|² − 1)/2 and of each ∂r/∂p at (0, I), in the design basis of c; shapes (10,), (10, k)."""
    residual = np.zeros(10)
    residual[[0, 1, 2]] = 0.5
    residual[9] = -0.5
    columns = [-np.eye(10)[:, 6 + i] for i in range(3)]  # ∂r/∂v_i = −c_i
    if kind == "sphere":
        columns.append(np.eye(10)[:, 0] + np.eye(10)[:, 1] + np.eye(10)[:, 2])  # |c|²
    else:
        columns.extend(np.eye(10)[:, j] for j in range(3))  # c_j²
        if kind == "full":
            # 2 c_j c_k = √2 · (√2 c_j c_k): the design entry 3 + m carries √2 c_j c_k
            columns.extend(math.sqrt(2.0) * np.eye(10)[:, 3 + m] for m in range(3))
    return residual, np.column_stack(columns)


def analyse_statistics(
    statistics: Statistics, calibration: Calibration, kind: str
) -> tuple[Observability, float, float]:
    """Observability of ``calibration`` from ``statistics`` alone, and the algebraic residual's mean and std.

    The weak directions are named by their share of a full tumble's information; no one-sigma is given:
    the algebraic residual's Jacobian gives the weakly determined directions more information than the
    samples hold (measured: the vertical offset's one-sigma 4 times too small under ±20° tilts, where the
    samples' own analysis matched the spread over repeated simulations). A direction with less than
    :data:`UNDETERMINED_INFORMATION` of a tumble's information is called not determined.
    """
    lmat = symmetric_unit_map(calibration)  # 1 / input units
    # c = L (x − V) with x = centre + scale · z: c = G z + h.
    gain = lmat * statistics.scale
    shift = lmat @ (statistics.centre - calibration.offset)
    transform = affine_design_transform(gain, shift)
    scatter = transform @ statistics.scatter @ transform.T  # Σ d(c) d(c)ᵀ
    residual, jacobian = _residual_and_jacobian(kind)
    total = float(statistics.n)
    k = jacobian.shape[1]
    information = jacobian.T @ scatter @ jacobian  # JᵀJ
    residual_variance = float(residual @ scatter @ residual) / max(total - k, 1.0)
    residual_mean = float(residual @ scatter[:, 9]) / total  # Σ r · 1
    condition, weak, _ = _weak_directions(information, residual_variance, total, kind)
    named = tuple(
        WeakDirection(
            description=w.description,
            relative_information=w.relative_information,
            sigma=None,
            determined=w.relative_information >= UNDETERMINED_INFORMATION,
            vector=w.vector,
        )
        for w in weak
    )
    return Observability(kind, condition, named, None), residual_mean, math.sqrt(max(residual_variance, 0.0))
