"""Automatic model choice: sphere, axis-aligned or full ellipsoid, robust when outliers are present.

The three models are nested (sphere ⊂ diag ⊂ full: 4, 6 and 9 parameters besides the rotation the
data cannot see). ``auto`` fits each, refines it to the maximum-likelihood fit of its model (Levenberg-
Marquardt on the first-order distances ``d`` of :mod:`magfit.diagnostics._geometry`, on a regular stride
of at most 20 000 samples), scores them by the Bayesian information criterion on RSS = Σ d²

    BIC = n ln(RSS / n) + k ln n              (Schwarz, Ann. Statist. 6, 1978; Gaussian residuals)

and keeps the lowest. Why BIC rather than cross-validation or the parameter uncertainty: it needs no
refit on held-out folds (one fit per candidate on a bounded stride, so it scales to 10⁷ samples), it is
consistent for nested models
(the true model is chosen with probability → 1 as n grows, where AIC and cross-validation keep a fixed
chance of over-fitting), and the penalty ``k ln n`` asks a richer model to explain more than the noise.

The BIC only judges how well each model fits the samples it saw. When the samples do not determine
part of a model (a vehicle that only yaws, or tilts ±20°: the vertical offset and scale trade off
against each other), a richer model can fit the band of samples as well as any other and return noise
along that direction. So the chosen model is then checked for observability (see
:mod:`magfit.diagnostics.uncertainty`): if a combination of its parameters has a one-sigma above 5 % of
the field, the model is kept (the BIC already found that the simpler models fit significantly worse, and
their misfit would cost more than this uncertainty) and the direction is named as not determined: a
vehicle tilting ±20° barely sees the vertical offset, which hardly matters for heading near level.
When the samples form a band around an axis (the sensor only turned about it),
the offset and scale along that axis are fixed by nothing: the model is passed over regardless, and if no
model is left, ``auto`` raises :class:`~magfit.CalibrationError` with the reason.

The calibration returned is the chosen model's maximum-likelihood fit (least squares on the distances
of the samples to the ellipsoid, Levenberg-Marquardt from the model's algebraic or ALS fit, on a stride of
at most 200 000 samples): under
restricted attitudes it is less biased than the algebraic fits (measured: 1.26° vs 1.37° for ALS and
6.8° for the algebraic ellipsoid on the benchmark's restricted case). For the full ellipsoid it is the
``ml`` method's fit (exact orthogonal distances, corrected for the σ²-bias of curved surfaces); for the
sphere and diag models, the first-order (Sampson) distances of the model choice.

Outliers: a robust fit (:mod:`magfit.methods.robust`) of the full model screens (a stride of at most
20 000 of) the samples first; when
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
from ..evaluate import unchecked_sphere_distances
from ..statistics import Statistics
from .quadric import check_field_strength, pin_field_strength
from .registry import METHODS, FitInput, check_choice, register
from .robust import encode_indices, fit_model, fit_robust, resolve_model, robust_scale

__all__ = ["CANDIDATES", "fit_auto", "fit_chosen"]

#: Candidate models, simplest first.
CANDIDATES = ("sphere", "diag", "full")
N_PARAMETERS = {"sphere": 4, "diag": 6, "full": 9}
OUTLIER_MODES = ("detect", "reject", "keep")
#: An optimum with a semi-axis shorter than this many RMS residual distances, along which the samples
#: spread less than FLAT_SPREAD times their widest spread and less than FLAT_NOISE_SPREAD residuals, is
#: flattened onto the samples. The last condition keeps a real, very eccentric ellipsoid seen through
#: heavy noise (the paper's steel case at 10 % noise: shortest semi-axis 7 residuals, spread along it 0.15
#: of the widest but 4.2 residuals), where samples in a plane spread about one residual across it.
FLAT_SEMI_AXIS = 10.0
FLAT_SPREAD = 0.25
FLAT_NOISE_SPREAD = 2.5
#: A sample beyond this many robust standard deviations counts as an outlier when screening.
_SCREEN_SIGMAS = 6.0


@register(
    "auto",
    min_samples=12,
    data="samples",
    summary="chooses sphere, diag or full ellipsoid by BIC, robust when outliers are found, "
    "falls back when the data cannot determine a model",
)
def fit_auto(data: FitInput, *, outliers: str = "detect", field_strength: float | None = None) -> Calibration:
    """Fit the simplest model the samples support, robustly when they hold outliers.

    Parameters
    ----------
    outliers : {"detect", "reject", "keep"}
        ``"detect"``: screen for outliers and fit robustly when they are found; ``"reject"``: always fit
        robustly; ``"keep"``: never.
    field_strength : float, optional
        Known magnitude of the local field (e.g. from the World Magnetic Model), input units: the chosen
        fit's matrix is scaled so that corrected samples have this magnitude (see ``pin_field_strength``).

    Returns
    -------
    Calibration
        ``method="auto"``; ``details``: ``chosen`` (e.g. ``"full"`` or ``"robust diag"``),
        ``chosen_model``, ``method_used`` (the registered method whose fit started the maximum-likelihood
        refinement that is returned), ``reason`` (one sentence),
        ``criterion`` (name, value per candidate, RSS and parameter count), ``weak`` (descriptions of the
        weakly determined directions of the chosen model), ``failed`` (candidates that could not be
        fitted, with the reason) and, when fitted robustly, ``n_rejected`` and ``rejected``.
    """
    check_choice("outliers", outliers, OUTLIER_MODES)
    known_field = check_field_strength(field_strength)
    samples = data.require_samples("auto")
    n = samples.shape[0]
    robust, inliers, screen_note = _screen(samples, outliers)
    failed: dict[str, str] = {}
    fits: dict[str, Calibration] = {}
    for model in CANDIDATES:
        try:
            fits[model] = _fit_candidate(model, samples, robust, data.statistics)
        except MagfitError as error:
            failed[model] = str(error)
    if not fits:
        raise _refusal("no model could be fitted to these samples", samples, failed)
    if robust:  # the common inliers: kept by every robust candidate
        for calibration in fits.values():
            inliers &= _kept(calibration, n)
    kept = samples if inliers.all() else samples[inliers]  # no copy of a long log without outliers
    rss, optima, degenerate = _optimal_rss(fits, kept)
    failed.update(degenerate)
    if not rss:
        raise _refusal("no model fits these samples", kept, failed)
    m = kept.shape[0]
    bic = {
        model: m * math.log(max(value, 1e-300) / m) + N_PARAMETERS[model] * math.log(m) for model, value in rss.items()
    }
    ranked = sorted(bic, key=bic.__getitem__)
    best = ranked[0]
    chosen, weak, fallback_reasons = _observable_choice(best, optima, kept)
    calibration = optima[chosen]
    if chosen == "full" or kept.shape[0] > 20_000:  # the optimum came from a stride of 20 000, or ml is due
        calibration = refine_chosen(chosen, calibration, kept)
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
    chosen_fit = Calibration(
        method="auto",
        offset=calibration.offset,
        matrix=calibration.matrix,
        field_strength=calibration.field_strength,
        n_samples=n,
        details=details,
    )
    return pin_field_strength(chosen_fit, known_field)


def _optimal_rss(
    fits: dict[str, Calibration], kept: NDArray[np.float64]
) -> tuple[dict[str, float], dict[str, Calibration], dict[str, str]]:
    """Σ d² at each model's maximum-likelihood optimum over all kept samples, and the optima themselves.

    The BIC compares maximised likelihoods: under isotropic Gaussian noise on the samples, each model is
    scored at the minimum of the sum of squared (first-order) distances of the samples to its ellipsoid,
    reached from the model's own fit and from the simpler model's optimum (so a richer model never scores
    worse than a simpler one it contains). On long logs the sum runs on a regular stride of at most
    20 000 samples, scaled to all of them; the sums are in units of the data's radius squared (only ratios
    matter). The optima (when real ellipsoids) are the calibrations ``auto`` returns and the references
    at which the observability is judged. A model whose optimum has a semi-axis shorter than
    :data:`FLAT_SEMI_AXIS` residual distances is left out (third return value: why).
    """
    from ..diagnostics import thin
    from ..diagnostics._geometry import Frame, calibration_from_parameters, maximum_likelihood, parameters, unit_map

    rows = kept[thin(kept.shape[0], 2_000)]
    scale = kept.shape[0] / rows.shape[0]
    frame = Frame.of(rows)
    z = frame.normalise(rows)
    rss: dict[str, float] = {}
    optima: dict[str, Calibration] = {}
    degenerate: dict[str, str] = {}
    previous: tuple[str, NDArray[np.float64]] | None = None
    widest = float(np.sqrt(np.linalg.eigvalsh(np.cov(z.T))[-1]))  # the samples' largest principal spread
    for model in CANDIDATES:  # simplest first: each richer model also starts from the simpler optimum
        if model not in fits:
            continue
        starts = [parameters(fits[model], model, frame)]
        if previous is not None:
            starts.append(_embed(previous[1], previous[0], model))
        value, optimum = maximum_likelihood(z, model, starts)
        eigenvalues, axes = np.linalg.eigh(unit_map(optimum, model))
        strongest = int(np.argmax(np.abs(eigenvalues)))
        shortest = 1.0 / float(abs(eigenvalues[strongest]))
        rms = math.sqrt(value / z.shape[0])
        # Only the two together mark a flattened fit: a short axis of a few residuals, along which the samples
        # barely spread compared with their widest direction (they lie in a plane). Noise alone (a short
        # axis of a few residuals on a full tumble with 10 % noise) is not flatness.
        spread = float(np.std(z @ axes[:, strongest]))
        if shortest < FLAT_SEMI_AXIS * rms and spread < min(FLAT_SPREAD * widest, FLAT_NOISE_SPREAD * rms):
            # An ellipsoid flattened onto the samples: they lie in a plane within the noise, and the fit
            # turned the noise across that plane into the ellipsoid's thickness.
            degenerate[model] = (
                f"its best fit is flattened onto the samples (shortest semi-axis {shortest / rms:.1f} times the "
                "residual distance): they lie in a plane within the noise"
            )
            continue
        rss[model] = scale * value
        previous = (model, optimum)
        try:
            optima[model] = calibration_from_parameters(optimum, model, frame, model)
        except MagfitError:
            optima[model] = fits[model]
    return rss, optima, degenerate


def refine_chosen(model: str, start: Calibration, samples: NDArray[np.float64]) -> Calibration:
    """What ``auto`` returns for ``model``, fitted to (a stride of at most 200 000 of) ``samples``.

    The full ellipsoid: the ``ml`` fit (orthogonal distances with the mean-curvature bias correction);
    the first-order maximum-likelihood fit of :func:`_optimal_rss` grows the ellipsoid by about σ²/B and
    skews it at high noise (measured at σ = 10 % of the field, N = 100 000: 1.45 % error in the
    ellipsoid matrix against 0.25 % for ``ml``). Sphere and diag, or when ``ml`` fails: that first-order
    fit, from ``start``.
    """
    from ..diagnostics import MAX_SAMPLES, thin
    from ..diagnostics._geometry import Frame, calibration_from_parameters, maximum_likelihood, parameters

    rows = samples[thin(samples.shape[0], MAX_SAMPLES)]
    if model == "full" and "ml" in METHODS:
        try:
            return METHODS["ml"].function(FitInput(Statistics.from_samples(rows), rows))
        except (MagfitError, np.linalg.LinAlgError):
            pass  # e.g. no ellipsoid to start from, or too few directions: the first-order fit below
    frame = Frame.of(rows)
    _, optimum = maximum_likelihood(frame.normalise(rows), model, [parameters(start, model, frame)])
    return calibration_from_parameters(optimum, model, frame, model)


def fit_chosen(model: str, samples: NDArray[np.float64]) -> Calibration:
    """What ``auto`` returns once it has chosen ``model``: the model's fit refined to maximum likelihood."""
    return refine_chosen(model, fit_model(model, samples), samples)


def _embed(p: NDArray[np.float64], kind: str, target: str) -> NDArray[np.float64]:
    """The parameters of a simpler model as parameters of a richer one (the same ellipsoid)."""
    offset = p[:3]
    scales = np.full(3, p[3]) if kind == "sphere" else p[3:6]
    if target == "diag":
        return np.concatenate([offset, scales])
    cross = np.zeros(3) if kind != "full" else p[6:9]
    return np.concatenate([offset, scales, cross])


def _screen(samples: NDArray[np.float64], mode: str) -> tuple[bool, NDArray[np.bool_], str]:
    """Whether to fit robustly, the inliers known so far, and a sentence on what was found.

    The screen is a robust full fit (sphere when that fails) on a regular stride of at most 20 000 samples:
    enough to see 0.2 % of outliers, cheap on long logs. The robust candidates then find their own inliers
    among all samples.
    """
    from ..diagnostics import thin

    everything = np.ones(samples.shape[0], dtype=bool)
    if mode == "keep":
        return False, everything, ""
    rows = samples[thin(samples.shape[0], 2_000)]
    screen = None
    for model in ("full", "sphere"):
        try:
            screen = fit_robust(FitInput(Statistics.from_samples(rows), rows), model=model)
            break
        except MagfitError:
            continue
    if screen is None:
        return mode == "reject", everything, ""
    residuals = unchecked_sphere_distances(screen, rows)
    centre, sigma = robust_scale(residuals)
    far = int(np.sum(np.abs(residuals - centre) > _SCREEN_SIGMAS * max(sigma, 1e-12)))
    found = far >= max(5, math.ceil(2e-3 * rows.shape[0]))
    if mode == "reject" or found:
        note = (
            f"{far} of {rows.shape[0]} screened samples lie beyond {_SCREEN_SIGMAS:.0f} robust standard deviations "
            "of the fitted ellipsoid (spikes, saturation or a magnet): every model was fitted robustly"
            if found
            else "robust fitting was requested"
        )
        return True, everything, note
    return False, everything, ""


def _refusal(opening: str, samples: NDArray[np.float64], failed: dict[str, str]) -> CalibrationError:
    """Why no model is left: ``opening``, what the samples' shape says, and each model's reason."""
    reasons = "; ".join(f"{model}: {reason}" for model, reason in failed.items())
    return CalibrationError(opening + _flatness(samples) + ": " + reasons)


def _kept(calibration: Calibration, n: int) -> NDArray[np.bool_]:
    mask = np.ones(n, dtype=bool)
    for start, stop in calibration.details.get("rejected", {}).get("runs", []):
        mask[start:stop] = False
    return mask


def _fit_candidate(model: str, samples: NDArray[np.float64], robust: bool, statistics: Statistics) -> Calibration:
    """``model`` fitted to the samples, robustly or not; ``statistics`` are the samples' (one pass saved)."""
    if robust:
        return fit_robust(FitInput(statistics, samples), model=model)
    return fit_model(model, samples, statistics)


def _observable_choice(
    best: str, optima: dict[str, Calibration], kept: NDArray[np.float64]
) -> tuple[str, list[str], list[str]]:
    """The best-scoring model, or the next simpler one whose parameters the samples determine.

    Two kinds of undetermined direction, two rules:

    - a band of directions around an axis (both ends of it unseen, the axes at right angles seen): the
      offset and scale along it are fixed by nothing in the samples. The model is passed over; if no model
      is left, :class:`CalibrationError`.
    - a combination of parameters with a one-sigma above 5 % of the field (e.g. the vertical offset and
      scale under ±20° tilts): the BIC has already judged that the richer model fits significantly better,
      so a simpler model's misfit would cost more than this uncertainty; the model is kept and the
      direction is named ("not determined"), and the diagnostics warn.

    Returns the chosen model, the descriptions of its weak directions and, for every model passed
    over, why.
    """
    passed_over: list[str] = []
    order = [model for model in CANDIDATES[: CANDIDATES.index(best) + 1][::-1] if model in optima]
    for model in order:
        observability, unseen = _observe(optima[model], model, kept)
        weak = [w.description + ("" if w.determined else " (not determined)") for w in observability.weak]
        undetermined = [w.description for w in observability.weak if not w.determined]
        band = [
            f"the offset and scale along {axis} (no samples with the field near +{axis} or −{axis}: the sensor "
            f"only turned about {axis})"
            for axis in unseen
        ]
        cone = observability.turn_axis
        if cone is not None and not band:  # a cone of directions: the same as a band, off the equator
            axis = cone[1:] if len(cone) == 2 else f"the direction {cone}"
            band.append(
                f"the offset and scale along {axis} (the field direction stayed on a cone: the sensor only "
                f"turned about {axis})"
            )
        if not band:
            return model, weak, passed_over
        passed_over.append(
            f"the {model} model was passed over: the samples do not determine {'; '.join(band + undetermined)}"
        )
    raise CalibrationError(
        "the samples determine no calibration model: "
        + "; ".join(passed_over)
        + "; record again turning the sensor through more attitudes (a full tumble is best)"
    )


def _observe(reference: Calibration, model: str, kept: NDArray[np.float64]) -> tuple[Any, tuple[str, ...]]:
    """Observability of ``model`` and the axes the samples form a band around, seen through ``reference``.

    The reference is the model's maximum-likelihood optimum: an algebraic fit that drifted along a weak
    direction (e.g. stretched along z to hug a cap of samples) makes the samples look better spread than
    they are; the distances to the ellipsoid cannot shrink by such a stretch, so the optimum does not drift
    that way.
    """
    calibration = reference
    from ..diagnostics import Frame, thin, weighted_even_subsample
    from ..diagnostics.coverage import coverage
    from ..diagnostics.uncertainty import analyse

    candidates = thin(kept.shape[0])
    z_candidates = Frame.corrected(calibration).normalise(kept[candidates])
    chosen, weights = weighted_even_subsample(z_candidates, total=kept.shape[0])
    z = z_candidates[chosen]
    observability, _ = analyse(kept[candidates][chosen], weights, model, calibration, 60.0)
    return observability, coverage(z).unseen_axes


def _flatness(samples: NDArray[np.float64]) -> str:
    """Words for the direction the samples hardly extend along, when they lie near a plane."""
    from ..diagnostics._geometry import axis_words

    spreads, directions = np.linalg.eigh(np.cov(samples.T))
    ratio = math.sqrt(max(spreads[0], 0.0) / spreads[2])
    if ratio > 0.25:
        return ""
    axis = axis_words(directions[:, 0] * np.sign(directions[np.argmax(np.abs(directions[:, 0])), 0])).lstrip("+")
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
