"""Input checks, in one place: every public entry point validates samples through these functions.

Messages say what was received and what to do. Arrays are never transposed behind the user's back:
(3, N) is an error that suggests ``.T``.
"""

from __future__ import annotations

import math
from typing import Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .errors import CalibrationError, OptionError, SampleError


class Moments(Protocol):
    """What :func:`check_support` reads of a :class:`~magfit.Statistics` (this module sits below it)."""

    @property
    def n(self) -> int: ...

    @property
    def mean(self) -> NDArray[np.float64]: ...

    @property
    def scale(self) -> float: ...

    @property
    def scatter(self) -> NDArray[np.float64]: ...


#: Below this ratio of the smallest to the largest spread (standard deviation along the principal
#: directions), the samples are taken to lie on a plane or a line.
FLATNESS_LIMIT = 1e-3
#: Largest magnitude of a sample value: its square, and sums of squares over a chunk, stay finite in float64
#: (1e150² = 1e300). Real magnetometer data in any unit are many orders of magnitude below.
MAX_MAGNITUDE = 1e150
#: Samples spread less than this many ulps of their magnitude are identical: float64 cannot tell them apart.
IDENTICAL_ULPS = 16
#: Spreads (standard deviation along the widest direction, input units) the fits are tested over. The
#: ellipsoid matrix scales as 1/spread² and its determinant as 1/spread⁶, which leaves float64 beyond about
#: 1e±50; the limits keep ten orders of magnitude of margin. Real recordings, in any unit, lie far inside.
SPREAD_RANGE = (1e-40, 1e40)
_AXIS_NAMES = ("x", "y", "z")


def check_shape(samples: ArrayLike) -> NDArray[np.generic]:
    """Return ``samples`` as a numeric (N, 3) array without copying when possible."""
    try:
        array = np.asarray(samples)
    except (TypeError, ValueError) as error:
        raise SampleError(f"samples cannot be read as a numeric array: {error}") from None
    if array.dtype == object or not (np.issubdtype(array.dtype, np.floating) or np.issubdtype(array.dtype, np.integer)):
        raise SampleError(f"samples must be numbers, got an array of dtype {array.dtype}")
    if array.ndim != 2 or array.shape[1] != 3:
        hint = "rows are samples, columns are x, y, z"
        if array.ndim == 2 and array.shape[0] == 3:
            hint = "it looks like one sample per column: pass samples.T"
        elif array.ndim == 1 and array.shape[0] == 3:
            hint = "a single sample needs shape (1, 3): use samples[None, :]"
        raise SampleError(f"samples must have shape (N, 3), got shape {array.shape}; {hint}")
    return array


def check_finite(array: NDArray[np.generic], first_row: int = 0) -> None:
    """Raise if any value is NaN or infinite, naming the first bad row."""
    finite = np.isfinite(array)
    if not finite.all():
        bad_rows = np.flatnonzero(~finite.all(axis=1))
        raise SampleError(
            f"samples contain NaN or inf in {bad_rows.size} row(s), the first is row {first_row + bad_rows[0]}; "
            "drop them first, e.g. samples[np.isfinite(samples).all(axis=1)]"
        )


def check_magnitude(array: NDArray[np.generic], first_row: int = 0) -> None:
    """Raise if any value of a finite (N, 3) array exceeds :data:`MAX_MAGNITUDE`, naming the first row.

    Checked where samples enter (every update of a Statistics), so that whether such a value is refused
    never depends on how the samples were split into chunks.
    """
    too_large = np.abs(array) > MAX_MAGNITUDE
    if too_large.any():
        rows = np.flatnonzero(too_large.any(axis=1))
        value = float(np.asarray(array)[rows[0]][np.argmax(too_large[rows[0]])])
        raise SampleError(
            f"samples contain values beyond ±{MAX_MAGNITUDE:g} in {rows.size} row(s), the first is row "
            f"{first_row + rows[0]} ({value:.3g}); magfit computes with their squares, which float64 cannot hold: "
            "rescale the samples (e.g. to µT or counts) or drop those rows"
        )


def as_samples(samples: ArrayLike) -> NDArray[np.float64]:
    """Validate and return an (N, 3) float64 array."""
    array = np.asarray(check_shape(samples), dtype=np.float64)
    check_finite(array)
    return array


def check_support(statistics: Moments, method: str, min_samples: int) -> None:
    """Raise :class:`CalibrationError` when the samples cannot support a fit of ``method``.

    Checks, in order: enough samples, not all identical, a spread within :data:`SPREAD_RANGE` (else a
    :class:`SampleError`: the samples need rescaling), spread over three dimensions.
    """
    n = statistics.n
    if n < min_samples:
        raise CalibrationError(
            f"method {method!r} needs at least {min_samples} samples, got {n}; "
            "record more while turning the sensor in all directions",
            codes=("too_few_samples",),
        )
    # The covariance in the normalised frame (unit = the samples' RMS spread): in input units its entries,
    # squares of the spread, would underflow for tiny samples (1e-200) and call them identical.
    scatter = statistics.scatter
    first = scatter[6:9, 9] / n
    spreads_squared, directions = np.linalg.eigh(scatter[6:9, 6:9] / n - np.outer(first, first))
    spreads = np.sqrt(np.clip(spreads_squared, 0.0, None)) * statistics.scale
    largest = spreads[-1]
    # Identical up to float64's resolution at their magnitude (x near 1e15 varying by ±200 is not identical).
    resolution = IDENTICAL_ULPS * np.finfo(np.float64).eps * float(np.max(np.abs(statistics.mean)))
    if not largest > resolution:
        raise CalibrationError(
            f"all {n} samples are identical ({_format_vector(statistics.mean)}): the sensor was not turned "
            "or not read; record while rotating it",
            codes=("no_ellipsoid",),
        )
    low, high = SPREAD_RANGE
    if not low <= largest <= high:
        exponent = 2 - round(math.log10(largest))  # a factor that brings the spread to about 100
        raise SampleError(
            f"the samples spread {largest:.3g} (input units), outside the {low:g} to {high:g} magfit fits in float64; "
            f"rescale them (e.g. multiply by 1e{exponent}) and scale the calibration back"
        )
    if spreads[1] < FLATNESS_LIMIT * largest:
        raise CalibrationError(
            f"the samples lie on a line along {_format_direction(directions[:, 2])}: they do not span three "
            "dimensions; rotate the sensor about more axes",
            codes=("single_axis",),
        )
    if spreads[0] < FLATNESS_LIMIT * largest:
        raise CalibrationError(
            f"the samples lie in a plane: nothing varies along {_format_direction(directions[:, 0])}, so the "
            "data do not span three dimensions; tilt the sensor so that this direction is also covered "
            "(a full tumble is best)",
            codes=("single_axis",),
        )


def _format_vector(vector: NDArray[np.float64]) -> str:
    return "(" + ", ".join(f"{value:.6g}" for value in vector) + ")"


def _format_direction(direction: NDArray[np.float64]) -> str:
    """Name a unit direction, by its sensor axis when it is (nearly) one."""
    direction = direction / np.linalg.norm(direction)
    axis = int(np.argmax(np.abs(direction)))
    if abs(direction[axis]) > 0.99:
        return f"the sensor {_AXIS_NAMES[axis]} axis"
    direction = direction * np.sign(direction[axis])
    return "direction (" + ", ".join(f"{value:+.2f}" for value in direction) + ")"


def check_choice(option: str, value: object, choices: tuple[str, ...]) -> None:
    """Raise an :class:`OptionError` when ``value`` is not one of ``choices``."""
    if value not in choices:
        raise OptionError(f"{option}={value!r} is not valid; choose one of: {', '.join(choices)}")


def check_rows(value: object, name: str, n: int, what: str) -> NDArray[np.float64]:
    """``name=`` as an (n, 3) float array, one finite row per sample (``what`` says what the rows are); a
    one-line :class:`OptionError` naming what is wrong (the streams ``vector`` and ``gyro`` take)."""
    try:
        array = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise OptionError(f"{name}= must be an (N, 3) array of numbers ({what}), got {type(value).__name__}") from None
    if array.shape != (n, 3):
        raise OptionError(
            f"{name}= must have one row (x, y, z) per sample, shape ({n}, 3) ({what}); got shape {array.shape}"
            + ("; transpose it" if array.shape == (3, n) else "")
        )
    bad = ~np.all(np.isfinite(array), axis=1)
    if bad.any():
        raise OptionError(f"{name}= has NaN or inf in row {int(np.argmax(bad))} (0-based); drop or fill those rows")
    return array


def check_times(value: object, name: str, n: int) -> NDArray[np.float64]:
    """``name=`` as (n,) finite seconds that increase strictly; a one-line :class:`OptionError` otherwise."""
    try:
        array = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise OptionError(f"{name}= must be an array of seconds, got {type(value).__name__}") from None
    if array.shape != (n,):
        raise OptionError(f"{name}= must have one time per sample, shape ({n},); got shape {array.shape}")
    if not np.all(np.isfinite(array)):
        raise OptionError(f"{name}= has NaN or inf in row {int(np.argmax(~np.isfinite(array)))} (0-based)")
    steps = np.diff(array)
    if np.any(steps <= 0):
        row = int(np.argmax(steps <= 0)) + 1
        raise OptionError(
            f"{name}= must increase strictly: row {row} (0-based) is {array[row]:g} s after {array[row - 1]:g} s; "
            "sort the samples by time and drop repeated ones"
        )
    return array


def check_inclination(value: object, name: str = "inclination_deg") -> float:
    """The field's inclination (dip), degrees, strictly inside (−90, 90); a one-line :class:`OptionError` if not.

    At ±90° the field lies along gravity: its horizontal part, which the heading is read from, is zero, so no
    calibration against it can fix a heading.
    """
    try:
        dip = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        dip = math.nan
    if not -90.0 < dip < 90.0:  # NaN fails too
        raise OptionError(
            f"{name} must be the field's dip in degrees within ±90 (not ±90 itself: a vertical field gives no "
            f"heading), got {value!r}"
        )
    return dip
