"""A recording -> the magnetometer's rotation into the vehicle frame: what ``magfit align`` prints.

:func:`align_file` reads the magnetometer and the accelerometer (a samples file with both, or a flight log
through :mod:`magfit.sources`), reads the field's inclination from the World Magnetic Model where a place is
known, fits (or takes) the magnitude-only calibration the alignment starts from, runs
:func:`magfit.alignment.align` on the corrected field and caps its verdict by that calibration's
(:func:`magfit.diagnostics.settle.starting_weakness`): an alignment is no better supported than the
calibration it starts from.
"""

from __future__ import annotations

import datetime
import math
import re
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..alignment import Alignment, _mirror_axis, align, nearest_rotations
from ..calibration import Calibration
from ..diagnostics.settle import starting_weakness
from ..errors import CalibrationError, DataFileError
from ..fit import fit
from ..geomag import field_at
from ..io.layout import sniff
from ..io.readers import read_samples
from ..remedy import option, options
from ..rotations import euler_angles, polar_decomposition

__all__ = ["ACCEL_COLUMNS", "SECONDS", "FileAlignment", "Recording", "align_file", "read_recording"]

#: Header names of accelerometer columns: ``ax``, ``imu_ax``, ``accel_x``, ``Ax``, ``acc_x`` ... (gyroscope columns
#: are not guessed: raw counts taken for rad/s would drop every sample as turning).
ACCEL_COLUMNS = re.compile(r"^(?:imu_?)?(?:a|acc|accel|accl|accelerometer)_?([xyz])$", re.IGNORECASE)
TIME_COLUMN = re.compile(r"^(?:t|time|time_s|timestamp|seconds)$", re.IGNORECASE)
#: Seconds per unit of a time column.
SECONDS = {"s": 1.0, "ms": 1e-3, "us": 1e-6}


@dataclass(frozen=True)
class Recording:
    """What is aligned: the raw field, the accelerometer, and what else the file holds.

    ``mounting`` is a rotation already applied to the samples (a log's magnetometer in the body frame);
    ``warnings`` what the reader found doubtful (a time column that looks like milliseconds).
    """

    description: str
    samples: NDArray[np.float64]
    accel: NDArray[np.float64]
    gyro: NDArray[np.float64] | None
    time_s: NDArray[np.float64] | None
    mounting: NDArray[np.float64] | None
    mounting_note: str
    slot: int | None
    position: tuple[float, float, float] | None
    notes: tuple[str, ...]
    recorded: datetime.datetime | None = None  # when the log's GNSS says it was recorded (for the model)
    warnings: tuple[str, ...] = ()


@dataclass(frozen=True)
class FileAlignment:
    """What :func:`align_file` found.

    Attributes
    ----------
    recording : Recording
        What was read.
    calibration : Calibration
        The magnitude-only calibration the alignment started from (fitted, or the one given).
    alignment : Alignment
        The rotation, its one-sigma and its verdict, capped by ``calibration``'s.
    inclination_deg : float or None
        The inclination used (None: fitted by the alignment, ``alignment.inclination_deg``).
    inclination_source : str
        ``"given"`` or the World Magnetic Model's field, in words.
    total : ndarray, shape (3, 3)
        The rotation to set in the firmware: the alignment's proper rotation combined with the orientation a
        log's magnetometer was already turned by (``recording.mounting``).
    """

    recording: Recording
    calibration: Calibration
    alignment: Alignment
    inclination_deg: float | None
    inclination_source: str
    total: NDArray[np.float64]


def columns_by_name(header: tuple[str, ...] | None, pattern: re.Pattern[str]) -> list[str] | None:
    """The x, y, z columns of ``header`` whose names match ``pattern`` (its group 1 the axis), or None."""
    if header is None:
        return None
    found = {}
    for name in header:
        match = pattern.match(name.strip())
        if match and match.group(1).lower() not in found:
            found[match.group(1).lower()] = name
    return [found[a] for a in "xyz"] if len(found) == 3 else None


def read_recording(
    path: Path,
    *,
    sensor: str | None = None,
    columns: list[str | int] | None = None,
    accel_columns: list[str | int] | None = None,
    gyro_columns: list[str | int] | None = None,
    gyro_unit: str = "rad/s",
    time_column: str | None = None,
    time_unit: str = "s",
) -> Recording:
    """The magnetometer, accelerometer and (when there) gyroscope and time of a flight log or a samples file."""
    from ..sources import log_kind

    if log_kind(path) is not None:
        return _read_log(path, sensor)
    return _read_samples_file(path, columns, accel_columns, gyro_columns, gyro_unit, time_column, time_unit)


def _read_samples_file(
    path: Path,
    columns: list[str | int] | None,
    accel_columns: list[str | int] | None,
    gyro_columns: list[str | int] | None,
    gyro_unit: str,
    time_column: str | None,
    time_unit: str,
) -> Recording:
    header = sniff(path).header
    accel_columns = accel_columns or columns_by_name(header, ACCEL_COLUMNS)  # type: ignore[assignment]
    if accel_columns is None:
        raise DataFileError(
            f"{path}: no accelerometer columns found (ax/ay/az, accel_x ..., imu_ax ...); name them with "
            f"{option('accel_columns', 'AX,AY,AZ')}, or give the vehicle's attitude and the reference field instead "
            f"({options([('attitude', 'ROLL,PITCH,YAW'), ('reference', 'N,E,D')])}: the rotation from the vector fit)"
        )
    mag = read_samples(path, columns=columns, nonfinite="error")
    accel = read_samples(path, columns=accel_columns, nonfinite="error").samples
    gyro = None
    if gyro_columns is not None:
        gyro = read_samples(path, columns=gyro_columns, nonfinite="error").samples
        gyro = np.radians(gyro) if gyro_unit == "deg/s" else gyro
    if time_column is None and header is not None:
        time_column = next((name for name in header if TIME_COLUMN.match(name.strip())), None)
    time_s, warnings = None, []
    if time_column is not None:
        # The reader reads triples of distinct columns: the time beside two of the magnetometer's.
        triple: list[str | int] = [time_column, *mag.columns[:2]]
        time_s = read_samples(path, columns=triple, nonfinite="error").samples[:, 0] * SECONDS[time_unit]
        step = float(np.median(np.diff(time_s))) if len(time_s) > 1 else 0.0
        if step >= 1.0:  # a 1 Hz magnetometer is rare; milliseconds read as seconds are not
            warnings.append(
                f"{path}: the time column {time_column} steps by {step:g} s between samples: if it counts "
                f"milliseconds or microseconds, say so with {option('time_unit', 'ms')} (or us); the rate gate uses it"
            )
    described = f"{path} (magnetometer {', '.join(mag.columns)}; accelerometer {', '.join(map(str, accel_columns))}"
    if gyro_columns is not None:
        described += f"; gyroscope {', '.join(map(str, gyro_columns))} in {gyro_unit}"
    if time_column is not None:
        described += f"; time {time_column} in {time_unit}"
    return Recording(described + ")", mag.samples, accel, gyro, time_s, None, "", None, None, (),
                     warnings=tuple(warnings))  # fmt: skip


def _read_log(path: Path, sensor: str | None) -> Recording:
    from ..sources import open_source

    source = open_source(path)
    motion = source.read_motion(sensor)
    if motion.accel is None:
        raise DataFileError(f"{path}: logs no accelerometer beside {motion.sensor}: the alignment needs one")
    notes = list(motion.notes)
    if motion.imu_frame and "body" not in motion.imu_frame.lower():
        notes.append(f"the accelerometer is in the {motion.imu_frame} frame: the rotation found is into that frame")
    mounting = motion.mounting if motion.magnetometer_frame == "body" else None
    if motion.magnetometer_frame == "body" and mounting is None:
        notes.append("the log's magnetometer is already rotated by an orientation it does not record: the rotation "
                     "found is what remains after it")  # fmt: skip
    slot = next((m.slot for m in source.magnetometers if m.id == motion.sensor), None)
    position, recorded = None, None
    if motion.position is not None:
        position = (motion.position.lat_deg, motion.position.lon_deg, motion.position.alt_km)
        if math.isfinite(motion.position.time_s):
            recorded = datetime.datetime.fromtimestamp(motion.position.time_s, tz=datetime.timezone.utc)
    return Recording(
        f"{path} ({source.format}, {motion.sensor})", motion.samples, motion.accel, motion.gyro, motion.time_s,
        mounting, motion.mounting_note, slot, position, tuple(notes), recorded,
    )  # fmt: skip


def starting_calibration(recording: Recording, inclination: float | None) -> Calibration:
    """The magnitude-only calibration the alignment starts from, fitted on the recording.

    With a gyroscope and time stamps, the gyro-aided fit's magnitude-only part (``gyro.sensor_matrix``):
    a vehicle that cannot tumble leaves ``auto`` the field's vertical part, which the dip angles rest on,
    poorly pinned, while the rotation kinematics pin it (benchmarks/results/vehicle). Otherwise, or where the
    gyro-aided fit is refused, ``auto``.
    """
    if recording.gyro is not None and recording.time_s is not None:
        try:
            kinematic = fit(
                recording.samples, method="gyro", gyro=recording.gyro, time_s=recording.time_s, accel=recording.accel,
                inclination_deg=inclination,  # the accelerometer's check, where it is known
            )  # fmt: skip
        except CalibrationError:
            kinematic = None  # auto below, with its own refusal if it has one
        if kinematic is not None and kinematic.gyro is not None and kinematic.gyro.sensor_matrix is not None:
            return Calibration(
                "gyro (its magnitude-only part)",
                kinematic.offset,
                np.asarray(kinematic.gyro.sensor_matrix, dtype=np.float64),
                kinematic.field_strength,
                support=kinematic.support,
            )
    try:
        return fit(recording.samples, method="auto")
    except CalibrationError as error:  # its advice names fit's options, which align does not take
        raise CalibrationError(
            f"the magnitude-only calibration the alignment starts from could not be fitted ({error}); "
            f"calibrate first (magfit calibrate FILE --method ... -o cal.json) and give it with "
            f"{option('calibration', 'cal.json')}"
        ) from None


def capped(result: Alignment, calibration: Calibration) -> Alignment:
    """``result`` no better supported than the calibration it starts from (weak at best when that one is)."""
    weakness = starting_weakness(calibration)
    if weakness is None:
        return result
    verdict = "weak" if result.verdict == "supported" else result.verdict
    return replace(result, verdict=verdict, warnings=(*result.warnings, str(weakness)))


def align_file(
    path: str | Path,
    *,
    sensor: str | None = None,
    columns: list[str | int] | None = None,
    accel_columns: list[str | int] | None = None,
    gyro_columns: list[str | int] | None = None,
    gyro_unit: str = "rad/s",
    time_column: str | None = None,
    time_unit: str = "s",
    calibration: Calibration | None = None,
    inclination_deg: float | None = None,
    location: tuple[float, float, float] | None = None,
    date: Any = None,
    max_rate_dps: float | None = 0.3,
    max_tilt_rate_dps: float = 30.0,
    allow_mirror: bool | None = None,
    allow_undetermined: bool = False,
) -> FileAlignment:
    """The magnetometer's rotation into the vehicle frame, from a recording's gravity and the field's inclination.

    Parameters
    ----------
    path : str or Path
        A flight log (ULog, DataFlash, a ROS bag) or a samples file with magnetometer and accelerometer columns.
    sensor, columns, accel_columns, gyro_columns, gyro_unit, time_column, time_unit
        Which magnetometer of a log; a samples file's columns (accelerometer ones found by name when not given),
        the gyroscope's unit (``"rad/s"``, ``"deg/s"``), the time column and its unit (``"s"``, ``"ms"``, ``"us"``).
    calibration : Calibration, optional
        A magnitude-only (``frame="sensor"``) calibration to correct the field with; fitted when not given.
    inclination_deg : float, optional
        The field's inclination, degrees positive down. Otherwise the World Magnetic Model's at ``location``
        (``(lat, lon, alt_km)``) or the log's GNSS fixes, on ``date`` (or the log's); otherwise fitted.
    max_rate_dps, max_tilt_rate_dps, allow_mirror, allow_undetermined
        As :func:`magfit.alignment.align`.

    Raises
    ------
    DataFileError
        No accelerometer, or a calibration in the vehicle frame given.
    CalibrationError
        The samples do not determine the rotation (unless ``allow_undetermined``), or no starting calibration
        could be fitted.
    """
    path = Path(path)
    recording = read_recording(
        path, sensor=sensor, columns=columns, accel_columns=accel_columns, gyro_columns=gyro_columns,
        gyro_unit=gyro_unit, time_column=time_column, time_unit=time_unit,
    )  # fmt: skip
    place = location or recording.position
    source = "given"
    if inclination_deg is None and place is not None:
        when = date if date is not None or location is not None else _recorded_date(recording)
        field = field_at(*place, date=when)
        inclination_deg, source = field.inclination_deg, field.describe()
    if calibration is None:
        calibration = starting_calibration(recording, inclination_deg)
    elif calibration.frame != "sensor":
        raise DataFileError("is a vehicle-frame calibration, already aligned; give a magnitude-only one")
    corrected = calibration.apply(recording.samples)
    result = align(
        corrected, recording.accel, inclination_deg=inclination_deg, gyro=recording.gyro, time_s=recording.time_s,
        max_rate_dps=max_rate_dps, max_tilt_rate_dps=max_tilt_rate_dps, allow_mirror=allow_mirror,
        allow_undetermined=allow_undetermined,
    )  # fmt: skip
    result = capped(result, calibration)
    # A log's magnetometer already turned by the firmware's orientation M: the rotation to set is R @ M.
    total = result.proper_matrix if recording.mounting is None else result.proper_matrix @ recording.mounting
    return FileAlignment(recording, calibration, result, inclination_deg, source, total)


def alignment_of_vector(calibration: Calibration, n_samples: int) -> Alignment:
    """The rotation into the vehicle frame held by a fit against a reference field (``method="vector"``).

    The rotation is the polar factor of the calibration's matrix (soft iron times misalignment), its one-sigma
    the fit's (``calibration.vector.alignment_sigma_deg``), its verdict the fit's; a mirror names the axis to
    invert. ``n_samples``: the rows read (the fit's ``n_samples`` are those it used).
    """
    rotation, _ = polar_decomposition(calibration.matrix)
    facts = calibration.vector
    sigma = facts.alignment_sigma_deg if facts is not None and facts.alignment_sigma_deg is not None else math.nan
    mirror = bool(np.linalg.det(rotation) < 0)
    inverted, nearest = _mirror_axis(rotation) if mirror else (None, nearest_rotations(rotation))
    proper = rotation @ np.diag([-1.0 if axis == inverted else 1.0 for axis in "xyz"]) if mirror else rotation
    roll, pitch, yaw = euler_angles(proper)
    support = calibration.support
    verdict = support.verdict if support is not None else "supported"
    warnings = tuple(str(w) for w in (*support.refusals, *support.weaknesses)) if support is not None else ()
    return Alignment(
        matrix=rotation, roll_deg=roll, pitch_deg=pitch, yaw_deg=yaw, sigma_deg=np.full(3, sigma),
        axis_sigma_deg=np.full(3, sigma), inclination_deg=math.nan, inclination_sigma_deg=math.nan,
        inclination_fitted=False, mirror=mirror, inverted_axis=inverted, nearest=nearest, residual_deg=math.nan,
        n_samples=n_samples, n_used=int(calibration.n_samples or 0), verdict=verdict, warnings=warnings,
    )  # fmt: skip


def _recorded_date(recording: Recording) -> datetime.date | None:
    """The date of a log's GNSS fixes (the model of that date), or None (today)."""
    return recording.recorded.date() if recording.recorded is not None else None
