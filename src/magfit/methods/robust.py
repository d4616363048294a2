"""Outlier-robust calibration: an M-estimator with a redescending loss on the geometric residual.

Spikes, saturated readings and a magnet passing by put samples far from the ellipsoid. A least-squares
fit (algebraic or geometric) gives each of them a weight that grows with its distance, so 2 % of spikes
can move the offset by more than the noise. ``robust`` fits any inner model (``model=``: sphere, diag or
the full ellipsoid) by iteratively reweighted least squares with Talwar's hard-redescending loss

    ρ(r) = r²  for |r| <= c σ,   c² σ²  otherwise        (weights 1 or 0)

on the geometric residual ``r = |L (x − V)| − 1`` (the sphere distance of ``magfit.sphere_distances``),
with the scale σ re-estimated at every iteration from the median absolute deviation
(σ = 1.4826 MAD, consistent for Gaussian noise). Weights of 0 or 1 mean every iteration is an ordinary
fit of the inner model on the current inliers, so the inner model keeps its own estimator (and its
statistics path). The iteration starts from a least-trimmed-squares fit (concentration steps on the 75 %
best-fitting samples), so that far spikes cannot steer the first fit.

Reference: Huber & Ronchetti, *Robust Statistics* (2nd ed., 2009), section 7.8 (IRLS) and 4.8
(redescending M-estimators); Talwar's loss is their "skipped" least squares.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..calibration import Calibration
from ..errors import CalibrationError, OptionError
from ..evaluate import unchecked_sphere_distances
from ..facts import Rejected, SolverStatus
from ..geometry.frame import N_PARAMETERS, Frame, distance_jacobian
from ..geometry.quadric import check_field_strength, pin_field_strength
from ..outliers import DEFAULT_THRESHOLD, inlier_mask, robust_scale
from ..statistics import Statistics
from .core import estimate, first_order_stand_in
from .registry import METHODS, FitInput, Judging, register

__all__ = [
    "DEFAULT_THRESHOLD", "MODELS", "fit_model", "fit_robust", "inlier_mask", "rejected_indices", "rejected_runs",
    "resolve_model", "robust_scale",
]  # fmt: skip

#: Inner models ``robust`` and ``auto`` accept; ``"full"`` is the best full-ellipsoid estimator registered.
MODELS = ("full", "sphere", "diag", "ellipsoid", "als", "ml")
#: At most this many runs of rejected samples are stored in ``details`` (see :func:`encode_indices`).
MAX_STORED_RUNS = 10_000


def resolve_model(model: str) -> tuple[str, Callable[..., Calibration]]:
    """The method that fits ``model`` and the function fitting it on (n, 3) samples.

    The function is ``run(samples, statistics=None)``: ``statistics``, when given, are those of exactly
    these samples (computed when not). ``"full"`` is the consistent ``"als"`` when it is registered, else
    the paper's ``"ellipsoid"``; ``"diag"`` is the registered ``"diag"`` method.
    """
    if model not in MODELS:
        raise OptionError(f"model={model!r} is not valid; choose one of: {', '.join(MODELS)}")
    name = model
    if model == "full":
        name = "als" if "als" in METHODS else "ellipsoid"
    if name not in METHODS:
        raise OptionError(f"model={model!r} needs the method {name!r}, which this magfit does not have")

    def run(samples: NDArray[np.float64], statistics: Statistics | None = None) -> Calibration:
        statistics = Statistics.from_samples(samples) if statistics is None else statistics
        return estimate(FitInput(statistics, samples), name)  # the refusals every caller of the method gets

    return name, run


def fit_model(model: str, samples: NDArray[np.float64], statistics: Statistics | None = None) -> Calibration:
    """Fit ``model`` (a name in :data:`MODELS`) to (n, 3) samples, without diagnostics.

    ``statistics``: those of exactly these samples, when the caller has them (one pass over a long log
    saved per model).
    """
    return resolve_model(model)[1](samples, statistics)


def _band(samples: NDArray[np.float64]) -> NDArray[np.bool_]:
    """Samples whose distance to the coordinate-wise median lies within the bulk of the distances.

    The median ignores up to half of the samples, so spikes cannot drag the centre; the band (median
    ± 4 σ_MAD of the distances, at least ± 60 % of the median for eccentric ellipsoids) keeps the far
    spikes out of a first least-squares fit.
    """
    distances = np.linalg.norm(samples - np.median(samples, axis=0), axis=1)
    centre, sigma = robust_scale(distances)
    return np.asarray(np.abs(distances - centre) <= max(4.0 * sigma, 0.6 * centre))


def _median_start(
    run: Callable[[NDArray[np.float64]], Calibration], samples: NDArray[np.float64]
) -> NDArray[np.bool_] | None:
    """The subset (as a mask) of the random-subset fit with the least median |r| over the samples."""
    n = samples.shape[0]
    size = min(60, n)
    rng = np.random.default_rng(0)
    scoring = samples[:: max(1, n // 20_000)]
    best: tuple[float, NDArray[np.int64]] | None = None
    for _ in range(20):
        subset = rng.choice(n, size, replace=False)
        try:
            calibration = run(samples[subset])
        except CalibrationError:
            continue
        median = float(np.median(np.abs(unchecked_sphere_distances(calibration, scoring))))
        if best is None or median < best[0]:
            best = (median, subset)
    if best is None:
        return None
    mask = np.zeros(n, dtype=bool)
    mask[best[1]] = True
    return mask


def _start(
    run: Callable[[NDArray[np.float64]], Calibration], samples: NDArray[np.float64], name: str
) -> tuple[Calibration, NDArray[np.bool_]]:
    """A starting fit by least trimmed squares: concentration steps from a few starts.

    Starts: the fit on all samples, the fit on the distance band (:func:`_band`) and the best of 20 fits
    on random subsets of 60 samples by the least median of squares (Rousseeuw, JASA 79, 1984; the random
    draws are seeded, so the result is repeatable). From each, three
    concentration steps of FAST-LTS (Rousseeuw & Van Driessen, Data Min. Knowl. Disc. 12, 2006): refit
    on the 75 % of samples with the smallest |r|, which never increases the trimmed sum of squares. The
    start with the smallest trimmed sum wins.
    """
    n = samples.shape[0]
    keep = int(0.75 * n)
    best: tuple[float, Calibration, NDArray[np.bool_]] | None = None
    errors = []
    for mask in (np.ones(n, dtype=bool), _band(samples), _median_start(run, samples)):
        if mask is None:
            continue
        try:
            calibration = run(samples[mask])
            for _ in range(3):
                residuals = np.abs(unchecked_sphere_distances(calibration, samples))
                mask = np.zeros(n, dtype=bool)
                mask[np.argpartition(residuals, keep - 1)[:keep]] = True
                calibration = run(samples[mask])
        except CalibrationError as error:
            errors.append(str(error))
            continue
        trimmed = float(np.sum(np.sort(np.abs(unchecked_sphere_distances(calibration, samples)))[:keep] ** 2))
        if best is None or trimmed < best[0]:
            best = (trimmed, calibration, mask)
    if best is None:
        raise CalibrationError(f"robust fit of {name!r} found no starting fit: {errors[-1]}")
    return best[1], best[2]


@register(
    "robust",
    min_samples=12,
    data="samples",
    summary="outlier-robust fit: redescending M-estimator (IRLS, MAD scale) around sphere/diag/full models",
    judging=Judging(stand_in=first_order_stand_in),  # iterative: 10 refits would take seconds on a long log
)
def fit_robust(
    data: FitInput,
    *,
    model: str = "full",
    threshold: float = DEFAULT_THRESHOLD,
    max_iterations: int = 30,
    field_strength: float | None = None,
) -> Calibration:
    """Fit ``model`` while rejecting samples far from the fitted ellipsoid (spikes, saturation, a magnet).

    Parameters
    ----------
    model : {"full", "sphere", "diag", "ellipsoid", "als", "ml"}
        The inner model; ``"full"`` is ``"als"`` when registered, else ``"ellipsoid"``.
    threshold : float
        Cut-off c of the loss in units of the robust scale σ (> 2): samples with
        ``|r − median(r)| > c σ`` get weight 0.
    max_iterations : int
        Upper bound on reweighting steps; the loop stops as soon as the inlier set repeats.
    field_strength : float, optional
        Known magnitude of the local field, input units: the final fit's matrix is scaled so that corrected
        samples have this magnitude (see ``pin_field_strength``).

    Returns
    -------
    Calibration
        The inner model fitted on the inliers; ``rejected`` (:class:`~magfit.facts.Rejected`: the count, the
        run-length encoded indices, see :func:`rejected_indices`, the threshold), ``solver`` (iterations,
        converged), ``model`` the inner model's family. ``details``: ``model`` (the inner method used),
        ``residual_sigma`` (σ, fraction of the field strength) and ``inner`` (the inner fit's own details).
    """
    samples = data.require_samples("robust")
    known_field = check_field_strength(field_strength)
    if not threshold > 2.0:
        raise OptionError(f"threshold={threshold!r} is not valid: it must exceed 2 (units of the robust σ)")
    if max_iterations < 1:
        raise OptionError(f"max_iterations={max_iterations!r} is not valid: it must be at least 1")
    name, run = resolve_model(model)
    n = samples.shape[0]
    calibration, inliers = _start(run, samples, name)
    converged = False
    iterations = 0
    sigma = 0.0
    parameters = N_PARAMETERS.get(str(calibration.model), N_PARAMETERS["full"])
    for iterations in range(1, max_iterations + 1):  # noqa: B007  (the count is reported)
        residuals = unchecked_sphere_distances(calibration, samples)
        centre, sigma = robust_scale(residuals)
        kept = int(np.count_nonzero(inliers))
        if kept - parameters < MIN_RESIDUAL_DOF:  # too few residuals beyond the model's own to tell an outlier
            inliers = np.ones(n, dtype=bool)
            calibration = _fit_subset(run, samples, inliers, name)
            converged = True
            break
        # Residuals of a fit of k parameters to m samples scatter by sqrt((m - k) / m) of the noise (the fit
        # absorbs k of their degrees of freedom): the threshold is on the noise, not on that shrunken scatter.
        sigma *= float(np.sqrt(kept / (kept - parameters)))
        new_inliers = np.abs(residuals - centre) <= threshold * max(sigma, 1e-12)
        new_inliers |= _within_prediction(
            calibration, samples, inliers, ~new_inliers, residuals - centre, threshold * sigma
        )
        if np.array_equal(new_inliers, inliers):
            converged = True
            break
        inliers = new_inliers
        calibration = _fit_subset(run, samples, inliers, name)
    rejected = np.flatnonzero(~inliers)
    details: dict[str, Any] = {"model": name, "residual_sigma": sigma, "inner": dict(calibration.details)}
    robust_fit = Calibration(
        method="robust",
        offset=calibration.offset,
        matrix=calibration.matrix,
        field_strength=calibration.field_strength,
        n_samples=n,
        details=details,
        model=calibration.model,
        rejected=rejected_runs(rejected, threshold),
        solver=SolverStatus(converged=converged, iterations=iterations),
    )
    return pin_field_strength(robust_fit, known_field)


#: The leverage of the rejection (:func:`_within_prediction`) is read from at most this many of the inliers.
LEVERAGE_ROWS = 20_000


def _within_prediction(
    calibration: Calibration,
    samples: NDArray[np.float64],
    inliers: NDArray[np.bool_],
    candidates: NDArray[np.bool_],
    deviations: NDArray[np.float64],
    cut: float,
) -> NDArray[np.bool_]:
    """The ``candidates`` (samples beyond ``cut`` = c σ) whose deviation is within c times its prediction error.

    A sample the fit of the ``inliers`` did not use is off that fit by its noise and by the fit's own error
    where it lies: with J the Jacobian of the distances at the fit (its corrected frame, where its parameters
    are v = 0, L = I) and H = Σ_inliers Jᵢᵀ Jᵢ, the deviation of sample i has variance ``σ² (1 + hᵢ)``,
    ``hᵢ = Jᵢ H⁻¹ Jᵢᵀ`` its leverage (the externally studentised residual: Cook & Weisberg, *Residuals and
    Influence in Regression*, 1982, section 2.2). Where the samples kept do not determine the model (a full
    ellipsoid on 30 samples of level flight) the fit extrapolates wildly to the samples left out, and their
    large distances are the fit's error, not theirs: rejected on ``|r| > c σ`` alone, 4 of 30 such samples left
    a fit 10° off in heading whose diagnostics, reading only the 26 kept, said ±1.9°. A sample is rejected
    only when ``|r| > c σ √(1 + hᵢ)``. On a recording that determines the model hᵢ ≈ k / n: nothing changes.
    """
    result = np.zeros(samples.shape[0], dtype=bool)
    if not candidates.any():
        return result
    kind = str(calibration.model) if calibration.model in N_PARAMETERS else "full"
    frame = Frame.corrected(calibration)
    p = np.zeros(N_PARAMETERS[kind])
    p[3 : 4 if kind == "sphere" else 6] = 1.0  # v = 0, L = I
    kept = np.flatnonzero(inliers)
    step = max(1, kept.size // LEVERAGE_ROWS)
    with np.errstate(all="ignore"):
        jac = distance_jacobian(p, frame.normalise(samples[kept[::step]]), kind)
        information = jac.T @ jac * (kept.size / max(jac.shape[0], 1))  # H, scaled from the stride to every inlier
        outside = np.flatnonzero(candidates)
        rows = distance_jacobian(p, frame.normalise(samples[outside]), kind)
        solved = np.linalg.lstsq(information, rows.T, rcond=1e-12)[0]
        leverage = np.einsum("ij,ji->i", rows, solved)
    leverage = np.where(np.isfinite(leverage), np.maximum(leverage, 0.0), np.inf)
    result[outside] = np.abs(deviations[outside]) <= max(cut, 1e-12) * np.sqrt(1.0 + leverage)
    return result


#: Fewest residual degrees of freedom (inliers beyond the model's parameters) with which samples are rejected:
#: below, the robust scale of the residuals is itself too uncertain (a MAD of 10 residuals is off by ±40 %) and
#: a fit that has absorbed most of the noise makes good samples look like outliers; every sample is kept.
MIN_RESIDUAL_DOF = 10


def _fit_subset(
    run: Callable[[NDArray[np.float64]], Calibration], samples: NDArray[np.float64], mask: NDArray[np.bool_], name: str
) -> Calibration:
    subset = samples[mask]
    try:
        return run(subset)
    except CalibrationError as error:
        raise CalibrationError(
            f"robust fit of {name!r} failed on the {subset.shape[0]} samples kept as inliers "
            f"({samples.shape[0] - subset.shape[0]} rejected): {error}"
        ) from None


def encode_indices(indices: NDArray[np.integer[Any]]) -> dict[str, Any]:
    """Run-length encode sorted sample indices: ``{"runs": [[start, stop], ...], "truncated": bool}``.

    A run ``[start, stop]`` stands for ``range(start, stop)`` (stop exclusive), so a passing magnet that
    spoils 5 000 consecutive samples costs one pair. At most :data:`MAX_STORED_RUNS` runs are kept (the
    first ones); ``truncated`` says when more existed (``n_rejected`` always counts them all).
    """
    indices = np.asarray(indices, dtype=np.int64)
    if indices.size == 0:
        return {"encoding": "runs", "runs": [], "truncated": False}
    breaks = np.flatnonzero(np.diff(indices) != 1) + 1
    starts = indices[np.concatenate([[0], breaks])]
    stops = indices[np.concatenate([breaks - 1, [indices.size - 1]])] + 1
    runs = np.column_stack([starts, stops])
    return {
        "encoding": "runs",
        "runs": runs[:MAX_STORED_RUNS].tolist(),
        "truncated": bool(runs.shape[0] > MAX_STORED_RUNS),
    }


def rejected_runs(indices: NDArray[np.integer[Any]], threshold: float | None = None) -> Rejected:
    """The typed record of rejected sample indices (sorted): the count and the runs (:func:`encode_indices`)."""
    encoded = encode_indices(indices)
    return Rejected(
        count=int(np.asarray(indices).size),
        runs=tuple((int(start), int(stop)) for start, stop in encoded["runs"]),
        truncated=bool(encoded["truncated"]),
        threshold=None if threshold is None else float(threshold),
    )


def rejected_indices(calibration: Calibration) -> NDArray[np.int64]:
    """The indices of the samples a robust fit rejected, sorted, shape (n_rejected,).

    Reads ``Calibration.rejected`` of a ``robust`` (or ``auto`` with a robust choice) calibration;
    raises :class:`~magfit.errors.MagfitError` when the list was truncated or the calibration has none.
    """
    from ..errors import MagfitError

    stored = calibration.rejected
    if stored is None:
        raise MagfitError(f"a {calibration.method!r} calibration records no rejected samples")
    if stored.truncated:
        raise MagfitError(
            f"the list of rejected samples was truncated to its first {MAX_STORED_RUNS} runs "
            f"({stored.count} samples were rejected); refit with fewer outliers"
        )
    if not stored.runs:
        return np.zeros(0, dtype=np.int64)
    return np.concatenate([np.arange(start, stop, dtype=np.int64) for start, stop in stored.runs])
