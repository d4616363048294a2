"""The two iterative solvers of magfit: Levenberg–Marquardt on the normal equations, and a bracketed root.

Levenberg–Marquardt serves the ``ml`` fit (orthogonal distances, millions of samples) and the
maximum-likelihood reference fits of ``auto`` and of the diagnostics (first-order distances, a bounded
subsample); the root finder serves the ``als`` noise variance.

Why not :func:`scipy.optimize.least_squares`: its methods factor the (N, k) Jacobian itself at every
iteration (a QR in MINPACK's ``lm``, an SVD or a dense least squares in the others): 0.8 s for a million
samples and 9 parameters on the 2-core machine this was measured on, against 0.01 s for ``JᵀJ`` (k x k),
and the Jacobian must then be held in memory whole. With at most 9 parameters in a normalised frame
``JᵀJ`` is well conditioned, so the normal equations lose no accuracy that matters, and they accumulate
chunk by chunk. Importing ``scipy.optimize`` also costs 0.4-0.6 s of CPU, a fifth of a ``magfit
calibrate`` run on 10 million rows and a third of ``auto`` on a million samples: that is why the
one-dimensional root of ``als`` is found here too, rather than by :func:`scipy.optimize.brentq`.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

__all__ = ["Evaluation", "Solution", "bracketed_root", "levenberg_marquardt"]


@dataclass
class Evaluation:
    """The residuals at one parameter vector, reduced to what Levenberg–Marquardt needs."""

    cost: float  # ½ Σ r²
    normal: NDArray[np.float64]  # JᵀJ, (k, k)
    gradient: NDArray[np.float64]  # Jᵀr, (k,)
    warm: Any = None  # what the next evaluation nearby may start from (the ml fit: foot-point roots)


@dataclass
class Solution:
    """Outcome of :func:`levenberg_marquardt`, with the status codes of MINPACK / scipy."""

    params: NDArray[np.float64]
    evaluation: Evaluation
    # 0: not converged (iteration limit, non-finite start); 1: gradient small; 2: cost converged; 3: step small
    status: int
    message: str
    iterations: int


def levenberg_marquardt(
    evaluate: Callable[[NDArray[np.float64], Any], Evaluation],
    params: NDArray[np.float64],
    *,
    n_residuals: int,
    max_iterations: int,
    current: Evaluation | None = None,
    cost_tolerance: float = 1e-12,
    solve: Callable[[NDArray[np.float64], NDArray[np.float64]], NDArray[np.float64]] | None = None,
    skip_small_steps: float = 0.0,
) -> Solution:
    """Minimise ``½ Σ r²`` from ``params``, with Marquardt's diagonal scaling of the damping (the running
    maximum of diag(JᵀJ), as MINPACK scales).

    ``evaluate(params, warm)`` returns the :class:`Evaluation` at ``params``; ``warm`` is the ``warm`` of
    the evaluation the step starts from (None at first). ``current`` is the evaluation at ``params`` when
    the caller has it already. ``solve(matrix, rhs)`` solves the damped normal equations (a caller whose
    normal matrix has a structure may solve them faster; it raises ``LinAlgError`` when singular).

    The damping follows the gain ratio (actual over predicted cost reduction) as Nielsen's rule does
    (H. B. Nielsen, *Damping parameter in Marquardt's method*, IMM-REP-1999-05; Madsen, Nielsen &
    Tingleff, *Methods for non-linear least squares problems*, 2004, section 3.2): it falls by up to 3x
    after a step the linear model predicted well and grows geometrically after failed ones, so that fewer
    trial steps are wasted than with the classic divide-or-multiply-by-ten rule.

    Stops when the gradient vanishes, when a step lowers the cost by less than ``cost_tolerance`` of
    itself, or when the step is shorter than 1e-3 standard errors of the fit in its own direction (a
    change no data could show). A non-finite starting cost returns at once with status 0.
    ``skip_small_steps``: a step shorter than this many standard errors (1e-3: the rule above) is not
    evaluated either (status 3 at the point it starts from): near the minimum, rounding makes such trials fail
    and grow the damping, an evaluation each.
    """
    size = params.size
    if current is None:
        current = evaluate(params, None)
    if not np.isfinite(current.cost):
        return Solution(params, current, 0, "the cost at the start is not finite", 0)
    damping, growth = 1e-3, 2.0
    scaling = np.zeros(size)
    for iteration in range(1, max_iterations + 1):
        diagonal = np.maximum(np.diag(current.normal), 1e-300)
        # Damping scaled by the largest diag(JᵀJ) seen so far (MINPACK's choice): a parameter whose column
        # shrinks on the way keeps its damping, instead of taking huge steps the next trial refuses.
        scaling = np.maximum(scaling, diagonal)
        residual_norm = math.sqrt(2.0 * current.cost) + 1e-300
        if float(np.max(np.abs(current.gradient) / np.sqrt(diagonal))) <= 1e-10 * residual_norm:
            return Solution(params, current, 1, "the gradient is zero to tolerance", iteration - 1)
        while True:
            try:
                damped = current.normal + damping * np.diag(scaling)
                step = np.linalg.solve(damped, -current.gradient) if solve is None else solve(damped, -current.gradient)
                length = math.sqrt(max(float(step @ current.normal @ step), 0.0))
                if skip_small_steps > 0 and length <= skip_small_steps * residual_norm / math.sqrt(
                        max(n_residuals - size, 1)):  # fmt: skip
                    return Solution(params, current, 3, f"the next step is below {skip_small_steps:g} standard errors",
                                    iteration - 1)  # fmt: skip
                trial = evaluate(params + step, current.warm)
                if np.isfinite(trial.cost) and trial.cost <= current.cost:
                    break
            except np.linalg.LinAlgError:  # singular at this damping: damp more
                pass
            damping *= growth
            growth *= 2.0
            if damping > 1e10:
                return Solution(params, current, 3, "no step lowers the cost: at a minimum", iteration)
        reduction = current.cost - trial.cost
        # The quadratic model's reduction, ½ δᵀ(μ D δ − Jᵀr), since (JᵀJ + μ D) δ = −Jᵀr.
        predicted = 0.5 * float(step @ (damping * scaling * step - current.gradient))
        gain = reduction / predicted if predicted > 0 else 0.0
        damping = max(damping * max(1.0 / 3.0, 1.0 - (2.0 * gain - 1.0) ** 3), 1e-12)
        growth = 2.0
        # The step's length in standard errors: sqrt(δᵀ JᵀJ δ) / σ, σ² = 2 cost / (n − k). That is the
        # Mahalanobis length in the parameters' covariance σ² (JᵀJ)⁻¹, so a slow crawl along a direction the
        # data barely determine counts in that direction's own (large) uncertainty.
        sigma = residual_norm / math.sqrt(max(n_residuals - size, 1))
        step_in_errors = math.sqrt(max(float(step @ current.normal @ step), 0.0)) / sigma
        params, current = params + step, trial
        if reduction <= cost_tolerance * current.cost:
            return Solution(params, current, 2, f"the cost changed by < {cost_tolerance:g} of itself", iteration)
        if step_in_errors <= 1e-3:
            return Solution(params, current, 3, "the step is below 1e-3 standard errors", iteration)
    return Solution(params, current, 0, "the iteration limit was reached", max_iterations)


def bracketed_root(
    function: Callable[[float], float],
    low: float,
    high: float,
    *,
    xtol: float = 1e-15,
    rtol: float = 1e-12,
    max_iterations: int = 200,
) -> float:
    """A root of a continuous ``function`` that changes sign between ``low`` and ``high``.

    The Illinois variant of regula falsi (Dowell & Jarratt, BIT 11, 1971): the secant through the two
    ends of the bracket, with the value kept at an end halved when that end survives twice, so that both
    ends close in (order about 1.44). A bisection step is taken whenever three steps have not halved the
    bracket, so a very flat function costs no more than bisection does. Stops when the bracket is shorter
    than ``xtol + rtol |x|`` (the tolerances of :func:`scipy.optimize.brentq`).
    """
    f_low, f_high = function(low), function(high)
    if f_low == 0.0:
        return float(low)
    if f_high == 0.0:
        return float(high)
    if np.sign(f_low) == np.sign(f_high):
        raise ValueError(f"no sign change between {low!r} (f = {f_low!r}) and {high!r} (f = {f_high!r})")
    kept = 0  # +1: the high end survived the last step, -1: the low end did
    reference_width, steps = abs(high - low), 0
    point = 0.5 * (low + high)
    for _ in range(max_iterations):
        if steps >= 3:  # three steps without halving the bracket: bisect
            point = 0.5 * (low + high)
        else:
            point = (low * f_high - high * f_low) / (f_high - f_low)
            if not min(low, high) < point < max(low, high):  # round-off at a tiny bracket
                point = 0.5 * (low + high)
        value = function(point)
        if value == 0.0:
            return float(point)
        if np.sign(value) == np.sign(f_high):
            high, f_high = point, value
            if kept == -1:
                f_low *= 0.5
            kept = -1
        else:
            low, f_low = point, value
            if kept == 1:
                f_high *= 0.5
            kept = 1
        width = abs(high - low)
        if width <= xtol + rtol * abs(point):
            return float(point)
        steps += 1
        if width <= 0.5 * reference_width:
            reference_width, steps = width, 0
    return float(point)
