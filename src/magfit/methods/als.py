"""Adjusted least squares (ALS): the consistent ellipsoid fit of the paper's reference [3].

Markovsky, Kukush and Van Huffel, "Consistent least squares fitting of ellipsoids", Numerische
Mathematik 98 (2004) 177–194. Model: the samples are points ``x₀`` of the ellipsoid plus independent
Gaussian noise of covariance ``σ² I``. The ordinary least-squares cost of the paper's eq. (4),
``Σ (θᵀ d(x))² = θᵀ ψ_ls θ``, is biased: ``E ψ_ls`` is the noise-free scatter plus terms in σ², so its
smallest eigenvector drifts away from the true θ however many samples are taken. [3] replaces every
monomial ``x₁^a x₂^b x₃^c`` of ``ψ_ls`` by ``t_a(x₁) t_b(x₂) t_c(x₃)``, where the ``t_k`` are the
(probabilists') Hermite-type polynomials with ``E t_k(x₀ + e) = x₀^k`` for ``e ~ N(0, σ²)``::

    t₀ = 1,  t₁ = x,  t₂ = x² − σ²,  t₃ = x³ − 3σ²x,  t₄ = x⁴ − 6σ²x² + 3σ⁴

Then ``E ψ_als(σ²)`` is the noise-free scatter, which has the true θ in its null space: the ALS estimate
(the eigenvector of the smallest eigenvalue of ψ_als) is consistent. Every entry of ψ_als is a
polynomial in σ² whose coefficients are moments of degree <= 4 of the samples, so ψ_als is built from a
:class:`~magfit.Statistics` alone: ``ψ_als(s) = Ψ₀ + s Ψ₁ + s² Ψ₂`` with ``Ψ₀ = ψ_ls``.

Unknown noise variance ([3], noise variance estimation): the true ``E ψ_als(σ²)`` is positive
semi-definite with a zero eigenvalue exactly at the true σ², so σ̂² is the smallest ``s > 0`` at which
``λ_min(ψ_als(s)) = 0`` (``λ_min`` is positive at ``s = 0``, where ψ_als is the scatter, and decreases
through zero there). The authors' own implementation bisects on the sign of ``λ_min`` below the bound
``s <= tr(cov) / 3``; here a scan of s brackets the first sign change and a bracketed secant search
(Illinois) refines it.
Where their code projects a fitted A that is not positive-definite onto the positive semi-definite
cone, magfit refuses the fit (:class:`~magfit.CalibrationError`), as for every method.

Correspondence with the algorithm of [3]: the values ``t_k(x_il)`` form its tensor T; the exponent
bookkeeping of its matrices M and R is :data:`~magfit.statistics.DESIGN_EXPONENTS` summed pairwise;
``ψ_als`` (with the factor 2 of the off-diagonal parameters) is :func:`als_matrices` with the √2 design
weights; its smallest eigenvector gives ``V = −½ M⁻¹ b`` and ``A = M / (Vᵀ M V − d)`` ([3], eq. 5,
as the magfit paper quotes it; shared with ``ellipsoid``). The other equation numbers of the article
could not be checked for this implementation, so its steps are named instead of numbered.

Everything runs in the normalised frame ``z = (x − centre) / scale`` of the statistics, where the
noise standard deviation is ``σ / scale`` (isotropic noise stays isotropic under that map).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from .._optimize import bracketed_root
from ..calibration import Calibration
from ..errors import CalibrationError, OptionError
from ..geometry.quadric import calibration_from_ellipsoid, check_field_strength, ellipsoid_from_quadric
from ..remedy import option
from ..statistics import DESIGN_EXPONENTS, DESIGN_WEIGHTS, Statistics
from .registry import FitInput, register

__all__ = ["als_matrices", "als_theta", "estimate_noise_variance", "fit_als"]

# t_k(x; s) = Σ coefficient · x^power · s^s_power: the Hermite-type polynomials of [3] with s = σ².
_HERMITE: tuple[tuple[tuple[int, float, int], ...], ...] = (
    ((0, 1.0, 0),),
    ((1, 1.0, 0),),
    ((2, 1.0, 0), (0, -1.0, 1)),
    ((3, 1.0, 0), (1, -3.0, 1)),
    ((4, 1.0, 0), (2, -6.0, 1), (0, 3.0, 2)),
)
#: Grid of trial noise variances (normalised frame, fraction of the largest possible) scanned for the
#: first sign change of λ_min; the root is then refined in that bracket (:func:`magfit._optimize.bracketed_root`).
_VARIANCE_GRID = np.concatenate([[0.0], np.geomspace(1e-12, 1.0, 121)])


def als_matrices(statistics: Statistics) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """The coefficients of ``ψ_als(s) = Ψ₀ + s Ψ₁ + s² Ψ₂`` (per sample, normalised frame), each (10, 10).

    Entry (i, j) corrects the moment ``Σ z^(αᵢ + αⱼ)`` of the scatter (``αᵢ`` the exponents of design
    monomial i): the product over the three axes of ``t_{a_k}(z_k; s)`` is expanded into moments.
    ``Ψ₀`` is the plain scatter divided by n.
    """
    n = statistics.n
    psi = np.zeros((3, 10, 10))
    cache: dict[tuple[int, int, int], NDArray[np.float64]] = {}
    for i, exp_i in enumerate(DESIGN_EXPONENTS):
        for j in range(i, 10):
            exp_j = DESIGN_EXPONENTS[j]
            total = (exp_i[0] + exp_j[0], exp_i[1] + exp_j[1], exp_i[2] + exp_j[2])
            if total not in cache:
                # Σ_n t_a(z₁) t_b(z₂) t_c(z₃) as a polynomial in s (coefficients of s⁰, s¹, s²).
                polynomial = np.zeros(3)
                for p1, c1, s1 in _HERMITE[total[0]]:
                    for p2, c2, s2 in _HERMITE[total[1]]:
                        for p3, c3, s3 in _HERMITE[total[2]]:
                            polynomial[s1 + s2 + s3] += c1 * c2 * c3 * statistics.moment((p1, p2, p3))
                cache[total] = polynomial / n
            psi[:, i, j] = psi[:, j, i] = DESIGN_WEIGHTS[i] * DESIGN_WEIGHTS[j] * cache[total]
    return psi[0], psi[1], psi[2]


def _smallest_eigenvalue(psi: tuple[NDArray[np.float64], ...], s: float) -> float:
    return float(np.linalg.eigvalsh(psi[0] + s * psi[1] + s * s * psi[2])[0])


def estimate_noise_variance(statistics: Statistics, psi: tuple[NDArray[np.float64], ...] | None = None) -> float:
    """σ̂² of [3] in the normalised frame: the smallest ``s >= 0`` with ``λ_min(ψ_als(s)) = 0``.

    Raises :class:`CalibrationError` when no such s exists below the largest variance the data allow
    (a third of the mean squared distance to their mean): then the samples are not an ellipsoid plus
    isotropic noise.
    """
    psi = als_matrices(statistics) if psi is None else psi
    largest = float(np.trace(statistics.covariance)) / statistics.scale**2 / 3.0
    scale = float(np.linalg.eigvalsh(psi[0])[-1])
    previous = 0.0
    value = _smallest_eigenvalue(psi, 0.0)
    if value <= 1e-13 * scale:  # noise-free (to round-off) samples: ψ_ls is already singular
        return 0.0
    for s in _VARIANCE_GRID[1:] * largest:
        current = _smallest_eigenvalue(psi, s)
        if current <= 0.0:
            return bracketed_root(lambda v: _smallest_eigenvalue(psi, v), previous, s, xtol=1e-15, rtol=1e-12)
        previous = s
    raise CalibrationError(
        "the als fit found no noise variance at which the data fit an ellipsoid (λ_min of ψ_als never reaches 0); "
        f"the samples do not outline an ellipsoid plus isotropic noise: use {option('method', 'ellipsoid')} or give "
        "noise_std"
    )


def als_theta(statistics: Statistics, noise_std: float | None = None) -> tuple[NDArray[np.float64], float, float]:
    """ALS quadric coefficients θ (normalised frame), the noise σ used (input units) and λ_min / λ_max of ψ_als.

    ``noise_std`` (input units) fixes σ; ``None`` estimates it from the data.
    """
    psi = als_matrices(statistics)
    if noise_std is None:
        variance = estimate_noise_variance(statistics, psi)
    else:
        variance = (noise_std / statistics.scale) ** 2
    # [3]: θ_als is the eigenvector of the smallest eigenvalue of ψ_als(σ²), i.e. argmin θᵀψ_als θ, |θ| = 1.
    eigenvalues, eigenvectors = np.linalg.eigh(psi[0] + variance * psi[1] + variance**2 * psi[2])
    return eigenvectors[:, 0], math.sqrt(variance) * statistics.scale, float(eigenvalues[0] / eigenvalues[-1])


def _check_noise_std(noise_std: float | None) -> float | None:
    if noise_std is None:
        return None
    try:
        value = float(noise_std)
    except (TypeError, ValueError):
        raise OptionError(f"noise_std must be a number (input units) or None, got {noise_std!r}") from None
    if not (math.isfinite(value) and value >= 0):
        raise OptionError(f"noise_std must be a finite number >= 0 (input units), got {noise_std!r}")
    return value


@register(
    "als",
    min_samples=10,
    data="statistics",
    summary="hard + soft iron: adjusted least squares, consistent under noise (paper's reference [3])",
    model="full",
)
def fit_als(
    data: FitInput, *, noise_std: float | None = None, field_strength: float | None = None, root: str = "sqrt"
) -> Calibration:
    """Fit the ellipsoid by adjusted least squares: the bias of the algebraic fit removed.

    Parameters
    ----------
    noise_std : float, optional
        Standard deviation of the noise on each axis, input units. By default it is estimated from the
        data ([3]: the σ at which ψ_als becomes singular) and reported in ``details["noise_std"]``.
    field_strength : float, optional
        Known magnitude of the local field (e.g. from the World Magnetic Model), input units. The fitted
        ellipsoid is unchanged; ``matrix`` is scaled so that corrected samples have this magnitude
        (then ``det(matrix) != 1``).
    root : {"sqrt", "cholesky"}
        Which square root of A becomes the correction matrix.
    """
    noise = _check_noise_std(noise_std)
    known_field = check_field_strength(field_strength)
    statistics = data.statistics
    theta, sigma, ratio = als_theta(statistics, noise)
    offset, shape = ellipsoid_from_quadric(theta, statistics, "als")  # V, A of [3] eq. (5); refused unless A > 0
    return calibration_from_ellipsoid(
        "als",
        offset,
        shape,
        root=root,
        n_samples=statistics.n,
        field_strength=known_field,
        details={
            "noise_std": sigma,
            "noise_std_source": "estimated" if noise is None else "given",
            # λ_min / λ_max of ψ_als at σ̂: 0 when σ was estimated, its size otherwise tells how well σ fits.
            "eigenvalue_ratio": ratio,
        },
    )
