"""The paper's hard-iron-only calibration (section III): linear least squares on eq. (7).

With W = I the model (6) is a sphere ``|x − V|² = B²``, linear in ``(2V, B² − |V|²)``:
``[x y z 1] · (2Vx, 2Vy, 2Vz, B² − |V|²) = x² + y² + z²`` (eq. 7, with the factor 2 the text lost).

With a known field strength B (option ``field_strength``, as ArduPilot and PX4 take it from the World
Magnetic Model) only V is unknown: it minimises the same algebraic residual of eq. (6),
``Σ (|x − V|² − B²)²``, now a quartic in V whose coefficients are sample moments of degree <= 4, so the
fit still reads only the :class:`~magfit.Statistics`. Pinning B matters when the samples cover only
part of the sphere: the free fit then trades centre against radius, the pinned fit cannot.
"""

from __future__ import annotations

from math import comb

import numpy as np
from numpy.typing import NDArray

from ..calibration import Calibration
from ..errors import CalibrationError
from ..facts import KnownField, SolverStatus
from ..geometry.quadric import check_field_strength
from ..statistics import Statistics
from .registry import FitInput, register
from .support import ellipsoid_outline_problem


def solve_sphere(statistics: Statistics) -> tuple[NDArray[np.float64], float]:
    """Least-squares sphere of eq. (7) in the normalised frame of ``statistics``: centre and B².

    B² may be <= 0 when the samples outline no sphere.
    """
    scatter = statistics.scatter
    # Normal equations of eq. (7) read off the scatter: u = (z, 1) is design entries 6..9 and
    # |z|² the sum of entries 0..2.
    normal = scatter[6:10, 6:10]
    right = scatter[6:10, 0:3].sum(axis=1)
    solution = np.linalg.lstsq(normal, right, rcond=None)[0]
    centre_z = 0.5 * solution[:3]  # eq. (7) solves for 2V
    return centre_z, float(solution[3] + centre_z @ centre_z)


@register(
    "sphere",
    min_samples=4,
    data="statistics",
    summary="hard iron only: least-squares sphere fit (paper, section III)",
    model="sphere",
)
def fit_sphere(data: FitInput, *, field_strength: float | None = None) -> Calibration:
    """Solve eq. (7) by least squares; the calibration is ``raw − V`` on a sphere of radius B (eq. 8).

    Parameters
    ----------
    field_strength : float, optional
        Known magnitude B of the local field, input units (e.g. from the World Magnetic Model). The
        offset is then fitted with the radius pinned to B, starting from the free fit's centre; the free fit's
        radius is kept in ``known_field.fitted``.
    """
    known_field = check_field_strength(field_strength)
    statistics = data.statistics
    # Whether the samples place the centre (a cap of directions, a band) is the verdict's to judge, in the
    # frame of the fitted sphere (magfit.diagnostics.verdict): a cap is enough for a sphere, not for more.
    centre_z, radius_squared_z = solve_sphere(statistics)
    if known_field is not None:
        free_centre_z = centre_z
        centre_z, iterations = _pinned_centre(statistics, centre_z, known_field / statistics.scale)
        fitted = statistics.scale * float(np.sqrt(max(radius_squared_z, 0.0)))
        _check_radius(statistics, centre_z, known_field)
        shift = statistics.scale * float(
            np.linalg.norm(_spanned(statistics, free_centre_z, radius_squared_z, centre_z - free_centre_z))
        )
        free_fit_holds = ellipsoid_outline_problem(statistics) is None  # else its centre is no reference
        if free_fit_holds and shift > RADIUS_TOLERANCE * known_field:
            # A far centre on a big sphere also passes the radius test: the samples then sit on a small cap. Only
            # along the directions the samples spread over does the free fit place its centre (_spanned).
            raise CalibrationError(
                f"the given field strength {known_field:.4g} moves the centre {shift:.4g} away from the free "
                f"fit's (radius {fitted:.4g}): the samples contradict it; check that it is in the samples' unit, "
                "or leave it out",
                codes=("field_mismatch",),
            )
        return Calibration(
            method="sphere",
            offset=statistics.centre + statistics.scale * centre_z,
            matrix=np.eye(3),
            field_strength=known_field,
            n_samples=statistics.n,
            known_field=KnownField(fitted=fitted, pinned=True),  # the fit itself used it: only the offset was fitted
            solver=SolverStatus(iterations=iterations),
        )
    if not radius_squared_z > 0:
        raise CalibrationError(
            "the sphere fit found no real sphere (B² <= 0): the samples do not outline a sphere; "
            "check that they are magnetometer readings taken while turning the sensor",
            codes=("no_ellipsoid",),
        )
    return Calibration(
        method="sphere",
        offset=statistics.centre + statistics.scale * centre_z,
        matrix=np.eye(3),
        field_strength=statistics.scale * np.sqrt(radius_squared_z),
        n_samples=statistics.n,
    )


#: The samples spread along a direction when their standard deviation along it is at least this many times the
#: noise (the free sphere's residual): below, what spread there is along it is the noise itself.
SPANNED_NOISE = 3.0


def _spanned(
    statistics: Statistics, centre_z: NDArray[np.float64], radius_squared_z: float, shift: NDArray[np.float64]
) -> NDArray[np.float64]:
    """``shift`` (normalised frame) without its part along directions the samples do not spread along.

    Samples on a circle (level turns) lie on every sphere through it: centre ``c₀ + t n`` (n the circle's
    axis) with radius ``√(ρ² + t²)``. The free fit of eq. (7) (centre ``centre_z``, radius² ``radius_squared_z``)
    picks one of them by the noise (at zero noise its normal equations are singular), so its centre along n is
    no reference a pinned radius could contradict: pinning B chooses ``t = ±√(B² − ρ²)``, which is what the
    given field strength is for. Along a direction u the free fit places its centre when the samples spread
    along u beyond their noise: the curvature the fit reads there is then the sphere's, not the noise's. The
    noise σ is the free sphere's algebraic residual, ``|y|² − ρ² ≈ 2ρ d`` for a distance d, so
    ``σ ≈ √(Σ (|y|² − ρ²)² / n) / (2ρ)``. Directions whose standard deviation is below :data:`SPANNED_NOISE` σ
    are left out of the shift (a cap of 30° about u spreads 6 σ along u at 1 % noise: kept). The pinned
    radius is still checked against the samples' distances (:func:`_check_radius`), and whether the offset
    along such a direction is determined is the verdict's (a single turning axis is refused as ``single_axis``).
    """
    radius = float(np.sqrt(max(radius_squared_z, 1e-300)))
    algebraic, _, _ = _pinned_objective(statistics, centre_z, radius)
    noise = float(np.sqrt(max(algebraic, 0.0) / statistics.n)) / (2.0 * radius)
    spreads, directions = np.linalg.eigh(statistics.covariance / statistics.scale**2)
    deviations = np.sqrt(np.clip(spreads, 0.0, None))
    spanned = directions[:, deviations >= SPANNED_NOISE * noise]
    return np.asarray(spanned @ (spanned.T @ shift), dtype=np.float64)


#: How far the samples' RMS distance from the pinned centre may stray from the given field strength, and
#: how far pinning may move the centre, as fractions of the given field strength.
RADIUS_TOLERANCE = 0.25


def _check_radius(statistics: Statistics, centre_z: NDArray[np.float64], known_field: float) -> None:
    """Refuse a given field strength that the samples contradict (most often a unit mix-up).

    With ``matrix = I`` the corrected samples keep the radius they have; the convention (corrected
    samples on a sphere of radius ``field_strength``) holds only when the given B is near that radius.
    """
    scatter = statistics.scatter
    sum_squares = float(scatter[0:3, 9].sum())  # Σ |z|²
    sum_z = scatter[6:9, 9]
    mean_square = (sum_squares - 2.0 * float(centre_z @ sum_z)) / statistics.n + float(centre_z @ centre_z)
    radius = statistics.scale * float(np.sqrt(max(mean_square, 0.0)))
    if abs(radius - known_field) > RADIUS_TOLERANCE * known_field:
        raise CalibrationError(
            f"the samples lie {radius:.4g} from the best centre, not at the given field strength "
            f"{known_field:.4g}: check that the field strength is in the samples' unit, or leave it out",
            codes=("field_mismatch",),
        )


def _shifted_moment(statistics: Statistics, exponent: tuple[int, int, int], shift: NDArray[np.float64]) -> float:
    """``Σ Π_k (z_k − shift_k)^(exponent_k)`` over the normalised samples, by binomial expansion."""
    total = 0.0
    for a in range(exponent[0] + 1):
        for b in range(exponent[1] + 1):
            for c in range(exponent[2] + 1):
                weight = (
                    comb(exponent[0], a) * (-shift[0]) ** (exponent[0] - a)
                    * comb(exponent[1], b) * (-shift[1]) ** (exponent[1] - b)
                    * comb(exponent[2], c) * (-shift[2]) ** (exponent[2] - c)
                )  # fmt: skip
                total += weight * statistics.moment((a, b, c))
    return total


def _pinned_objective(
    statistics: Statistics, centre: NDArray[np.float64], radius: float
) -> tuple[float, NDArray[np.float64], NDArray[np.float64]]:
    """``f(c) = Σ (|z − c|² − r²)²``, its gradient and Hessian, from moments of y = z − c."""

    def moment(*axes: int) -> float:
        exponent = [0, 0, 0]
        for axis in axes:
            exponent[axis] += 1
        return _shifted_moment(statistics, (exponent[0], exponent[1], exponent[2]), centre)

    n = statistics.n
    sum_y = np.array([moment(i) for i in range(3)])
    outer = np.array([[moment(i, j) for j in range(3)] for i in range(3)])  # Σ y yᵀ
    sum_r2 = float(np.trace(outer))  # Σ |y|²
    sum_r2_y = np.array([sum(moment(i, k, k) for k in range(3)) for i in range(3)])  # Σ |y|² y
    sum_r4 = sum(moment(k, k, m, m) for k in range(3) for m in range(3))  # Σ |y|⁴
    value = sum_r4 - 2.0 * radius**2 * sum_r2 + n * radius**4
    gradient = -4.0 * (sum_r2_y - radius**2 * sum_y)  # ∇_c Σ q², q = |y|² − r², ∇q = −2y
    hessian = 8.0 * outer + 4.0 * (sum_r2 - n * radius**2) * np.eye(3)
    return value, gradient, hessian


def _pinned_centre(
    statistics: Statistics, start: NDArray[np.float64], radius: float, max_iterations: int = 50
) -> tuple[NDArray[np.float64], int]:
    """Newton's method with backtracking on ``Σ (|z − c|² − r²)²`` (eq. 6 with B known), normalised frame.

    Returns the centre and the number of iterations; raises :class:`CalibrationError` unless it ends
    at a minimum (positive-definite Hessian).
    """
    centre = np.asarray(start, dtype=np.float64)
    value, gradient, hessian = _pinned_objective(statistics, centre, radius)
    iteration = 0
    while iteration < max_iterations:
        iteration += 1
        eigenvalues, eigenvectors = np.linalg.eigh(hessian)
        # Newton step; along directions of negative curvature the step is scaled as a gradient step.
        safe = np.maximum(np.abs(eigenvalues), 1e-9 * max(float(np.abs(eigenvalues).max()), 1e-300))
        step = -eigenvectors @ ((eigenvectors.T @ gradient) / safe)
        for _ in range(60):
            trial = centre + step
            trial_value, trial_gradient, trial_hessian = _pinned_objective(statistics, trial, radius)
            if trial_value <= value:
                break
            step = 0.5 * step
        else:
            break  # no decrease along the step: at a minimum to round-off
        moved = float(np.linalg.norm(trial - centre))
        centre, value, gradient, hessian = trial, trial_value, trial_gradient, trial_hessian
        if moved <= 1e-12 * max(1.0, float(np.linalg.norm(centre))):
            break
    if not np.all(np.linalg.eigvalsh(hessian) > 0):
        raise CalibrationError(
            "the sphere fit with a known field_strength found no minimum: the samples do not outline a sphere "
            "of that radius; check the field_strength and its unit, or record while turning the sensor",
            codes=("field_mismatch",),
        )
    return centre, iteration
