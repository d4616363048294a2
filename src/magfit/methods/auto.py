"""Automatic model choice: sphere, axis-aligned or full ellipsoid, robust when outliers are present.

The three models are nested (sphere ⊂ diag ⊂ full: 4, 6 and 9 parameters besides the rotation the
data cannot see). ``auto`` fits each, scores them by the Bayesian information criterion on the
geometric residual ``r = |L (x − V)| − 1`` (the sphere distance of ``magfit.sphere_distances``)

    BIC = n ln(RSS / n) + k ln n              (Schwarz, Ann. Statist. 6, 1978; Gaussian residuals)

and keeps the lowest. Why BIC rather than cross-validation or the parameter uncertainty: it needs no
refit (a residual pass per candidate, so it scales to 10⁷ samples), it is consistent for nested models
(the true model is chosen with probability → 1 as n grows, where AIC and cross-validation keep a fixed
chance of over-fitting), and the penalty ``k ln n`` asks a richer model to explain more than the noise.

The BIC only judges how well each model fits the samples it saw. When the samples do not determine
part of a model (a vehicle that only yaws, or tilts ±20°: the vertical offset and scale trade off
against each other), a richer model can fit the band of samples as well as any other and return noise
along that direction. So the chosen model is then checked for observability (see
:mod:`magfit.diagnostics.uncertainty`): if a combination of its parameters has a one-sigma above 5 % of
the field, ``auto`` falls back to the next simpler model that is determined, and names the direction.
If the sphere is not determined either, it raises :class:`~magfit.CalibrationError` with the reason.

Outliers: a robust fit (:mod:`magfit.methods.robust`) of the full model screens the samples first; when
more than 0.2 % of them (and at least 5) lie beyond 6 robust standard deviations, every candidate is
fitted robustly and the criterion is computed on the common inliers.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..calibration import Calibration
from ..errors import CalibrationError, MagfitError
from ..statistics import Statistics
from .registry import FitInput, check_choice, register
from .robust import encode_indices, fit_model, fit_robust, geometric_residuals, resolve_model, robust_scale

__all__ = ["CANDIDATES", "fit_auto"]

#: Candidate models, simplest first.
CANDIDATES = ("sphere", "diag", "full")
N_PARAMETERS = {"sphere": 4, "diag": 6, "full": 9}
OUTLIER_MODES = ("detect", "reject", "keep")
#: A sample beyond this many robust standard deviations counts as an outlier when screening.
_SCREEN_SIGMAS = 6.0


@register(
    "auto",
    min_samples=12,
    data="samples",
    summary="chooses sphere, diag or full ellipsoid by BIC, robust when outliers are found, "
    "falls back when the data cannot determine a model",
)
def fit_auto(data: FitInput, *, outliers: str = "detect") -> Calibration:
    """Fit the simplest model the samples support, robustly when they hold outliers.

    Parameters
    ----------
    outliers : {"detect", "reject", "keep"}
        ``"detect"``: screen for outliers and fit robustly when they are found; ``"reject"``: always fit
        robustly; ``"keep"``: never.

    Returns
    -------
    Calibration
        ``method="auto"``; ``details``: ``chosen`` (e.g. ``"full"`` or ``"robust diag"``),
        ``chosen_model``, ``method_used`` (the registered method behind it), ``reason`` (one sentence),
        ``criterion`` (name, value per candidate, RSS and parameter count), ``weak`` (descriptions of the
        weakly determined directions of the chosen model), ``failed`` (candidates that could not be
        fitted, with the reason) and, when fitted robustly, ``n_rejected`` and ``rejected``.
    """
    check_choice("outliers", outliers, OUTLIER_MODES)
    samples = data.require_samples("auto")
    n = samples.shape[0]
    robust, inliers, screen_note = _screen(samples, outliers)
    failed: dict[str, str] = {}
    fits: dict[str, Calibration] = {}
    for model in CANDIDATES:
        try:
            fits[model] = _fit_candidate(model, samples, robust)
        except MagfitError as error:
            failed[model] = str(error)
    if not fits:
        raise CalibrationError(
            "no model could be fitted to these samples"
            + _flatness(samples)
            + ": "
            + "; ".join(f"{model}: {reason}" for model, reason in failed.items())
        )
    if robust:  # the common inliers: kept by every robust candidate
        for calibration in fits.values():
            inliers &= _kept(calibration, n)
    kept = samples[inliers]
    rss = {model: float(np.sum(geometric_residuals(cal, kept) ** 2)) for model, cal in fits.items()}
    m = kept.shape[0]
    bic = {
        model: m * math.log(max(value, 1e-300) / m) + N_PARAMETERS[model] * math.log(m) for model, value in rss.items()
    }
    ranked = sorted(bic, key=bic.__getitem__)
    best = ranked[0]
    chosen, weak, fallback_reasons = _observable_choice(best, fits, kept)
    calibration = fits[chosen]
    prefix = "robust " if robust else ""
    reason = _reason(best, chosen, bic, weak, fallback_reasons, failed, screen_note)
    details: dict[str, Any] = {
        "chosen": prefix + chosen,
        "chosen_model": chosen,
        "method_used": ("robust/" if robust else "") + resolve_model(chosen)[0],
        "reason": reason,
        "criterion": {
            "name": "BIC",
            "values": {model: bic.get(model) for model in CANDIDATES},
            "rss": {model: rss.get(model) for model in CANDIDATES},
            "parameters": dict(N_PARAMETERS),
            "n": m,
        },
        "weak": [w for w in weak],
        "failed": failed,
        "outliers": outliers,
        "robust": robust,
    }
    if robust:
        rejected = np.flatnonzero(~inliers)
        details["n_rejected"] = int(rejected.size)
        details["rejected"] = encode_indices(rejected)
    return Calibration(
        method="auto",
        offset=calibration.offset,
        matrix=calibration.matrix,
        field_strength=calibration.field_strength,
        n_samples=n,
        details=details,
    )


def _screen(samples: NDArray[np.float64], mode: str) -> tuple[bool, NDArray[np.bool_], str]:
    """Whether to fit robustly, the screening fit's inliers, and a sentence on what was found."""
    everything = np.ones(samples.shape[0], dtype=bool)
    if mode == "keep":
        return False, everything, ""
    try:
        screen = fit_robust(FitInput(Statistics.from_samples(samples), samples), model="full")
    except MagfitError:
        try:
            screen = fit_robust(FitInput(Statistics.from_samples(samples), samples), model="sphere")
        except MagfitError:
            return mode == "reject", everything, ""
    residuals = geometric_residuals(screen, samples)
    centre, sigma = robust_scale(residuals)
    far = int(np.sum(np.abs(residuals - centre) > _SCREEN_SIGMAS * max(sigma, 1e-12)))
    found = far >= max(5, math.ceil(2e-3 * samples.shape[0]))
    if mode == "reject" or found:
        note = (
            f"{far} samples lie beyond {_SCREEN_SIGMAS:.0f} robust standard deviations of the fitted ellipsoid "
            "(spikes, saturation or a magnet): every model was fitted robustly"
            if found
            else "robust fitting was requested"
        )
        return True, _kept(screen, samples.shape[0]), note
    return False, everything, ""


def _kept(calibration: Calibration, n: int) -> NDArray[np.bool_]:
    mask = np.ones(n, dtype=bool)
    for start, stop in calibration.details.get("rejected", {}).get("runs", []):
        mask[start:stop] = False
    return mask


def _fit_candidate(model: str, samples: NDArray[np.float64], robust: bool) -> Calibration:
    if robust:
        return fit_robust(FitInput(Statistics.from_samples(samples), samples), model=model)
    return fit_model(model, samples)


def _observable_choice(
    best: str, fits: dict[str, Calibration], kept: NDArray[np.float64]
) -> tuple[str, list[str], list[str]]:
    """The best-scoring model, or the next simpler one whose parameters the samples determine.

    Returns the chosen model, the descriptions of its weak directions and, for every model passed
    over, why.
    """
    from ..diagnostics import Frame, even_subsample, thin
    from ..diagnostics._geometry import symmetric_unit_map
    from ..diagnostics.coverage import coverage
    from ..diagnostics.uncertainty import analyse

    passed_over: list[str] = []
    order = [model for model in CANDIDATES[: CANDIDATES.index(best) + 1][::-1] if model in fits]
    for model in order:
        calibration = fits[model]
        candidates = thin(kept.shape[0])
        z_candidates = Frame.corrected(calibration).normalise(kept[candidates])
        chosen, weights = even_subsample(z_candidates, total=kept.shape[0])
        z = z_candidates[chosen]
        observability, _ = analyse(z, weights, model, symmetric_unit_map(calibration), 60.0)
        undetermined = [w.description for w in observability.weak if not w.determined]
        # A band of directions around an axis (both ends unseen) fixes neither the offset nor the scale
        # along it, even where the linearisation at a drifted solution says otherwise.
        undetermined += [
            f"the offset and scale along {axis} (no samples with the field near +{axis} or −{axis}: the sensor "
            f"only turned about {axis})"
            for axis in coverage(z).unseen_axes
        ]
        if not undetermined:
            return model, [w.description for w in observability.weak], passed_over
        turn = f" (the sensor only turned about {observability.turn_axis})" if observability.turn_axis else ""
        passed_over.append(
            f"the {model} model was passed over: the samples do not determine {'; '.join(undetermined)}{turn}"
        )
    raise CalibrationError(
        "the samples determine no calibration model: "
        + "; ".join(passed_over)
        + "; record again turning the sensor through more attitudes (a full tumble is best)"
    )


def _flatness(samples: NDArray[np.float64]) -> str:
    """Words for the direction the samples hardly extend along, when they lie near a plane."""
    from ..diagnostics._geometry import axis_words

    spreads, directions = np.linalg.eigh(np.cov(samples.T))
    ratio = math.sqrt(max(spreads[0], 0.0) / spreads[2])
    if ratio > 0.25:
        return ""
    axis = axis_words(directions[:, 0] * np.sign(directions[np.argmax(np.abs(directions[:, 0])), 0]))
    return (
        f" (they lie close to a plane: their spread along {axis} is {100 * ratio:.0f} % of the largest, so the "
        f"sensor turned mostly about {axis} and the offset and scale along {axis} are not determined)"
    )


def _reason(
    best: str,
    chosen: str,
    bic: dict[str, float],
    weak: list[str],
    passed_over: list[str],
    failed: dict[str, str],
    screen_note: str,
) -> str:
    scores = ", ".join(f"{model} {value:.1f}" for model, value in sorted(bic.items(), key=lambda item: item[1]))
    parts = [f"lowest BIC: {best} (BIC {scores})"]
    if chosen != best:
        parts.append("; ".join(passed_over) + f"; fell back to the {chosen} model")
    if weak:
        parts.append(f"weakly determined in the {chosen} model: " + "; ".join(weak))
    if failed:
        parts.append("could not fit: " + ", ".join(sorted(failed)))
    if screen_note:
        parts.append(screen_note)
    return "; ".join(parts)
