"""The one public entry point for fitting: :func:`fit`."""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from ._validation import check_finite, check_shape, check_support
from .calibration import Calibration
from .errors import OptionError
from .methods import METHODS, FitInput, get_method
from .statistics import Statistics

__all__ = ["fit"]


def fit(
    samples: ArrayLike | Statistics, method: str = "ellipsoid", *, diagnostics: bool = True, **options: Any
) -> Calibration:
    """Fit a calibration to magnetometer samples.

    Parameters
    ----------
    samples : array_like, shape (N, 3), or Statistics
        Raw magnetometer samples, one (x, y, z) per row, any unit, recorded while turning the sensor in
        all directions. The linear methods also accept a :class:`Statistics` accumulated in chunks.
    method : str
        A name in ``magfit.METHODS``: ``"ellipsoid"`` (hard + soft iron, paper section II),
        ``"sphere"`` (hard iron only, section III), ``"minmax"`` (pseudo-calibration, section IV), ...
    diagnostics : bool
        Attach :func:`magfit.diagnose`'s report as ``details["diagnostics"]`` (read it typed with
        ``calibration.diagnostics``). It runs on at most 20 000 spatially even samples; from
        ``Statistics`` only what statistics allow is attached.
    **options
        Keyword options of the method (see ``magfit.METHODS[method].options``); an unknown name is an
        :class:`OptionError` that lists the valid ones.

    Returns
    -------
    Calibration
        ``corrected = matrix @ (raw - offset)`` lies on a sphere of radius ``field_strength``.

    Raises
    ------
    SampleError
        The samples are not an (N, 3) array of finite numbers.
    CalibrationError
        The data cannot support the fit (too few samples, no 3-D spread, not an ellipsoid ...).
    OptionError
        Unknown method or option, or an option value out of range.
    """
    spec = get_method(method)
    unknown = sorted(set(options) - set(spec.options))
    if unknown:
        valid = ", ".join(spec.options) or "none"
        raise OptionError(f"method {spec.name!r} has no option {', '.join(map(repr, unknown))}; valid options: {valid}")
    if isinstance(samples, Statistics):
        if spec.data == "samples":
            raise OptionError(
                f"method {spec.name!r} needs the samples, not Statistics; methods that accept Statistics: "
                + ", ".join(name for name, s in METHODS.items() if s.data == "statistics")
            )
        data = FitInput(samples, None)
    else:
        # Validated in the caller's dtype: float32 (or integer) samples are converted to float64 a chunk
        # at a time by Statistics, and whole only for the methods that iterate over the samples.
        array = check_shape(samples)
        check_finite(array)
        if spec.data == "samples":
            array = np.asarray(array, dtype=np.float64)
        data = FitInput(Statistics.from_samples(array), array)
    check_support(data.statistics, spec.name, spec.min_samples)
    for check in spec.checks:
        check(data.statistics, spec.name)
    calibration = spec.function(data, **options)
    if not diagnostics:
        return calibration
    from .diagnostics import attach_diagnostics  # lazy: the diagnostics import the methods

    return attach_diagnostics(calibration, data.samples, data.statistics)
