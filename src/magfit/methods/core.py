"""The one path by which every method runs: validate, reduce to statistics, check support, dispatch.

:func:`magfit.fit` (with the verdict and the diagnostics on top), the robust fit's inner models, ``auto``'s
candidates and the held-out refits of the diagnostics all go through :func:`estimate`, so a method refuses
the same data whoever calls it. The user's options are recorded explicitly in
``details["options"]`` (see :func:`recorded_options`), so that a refit or a later diagnosis uses exactly
what the user asked for, never options guessed back from other entries of ``details``.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .._validation import check_finite, check_shape, check_support
from ..calibration import Calibration
from ..errors import OptionError
from ..statistics import Statistics
from .registry import METHODS, FitInput, MethodSpec, get_method

__all__ = ["Refit", "estimate", "prepare", "recorded_options", "refitter"]

#: A function that fits a method (with fixed options) to (n, 3) samples: what the diagnostics receive.
Refit = Callable[[NDArray[np.float64]], Calibration]


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
    check_finite(array)
    if spec.data == "samples":
        array = np.asarray(array, dtype=np.float64)
    return FitInput(Statistics.from_samples(array), array)


def estimate(data: FitInput, method: str, options: Mapping[str, Any] | None = None) -> Calibration:
    """Run ``method`` on prepared data: the support checks every fit gets, the method's own, the method.

    Returns the method's calibration with its options (the user's, and the defaults of the others)
    recorded in ``details["options"]``; no verdict and no diagnostics (:func:`magfit.fit` adds those).
    """
    options = dict(options or {})
    spec = method_spec(method, options)
    check_support(data.statistics, spec.name, spec.min_samples)
    for check in spec.checks:
        check(data.statistics, spec.name)
    calibration = spec.function(data, **options)
    effective = {**spec.defaults, **options}  # every option, as the method ran: a refit needs no guessing
    return replace(calibration, details={**calibration.details, "options": recorded_options(effective)})


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
