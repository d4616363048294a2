"""Levenberg–Marquardt on the normal equations: the one nonlinear least-squares solver of magfit.

Used by the ``ml`` fit (orthogonal distances, millions of samples) and by the maximum-likelihood
reference fits of ``auto`` and of the diagnostics (first-order distances, a bounded subsample).

Why not :func:`scipy.optimize.least_squares`: both its methods factor the (N, k) Jacobian itself at every
iteration (QR in MINPACK, an SVD in ``trf``): 0.8 s for a million samples and 9 parameters on the 2-core
machine this was measured on, against 0.01 s for ``JᵀJ`` (k x k), and the Jacobian must then be held in
memory whole. With at most 9 parameters in a normalised frame ``JᵀJ`` is well conditioned, so the
normal equations lose no accuracy that matters, and they accumulate chunk by chunk. Importing
``scipy.optimize`` also costs 0.4 s of CPU, a fifth of a ``magfit calibrate`` run on 10 million rows.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

__all__ = ["Evaluation", "Solution", "levenberg_marquardt"]


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
    status: int  # 0: iteration limit; 1: gradient small; 2: cost converged; 3: step small
    message: str
    iterations: int


def levenberg_marquardt(
    evaluate: Callable[[NDArray[np.float64], Any], Evaluation],
    params: NDArray[np.float64],
    *,
    n_residuals: int,
    max_iterations: int,
    current: Evaluation | None = None,
) -> Solution:
    """Minimise ``½ Σ r²`` from ``params``, with Marquardt's diagonal scaling of the damping.

    ``evaluate(params, warm)`` returns the :class:`Evaluation` at ``params``; ``warm`` is the ``warm`` of
    the evaluation the step starts from (None at first). ``current`` is the evaluation at ``params`` when
    the caller has it already.

    Stops when the gradient vanishes, when the cost changes by less than 1e-12 of itself, or when the
    step is shorter than 1e-3 standard errors of the fit in its own direction (a change no data could
    show). A non-finite starting cost returns at once with status 0.
    """
    size = params.size
    if current is None:
        current = evaluate(params, None)
    if not np.isfinite(current.cost):
        return Solution(params, current, 0, "the cost at the start is not finite", 0)
    damping = 1e-3
    for iteration in range(1, max_iterations + 1):
        diagonal = np.maximum(np.diag(current.normal), 1e-300)
        residual_norm = math.sqrt(2.0 * current.cost) + 1e-300
        if float(np.max(np.abs(current.gradient) / np.sqrt(diagonal))) <= 1e-10 * residual_norm:
            return Solution(params, current, 1, "the gradient is zero to tolerance", iteration - 1)
        while True:
            try:
                step = np.linalg.solve(current.normal + damping * np.diag(diagonal), -current.gradient)
                trial = evaluate(params + step, current.warm)
                if np.isfinite(trial.cost) and trial.cost <= current.cost:
                    break
            except np.linalg.LinAlgError:  # singular at this damping: damp more
                pass
            damping *= 10.0
            if damping > 1e10:
                return Solution(params, current, 3, "no step lowers the cost: at a minimum", iteration)
        reduction = current.cost - trial.cost
        # The step's length in standard errors: sqrt(δᵀ JᵀJ δ) / σ, σ² = 2 cost / (n − k). That is the
        # Mahalanobis length in the parameters' covariance σ² (JᵀJ)⁻¹, so a slow crawl along a direction the
        # data barely determine counts in that direction's own (large) uncertainty.
        sigma = residual_norm / math.sqrt(max(n_residuals - size, 1))
        step_in_errors = math.sqrt(max(float(step @ current.normal @ step), 0.0)) / sigma
        params, current = params + step, trial
        damping = max(damping / 10.0, 1e-12)
        if reduction <= 1e-12 * current.cost:
            return Solution(params, current, 2, "the cost changed by < 1e-12 of itself", iteration)
        if step_in_errors <= 1e-3:
            return Solution(params, current, 3, "the step is below 1e-3 standard errors", iteration)
    return Solution(params, current, 0, "the iteration limit was reached", max_iterations)
