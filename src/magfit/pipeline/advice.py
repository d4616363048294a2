"""What to run instead, as data: remedies (``(argument, value)`` pairs, :class:`magfit.findings.Reason`'s
``remedy``) rendered as the Python call here (:func:`python_call`) and as the command line by the CLI.

:func:`vehicle_advice`: for a recording that looks like a vehicle's (a flight log, or samples that turn
about one axis more than they tilt: level with turns), the methods that work for it: ``vector`` with the
file's or log's attitude and reference field, ``tilt`` with its roll and pitch where it has an attitude (its
yaw may be steered by the compass being calibrated), ``gyro`` with its gyroscope, and, unless the samples lie on
a circle (level turns only: :func:`level_only`), the sphere pinned to the known field. Never only "tumble it": a
vehicle cannot.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from ..errors import CalibrationError, OptionError
from ..findings import Reason
from ..remedy import STREAM_ARGUMENTS, python_call

__all__ = [
    "STREAM_ARGUMENTS",
    "RefusedWithAdvice",
    "StreamsMissing",
    "level_only",
    "looks_like_vehicle",
    "python_call",
    "vehicle_advice",
]

#: Samples whose smallest principal spread is below this share of their largest turned about one axis
#: mostly (level with turns, a car, a boat): a vehicle's.
LEVEL_SHARE = 0.35
#: Samples whose largest spread is below this share of the field's strength did not turn.
TURNED_SHARE = 0.05


class RefusedWithAdvice(CalibrationError):
    """A refusal of a vehicle's recording, with the methods that work for it (:func:`vehicle_advice`).

    ``text`` is the refusal; ``advice`` the reasons with their remedies; the message adds each as a Python
    call, the command line renders its own.
    """

    def __init__(self, path: Path, text: str, advice: tuple[Reason, ...], codes: tuple[str, ...] = ()) -> None:
        self.path = path
        self.text = text
        self.advice = advice
        said = "; ".join(f"{reason} ({python_call(path, reason.remedy)})" for reason in advice)
        super().__init__(f"{text}; what works for a vehicle: {said}" if advice else text, codes=codes)


class StreamsMissing(OptionError):
    """A method needs a stream the samples file does not hold (or holds under names not recognised).

    ``text`` says what is missing; ``remedy`` is the call that would run, as ``(argument, value)`` pairs; the
    message adds the Python call, the command line renders its own from ``remedy``.
    """

    def __init__(self, path: Path, text: str, remedy: tuple[tuple[str, str], ...]) -> None:
        self.path = path
        self.text = text
        super().__init__(f"{text}; from Python: {python_call(path, remedy)}", remedy=remedy)


def looks_like_vehicle(covariance: NDArray[np.float64], mean_square: float) -> bool:
    """Whether samples of this covariance (3, 3) and mean square norm turned, and mostly about one axis (a
    small share of spread across the plane the field turns in): level with turns, as a vehicle moves; a tumble
    spreads in every direction."""
    spreads = np.sqrt(np.maximum(np.linalg.eigvalsh(covariance), 0.0))
    return bool(_turned(spreads[-1], mean_square) and spreads[0] < LEVEL_SHARE * spreads[-1])


def turned(samples: NDArray[np.float64]) -> bool:
    """Whether the field turned in the sensor at all (a spread beyond :data:`TURNED_SHARE` of its strength): a
    sensor never turned (or never read) is helped by no method, only by recording again."""
    finite = samples[np.all(np.isfinite(samples), axis=1)]
    if len(finite) < 10:
        return False
    largest = float(np.sqrt(max(float(np.max(np.linalg.eigvalsh(np.cov(finite.T)))), 0.0)))
    return _turned(largest, float(np.mean(np.sum(finite**2, axis=1))))


def _turned(largest_spread: float, mean_square: float) -> bool:
    return bool(largest_spread > TURNED_SHARE * np.sqrt(max(mean_square, 0.0)))


#: Samples whose smallest principal spread is below this share of their largest lie on a circle: level turns,
#: tilted less than a few degrees (a tilt of ±δ spreads the field's horizontal part H by about H sin δ across the
#: circle's plane; ±6° on the campaign's level flights is 0.1 of the spread in the plane).
LEVEL_ONLY_SHARE = 0.05


def level_only(covariance: NDArray[np.float64]) -> bool:
    """Whether samples of this covariance (3, 3) lie on a circle (:data:`LEVEL_ONLY_SHARE`): level turns only.

    A sphere of a known radius B through a circle of radius ρ has its centre on the circle's axis at
    ``±√(B² − ρ²)`` from its plane: two offsets fit the samples alike, so the sphere pinned to the field
    strength cannot calibrate them (:func:`magfit.diagnostics.verdict.mirrored_offset`).
    """
    spreads = np.sqrt(np.maximum(np.linalg.eigvalsh(covariance), 0.0))
    return bool(spreads[0] < LEVEL_ONLY_SHARE * spreads[-1])


def vehicle_advice(
    path: Path,
    *,
    is_log: bool,
    streams: Sequence[str],
    unit: str | None,
    method: str,
    sensor: str | None = None,
    level: bool = False,
) -> tuple[Reason, ...]:
    """The methods that work for a vehicle's recording, each a :class:`Reason` with its remedy (the arguments
    of :func:`magfit.calibrate_file` / the command line's options). ``streams``: those the file or log holds
    (``attitude``, ``reference``, ``place``, ``gyro``, ``time``); ``sensor``: the log's compass, named in
    each remedy (a log holding several); ``level``: the samples lie on a circle (:func:`level_only`), where the
    sphere pinned to the field strength has two solutions and is not named."""
    advice = [
        Reason(reason.text, reason.code, reason.remedy + ((("sensor", sensor),) if sensor is not None else ()))
        for reason in _advice(is_log=is_log, streams=streams, unit=unit, method=method, level=level)
    ]
    return tuple(advice)


def _advice(*, is_log: bool, streams: Sequence[str], unit: str | None, method: str, level: bool) -> list[Reason]:
    advice = []
    physical = unit not in (None, "", "counts")
    unit_pair = (("unit", unit or "UNIT"),)  # the samples' unit: the user's, or a place to give it
    if method != "vector":
        if is_log:
            advice.append(Reason(
                "the log's attitude and GNSS give the field expected at each sample (the vector method)",
                "vehicle_methods", (("method", "vector"),),
            ))  # fmt: skip
        else:
            remedy: list[tuple[str, str]] = [("method", "vector")]
            if "attitude" not in streams:
                remedy.append(("attitude", "ROLL,PITCH,YAW"))
            if "reference" not in streams and "place" not in streams:
                remedy += [("reference", "N,E,D")]
            advice.append(Reason(
                "the vehicle's attitude with the reference field (its N/E/D columns, or the World Magnetic Model at "
                "the place) gives the field expected at each sample (the vector method)",
                "vehicle_methods", (*remedy, *unit_pair),
            ))  # fmt: skip
    if method != "tilt" and "attitude" in streams:  # roll and pitch logged: the yaw need not be trusted
        remedy = [("method", "tilt")]
        if not is_log and "reference" not in streams and "place" not in streams:
            remedy.append(("reference", "N,E,D"))
        advice.append(Reason(
            "the logged roll and pitch with the reference field's horizontal strength and vertical component, the "
            "yaw left free (the tilt method): for a recording whose logged heading is suspect (an estimator that "
            "steers it by this compass)",
            "vehicle_methods", (*remedy, *(unit_pair if not is_log else ())),
        ))  # fmt: skip
    if method != "gyro":
        remedy = [("method", "gyro")]
        if not is_log and "gyro" not in streams:
            remedy.append(("gyro", "GX,GY,GZ"))
        if not is_log and "time" not in streams:
            remedy.append(("time", "TIME"))
        advice.append(Reason(
            "the gyroscope's rates pin the distortion the turns cannot (the gyro method, rates in rad/s)",
            "vehicle_methods", tuple(remedy),
        ))  # fmt: skip
    # Not on level turns only: the field strength fixes the size of the field's vertical part, not its sign, and
    # the offset along the turning axis has two values that fit alike (level_only).
    if not level and (unit is None or unit == "" or physical):  # a physical field strength: raw counts have none
        remedy = [("method", "sphere"), ("field_strength", "wmm")]
        if not is_log:
            remedy += [("location", "LAT,LON,ALT_KM"), *unit_pair]
        advice.append(Reason(
            "the sphere pinned to the World Magnetic Model's field strength: offsets only, where the vehicle also "
            "banked or pitched (a few tens of degrees); on level turns only the offset along the turning axis has "
            "two values the field strength cannot choose between", "vehicle_methods", tuple(remedy),
        ))  # fmt: skip
    return advice
