"""Maximum-likelihood refinement: the ellipsoid nearest to the samples in orthogonal distance.

Model: each sample is a point ``x₀`` of the ellipsoid ``(x − V)ᵀ A (x − V) = 1`` (eq. 2 scaled to the
unit sphere) plus independent Gaussian noise ``e ~ N(0, σ² I)`` on the raw axes. With the true points
``x₀`` as nuisance parameters, the likelihood is maximal when ``Σ dᵢ²`` is minimal, ``dᵢ`` the
orthogonal (Euclidean) distance of sample i to the ellipsoid (geometric fitting). Note that
``|W⁻¹(x − V)| − B``, the usual "radius error", is a distance measured after the soft-iron correction:
it weights the samples by the local stretch of the ellipsoid and is not this likelihood when the soft
iron is strong.

Distance (the foot point, solved exactly): in the principal frame of A (semi-axes ``a_k``, sample
coordinates ``w_k``), the nearest point is ``p_k = a_k² w_k / (a_k² + t)`` where t is the root of
``g(t) = Σ a_k² w_k² / (a_k² + t)² − 1`` on ``t > −a_min²``. g is convex and decreasing there, so
Newton's method, kept above the bracket ``t >= −a_min² + a_min |w_min|`` (where g >= 0), converges for
every sample at once (vectorised, a handful of iterations from the first-order start
``t ≈ 2 F / |∇F|²``). Then ``d = t |∇F(p)| / 2`` (signed, positive outside), with
``F(y) = (y − V)ᵀ A (y − V) − 1``, and ``∂d/∂θ = (∂F/∂θ)(p) / |∇F(p)|`` for every parameter θ.

Bias correction: the maximum-likelihood ellipsoid of a curved surface is not consistent: a noisy sample
lies on average ``σ² H`` outside the surface (``H = (κ₁ + κ₂)/2`` the mean curvature at its foot point:
``E d = E[e_n + (κ₁e₁² + κ₂e₂²)/2]``), so the plain fit grows the ellipsoid by about ``σ²/B``. With
``bias_correction=True`` (the default) the residual is ``dᵢ − σ² Hᵢ``, which has mean zero at the true
ellipsoid to second order in σ (σ from the ALS start, or from the distances when that fails). The
remaining bias is O(σ⁴); the fit keeps the efficiency of the geometric fit at low noise.

Parameters: the offset V and the Cholesky factor L of ``A = L Lᵀ`` (log-diagonal), so that every
iterate is a real ellipsoid (positive definite): 9 parameters. Solved by
Levenberg–Marquardt (analytic Jacobian, normal equations: see :mod:`magfit._optimize` for why not
:func:`scipy.optimize.least_squares`) in the normalised frame of the statistics, started from ``als``
(or ``ellipsoid`` when the ALS fit is not an ellipsoid).

Known field strength: unlike the sphere's radius, the size of a general ellipsoid is fitted from the
data, and B cannot be pinned inside the fit without assuming ``det W = 1`` (soft iron that keeps the
volume), which real iron breaks (the paper's steel cases as ``magfit.scenario`` simulates them: semi-axes
of geometric mean 2.1 B and 0.70 B). So, as for ``ellipsoid``, a given ``field_strength`` scales the
correction matrix only.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .._optimize import Evaluation, Solution, levenberg_marquardt
from ..calibration import Calibration
from ..errors import CalibrationError, OptionError
from ..facts import SolverStatus
from ..geometry.quadric import calibration_from_ellipsoid, check_field_strength, ellipsoid_from_quadric
from ..remedy import option
from ..statistics import Statistics
from .als import als_theta
from .core import first_order_stand_in
from .registry import FitInput, Judging, register

__all__ = ["COVARIANCE_PARAMETERS", "fit_ml", "orthogonal_distances"]

#: Order of the rows and columns of ``details["covariance"]``: the offset (input units) and the
#: entries of the unit-sphere ellipsoid matrix A (``Calibration.ellipsoid_matrix``, input units⁻²).
COVARIANCE_PARAMETERS = ("offset_x", "offset_y", "offset_z", "A_xx", "A_yy", "A_zz", "A_xy", "A_xz", "A_yz")
# (row, column) of A for each A entry above; off-diagonal entries appear twice in the quadratic form.
_A_ENTRIES = ((0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2))
_L_OFF_DIAGONAL = ((1, 0), (2, 0), (2, 1))
_NEWTON_ITERATIONS = 60
#: Samples per chunk of the residual evaluation: temporaries stay small enough to be reused, not re-faulted.
_CHUNK = 1 << 15


def _foot_points(
    zt: NDArray[np.float64],
    centre: NDArray[np.float64],
    shape: NDArray[np.float64],
    t_start: NDArray[np.float64] | None = None,
) -> _Feet:
    """Nearest points of the ellipsoid ``(y − centre)ᵀ shape (y − centre) = 1`` to the columns of ``zt`` (3, N).

    ``t_start`` (N,) warm-starts the Newton iteration (the previous parameters' roots).
    """
    eigenvalues, rotation = np.linalg.eigh(shape)
    semi_squared = 1.0 / eigenvalues  # a_k²
    # Small products by einsum, not BLAS: threaded BLAS on (3, n) operands costs more than it saves.
    w = np.einsum("ki,kn->in", rotation, zt - centre[:, None])  # principal-frame coordinates, (3, N)
    weighted = w * w * semi_squared[:, None]  # a_k² w_k²
    smallest = int(np.argmin(semi_squared))
    a_min = math.sqrt(semi_squared[smallest])
    lower = a_min * np.abs(w[smallest]) - semi_squared[smallest]  # g(lower) >= 0: the root lies above
    # A sample on the principal plane deep inside (w_min = 0) would put the bound on the pole at −a_min².
    np.maximum(lower, -semi_squared[smallest] * (1.0 - 1e-12), out=lower)
    if t_start is None:
        # First order: t ≈ 2 F / |∇F|², F = Σ w²/a² − 1, |∇F|² = 4 Σ w²/a⁴.
        level = np.einsum("k,kn->n", eigenvalues**2, weighted) - 1.0
        gradient_squared = 4.0 * np.einsum("k,kn->n", eigenvalues**3, weighted)
        t = 2.0 * level / np.maximum(gradient_squared, 1e-300)
    else:
        t = t_start.copy()
    np.maximum(t, lower, out=t)
    tolerance = 1e-13 * float(semi_squared.max())
    shifted = np.empty_like(w)
    for _ in range(_NEWTON_ITERATIONS):
        np.add(semi_squared[:, None], t, out=shifted)
        inverse = np.reciprocal(shifted, out=shifted)  # 1 / (a_k² + t)
        term = weighted * inverse * inverse
        g = term[0] + term[1] + term[2] - 1.0
        term *= inverse
        slope = term[0] + term[1] + term[2]  # −g'(t) / 2
        step = g / (2.0 * slope)  # Newton: t ← t − g / g'
        t_new = np.maximum(t + step, lower)
        largest_change = float(np.max(np.abs(t_new - t)))
        t = t_new
        if largest_change <= tolerance:
            break
    inverse = 1.0 / (semi_squared[:, None] + t)
    foot = w * semi_squared[:, None] * inverse  # p_k = a_k² w_k / (a_k² + t)
    normal = foot * eigenvalues[:, None]  # ∇F(p) / 2 = p_k / a_k²
    normal_squared = normal[0] ** 2 + normal[1] ** 2 + normal[2] ** 2
    normal_length = np.sqrt(normal_squared)
    # κ₁ + κ₂ = (|∇F|² tr ∇²F − ∇Fᵀ ∇²F ∇F) / |∇F|³ with ∇F = 2 p/a², ∇²F = 2 diag(1/a²).
    curvature_sum = (normal_squared * eigenvalues.sum() - np.einsum("k,kn->n", eigenvalues, normal * normal)) / (
        normal_squared * normal_length
    )
    return _Feet(t, t * normal_length, np.einsum("ik,kn->in", rotation, foot), 2.0 * normal_length, 0.5 * curvature_sum)


@dataclass
class _Feet:
    """Foot points of the samples on an ellipsoid (normalised frame)."""

    root: NDArray[np.float64]  # t of each sample, (N,)
    distance: NDArray[np.float64]  # signed orthogonal distance d = t |∇F(p)| / 2, (N,)
    foot: NDArray[np.float64]  # foot point minus the centre, (3, N)
    gradient_norm: NDArray[np.float64]  # |∇F(p)|, (N,)
    mean_curvature: NDArray[np.float64]  # (κ₁ + κ₂) / 2 at the foot point, (N,)


def orthogonal_distances(calibration: Calibration, samples: NDArray[np.float64]) -> NDArray[np.float64]:
    """Signed Euclidean distance (input units, positive outside) of each sample to a calibration's ellipsoid.

    Parameters
    ----------
    calibration : Calibration
    samples : ndarray, shape (N, 3)
        Raw samples, input units.

    Returns
    -------
    ndarray, shape (N,)
    """
    samples = np.asarray(samples, dtype=np.float64)
    distances = np.empty(samples.shape[0])
    for start in range(0, samples.shape[0], _CHUNK):
        chunk = np.ascontiguousarray(samples[start : start + _CHUNK].T)
        feet = _foot_points(chunk, calibration.offset, calibration.ellipsoid_matrix)
        distances[start : start + _CHUNK] = feet.distance
    return distances


class _Model:
    """Residuals and Jacobian of the (bias-corrected) orthogonal distances, in the normalised frame."""

    size = 9  # offset (3), log-diagonal (3) and off-diagonal (3) of the Cholesky factor L of A

    def __init__(self, zt: NDArray[np.float64], variance: float) -> None:
        self.zt = zt  # samples, (3, N)
        self.variance = variance  # σ² of the bias correction (normalised frame), 0 for none

    def unpack(self, params: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Centre (3,) and lower-triangular L (3, 3) from the parameter vector."""
        lower = np.diag(np.exp(params[3:6]))
        for k, (i, j) in enumerate(_L_OFF_DIAGONAL):
            lower[i, j] = params[6 + k]
        return params[:3].copy(), lower

    def pack(self, centre: NDArray[Any], lower: NDArray[Any]) -> NDArray[np.float64]:
        return np.concatenate([centre, np.log(np.diag(lower)), [lower[i, j] for i, j in _L_OFF_DIAGONAL]])

    def shape_jacobian(self, lower: NDArray[np.float64]) -> NDArray[np.float64]:
        """d(A entries, order of ``_A_ENTRIES``) / d(shape parameters), (6, 6)."""
        directions = []
        for k in range(3):
            unit = np.zeros((3, 3))
            unit[k, k] = lower[k, k]  # d exp(l_k) = exp(l_k) dl_k
            directions.append(unit)
        for i, j in _L_OFF_DIAGONAL:
            unit = np.zeros((3, 3))
            unit[i, j] = 1.0
            directions.append(unit)
        columns = []
        for d_lower in directions:
            d_shape = d_lower @ lower.T + lower @ d_lower.T  # dA = dL Lᵀ + L dLᵀ
            columns.append([d_shape[i, j] for i, j in _A_ENTRIES])
        return np.array(columns).T

    def _jacobian_transposed(self, lower: NDArray[np.float64], feet: _Feet) -> NDArray[np.float64]:
        """Jᵀ of one chunk, (size, n): ``∂d/∂θ = (∂F/∂θ)(p) / |∇F(p)|``, ``∂F/∂V = −2 A p``, ``∂F/∂A_ij = p_i p_j``.

        The bias-correction term σ² H is O(σ²) and its derivative is left out (a Gauss–Newton
        approximation: the fixed point Jᵀ r = 0 it converges to is unchanged).
        """
        shape = lower @ lower.T
        inverse_norm = 1.0 / feet.gradient_norm
        products = np.empty((6, feet.foot.shape[1]))
        for k, (i, j) in enumerate(_A_ENTRIES):
            np.multiply(feet.foot[i], feet.foot[j], out=products[k])
            products[k] *= inverse_norm if i == j else 2.0 * inverse_norm  # A_ij appears twice off the diagonal
        jacobian_t = np.empty((self.size, feet.foot.shape[1]))
        jacobian_t[:3] = np.einsum("ij,jn->in", -2.0 * shape, feet.foot) * inverse_norm
        jacobian_t[3:] = np.einsum("ki,kn->in", self.shape_jacobian(lower), products)
        return jacobian_t

    def evaluate(self, params: NDArray[np.float64], roots: NDArray[np.float64] | None = None) -> Evaluation:
        """Cost, JᵀJ and Jᵀr at ``params``, accumulated over chunks of samples (bounded memory, no page faults).

        ``roots`` (N,) warm-starts the foot-point iterations from a nearby parameter vector.
        """
        centre, lower = self.unpack(params)
        shape = lower @ lower.T
        n = self.zt.shape[1]
        # eigh, as _foot_points computes it (eigvalsh may differ in the last bit and pass a non-positive one)
        if not (np.all(np.isfinite(shape)) and np.linalg.eigh(shape)[0][0] > 1e-12 * np.abs(shape).max()):
            # A trial step so long that L under- or overflowed: no ellipsoid, so no distances; Levenberg-
            # Marquardt refuses the step (infinite cost) and damps more.
            return Evaluation(math.inf, np.zeros((self.size, self.size)), np.zeros(self.size), warm=None)
        new_roots = np.empty(n)
        cost = 0.0
        normal = np.zeros((self.size, self.size))
        gradient = np.zeros(self.size)
        for start in range(0, n, _CHUNK):
            stop = min(start + _CHUNK, n)
            feet = _foot_points(self.zt[:, start:stop], centre, shape, None if roots is None else roots[start:stop])
            new_roots[start:stop] = feet.root
            residual = feet.distance - self.variance * feet.mean_curvature if self.variance > 0 else feet.distance
            jacobian_t = self._jacobian_transposed(lower, feet)
            cost += 0.5 * float(np.einsum("n,n->", residual, residual))  # no threaded BLAS dot
            normal += jacobian_t @ jacobian_t.T  # JᵀJ: a 9x9 BLAS product (single-threaded at this shape)
            gradient += np.einsum("in,n->i", jacobian_t, residual)  # Jᵀr
        return Evaluation(cost, normal, gradient, warm=new_roots)


def _start(statistics: Statistics) -> tuple[str, NDArray[np.float64], NDArray[np.float64], float | None]:
    """Starting ellipsoid (centre, shape) in the normalised frame: ALS, else the algebraic fit.

    Also returns σ² (normalised frame) estimated by ALS, or None for the algebraic start.
    """
    reasons = []
    try:
        theta, sigma, _ = als_theta(statistics)
        offset, shape = ellipsoid_from_quadric(theta, statistics, "als")
        return (
            "als",
            (offset - statistics.centre) / statistics.scale,
            shape * statistics.scale**2,
            (sigma / statistics.scale) ** 2,
        )
    except CalibrationError as error:
        reasons.append(str(error).split(";")[0])
    try:
        theta = np.linalg.eigh(statistics.scatter)[1][:, 0]
        offset, shape = ellipsoid_from_quadric(theta, statistics, "ellipsoid")
        return "ellipsoid", (offset - statistics.centre) / statistics.scale, shape * statistics.scale**2, None
    except CalibrationError as error:
        reasons.append(str(error).split(";")[0])
    raise CalibrationError(
        "the ml fit has no starting ellipsoid (" + "; ".join(reasons) + "): the samples cover too few directions; "
        f"rotate the sensor through more attitudes, or use {option('method', 'sphere')} (hard iron only)"
    )


def _score_length(evaluation: Evaluation, size: int) -> tuple[float, NDArray[np.float64]]:
    """The undamped Gauss–Newton step ``δ = −(JᵀJ)⁻¹ Jᵀr`` and its length in standard errors, ``√(δᵀJᵀJδ)/σ``."""
    step = np.asarray(np.linalg.solve(evaluation.normal, -evaluation.gradient), dtype=np.float64)
    n = evaluation.warm.shape[0]  # one foot-point root per sample
    sigma = math.sqrt(2.0 * evaluation.cost / max(n - size, 1)) + 1e-300
    return math.sqrt(max(float(-step @ evaluation.gradient), 0.0)) / sigma, step


def _solve_estimating_equation(model: _Model, solution: Solution, max_iterations: int) -> Solution:
    """Drive the bias-corrected estimating equation ``Jᵀ r = 0`` to zero by Gauss–Newton steps.

    With the correction, ``r = d − σ² H`` and the Jacobian leaves out ``σ² ∂H/∂θ``, so the least-squares
    cost that Levenberg–Marquardt watches is not exactly the function whose stationary point is wanted:
    near the solution its steps can stop lowering that cost and shrink without reaching ``Jᵀ r = 0``
    (seen on tilt-limited coverage at 10 % noise). This polish accepts a step (halved up to 20 times)
    when it shortens the Gauss–Newton step itself, and stops when that step is below 1e-3 standard
    errors: then ``Jᵀ r = 0`` holds far inside the noise.
    """
    params, current = solution.params, solution.evaluation
    length, step = _score_length(current, model.size)
    if length <= 1e-3:  # the usual case: Levenberg–Marquardt already ended on the solution
        return solution
    for iteration in range(1, max_iterations + 1):
        if length <= 1e-3:
            return Solution(
                params, current, max(solution.status, 1), "the estimating equation holds to 1e-3 standard errors",
                solution.iterations + iteration - 1,
            )  # fmt: skip
        fraction = 1.0
        for _ in range(20):
            trial = model.evaluate(params + fraction * step, current.warm)
            if np.isfinite(trial.cost):  # else no ellipsoid there (see _Model.evaluate): a shorter step
                trial_length, trial_step = _score_length(trial, model.size)
                if trial_length < length:
                    break
            fraction *= 0.5
        else:
            return Solution(params, current, 0, "the bias-corrected equation has no nearby solution", iteration)
        params, current, length, step = params + fraction * step, trial, trial_length, trial_step
    return Solution(params, current, 0, "the iteration limit was reached", solution.iterations + max_iterations)


@register(
    "ml",
    min_samples=10,
    data="samples",
    summary="hard + soft iron: maximum likelihood (orthogonal distance), bias-corrected, started from als",
    model="full",
    judging=Judging(stand_in=first_order_stand_in),  # iterative: 10 refits would take seconds on a long log
)
def fit_ml(
    data: FitInput,
    *,
    field_strength: float | None = None,
    bias_correction: bool = True,
    max_iterations: int = 200,
    root: str = "sqrt",
) -> Calibration:
    """Refine the ellipsoid by least squares on the orthogonal distances of the samples (Gaussian ML).

    Parameters
    ----------
    field_strength : float, optional
        Known magnitude of the local field (e.g. from the World Magnetic Model), input units. The fitted
        ellipsoid is unchanged; ``matrix`` is scaled so that corrected samples have this magnitude
        (then ``det(matrix) != 1``). See the module docstring for why it is not pinned inside the fit.
    bias_correction : bool
        Subtract the mean-curvature bias ``σ² H`` from each distance (see the module docstring), so that
        the fit stays close to consistent at high noise. ``False`` gives the plain geometric (ML) fit.
    max_iterations : int
        Limit on the Levenberg–Marquardt iterations; reaching it is a :class:`CalibrationError`.
    root : {"sqrt", "cholesky"}
        Which square root of A becomes the correction matrix.

    Notes
    -----
    ``details`` holds the solver's ``status``, ``message``, ``iterations``, ``cost`` (half the sum of
    squared residuals, input units²), ``noise_std`` (RMS residual, input units), ``start`` (``"als"``
    or ``"ellipsoid"``) and ``covariance``: the 9x9 ``σ² (JᵀJ)⁻¹`` of ``COVARIANCE_PARAMETERS``.
    """
    known_field = check_field_strength(field_strength)
    if not isinstance(bias_correction, (bool, np.bool_)):
        raise OptionError(f"bias_correction must be True or False, got {bias_correction!r}")
    if isinstance(max_iterations, bool) or not isinstance(max_iterations, (int, np.integer)) or max_iterations < 1:
        raise OptionError(f"max_iterations must be a positive integer, got {max_iterations!r}")
    samples = data.require_samples("ml")
    statistics = data.statistics
    scale = statistics.scale
    zt = (samples.T - statistics.centre[:, None]) / scale  # normalised frame, (3, N)
    start, centre_z, shape_z, variance = _start(statistics)
    if variance is None:  # algebraic start: σ² from the distances to it
        plain = _Model(zt, 0.0)
        variance = 2.0 * plain.evaluate(plain.pack(centre_z, np.linalg.cholesky(shape_z))).cost / zt.shape[1]
    model = _Model(zt, variance if bias_correction else 0.0)
    params = model.pack(centre_z, np.linalg.cholesky(shape_z))
    current = model.evaluate(params)
    if not np.isfinite(current.cost):
        raise CalibrationError(
            "the ml fit cannot measure the distances of the samples to the starting ellipsoid (non-finite); "
            f"use {option('method', 'als')}"
        )
    try:
        solution = levenberg_marquardt(
            model.evaluate, params, n_residuals=zt.shape[1], max_iterations=int(max_iterations), current=current
        )
        polish = None
        if solution.status > 0 and model.variance > 0:
            polished = _solve_estimating_equation(model, solution, int(max_iterations))
            # Where the polish finds no root (it crawled along a direction the samples hardly inform: level flight
            # with a drifting field), Levenberg-Marquardt's minimum of the corrected residuals stands.
            solution, polish = (polished, None) if polished.status > 0 else (solution, polished.message)
    except np.linalg.LinAlgError as error:  # JᵀJ singular at the optimum: the samples do not fix all 9 parameters
        raise CalibrationError(
            f"the ml fit cannot determine the ellipsoid from these samples ({error}); they cover too few "
            f"directions: rotate the sensor through more attitudes, or use {option('method', 'auto')}"
        ) from None
    if not np.all(np.isfinite(solution.params)):
        raise CalibrationError(
            f"the ml fit did not converge ({solution.message}, after {solution.iterations} iterations); "
            f"raise max_iterations, or use {option('method', 'als')} (no iterations)"
        )
    centre_z, lower = model.unpack(solution.params)
    shape_z = lower @ lower.T
    if not np.linalg.eigvalsh(shape_z)[0] > 0:
        raise CalibrationError(
            f"the ml fit ended on a quadric that is not positive-definite; use {option('method', 'als')}"
        )
    residual_variance = 2.0 * solution.evaluation.cost / max(zt.shape[1] - model.size, 1)
    details: dict[str, Any] = {
        "status": solution.status,
        "message": solution.message,
        "cost": solution.evaluation.cost * scale**2,
        "start": start,
        "bias_correction": bool(bias_correction),
        "noise_std": math.sqrt(residual_variance) * scale,
        "covariance_parameters": list(COVARIANCE_PARAMETERS),
        "covariance": _covariance(model, solution, residual_variance, scale),
    }
    if polish is not None:
        details["polish"] = f"the bias-corrected estimating equation was not solved further ({polish})"
    problem = None
    if solution.status <= 0:  # judged by the verdict, which refuses it (or returns it forced, marked)
        problem = (
            f"the ml fit did not converge ({solution.message}, after {solution.iterations} iterations): it crawled "
            "along a combination the samples hardly determine; record more attitudes, raise max_iterations, or use "
            f"{option('method', 'auto')}"
        )
    fitted = calibration_from_ellipsoid(
        "ml",
        statistics.centre + scale * centre_z,
        shape_z / scale**2,
        root=root,
        n_samples=statistics.n,
        details=details,
        field_strength=known_field,
    )
    status = SolverStatus(converged=solution.status > 0, iterations=solution.iterations, problem=problem)
    return replace(fitted, solver=status)


def _covariance(model: _Model, solution: Solution, variance: float, scale: float) -> list[list[float]]:
    """``σ² (JᵀJ)⁻¹`` mapped to (offset, A entries) in input units, as a nested list (9x9)."""
    parameter_covariance = variance * np.linalg.pinv(solution.evaluation.normal)
    _, lower = model.unpack(solution.params)
    mapping = np.zeros((9, model.size))
    mapping[:3, :3] = scale * np.eye(3)  # V = centre + scale V_z
    mapping[3:, 3:] = model.shape_jacobian(lower) / scale**2  # A = A_z / scale²
    covariance = mapping @ parameter_covariance @ mapping.T
    return [[float(value) for value in row] for row in covariance]
