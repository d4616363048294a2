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
import math
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
#: The accelerometer's mean vertical component in the attitude's world (north-east-down), as a share of its
#: mean magnitude, from which the world is upside down (:func:`_check_attitude_up`): at rest it is −1, a ROS
#: attitude read as NED +1; a vehicle's own accelerations average out over a recording.
UPSIDE_DOWN = 0.5
#: The widest declination (degrees, absolute) of the Earth's field where its inclination is shallower than the
#: first figure (degrees, absolute): the World Magnetic Model 2025 on a 2° x 4° grid at sea level (the figures:
#: docs/methods.md, "vector"); steeper than 70° any declination occurs (near the magnetic poles).
EARTH_DECLINATION = ((50.0, 24.3), (55.0, 27.2), (60.0, 47.1), (65.0, 61.0), (70.0, 79.2))
#: Degrees added to those for the years the model drifts and the grid's coarseness.
DECLINATION_MARGIN = 10.0
#: What a samples file's attitude read in ROS's convention says of its frame (``Motion.frames``), by which the
#: check names the other convention.
ENU_MARK = "from ENU"


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
    upside_down = False
    if "reference" in needs or "down" in needs:  # the attitude's world must be the accelerometer's
        try:
            _check_attitude_up(source, motion, where)
        except (DataFileError, OptionError) as error:
            if not available:
                raise
            notes.append(str(error))
            upside_down = True  # a comparison runs the methods that do not read the attitude
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
        if "reference" in needs and not upside_down:
            options["reference"] = _reference(source, motion, where, unit, date, notes, reference_ned)
    except (DataFileError, OptionError) as error:
        if not available:
            raise
        notes.append(str(error))
    if "down" in needs and motion.attitude is not None and not upside_down:  # tilt: the vertical, roll and pitch
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


def _check_attitude_up(source: Source, motion: Any, where: str) -> None:
    """Refuses an attitude whose world is upside down against the accelerometer's gravity.

    At rest the accelerometer reads the specific force ``−g``, up; turned into the world frame by the
    attitude, ``f = R a`` (:math:`R` body to NED), its mean over the recording is ``(0, 0, −g)``: the
    vehicle's own accelerations average out, gravity does not. A ROS attitude (body forward-left-up to
    East-North-Up) read as NED is ``T R F`` with the world turned 180° about the north-east diagonal (``T``),
    which turns that mean to ``(0, 0, +g)``: the reference is turned with it when it comes from the same
    file, so the fit against it is exact, but into the forward-left-up body frame, its heading mirrored in
    the north-east-down frames of the exports and the firmwares (docs/methods.md, "vector", the attitude's
    convention). The same mean, the other way round, betrays NED data read as ENU, and an accelerometer that
    logs gravity instead of the specific force; the check cannot tell these apart and names them all. It is
    made only where the accelerometer is in the attitude's body frame, and decides only a mean at least
    :data:`UPSIDE_DOWN` of the mean ``|a|`` along the vertical: a mean between (an accelerometer in another
    frame, a vehicle that never settles) is left to the fit.
    """
    if motion.attitude is None or motion.accel is None:
        return
    frames = motion.frames or {}
    if "attitude" in frames and "accel" in frames and _frame_name(frames["attitude"]) != _frame_name(frames["accel"]):
        return
    attitude, accel = np.asarray(motion.attitude), np.asarray(motion.accel)
    good = np.all(np.isfinite(accel), axis=1) & np.all(np.isfinite(attitude), axis=(1, 2))
    if not np.any(good):
        return
    world = np.einsum("kij,kj->i", attitude[good], accel[good]) / int(good.sum())
    size = float(np.mean(np.linalg.norm(accel[good], axis=1)))
    if not (size > 0 and world[2] >= UPSIDE_DOWN * size):
        return
    ratio = world[2] / size
    said = (
        f"{where}: the accelerometer, turned into the world frame by the attitude, reads gravity's specific force "
        f"pointing down (its mean vertical component {ratio:+.2f} of |a| in the north-east-down frame; at rest "
        "it points up, −1): the attitude's world is upside down"
    )
    if source.kind == "samples":
        given = _convention_of(motion)
        other = "ned" if given == "enu" else "enu"
        words = {
            "enu": "ROS's, body forward-left-up to East-North-Up",
            "ned": "body forward-right-down to North-East-Down",
        }
        raise OptionError(
            f"{said}: the attitude and the IMU columns are of the other convention ({words[other]}); give "
            f"{option('attitude_convention', other)} (or, if the accelerometer logs gravity rather than the specific "
            "force, negate its columns)",
            codes=("attitude_convention",),
            remedy=(("attitude_convention", other),),
        )
    raise DataFileError(
        f"{said}: the log's attitude and its accelerometer disagree on up and down (an attitude in another "
        "convention than the reader's, or an accelerometer that logs gravity rather than the specific force); the "
        "attitude-aided methods cannot use it: fit a magnitude-only method, or fix the attitude's convention",
        codes=("attitude_convention",),
    )


def _declination_limit(inclination_deg: float) -> float:
    """The widest declination (degrees) the Earth's field has where its inclination is as steep as
    ``inclination_deg`` or less (:data:`EARTH_DECLINATION`, with :data:`DECLINATION_MARGIN`); 180 beyond."""
    for steepest, widest in EARTH_DECLINATION:
        if abs(inclination_deg) < steepest:
            return widest + DECLINATION_MARGIN
    return 180.0


def _convention_of(motion: Any) -> str:
    """``"enu"`` for a samples file read in ROS's convention (:data:`ENU_MARK`), else ``"ned"``."""
    return "enu" if ENU_MARK in (motion.frames or {}).get("attitude", "") else "ned"


def _unearthly(reference_ned: NDArray[np.float64], given: str = "ned") -> str:
    """A note when the file's reference points where the Earth's field points nowhere: a declination wider than
    any where the inclination is as shallow (:func:`_declination_limit`); with the reading of the columns as
    East-North-Up (a ROS file, the attitude's convention not given) when that one is the Earth's.

    Without an accelerometer nothing else betrays a ROS file read as NED: its reference turns with its attitude,
    and the fit is exact, into the forward-left-up body frame (:func:`_check_attitude_up`)."""
    north, east, down = np.median(reference_ned, axis=0)
    horizontal = float(np.hypot(north, east))
    if not horizontal > 0:
        return ""
    declination = math.degrees(math.atan2(east, north))
    inclination = math.degrees(math.atan2(down, horizontal))
    if abs(declination) <= _declination_limit(inclination):
        return ""
    said = (
        f"the reference field's columns give a declination of {declination:.0f}° at an inclination of "
        f"{inclination:.0f}°: the Earth's field has none wider than {_declination_limit(inclination):.0f}° where it "
        "dips so little (a local world frame, or columns in another order)"
    )
    # The other convention swaps the first two columns and negates the third, both ways round.
    other_declination = (90.0 - declination + 180.0) % 360.0 - 180.0
    if abs(other_declination) <= _declination_limit(-inclination):
        other, words = ("ned", "North, East, Down") if given == "enu" else ("enu", "East, North, Up (ROS's convention)")
        said += (
            f"; read as {words} they give {other_declination:.0f}° and {-inclination:.0f}°: if the file is so, "
            f"give {option('attitude_convention', other)}, or the calibration comes out in a body frame turned 180° "
            "about its forward axis, its heading mirrored"
        )
    return said


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
        doubt = _unearthly(reference_ned, _convention_of(motion))
        if doubt:
            notes.append(f"{where}: {doubt}")
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
