"""The one path by which every method runs: validate, reduce to statistics, check support, dispatch.

Rows clipped at the sensor's full scale (:mod:`magfit.saturation`) are left out here, before any method
sees them, and counted in ``details["saturation"]``; when too few rows remain the fit is refused (code
``"saturated"``), naming the full-scale range to change.

:func:`magfit.fit` (with the verdict and the diagnostics on top), the robust fit's inner models, ``auto``'s
candidates and the held-out refits of the diagnostics all go through :func:`estimate`, so a method refuses
the same data whoever calls it. The user's options are recorded explicitly in
``Calibration.options`` (see :func:`recorded_options`), so that a refit or a later diagnosis uses exactly
what the user asked for, never options guessed back from other entries of ``details``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .._validation import check_finite, check_shape, check_support
from ..calibration import Calibration
from ..errors import CalibrationError, OptionError
from ..saturation import Clipping, find_clipped, statistics_and_clipping
from ..statistics import Statistics
from .registry import METHODS, FitInput, MethodSpec, Refit, get_method

__all__ = ["Refit", "estimate", "first_order_refit", "first_order_stand_in", "prepare", "recorded_options", "refitter"]

#: The first-order refits stop at this relative change of Σd² or after this many iterations: they start
#: at the calibration refitted, which a stretch of the recording moves a little.
FIRST_ORDER_TOLERANCE = 1e-4
FIRST_ORDER_ITERATIONS = 5


def method_spec(method: str, options: Mapping[str, Any]) -> MethodSpec:
    """The registered method, after checking that it takes every option given (listing the valid ones)."""
    spec = get_method(method)
    unknown = sorted(set(options) - set(spec.options))
    if unknown:
        valid = ", ".join(spec.options) or "none"
        raise OptionError(f"method {spec.name!r} has no option {', '.join(map(repr, unknown))}; valid options: {valid}")
    return spec


def prepare(samples: ArrayLike | Statistics, spec: MethodSpec) -> FitInput:
    """Validated samples reduced to :class:`Statistics` (one chunked pass), as ``spec`` needs them.

    Samples are validated in the caller's dtype: float32 (or integer) samples reach the linear methods
    through the chunks of :class:`Statistics` and are converted whole only for the methods that iterate.
    """
    if isinstance(samples, Statistics):
        if spec.data == "samples":
            raise OptionError(
                f"method {spec.name!r} needs the samples, not Statistics; methods that accept Statistics: "
                + ", ".join(name for name, s in METHODS.items() if s.data == "statistics")
            )
        return FitInput(samples, None)
    array = check_shape(samples)
    if spec.data == "samples":
        check_finite(array)
        array = np.asarray(array, dtype=np.float64)
    # (A method that reads the statistics: Statistics.update checks each chunk as it reads it and names the
    # row, without a whole-array temporary: 30 MB and a pass over 1e7 samples.)
    if spec.needs:  # vector's and gyro's samples are not searched for clipped rows (estimate)
        return FitInput(Statistics.from_samples(array), array)
    statistics, clipping = statistics_and_clipping(array)  # one pass for both
    return FitInput(statistics, array, clipping)


def estimate(data: FitInput, method: str, options: Mapping[str, Any] | None = None) -> Calibration:
    """Run ``method`` on prepared data: the support checks every fit gets, the method's own, the method.

    Returns the method's calibration with its options (the user's, and the defaults of the others)
    recorded (``Calibration.options``) and its model family (the method's, or the registry entry's);
    no verdict and no diagnostics (:func:`magfit.fit` adds those).
    """
    options = dict(options or {})
    spec = method_spec(method, options)
    clipping = None
    if data.samples is not None and not spec.needs:  # vector's and gyro's arrays run row by row beside them
        data, clipping = without_clipped(data, spec)
    check_support(data.statistics, spec.name, spec.min_samples)
    for check in spec.checks:
        check(data.statistics, spec.name)
    calibration = spec.function(data, **options)
    effective = {**spec.defaults, **options}  # every option, as the method ran: a refit needs no guessing
    details = dict(calibration.details)
    if clipping is not None:
        details["saturation"] = clipping.to_dict()
    model = calibration.model if calibration.model is not None else spec.model
    return replace(calibration, details=details, options=recorded_options(effective), model=model)


#: A fit is refused when more than this share of the rows is clipped at the full scale: what is left is
#: the directions where the field plus offset stayed within the range, a band the clipping cut.
MAX_CLIPPED_SHARE = 0.5

FULL_SCALE_ADVICE = (
    "set a larger full-scale range on the magnetometer (its range or gain setting, e.g. ±8 gauss instead of "
    "±2 gauss; the firmware's compass range parameter where it has one), or mount it further from the magnet, "
    "motor or steel whose field pushes it out of range, and record again"
)


def without_clipped(data: FitInput, spec: MethodSpec) -> tuple[FitInput, Clipping | None]:
    """``data`` without the rows clipped at the sensor's full scale, and what was clipped (None: nothing).

    Raises :class:`CalibrationError` (code ``"saturated"``) when more than :data:`MAX_CLIPPED_SHARE` of the
    rows, or all but fewer than the method needs, are clipped.
    """
    assert data.samples is not None
    clipping = data.clipping if data.clipping is not None else find_clipped(data.samples)
    if not clipping.n_clipped:
        return data, None
    kept = data.samples[~clipping.clipped]
    if clipping.n_clipped > MAX_CLIPPED_SHARE * clipping.n_samples or kept.shape[0] < spec.min_samples:
        raise CalibrationError(
            f"the samples do not support the {spec.name} calibration: {clipping.n_clipped} of "
            f"{clipping.n_samples} samples are clipped at the sensor's full scale ({clipping.describe()}): the "
            "field plus the offset exceeded the range the sensor was set to, so those readings are its range's end, "
            f"not the field, and the {kept.shape[0]} left are too few to fit; {FULL_SCALE_ADVICE}",
            codes=("saturated",),
        )
    return FitInput(Statistics.from_samples(kept), kept), clipping


#: How :func:`recorded_options` records an array option (its length only: a refit takes the new one).
_ARRAY_RECORD = "an array of {} rows"


def is_recorded_array(value: Any) -> bool:
    """Whether a recorded option stands for an array the method was given (which a refit must be given again)."""
    prefix = _ARRAY_RECORD.split("{", 1)[0]
    return isinstance(value, str) and value.startswith(prefix) and value.endswith(" rows")


def recorded_options(options: Mapping[str, Any]) -> dict[str, Any]:
    """The options as JSON can hold them (numbers as floats, strings as they are)."""
    recorded: dict[str, Any] = {}
    for name, value in options.items():
        if isinstance(value, (bool, str)) or value is None:
            recorded[name] = value
        elif isinstance(value, (np.ndarray, list, tuple)):  # vector's reference= and time_s=: their shape only
            recorded[name] = _ARRAY_RECORD.format(len(value))
        elif isinstance(value, (int, float, np.integer, np.floating)) and math.isfinite(float(value)):
            recorded[name] = float(value) if not isinstance(value, (int, np.integer)) else int(value)
        else:
            recorded[name] = repr(value)
    return recorded


def refitter(method: str, options: Mapping[str, Any]) -> Refit:
    """A function that fits ``method`` with ``options`` to (n, 3) samples through :func:`estimate`."""
    fixed = dict(options)

    def refit(samples: NDArray[np.float64]) -> Calibration:
        spec = method_spec(method, fixed)
        return estimate(prepare(samples, spec), method, fixed)

    return refit


def first_order_refit(
    model: str, start: Calibration, samples: NDArray[np.float64], *, field_strength: float | None = None
) -> Calibration:
    """The first-order maximum-likelihood fit of ``model`` (sphere, diag, full) to ``samples``, from ``start``.

    A few Levenberg-Marquardt iterations on the first-order distances of :mod:`magfit.geometry.frame`; the
    result is scaled to ``field_strength`` when given.
    """
    from ..geometry.frame import Frame, calibration_from_parameters, maximum_likelihood, parameters
    from ..geometry.quadric import check_field_strength, pin_field_strength

    frame = Frame.of(samples)
    z = frame.normalise(samples)
    _, optimum = maximum_likelihood(
        z, model, [parameters(start, model, frame)], cost_tolerance=FIRST_ORDER_TOLERANCE,
        max_iterations=FIRST_ORDER_ITERATIONS,
    )  # fmt: skip
    fitted = calibration_from_parameters(optimum, model, frame, model)
    fitted = replace(fitted, model=model)  # type: ignore[arg-type]
    return pin_field_strength(fitted, check_field_strength(field_strength))


def first_order_stand_in(calibration: Calibration, options: Mapping[str, Any]) -> Refit:
    """The first-order fit of ``calibration``'s model, from it: the stand-in of an iterative method
    (:attr:`magfit.methods.registry.Judging.stand_in`)."""
    from ..diagnostics import model_kind

    kind = model_kind(calibration)
    known = options.get("field_strength")
    return lambda samples: first_order_refit(kind, calibration, samples, field_strength=known)
