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
from .diagnostics import DEFAULT_INCLINATION_DEG, MAX_SAMPLES, Diagnostics, Refit, diagnose_statistics
from .diagnostics import diagnose as diagnose_samples
from .diagnostics.reference import judged as judged_against_reference
from .diagnostics.settle import settle, with_reasons
from .errors import MagfitError, OptionError
from .findings import Reason
from .methods import METHODS, FitInput
from .methods.core import estimate, is_recorded_array, method_spec, prepare, recorded_options, refitter
from .methods.registry import MethodSpec, Undetermined
from .statistics import Statistics

__all__ = ["diagnose", "fit", "refit"]


#: The default method of :func:`fit`. ``calibrate_file`` and live calibration default to ``"auto"``; a
#: Python call keeps the paper's algebraic ellipsoid, which also runs on :class:`Statistics` (``auto``
#: needs the samples) and answers in one linear solve (see docs/methods.md, "The default method").
DEFAULT_METHOD = "ellipsoid"


def fit(
    samples: ArrayLike | Statistics,
    method: str = DEFAULT_METHOD,
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
        A name in ``magfit.METHODS``: ``"ellipsoid"`` (hard + soft iron, paper section II, the default),
        ``"sphere"`` (hard iron only, section III), ``"minmax"`` (pseudo-calibration, section IV),
        ``"auto"`` (the simplest model the samples determine: the default of ``calibrate_file``, the
        command line and live calibration), ... The default stays ``"ellipsoid"`` here because it also
        takes a :class:`Statistics` (chunked, merged across processes), which ``auto`` cannot, and because
        a Python caller who named no method has relied on it since the first release.
    diagnostics : bool or "quick"
        Attach :func:`diagnose`'s full report as ``details["diagnostics"]`` (read it typed with
        ``calibration.diagnostics``). It runs on at most 20 000 spatially even samples; from
        ``Statistics`` only what statistics allow is attached. ``False``: the verdict is still reached
        (``calibration.support``), on the checks that need no refit of the method. ``"quick"``: those
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
        ``calibration.support`` holds the verdict: ``"supported"`` or ``"weak"`` (with the weaknesses
        named, each with its code).

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
    except Undetermined as refused:
        if not allow_undetermined:
            raise
        # Refused with a best answer all the same: forced, that answer, its refusal the first warning.
        chosen = replace(refused.calibration, options=recorded_options({**spec.defaults, **options}))
        refusal = Reason(str(refused), refused.codes[0] if refused.codes else "model_inadequate")
        return _judged(chosen, data, spec, options, diagnostics, True, refusal)
    return _judged(calibration, data, spec, options, diagnostics, allow_undetermined)


def refit(
    calibration: Calibration,
    samples: ArrayLike,
    *,
    diagnostics: bool | Literal["quick"] = "quick",
    allow_undetermined: bool = False,
    **streams: ArrayLike,
) -> Calibration:
    """``calibration``'s method fitted again to ``samples`` with the options it recorded, judged as :func:`fit` judges.

    A method may refit by its own rule (its registry entry's ``Judging.refit``): for an ``auto`` calibration
    the model it chose is refitted (its first-order maximum-likelihood fit, from ``calibration``: a few
    iterations) without a new model choice: what a live calibration does between two full ``auto`` fits, as
    new samples arrive; what the method said of its choice is kept. A calibration fitted with arrays beside the samples
    (``vector``: ``reference=``, ``time_s=``; ``gyro``: ``gyro=``, ``time_s=``) records only their length: the
    new samples' own arrays are given as keywords (``streams``), the same ones. Raises as :func:`fit` does.
    """
    options = dict(calibration.options)
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
    if refitted.method != calibration.method:  # the method's own refit (auto's chosen model): keep what it said
        details = {k: v for k, v in {**calibration.details, **refitted.details}.items() if k != "diagnostics"}
        kept = {name: getattr(calibration, name) for name in ("auto", "vector", "gyro", "rejected")}
        refitted = replace(refitted, method=calibration.method, details=details, options=options, **kept)
    return _judged(refitted, data, spec, options, diagnostics, allow_undetermined)


def _judged(
    calibration: Calibration,
    data: FitInput,
    spec: MethodSpec,
    options: dict[str, Any],
    diagnostics: bool | Literal["quick"],
    allow_undetermined: bool,
    refusal: Reason | None = None,
) -> Calibration:
    """``calibration`` with its verdict (and diagnostics) attached, or the refusal raised (:func:`settle`).

    ``refusal``: the method's own, when it was forced to return a calibration (``auto``: no model the samples
    determine describes them within a useful heading bound). The rows of ``data.samples`` clipped at full
    scale, found in the statistics' pass that also checked them finite (``data.clipping``), are handed to the
    diagnostics, which search them again only when that pass did not run. The method's registry entry adds
    what it knows (:class:`~magfit.methods.registry.Judging`): a model error joins the heading one-sigma before
    the verdict, and its own weaknesses join the verdict's.
    """
    if calibration.frame == "vehicle":  # fitted against a reference field: judged there, not by its magnitude
        return judged_against_reference(calibration, spec.name, diagnostics, allow_undetermined)
    judging = spec.judging
    model_error = judging.model_error_deg(calibration) if judging.model_error_deg is not None else 0.0
    offset_error = judging.model_error_offset(calibration) if judging.model_error_offset is not None else None
    if data.samples is None:
        report = diagnose_statistics(calibration, data.statistics)
    else:
        thorough = diagnostics is True
        refit = refit_of(calibration, spec.name, options) if thorough else None
        # The halves and the block jackknife refit 10 times: an iterative method (ml, robust: seconds on a
        # long log) is stood in for by its registry entry's quick fit, which the same stretches move the same way.
        variation = judging.stand_in(calibration, options) if thorough and judging.stand_in is not None else None
        report = diagnose_samples(
            calibration,
            data.samples,
            refit=refit,
            thorough=thorough,
            compare_ml=judging.compare_ml,
            variation_refit=variation,
            model_error_heading_deg=model_error,
            model_error_offset=offset_error,
            clipping=data.clipping,
            fitted_rows=spec.fit_rows,  # auto's refit reads a stride: its uncertainty is for those rows
        )
    assert report.support is not None  # both diagnoses reach a verdict
    own = judging.weaknesses(calibration, report) if judging.weaknesses is not None else ()
    support = with_reasons(report.support, () if refusal is None else (refusal,), own)
    return settle(
        calibration,
        support,
        method=spec.name,
        allow_undetermined=allow_undetermined,
        report=report if diagnostics else None,
    )


def refit_of(calibration: Calibration, method: str, options: dict[str, Any]) -> Refit:
    """The refit the diagnostics use: the method's own (its registry entry's), else the method with the options."""
    spec = METHODS.get(method)
    if spec is not None and spec.judging.refit is not None:
        return spec.judging.refit(calibration, options)
    return refitter(method, options)


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
    recorded (``calibration.options``); a calibration of an unknown method gets the other checks.
    See :func:`magfit.diagnostics.diagnose` for the parameters.

    Raises
    ------
    OptionError
        The calibration's method rests on more than the samples (``vector``: a reference field; ``gyro``: the
        body rates): its verdict is the one made when it was fitted (``calibration.support``).
    """
    spec = METHODS.get(calibration.method)
    if spec is not None and spec.needs:
        # These samples alone would be judged by |field| only, which the method does not rest on: the
        # magnitude-only verdict (a flight "covers 7 % of the directions") would contradict its own.
        raise OptionError(
            f"magfit.diagnose judges a calibration from the samples alone; a {calibration.method!r} calibration also "
            f"rests on {' and '.join(spec.needs)}: its verdict, made when it was fitted, is calibration.support "
            f"(fit it again with magfit.fit(samples, method={calibration.method!r}, ...) to judge it on new samples)"
        )
    refit = None
    options = dict(calibration.options)
    try:
        method_spec(calibration.method, options)
        refit = refit_of(calibration, calibration.method, options)
    except MagfitError:
        refit = None
    judging = spec.judging if spec is not None else None
    model_error = judging.model_error_deg(calibration) if judging and judging.model_error_deg else 0.0
    offset_error = judging.model_error_offset(calibration) if judging and judging.model_error_offset else None
    report = diagnose_samples(
        calibration,
        samples,
        inclination_deg=inclination_deg,
        max_samples=max_samples,
        held_out=held_out,
        represents=represents,
        refit=refit,
        model_error_heading_deg=model_error,
        model_error_offset=offset_error,
        fitted_rows=spec.fit_rows if spec is not None else None,
    )
    own = judging.weaknesses(calibration, report) if judging and judging.weaknesses else ()
    if not own or report.support is None:
        return report
    support = with_reasons(report.support, (), own)
    return replace(report, support=support, warnings=support.warnings)
