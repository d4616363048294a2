"""What a log holds beside a compass, as the options of the methods that need it (``vector``, ``gyro``).

A magnitude-only method needs the samples alone. ``vector`` needs the field expected at each sample in the
vehicle frame: the Earth's field from the World Magnetic Model at the log's own place and date, turned into
the body frame by the logged attitude (``reference = attitudeᵀ · (north, east, down)``, in the samples'
unit). ``gyro`` needs the body rates and the time stamps. :func:`method_streams` reads them once through
:meth:`magfit.sources.Source.read_motion` (which puts every stream on the magnetometer's stamps) and says in
words what is missing and how to log it.
"""

from __future__ import annotations

import datetime
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..errors import DataFileError, OptionError
from ..sources import Source
from ..units import get_unit

__all__ = ["MethodStreams", "method_streams"]


@dataclass(frozen=True)
class MethodStreams:
    """The samples of one compass with the streams a method needs, all on the compass's time stamps.

    Attributes
    ----------
    samples : ndarray, shape (N, 3)
        The compass's samples kept (those the other streams cover).
    options : dict
        ``reference``, ``gyro`` and ``time_s`` as the methods take them (only those asked for).
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
    unit: str | None,
    date: datetime.date | str | None = None,
    available: bool = False,
) -> MethodStreams:
    """Read ``sensor``'s samples with the streams ``needs`` names (``reference``, ``gyro``, ``time_s``).

    ``available``: give the streams the log holds and say in ``notes`` why the others are missing (a
    comparison of several methods runs those it can), instead of raising.

    Raises
    ------
    DataFileError
        The log lacks a stream that is needed (no attitude, no gyroscope, no GNSS fix for the model's
        field), with what to log.
    OptionError
        The samples' unit is not physical (raw counts): the model's field cannot be put in it.
    """
    motion = source.read_motion(sensor)
    where = f"{source.path} ({sensor})"
    options: dict[str, Any] = {}
    notes = [f"{where}: {note}" for note in motion.notes]
    if "time_s" in needs:
        options["time_s"] = motion.time_s
    try:
        if "gyro" in needs:
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
            options["reference"] = _reference(source, motion, where, unit, date, notes)
    except (DataFileError, OptionError) as error:
        if not available:
            raise
        notes.append(str(error))
    details: dict[str, Any] = {}
    if motion.magnetometer_frame == "body" and motion.mounting is not None:
        details["applied_rotation"] = np.asarray(motion.mounting).tolist()
    return MethodStreams(np.asarray(motion.samples), options, details, tuple(notes))


def _reference(
    source: Source,
    motion: Any,
    where: str,
    unit: str | None,
    date: datetime.date | str | None,
    notes: list[str],
) -> NDArray[np.float64]:
    """The model's field turned into the body frame at each sample: ``attitudeᵀ · (N, E, D)``."""
    from ..geomag import field_at

    if motion.attitude is None:
        raise DataFileError(
            f"{where}: the log holds no attitude beside this compass; the vector method needs one (ArduPilot ATT or "
            "XKQ, PX4 vehicle_attitude, a ROS sensor_msgs/Imu with its orientation)"
        )
    label = unit or motion.unit
    if not label or not get_unit(label).is_physical:
        raise OptionError(
            f"{where}: the vector method compares the samples with the World Magnetic Model's field, which needs "
            "their physical unit (unit='uT', 'G', 'mG' ...): raw counts have no known scale"
        )
    position = motion.position or source.position
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
