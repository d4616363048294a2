"""The reference field: the field expected at each sample in the vehicle frame (the Earth's field rotated by the
vehicle's attitude), checked, interpolated in time, and the design ``[r, 1]`` of (1) of :mod:`.method`.

A gyro given beside it is checked against it: a fixed field seen from the turning vehicle turns as
``ṙ = r × ω``, so a gyro that predicts ``ṙ`` far better divided by 57.3 is in degrees per second, and times
that let it predict far better divided by 1000 are milliseconds (:func:`_check_rate_units`).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..._validation import check_rows
from ...errors import OptionError
from ...timeunits import time_readings

#: A reading of the gyro's or the time's unit is refused when it leaves this share of the given one's residual.
READING_GAIN = 0.25


def _reference_array(reference: Any, n: int) -> NDArray[np.float64]:
    if reference is None:
        raise OptionError(
            "method 'vector' needs reference=: the field expected at each sample in the vehicle frame, an (N, 3) "
            "array in the samples' unit (the Earth's field rotated by each sample's attitude)"
        )
    if isinstance(reference, str):  # what a refit finds recorded: the reference itself is not kept
        raise OptionError(
            "a vector calibration is refitted only with a new reference: call magfit.fit(samples, method='vector', "
            "reference=...) with the field expected at each new sample"
        )
    return check_rows(reference, "reference", n, "the field expected at each sample")


def _design(reference: NDArray[np.float64]) -> NDArray[np.float64]:
    return np.column_stack([reference, np.ones(reference.shape[0])])


def _shifted(reference: NDArray[np.float64], time_s: NDArray[np.float64], at: NDArray[np.float64]) -> NDArray[Any]:
    """``reference`` linearly interpolated at the times ``at`` (inside ``time_s``): one search for the 3 axes."""
    index = np.clip(np.searchsorted(time_s, at) - 1, 0, time_s.size - 2)
    weight = ((at - time_s[index]) / (time_s[index + 1] - time_s[index]))[:, None]
    return reference[index] * (1.0 - weight) + reference[index + 1] * weight


def _field(reference: NDArray[np.float64]) -> float:
    """The reference's median magnitude; a reference zero at most samples, or at any, is refused."""
    magnitudes = np.linalg.norm(reference, axis=1)
    field = float(np.median(magnitudes))
    if not field > 0:
        raise OptionError("reference= is zero at most samples: it must be the field expected at each sample")
    if np.any(magnitudes < 1e-6 * field):  # the Earth's field is never zero: a missing attitude written as 0
        row = int(np.argmax(magnitudes < 1e-6 * field))
        raise OptionError(f"reference= is zero in row {row} (0-based): drop the samples without an attitude")
    return field


def _check_rate_units(reference: NDArray[np.float64], time_s: NDArray[np.float64], gyro: NDArray[np.float64]) -> None:
    """A gyro in degrees per second, or times in milliseconds or microseconds: refused with the fix (the
    still-sample gate would read every row as a turn, the lag search would span a thousandth of its seconds).

    The reference, a fixed field seen from the turning vehicle, turns as ``ṙ = r × ω``; each reading of the
    inputs scales the prediction, in the units of the ``ṙ`` given: a gyro in degrees per second by π/180, times
    in milliseconds by 1/1000 (the reference turns a thousandth as much per unit;
    :func:`magfit.timeunits.time_readings`). A reading that predicts ``ṙ`` far better than the one given
    (:data:`READING_GAIN`) is refused with its own code, ``gyro_unit`` or ``time_unit`` (the test of
    :func:`magfit.methods.gyro`'s readings, on the reference instead of the samples). A vehicle that never turns
    fits all alike.
    """
    rate = np.gradient(reference, time_s, axis=0)
    predicted = np.cross(reference, gyro)
    given = float(np.sum((rate - predicted) ** 2))
    readings: list[tuple[float, str, str, tuple[tuple[str, str], ...]]] = [(
        float(np.sum((rate - (math.pi / 180.0) * predicted) ** 2)), "gyro_unit",
        "gyro= looks like degrees per second (the reference turns as it predicts {gain:.0f} times better after "
        "dividing it by 57.3): give it in rad/s (numpy.radians(gyro))", (("gyro", "numpy.radians(gyro)"),),
    )]  # fmt: skip
    step = float(np.median(np.diff(time_s)))
    for reading in time_readings(time_s):
        readings.append((
            float(np.sum((rate - reading.factor * predicted) ** 2)), "time_unit",
            reading.words("time_s=", step) + " (the gyro predicts the reference's turning {gain:.0f} times better so)",
            (("time_s", f"time_s / {reading.divisor}"),),
        ))  # fmt: skip
    rss, code, words, remedy = min(readings, key=lambda item: item[0])
    if rss < READING_GAIN * given:
        raise OptionError(words.format(gain=given / max(rss, 1e-300)), codes=(code,), remedy=remedy)
