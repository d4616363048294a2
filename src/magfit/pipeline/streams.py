"""What a log holds beside a compass, as the options of the methods that need it (``vector``, ``gyro``).

A magnitude-only method needs the samples alone. ``vector`` needs the field expected at each sample in the
vehicle frame: the Earth's field from the World Magnetic Model at the log's own place and date, turned into
the body frame by the logged attitude (``reference = attitudeᵀ · (north, east, down)``, in the samples'
unit). ``gyro`` needs the body rates and the time stamps. :func:`method_streams` reads them once through
:meth:`magfit.sources.Source.read_motion` (which puts every stream on the magnetometer's stamps) and says in
words what is missing and how to log it.

Both methods also *take* the accelerometer (``accel=``, optional): where the vehicle is still or slow it
sees gravity alone, which pins the tilt of the mounting better than the attitude the estimator logs
(``vector`` takes the gyro too, optional, to find those samples). :func:`stream_names` says which streams
methods need and which they only take (those their signature has); the latter are given when the log has
them, never a reason to refuse. It is given only in the frame the
method expects: ``vector`` compares the samples with a reference in the body frame of the *attitude*, and
``gyro`` relates them to the *gyroscope's* axes, so the accelerometer's frame must be that one (the logs
give the rotated, calibrated IMU in the body frame: ArduPilot's IMU, PX4's ``sensor_combined``; PX4's raw
``sensor_accel`` is in the board's frame before ``SENS_BOARD_ROT`` and is left out for ``vector``). A log
without an accelerometer is no error: the methods run without it, and the notes say so.
"""

from __future__ import annotations

import datetime
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from ..errors import DataFileError, OptionError
from ..methods import get_method
from ..remedy import option
from ..sources import Source
from ..units import get_unit

__all__ = ["OPTIONAL_STREAMS", "MethodStreams", "StreamNames", "method_streams", "stream_names"]

#: Streams a method may take beside those it needs: read from the log for a method whose options include them,
#: and never a reason to refuse (a log without them is fitted without them). ``time_s``: vector estimates the
#: attitude's lag behind the samples from the stamps; ``gyro``: vector's still-sample gate.
OPTIONAL_STREAMS = ("time_s", "gyro", "accel", "inclination_deg")


class StreamNames(NamedTuple):
    """The log's streams some methods need (``needed``) and those they only take (``optional``)."""

    needed: tuple[str, ...]
    optional: tuple[str, ...]


def stream_names(methods: Sequence[str]) -> StreamNames:
    """The streams to read from a log for ``methods``: what each needs, and the optional streams it takes.

    Only a method that needs a stream of the log (``vector``, ``gyro``) gets the optional ones: a
    magnitude-only method reads the samples alone. A stream one method needs is needed, whoever else only
    takes it.
    """
    needed: dict[str, None] = {}
    optional: dict[str, None] = {}
    for method in methods:
        spec = get_method(method)
        if not spec.needs:
            continue
        needed.update(dict.fromkeys(spec.needs))
        optional.update(dict.fromkeys(stream for stream in OPTIONAL_STREAMS if stream in spec.options))
    return StreamNames(tuple(needed), tuple(name for name in optional if name not in needed))


@dataclass(frozen=True)
class MethodStreams:
    """The samples of one compass with the streams a method needs, all on the compass's time stamps.

    Attributes
    ----------
    samples : ndarray, shape (N, 3)
        The compass's samples kept (those the other streams cover).
    options : dict
        ``reference``, ``gyro``, ``time_s`` and ``accel`` as the methods take them (only those asked for, and
        ``accel`` only where the log has it in the frame the methods expect).
    sensor_details : dict
        What the exports need to know of the frame of the samples (``applied_rotation`` when the firmware
        had already turned them into the body frame: ArduPilot's MAG after ``COMPASS_ORIENT``).
    notes : tuple of str
        Where each stream came from, what was dropped, the model's field used.
    """

    samples: NDArray[np.float64]
    options: dict[str, Any]
    sensor_details: dict[str, Any]
    notes: tuple[str, ...]


def method_streams(
    source: Source,
    sensor: str,
    needs: Sequence[str],
    *,
    optional: Sequence[str] = (),
    unit: str | None,
    date: datetime.date | str | None = None,
    available: bool = False,
    gyro_own_rate: bool = False,
    reference_ned: NDArray[np.float64] | None = None,
) -> MethodStreams:
    """Read ``sensor``'s samples with the streams ``needs`` names (``reference``, ``gyro``, ``time_s``) and
    those of ``optional`` the log holds (``time_s``, ``gyro``, ``accel``; :func:`stream_names` gives both for
    some methods).

    ``available``: give the streams the log holds and say in ``notes`` why the others are missing (a
    comparison of several methods runs those it can), instead of raising. ``gyro_own_rate``: for one method
    that takes ``gyro_time_s`` (``gyro``), the gyroscope at its own stamps (``gyro`` then has its own rows)
    where it is logged faster than the compass; a comparison shares one ``gyro`` on the compass's stamps.
    ``inclination_deg`` is the World Magnetic Model's at the log's fixes (the accelerometer's check of
    ``gyro``). An optional stream is never a reason to raise: missing, or (``accel``) in another frame than the
    attitude's (``reference``) or the gyroscope's (``gyro``) it is used with, it is left out and the notes say
    why.

    Raises
    ------
    DataFileError
        The log lacks a stream that is needed (no attitude, no gyroscope, no GNSS fix for the model's
        field), with what to log.
    OptionError
        The samples' unit is not physical (raw counts): the model's field cannot be put in it.
    """
    motion = source.read_motion(sensor)
    # A samples file's compass is its three columns (its id "columns" alone would say nothing): named by them.
    named = next((m.description for m in source.magnetometers if m.id == sensor and m.id == "columns"), None)
    where = f"{source.path} ({sensor} {named})" if named else f"{source.path} ({sensor})"
    options: dict[str, Any] = {}
    notes = [f"{where}: {note}" for note in motion.notes]
    wanted = (*needs, *optional)
    if "time_s" in wanted:
        options["time_s"] = motion.time_s
    try:
        if "gyro" in needs:
            if motion.gyro is None and source.kind == "samples":
                raise DataFileError(
                    f"{where}: the file holds no gyroscope columns beside the magnetometer (gx, gy, gz, gyro_x ...); "
                    f"the gyro method needs them, in rad/s (name them with {option('gyro', '...')})"
                )
            if motion.gyro is None:
                raise DataFileError(
                    f"{where}: the log holds no gyroscope beside this compass; the gyro method needs one (log the "
                    "IMU: ArduPilot LOG_BITMASK's IMU bit, PX4's sensor_combined or vehicle_angular_velocity)"
                )
            options["gyro"] = motion.gyro
    except DataFileError as error:
        if not available:
            raise
        notes.append(str(error))
    try:
        if "reference" in needs:
            options["reference"] = _reference(source, motion, where, unit, date, notes, reference_ned)
    except (DataFileError, OptionError) as error:
        if not available:
            raise
        notes.append(str(error))
    if "down" in needs and motion.attitude is not None:  # tilt: the vertical from roll and pitch (yaw unused)
        options["down"] = np.asarray(motion.attitude)[:, 2, :]
    if "accel" in wanted:
        accel, said = _accel(motion, wanted)
        if source.kind == "samples" and accel is None:
            said = "no accelerometer columns beside the magnetometer: the methods run without it (gravity not used)"
        notes.append(f"{where}: {said}")
        if accel is not None:
            options["accel"] = accel
    # A gyro only taken (vector's) finds where the accelerometer sees gravity alone: useless, and refused by
    # vector, without the accelerometer.
    if "gyro" in optional and "gyro" not in needs and "accel" in options:
        if motion.gyro is not None:
            options["gyro"] = motion.gyro
        else:
            notes.append(f"{where}: no gyroscope beside this compass: the methods that only take one run without it")
    if gyro_own_rate and "gyro" in options and motion.gyro_stream is not None and len(motion.time_s) > 1:
        own = motion.gyro_stream
        faster = np.median(np.diff(motion.time_s)) / max(float(np.median(np.diff(own.time_s))), 1e-12)
        if faster >= 1.5:  # integrated at its own rate: what happens between two compass samples counts
            options["gyro"], options["gyro_time_s"] = own.values, own.time_s
            notes.append(f"{where}: the gyroscope at its own rate ({faster:.1f}x the compass's), integrated in between")
    if "inclination_deg" in wanted:
        inclination, said = _inclination(source, motion, date)
        notes.append(f"{where}: {said}")
        if inclination is not None:
            options["inclination_deg"] = inclination
    details: dict[str, Any] = {}
    if motion.magnetometer_frame == "body" and motion.mounting is not None:
        details["applied_rotation"] = np.asarray(motion.mounting).tolist()
    return MethodStreams(np.asarray(motion.samples), options, details, tuple(notes))


def _inclination(source: Source, motion: Any, date: datetime.date | str | None) -> tuple[float | None, str]:
    """The World Magnetic Model's inclination at the log's fixes, and a note; None where it cannot be known."""
    position = motion.position or source.position
    if position is None:
        return None, "no GNSS fix: the accelerometer is not checked against the model's inclination"
    from ..errors import MagfitError
    from ..geomag import field_at

    try:
        field = field_at(position.lat_deg, position.lon_deg, position.alt_km, date=date or motion.date)
    except MagfitError as error:  # the wmm extra missing, a date out of the model's range
        return None, f"the accelerometer is not checked against the model's inclination: {error}"
    said = f"inclination {field.inclination_deg:.1f}° ({field.describe()}), the accelerometer's check"
    return field.inclination_deg, said


def _reference(
    source: Source,
    motion: Any,
    where: str,
    unit: str | None,
    date: datetime.date | str | None,
    notes: list[str],
    reference_ned: NDArray[np.float64] | None = None,
) -> NDArray[np.float64]:
    """The model's field (or ``reference_ned``, row by row) turned into the body frame at each sample:
    ``attitudeᵀ · (N, E, D)``."""
    from ..geomag import field_at

    if motion.attitude is None and source.kind == "samples":
        raise DataFileError(
            f"{where}: the file holds no attitude columns beside the magnetometer (roll, pitch, yaw or qw, qx, qy, "
            f"qz); the vector method needs them (name them with {option('attitude', '...')})"
        )
    if motion.attitude is None:
        raise DataFileError(
            f"{where}: the log holds no attitude beside this compass; the vector method needs one (ArduPilot ATT or "
            "XKQ, PX4 vehicle_attitude, a ROS sensor_msgs/Imu with its orientation)"
        )
    if reference_ned is not None:
        said = f" ({unit})" if unit else " (the samples' unit)"
        notes.append(
            f"{where}: reference field from the file's N/E/D columns{said}, turned into the body frame by the attitude"
        )
        return np.einsum("kji,kj->ki", motion.attitude, reference_ned)
    label = unit or motion.unit
    if not label or not get_unit(label).is_physical:
        raise OptionError(
            f"{where}: the vector method compares the samples with the World Magnetic Model's field, which needs "
            f"their physical unit ({option('unit', 'uT')}, G, mG ...): raw counts have no known scale"
        )
    position = motion.position or source.position
    if position is None and source.kind == "samples":
        raise DataFileError(
            f"{where}: the file holds neither the reference field's N/E/D columns nor latitude and longitude "
            "columns, and no location was given: the vector method needs the field at each sample (name the "
            f"reference columns with {option('reference', '...')}, or give {option('location', 'LAT,LON[,ALT]')})"
        )
    if position is None:
        raise DataFileError(
            f"{where}: the log holds no 3-D GNSS fix, so the World Magnetic Model's field there is not known; the "
            "vector method needs it (log the GPS, or fit a magnitude-only method)"
        )
    when = date or motion.date
    field = field_at(position.lat_deg, position.lon_deg, position.alt_km, date=when)
    notes.append(
        f"{where}: reference field {field.describe()}: {field.total_in(label):.6g} {label}, inclination "
        f"{field.inclination_deg:.1f}°, declination {field.declination_deg:.1f}°, turned into the body frame by the "
        f"logged attitude ({(motion.sources or {}).get('attitude', 'attitude')})"
    )
    return np.einsum("kji,j->ki", motion.attitude, field.vector_in(label))


def _frame_name(frame: str) -> str:
    """A stream's frame without its remarks: ``body (FRD), bias removed`` and ``body (FRD)`` are both the body
    frame; PX4's raw ``sensor (before SENS_BOARD_ROT and the gyro calibration)`` is the board's ``sensor`` frame;
    a ROS frame (``frame_id imu_link (REP-103 ...)``) is its frame_id."""
    return frame.split(" (")[0].split(",")[0].strip()


def _accel(motion: Any, needs: Sequence[str]) -> tuple[NDArray[np.float64] | None, str]:
    """The accelerometer for the methods ``needs`` serves, when it is in the frame they expect, and a note."""
    if motion.accel is None:
        return None, "no accelerometer beside this compass: the methods run without it (gravity not used)"
    frames = motion.frames or {}
    came = (motion.sources or {}).get("accel", "the accelerometer")
    mine = _frame_name(frames.get("accel", ""))
    # vector's reference is in the attitude's body frame; gyro's rates in the gyroscope's: the accelerometer
    # must be in the frame of each stream it is used with.
    wanted = {"reference": "attitude", "gyro": "gyro"}
    for need, stream in wanted.items():
        if need in needs and stream in frames and _frame_name(frames[stream]) != mine:
            return None, (
                f"accelerometer {came} left out: it is in the {frames['accel']} frame, the {stream} in the "
                f"{frames[stream]} frame (the methods run without it; log the rotated IMU: ArduPilot's IMU, PX4's "
                "sensor_combined)"
            )
    frame = frames.get("accel", "IMU")
    return np.asarray(motion.accel), f"accelerometer: {came}, m/s² in the {frame} frame, given to the fit (gravity)"
