"""The public entry points for fitting: :func:`fit` (estimate, verdict, diagnostics) and :func:`diagnose`.

The flow is one way: the samples are validated and reduced to :class:`Statistics` and the method runs
(:func:`magfit.methods.core.estimate`, the one path every method runs by), then the calibration is judged
in its own frame (:mod:`magfit.diagnostics.verdict`): refused calibrations raise, weak ones carry their
warnings.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any, Literal

import numpy as np
from numpy.typing import ArrayLike

from .calibration import Calibration
from .diagnostics import DEFAULT_INCLINATION_DEG, MAX_SAMPLES, Diagnostics, Refit, diagnose_statistics, model_kind
from .diagnostics import diagnose as diagnose_samples
from .diagnostics.reference import judged as judged_against_reference
from .errors import CalibrationError, MagfitError, OptionError
from .findings import Reason, Support
from .methods import METHODS, FitInput, get_method
from .methods.auto import UndeterminedChoice, refit_first_order
from .methods.core import estimate, is_recorded_array, method_spec, prepare, recorded_options, refitter
from .statistics import Statistics

__all__ = ["diagnose", "fit", "refit"]


def fit(
    samples: ArrayLike | Statistics,
    method: str = "ellipsoid",
    *,
    diagnostics: bool | Literal["quick"] = True,
    allow_undetermined: bool = False,
    **options: Any,
) -> Calibration:
    """Fit a calibration to magnetometer samples, if the samples support it.

    Parameters
    ----------
    samples : array_like, shape (N, 3), or Statistics
        Raw magnetometer samples, one (x, y, z) per row, any unit, in recording order, recorded while
        turning the sensor in all directions. The linear methods also accept a :class:`Statistics`
        accumulated in chunks.
    method : str
        A name in ``magfit.METHODS``: ``"ellipsoid"`` (hard + soft iron, paper section II),
        ``"sphere"`` (hard iron only, section III), ``"minmax"`` (pseudo-calibration, section IV), ...
    diagnostics : bool or "quick"
        Attach :func:`diagnose`'s full report as ``details["diagnostics"]`` (read it typed with
        ``calibration.diagnostics``). It runs on at most 20 000 spatially even samples; from
        ``Statistics`` only what statistics allow is attached. ``False``: the verdict is still reached
        (``details["support"]``), on the checks that need no refit of the method. ``"quick"``: those
        checks' findings are attached too (coverage, observability, the uncertainty without the block
        jackknife, consistency): what a live view refreshed several times a second needs.
    allow_undetermined : bool
        Return a calibration that the samples do not support (see below) instead of raising; its
        refusal is then the first of its warnings (``--force`` on the command line).
    **options
        Keyword options of the method (see ``magfit.METHODS[method].options``); an unknown name is an
        :class:`OptionError` that lists the valid ones.

    Returns
    -------
    Calibration
        ``corrected = matrix @ (raw - offset)`` lies on a sphere of radius ``field_strength``.
        ``details["support"]`` holds the verdict: ``"supported"`` or ``"weak"`` (with the weaknesses
        named, in words).

    Raises
    ------
    SampleError
        The samples are not an (N, 3) array of finite numbers.
    CalibrationError
        The data cannot support the fit: too few samples, no 3-D spread, not an ellipsoid, a sensor
        that barely moved or turned about one axis only, parameters the samples do not determine, a
        known field strength the samples contradict. The message names what is missing and what to record.
    OptionError
        Unknown method or option, or an option value out of range.
    """
    spec = method_spec(method, options)
    data = prepare(samples, spec)
    try:
        calibration = estimate(data, spec.name, options)
    except UndeterminedChoice as refused:
        if not allow_undetermined:
            raise
        # auto refused: forced, it returns the model its unforced choice ranks best, its refusal the first warning.
        chosen = refused.calibration
        recorded = {**chosen.details, "options": recorded_options({**spec.defaults, **options})}
        refusal = Reason(str(refused), refused.codes[0] if refused.codes else "model_inadequate")
        return _judged(replace(chosen, details=recorded), data, spec.name, options, diagnostics, True, refusal)
    return _judged(calibration, data, spec.name, options, diagnostics, allow_undetermined)


def refit(
    calibration: Calibration,
    samples: ArrayLike,
    *,
    diagnostics: bool | Literal["quick"] = "quick",
    allow_undetermined: bool = False,
    **streams: ArrayLike,
) -> Calibration:
    """``calibration``'s method fitted again to ``samples`` with the options it recorded, judged as :func:`fit` judges.

    For an ``auto`` calibration the model it chose is refitted (its first-order maximum-likelihood fit,
    from ``calibration``: a few iterations) without a new model choice: what a live calibration does
    between two full ``auto`` fits, as new samples arrive. A calibration fitted with arrays beside the samples
    (``vector``: ``reference=``, ``time_s=``; ``gyro``: ``gyro=``, ``time_s=``) records only their length: the
    new samples' own arrays are given as keywords (``streams``), the same ones. Raises as :func:`fit` does.
    """
    options = calibration.details.get("options", {})
    if not isinstance(options, dict):
        raise CalibrationError(f"the {calibration.method} calibration records no options to refit it with")
    arrays = [name for name, value in options.items() if is_recorded_array(value)]
    unexpected = sorted(set(streams) - set(arrays))
    if unexpected:
        taken = f"only {', '.join(arrays)}" if arrays else "none"
        raise OptionError(
            f"refit takes the arrays the {calibration.method} calibration was fitted with ({taken}), not "
            f"{', '.join(unexpected)}; to change other options call magfit.fit"
        )
    missing = [name for name in arrays if name not in streams]
    if missing:
        raise OptionError(
            f"a {calibration.method} calibration is refitted with the new samples' own "
            f"{' and '.join(missing)}: magfit.refit(calibration, samples, {', '.join(f'{m}=...' for m in missing)})"
        )
    options = {**options, **streams}
    spec = method_spec(calibration.method, options)
    data = prepare(samples, spec)
    assert data.samples is not None  # an array was given
    refitted = refit_of(calibration, spec.name, options)(np.asarray(data.samples, dtype=np.float64))
    if spec.name == "auto":  # keep what auto said of its choice, with the refitted numbers
        refitted = replace(refitted, method="auto", details={**calibration.details, **refitted.details})
        refitted = replace(refitted, details={k: v for k, v in refitted.details.items() if k != "diagnostics"})
    return _judged(refitted, data, spec.name, options, diagnostics, allow_undetermined)


def _judged(
    calibration: Calibration,
    data: FitInput,
    method: str,
    options: dict[str, Any],
    diagnostics: bool | Literal["quick"],
    allow_undetermined: bool,
    refusal: Reason | None = None,
) -> Calibration:
    """``calibration`` with its verdict (and diagnostics) attached, or the refusal raised.

    ``refusal``: the method's own, when it was forced to return a calibration (``auto``: no model the samples
    determine describes them within a useful heading bound). ``auto``'s chosen model may leave out a
    distortion that a richer model, which the samples do not determine, shows (``details["omitted_distortion"]``):
    the heading error it can cause joins the heading one-sigma before the verdict, and is named a weakness.
    """
    if calibration.frame == "vehicle":  # fitted against a reference field: judged there, not by its magnitude
        return judged_against_reference(calibration, method, diagnostics, allow_undetermined)
    if data.samples is None:
        report = diagnose_statistics(calibration, data.statistics)
    else:
        thorough = diagnostics is True
        refit = refit_of(calibration, method, options) if thorough else None
        # The halves and the block jackknife refit 10 times: an iterative method (ml, robust: seconds on a
        # long log) is stood in for by its model's first-order maximum-likelihood fit, which the same
        # stretches of the recording move the same way.
        iterative = get_method(method).data == "samples" and method != "auto"
        variation = _first_order_refit(calibration, options) if thorough and iterative else None
        # auto returns its chosen model's maximum-likelihood fit: the comparison with that fit is moot.
        report = diagnose_samples(
            calibration,
            data.samples,
            refit=refit,
            thorough=thorough,
            compare_ml=method != "auto",
            variation_refit=variation,
            model_error_heading_deg=_omitted_heading_deg(calibration),
        )
    support = report.support
    assert support is not None  # both diagnoses reach a verdict
    omitted = _omitted_weakness(calibration, report)
    if omitted is not None or refusal is not None:
        support = Support.judged(
            (*(() if refusal is None else (refusal,)), *support.refusals),
            (*support.weaknesses, *(() if omitted is None else (omitted,))),
            support.advice,
        )
        report = replace(report, support=support, warnings=support.warnings)
    if support.verdict == "refused":
        if not allow_undetermined:
            raise CalibrationError(support.message(method), codes=support.codes)
        support = replace(support, forced=True)
        report = replace(report, support=support, warnings=support.warnings)
    details: dict[str, Any] = {**calibration.details, "support": support.to_dict()}
    if method == "auto" and "weak" in details:  # the chosen model's weaknesses: the verdict's, one uncertainty
        details["weak"] = [str(w) for w in support.weaknesses]
    if diagnostics:
        details["diagnostics"] = report.to_dict()
    return replace(calibration, details=details)


def _omitted_heading_deg(calibration: Calibration) -> float:
    """The heading error (degrees) of the distortion ``auto``'s chosen model leaves out, 0 when none."""
    omitted = calibration.details.get("omitted_distortion")
    if not isinstance(omitted, dict):
        return 0.0
    value = omitted.get("heading_deg")
    return float(value) if isinstance(value, (int, float)) and value > 0 else 0.0


def _omitted_weakness(calibration: Calibration, report: Diagnostics) -> Reason | None:
    """The weakness naming the distortion ``auto``'s chosen model leaves out, with the heading error it causes."""
    heading = _omitted_heading_deg(calibration)
    omitted = calibration.details.get("omitted_distortion")
    if not heading or not isinstance(omitted, dict):
        return None
    model = calibration.details.get("chosen_model", "chosen")
    stated = report.uncertainty.heading_sigma_deg if report.uncertainty is not None else None
    total = "" if stated is None else f"; the heading one-sigma stated includes it: ±{stated:.2g}°"
    difference = omitted.get("heading_difference_deg")
    witness_sigma = omitted.get("witness_heading_sigma_deg")
    parts = (
        f"their level headings differ by {difference:.2g}° (RMS) and the {omitted.get('model')} model's own heading "
        f"one-sigma is ±{witness_sigma:.2g}°: "
        if isinstance(difference, (int, float)) and isinstance(witness_sigma, (int, float))
        else ""
    )
    return Reason(
        f"the {model} model may leave out a distortion the samples show but do not determine (the "
        f"{omitted.get('model')} model, fitted to the same samples, predicts held-out stretches of the recording as "
        f"well or better); {parts}the heading error it can cause is ±{heading:.2g}°{total}; a reference field "
        "(method 'vector' with the attitude) or more tilt while recording would determine it",
        "model_inadequate",
    )


def refit_of(calibration: Calibration, method: str, options: dict[str, Any]) -> Refit:
    """The refit the diagnostics use: the method with the user's options, or ``auto``'s chosen model."""
    if method == "auto" and "chosen_model" in calibration.details:
        chosen = str(calibration.details["chosen_model"])
        known = options.get("field_strength")
        return lambda samples: refit_first_order(chosen, calibration, samples, field_strength=known)
    return refitter(method, options)


def _first_order_refit(calibration: Calibration, options: dict[str, Any]) -> Refit:
    """The first-order maximum-likelihood fit of ``calibration``'s model, from it (see :func:`_judged`)."""
    kind = model_kind(calibration)
    known = options.get("field_strength")
    return lambda samples: refit_first_order(kind, calibration, samples, field_strength=known)


def diagnose(
    calibration: Calibration,
    samples: ArrayLike,
    *,
    inclination_deg: float = DEFAULT_INCLINATION_DEG,
    max_samples: int = MAX_SAMPLES,
    held_out: bool = True,
    represents: int | None = None,
) -> Diagnostics:
    """Diagnose any calibration on samples (its verdict, coverage, observability, uncertainty, goodness).

    The held-out evaluation and the two-halves check refit the calibration's method with the options it
    recorded (``details["options"]``); a calibration of an unknown method gets the other checks.
    See :func:`magfit.diagnostics.diagnose` for the parameters.

    Raises
    ------
    OptionError
        The calibration's method rests on more than the samples (``vector``: a reference field; ``gyro``: the
        body rates): its verdict is the one made when it was fitted (``details["support"]``).
    """
    spec = METHODS.get(calibration.method)
    if spec is not None and spec.needs:
        # These samples alone would be judged by |field| only, which the method does not rest on: the
        # magnitude-only verdict (a flight "covers 7 % of the directions") would contradict its own.
        raise OptionError(
            f"magfit.diagnose judges a calibration from the samples alone; a {calibration.method!r} calibration also "
            f"rests on {' and '.join(spec.needs)}: its verdict, made when it was fitted, is details['support'] "
            f"(fit it again with magfit.fit(samples, method={calibration.method!r}, ...) to judge it on new samples)"
        )
    refit = None
    options = calibration.details.get("options", {})
    if isinstance(options, dict):
        try:
            method_spec(calibration.method, options)
            refit = refit_of(calibration, calibration.method, options)
        except MagfitError:
            refit = None
    report = diagnose_samples(
        calibration,
        samples,
        inclination_deg=inclination_deg,
        max_samples=max_samples,
        held_out=held_out,
        represents=represents,
        refit=refit,
        model_error_heading_deg=_omitted_heading_deg(calibration),
    )
    omitted = _omitted_weakness(calibration, report)
    if omitted is None or report.support is None:
        return report
    support = Support.judged(report.support.refusals, (*report.support.weaknesses, omitted), report.support.advice)
    return replace(report, support=support, warnings=support.warnings)
