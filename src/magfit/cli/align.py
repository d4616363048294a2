"""``magfit align``: the magnetometer's rotation into the vehicle frame, from gravity and the inclination.

The work is :func:`magfit.alignment.align`; this module reads the magnetometer and the accelerometer (a
samples file with both, or a flight log through :mod:`magfit.sources`), fits the magnitude-only calibration
the alignment needs (or reads one), and prints the rotation, its one-sigma, the nearest rotation of each
firmware and the parameter lines to set.
"""

from __future__ import annotations

import datetime
import math
import re
from dataclasses import dataclass, replace
from pathlib import Path

import click
import numpy as np
from numpy.typing import NDArray

from ..alignment import Alignment, _mirror_axis, align, nearest_rotations
from ..calibration import Calibration
from ..diagnostics.settle import starting_weakness
from ..errors import CalibrationError, DataFileError
from ..fit import fit
from ..geomag import field_at, parse_date, parse_location
from ..io.layout import sniff
from ..io.readers import read_samples
from ..io.streams import find_stream_columns
from ..pipeline import RefusedWithAdvice, StreamsMissing, calibrate_file
from ..pipeline.table import StreamSpec
from ..rotations import CUSTOM, custom_angles, euler_angles, polar_decomposition
from ..sources import log_kind, open_source
from ._common import command_line, fail, geomag_option, one_line, parse_columns, parse_stream, vector, warn

#: Header names of accelerometer columns: ``ax``, ``imu_ax``, ``accel_x``, ``Ax``, ``acc_x`` ... (gyroscope columns are
#: not guessed: raw counts taken for rad/s would drop every sample as turning).
_ACCEL = re.compile(r"^(?:imu_?)?(?:a|acc|accel|accl|accelerometer)_?([xyz])$", re.IGNORECASE)
_TIME = re.compile(r"^(?:t|time|time_s|timestamp|seconds)$", re.IGNORECASE)


#: Seconds per unit of a time column.
_SECONDS = {"s": 1.0, "ms": 1e-3, "us": 1e-6}

#: The library's keywords in its messages, and the options that set them here.
_OPTIONS = {
    "allow_mirror=False": "--no-mirror",
    "max_tilt_rate_dps": "--max-tilt-rate",
    "max_rate_dps": "--max-rate",
    "allow_undetermined": "--force",
}


@dataclass(frozen=True)
class _Recording:
    """What the command aligns: the raw field, the accelerometer, and what else the file holds."""

    description: str
    samples: NDArray[np.float64]
    accel: NDArray[np.float64]
    gyro: NDArray[np.float64] | None
    time_s: NDArray[np.float64] | None
    mounting: NDArray[np.float64] | None  # already applied to the samples (a log's magnetometer in the body frame)
    mounting_note: str
    slot: int | None
    position: tuple[float, float, float] | None
    notes: tuple[str, ...]
    recorded: datetime.datetime | None = None  # when the log's GNSS says it was recorded (for the model)


def _columns_by_name(header: tuple[str, ...] | None, pattern: re.Pattern[str]) -> list[str] | None:
    if header is None:
        return None
    found = {}
    for name in header:
        match = pattern.match(name.strip())
        if match and match.group(1).lower() not in found:
            found[match.group(1).lower()] = name
    return [found[a] for a in "xyz"] if len(found) == 3 else None


def _read_samples_file(
    path: Path,
    columns: list[str | int] | None,
    accel_columns: list[str | int] | None,
    gyro_columns: list[str | int] | None,
    gyro_unit: str,
    time_column: str | None,
    time_unit: str,
) -> _Recording:
    header = sniff(path).header
    accel_columns = accel_columns or _columns_by_name(header, _ACCEL)  # type: ignore[assignment]
    if accel_columns is None:
        fail(
            f"{path}: no accelerometer columns found (ax/ay/az, accel_x ..., imu_ax ...); name them with "
            "--accel-columns AX,AY,AZ, or give the vehicle's attitude and the reference field instead (--attitude "
            "ROLL,PITCH,YAW --reference N,E,D: the rotation from the vector fit)"
        )
    mag = read_samples(path, columns=columns, nonfinite="error")
    accel = read_samples(path, columns=accel_columns, nonfinite="error").samples
    gyro = None
    if gyro_columns is not None:
        gyro = read_samples(path, columns=gyro_columns, nonfinite="error").samples
        gyro = np.radians(gyro) if gyro_unit == "deg/s" else gyro
    if time_column is None and header is not None:
        time_column = next((name for name in header if _TIME.match(name.strip())), None)
    time_s = None
    if time_column is not None:
        # The reader reads triples of distinct columns: the time beside two of the magnetometer's.
        triple: list[str | int] = [time_column, *mag.columns[:2]]
        time_s = read_samples(path, columns=triple, nonfinite="error").samples[:, 0] * _SECONDS[time_unit]
        step = float(np.median(np.diff(time_s))) if len(time_s) > 1 else 0.0
        if step >= 1.0:  # a 1 Hz magnetometer is rare; milliseconds read as seconds are not
            warn(f"{path}: the time column {time_column} steps by {step:g} s between samples: if it counts "
                 "milliseconds or microseconds, say so with --time-unit ms (or us); the rate gate uses it")  # fmt: skip
    described = f"{path} (magnetometer {', '.join(mag.columns)}; accelerometer {', '.join(map(str, accel_columns))}"
    if gyro_columns is not None:
        described += f"; gyroscope {', '.join(map(str, gyro_columns))} in {gyro_unit}"
    if time_column is not None:
        described += f"; time {time_column} in {time_unit}"
    return _Recording(described + ")", mag.samples, accel, gyro, time_s, None, "", None, None, ())


def _read_log(path: Path, sensor: str | None) -> _Recording:
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
    return _Recording(
        f"{path} ({source.format}, {motion.sensor})", motion.samples, motion.accel, motion.gyro, motion.time_s,
        mounting, motion.mounting_note, slot, position, tuple(notes), recorded,
    )  # fmt: skip


def _by_reference(path: Path, attitude: list[str | int] | None) -> bool:
    """Whether a samples file is aligned by the vector fit: attitude columns (given or found by name) and no
    accelerometer columns found by name."""
    header = sniff(path).header
    if header is not None and _columns_by_name(header, _ACCEL) is not None:
        return False
    return attitude is not None or (header is not None and "attitude" in find_stream_columns(header))


def _align_by_reference(
    path: Path,
    columns: list[str | int] | None,
    spec: StreamSpec,
    unit: str | None,
    location: tuple[float, float, float] | None,
    date: object,
    force: bool,
) -> None:
    """The rotation into the vehicle frame from the vector fit (the polar factor of its matrix), printed as the
    gravity path prints its own: the same numbers as ``magfit.fit(samples, method="vector", reference=...)``."""
    try:
        result = calibrate_file(
            path, "vector", columns=columns, unit=unit, location=location, date=date, force=force,  # type: ignore[arg-type]
            attitude=spec.attitude, reference=spec.reference, gyro=spec.gyro, time=spec.time,
            attitude_convention=spec.convention, angle_unit=spec.angle_unit, gyro_unit=spec.gyro_unit, notify=None,
        )  # fmt: skip
    except StreamsMissing as error:
        fail(f"{one_line(error.text)}; on the command line: {command_line('align', path, error.remedy)}")
    except RefusedWithAdvice as error:  # the methods that work, as commands (not the library's Python calls)
        said = "; ".join(f"{reason} ({command_line('calibrate', path, reason.remedy)})" for reason in error.advice)
        raise CalibrationError(f"{one_line(error.text)}; what works for a vehicle: {said}") from None
    compass = result.compasses[0]
    calibration = compass.calibration
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
    aligned = Alignment(
        matrix=rotation, roll_deg=roll, pitch_deg=pitch, yaw_deg=yaw, sigma_deg=np.full(3, sigma),
        axis_sigma_deg=np.full(3, sigma), inclination_deg=math.nan, inclination_sigma_deg=math.nan,
        inclination_fitted=False, mirror=mirror, inverted_axis=inverted, nearest=nearest, residual_deg=math.nan,
        n_samples=compass.n_rows, n_used=int(calibration.n_samples or 0), verdict=verdict, warnings=warnings,
    )  # fmt: skip
    out = click.echo
    out(f"{'file':16s} {path} (magnetometer {', '.join(map(str, compass.columns))})")
    out(f"{'calibration':16s} vector: against the file's attitude and reference field ({verdict})")
    out(f"{'samples used':16s} {calibration.n_samples} of {compass.n_rows}")
    matrix_lines = [vector(row, lambda v: f"{v:+.5f}") for row in rotation]
    out(f"{'rotation':16s} {matrix_lines[0]}    body = rotation @ sensor (the polar factor of the vector fit)")
    for line in matrix_lines[1:]:
        out(f"{'':16s} {line}")
    out(f"{'roll pitch yaw':16s} {roll:+.2f}°, {pitch:+.2f}°, {yaw:+.2f}° ± {sigma:.2f}° (RMS angle, one-sigma; "
        "Rz(yaw) Ry(pitch) Rx(roll))")  # fmt: skip
    if mirror:
        out(f"{'mirror':16s} yes: invert the sensor's {inverted} axis; the angles above are after that")
    out(f"{'verdict':16s} {verdict}")
    for warning in warnings:
        out(f"{'':16s} {warning}")
    for note in compass.notes:
        out(f"{'note':16s} {note}")
    if mirror:
        out(f"{'set':16s} no firmware rotation represents a mirror: fix the axis first; then, for the rotation left:")
    for index, line in enumerate(_parameter_lines(aligned, proper, None)):
        out(f"{'set' if index == 0 and not mirror else '':16s} {line}")
    if verdict == "refused":
        warn(f"printed because of --force: {warnings[0] if warnings else 'refused'}")


def _recorded_date(recording: _Recording) -> datetime.date | None:
    """The date of a log's GNSS fixes (the model of that date), or None (today)."""
    return recording.recorded.date() if recording.recorded is not None else None


def _parameter_lines(result: Alignment, total: NDArray[np.float64], slot: int | None) -> list[str]:
    """What to set in each firmware: its nearest table entry and, where it has one, the custom angles."""
    lines = []
    for entry in result.nearest:
        firmware, rotation = entry.firmware, entry.rotation
        parameter = entry.parameter.replace("MAG0", f"MAG{slot if slot is not None else 0}")
        if firmware in ("betaflight", "inav"):
            # The CLI takes the names of lookupTableAlignment (src/main/cli/settings.c): CW180FLIP, not 7.
            setting = f"set {parameter} = {rotation.name.replace('_DEG', '').replace('_', '')}"
        else:
            setting = f"{parameter} {rotation.id}"
        lines.append(f"{firmware:10s} {setting}   # {rotation.name}, {rotation.angle_deg:.1f}° from the fit")
        custom = CUSTOM[firmware]
        if custom is None:
            # An internal compass follows the board: CAL_MAGn_ROT = -1 (sensor_calibration/Magnetometer.cpp).
            lines.append(f"{'':10s} # an external compass; an internal one follows SENS_BOARD_ROT")
            if rotation.angle_deg > 2.0:
                lines.append(f"{'':10s} # PX4 has no custom compass rotation: {rotation.angle_deg:.1f}° remain")
            continue
        name, value, angle_names, _ = custom
        angles = [round(a, 1) + 0.0 for a in custom_angles(total, firmware)]  # + 0.0: no "-0.0" to paste
        if firmware == "ardupilot":
            text = f"CUST_ROT_ENABLE 1, {name} {value}, " + ", ".join(
                f"{n} {a:.1f}" for n, a in zip(angle_names, angles, strict=True)
            )
        else:
            choose = f"set {name} = CUSTOM, " if value else ""
            text = choose + ", ".join(f"set {n} = {round(a)}" for n, a in zip(angle_names, angles, strict=True))
        version = "  (Betaflight 2026.6 and later; 4.1-2025.12 take INAV's signs)" if firmware == "betaflight" else ""
        lines.append(f"{'':10s} or exactly: {text}{version}")
    return lines


def _starting_calibration(recording: _Recording, inclination: float | None) -> Calibration:
    """The magnitude-only calibration the alignment starts from, fitted on the recording.

    With a gyroscope and time stamps, the gyro-aided fit's magnitude-only part (``gyro.sensor_matrix``):
    a vehicle that cannot tumble leaves ``auto`` the field's vertical part, which the dip angles rest on,
    poorly pinned, while the rotation kinematics pin it (benchmarks/results/vehicle: flight, car and boat at
    6 000 samples, 8 trials each, the alignment 0.45°, 0.15°, 0.32° RMS from the true mounting starting from it,
    2.5°, 1.9°, 1.5° starting from ``auto``). Otherwise, or where the gyro-aided fit is refused, ``auto``.
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
            "calibrate first (magfit calibrate FILE --method ... -o cal.json) and give it with --calibration"
        ) from None


def _capped_by_calibration(result: Alignment, calibration: Calibration) -> Alignment:
    """An alignment is no better supported than the calibration it starts from (the cap of the verdict step,
    :func:`magfit.diagnostics.settle.starting_weakness`)."""
    weakness = starting_weakness(calibration)
    if weakness is None:
        return result
    verdict = "weak" if result.verdict == "supported" else result.verdict
    return replace(result, verdict=verdict, warnings=(*result.warnings, str(weakness)))


@click.command("align")
@click.argument("file", type=click.Path(dir_okay=True, path_type=Path))
@click.option("--sensor", help="The magnetometer of a log (its id or device id, see 'magfit inspect').")
@click.option("--columns", callback=parse_columns, help="Magnetometer columns X,Y,Z of a samples file.")
@click.option("--accel-columns", "--accel", "accel_columns", callback=parse_columns,
              help="Accelerometer columns (found by name by default).")  # fmt: skip
@click.option("--gyro-columns", "--gyro", "gyro_columns", callback=parse_columns,
              help="Gyroscope columns, in --gyro-unit (not guessed).")  # fmt: skip
@click.option("--gyro-unit", type=click.Choice(["rad/s", "deg/s"]), default="rad/s", show_default=True)
@click.option("--time-column", "--time", "time_column", help="Time column (found by name: t, time, timestamp).")
@click.option("--time-unit", type=click.Choice(list(_SECONDS)), default="s", show_default=True)
@click.option("--calibration", "calibration_path", type=click.Path(dir_okay=False, path_type=Path),
              help="A magnitude-only calibration (JSON) to correct the field with; fitted by default.")  # fmt: skip
@click.option("--inclination", type=float, help="The field's inclination, degrees (positive down).")
@click.option("--location", callback=geomag_option(parse_location),
              help="LAT,LON[,ALT]: the inclination of the World Magnetic Model ('magfit[wmm]').")  # fmt: skip
@click.option("--date", callback=geomag_option(parse_date), help="YYYY-MM-DD for --location (default: today).")
@click.option("--max-rate", default="0.3", show_default=True,
              help="Fastest turn in heading (°/s) of a sample used; 'none': turning about the sensor.")  # fmt: skip
@click.option("--max-tilt-rate", default=30.0, show_default=True, type=click.FloatRange(min=0.0, min_open=True),
              help="Fastest rotation (°/s) of a sample used, rolling and pitching too (with a gyroscope).")  # fmt: skip
@click.option("--no-mirror", is_flag=True,
              help="Right-handed sensor axes (by default a mirror is named where the samples tell).")  # fmt: skip
@click.option("--force", is_flag=True, help="Print an alignment the samples do not determine, its refusal first.")
@click.option("--attitude", callback=parse_stream, metavar="ROLL,PITCH,YAW|W,X,Y,Z",
              help="A samples file without an accelerometer: its attitude columns; the rotation then comes from the "
              "vector fit against the reference field (found by name by default).")  # fmt: skip
@click.option("--reference", callback=parse_stream, metavar="N,E,D",
              help="The reference field's columns (N, E, D in the samples' unit), with --attitude; else the World "
              "Magnetic Model at --location or the file's lat/lon columns.")  # fmt: skip
@click.option("--unit", help="The samples' unit (for the World Magnetic Model's reference field).")
@click.option("--attitude-convention", type=click.Choice(["ned", "enu"]), default="ned", show_default=True,
              help="ned: aerospace 3-2-1, body FRD to NED; enu: ROS's, FLU to ENU.")  # fmt: skip
@click.option("--angle-unit", type=click.Choice(["auto", "deg", "rad"]), default="auto", show_default=True)
def align_command(
    file: Path,
    sensor: str | None,
    columns: list[str | int] | None,
    accel_columns: list[str | int] | None,
    gyro_columns: list[str | int] | None,
    gyro_unit: str,
    time_column: str | None,
    time_unit: str,
    calibration_path: Path | None,
    inclination: float | None,
    location: tuple[float, float, float] | None,
    date: object,
    max_rate: str,
    max_tilt_rate: float,
    no_mirror: bool,
    force: bool,
    attitude: list[str | int] | None = None,
    reference: list[str | int] | None = None,
    unit: str | None = None,
    attitude_convention: str = "ned",
    angle_unit: str = "auto",
) -> None:
    """Find the magnetometer's rotation into the vehicle frame from gravity and the field's inclination.

    FILE is a samples file with magnetometer and accelerometer columns (and optionally gyroscope and time),
    or a flight log (PX4 ULog, ArduPilot DataFlash, ROS bag). A samples file without an accelerometer but
    with the vehicle's attitude and the reference field (or a place for the World Magnetic Model) is
    aligned by the vector fit instead: the rotation is the polar factor of its matrix. The accelerometer
    gives gravity while the vehicle is still or slow; the angle between gravity and the field is the same
    everywhere, so the rotation follows without any attitude. Prints the rotation, its one-sigma, the
    nearest rotation of ArduPilot, PX4, Betaflight and INAV and the parameters to set. Exit status 1 when the samples do
    not determine it (a vehicle that stayed level cannot show its mount's yaw).

    \b
    Examples:
      magfit align imu.csv --inclination 64 --max-rate none
      magfit align flight.ulg --location 47.4,8.5 --no-mirror
      magfit align survey.csv --attitude roll,pitch,yaw --reference ref_n,ref_e,ref_d
    """
    if max_rate.strip().lower() == "none":
        max_rate_dps: float | None = None
    else:
        try:
            max_rate_dps = float(max_rate)
        except ValueError:
            fail(f"--max-rate takes a number of °/s or 'none', got {max_rate!r}")
    if inclination is not None and location is not None:
        fail("give --inclination or --location, not both")
    if log_kind(file) is not None:
        recording = _read_log(file, sensor)
    elif accel_columns is None and _by_reference(file, attitude):
        spec = StreamSpec(attitude, reference, gyro_columns, None, [time_column] if time_column else None,
                          attitude_convention, angle_unit, gyro_unit)  # type: ignore[arg-type]  # fmt: skip
        _align_by_reference(file, columns, spec, unit, location, date, force)
        return
    else:
        recording = _read_samples_file(file, columns, accel_columns, gyro_columns, gyro_unit, time_column, time_unit)
    place = location or recording.position
    source_of_inclination = "given"
    if inclination is None and place is not None:
        when = date if date is not None or location is not None else _recorded_date(recording)
        field = field_at(*place, date=when)  # type: ignore[arg-type]
        inclination = field.inclination_deg
        source_of_inclination = field.describe()

    if calibration_path is not None:
        calibration = Calibration.from_json(calibration_path.read_text(encoding="utf-8"))
        if calibration.frame != "sensor":
            fail(f"{calibration_path}: is a vehicle-frame calibration, already aligned; give a magnitude-only one")
    else:
        calibration = _starting_calibration(recording, inclination)
    corrected = calibration.apply(recording.samples)
    try:
        result = align(
            corrected, recording.accel, inclination_deg=inclination, gyro=recording.gyro, time_s=recording.time_s,
            max_rate_dps=max_rate_dps, max_tilt_rate_dps=max_tilt_rate, allow_mirror=False if no_mirror else None,
            allow_undetermined=force,
        )  # fmt: skip
    except CalibrationError as error:  # the library's keywords as this command's options
        message = str(error)
        for keyword, option in _OPTIONS.items():
            message = message.replace(keyword, option)
        raise CalibrationError(message) from None
    result = _capped_by_calibration(result, calibration)
    # A log's magnetometer already turned by the firmware's orientation M: the rotation to set is R @ M.
    total = result.proper_matrix if recording.mounting is None else result.proper_matrix @ recording.mounting

    out = click.echo
    out(f"{'file':16s} {recording.description}")
    origin = f"read from {calibration_path}" if calibration_path else "fitted"
    verdict = calibration.support.verdict if calibration.support is not None else "no verdict recorded"
    out(f"{'calibration':16s} {calibration.method} ({origin}, {verdict})")
    dropped = "; ".join(f"{count} {reason}" for reason, count in result.dropped.items())
    out(f"{'samples used':16s} {result.n_used} of {result.n_samples}" + (f" (dropped: {dropped})" if dropped else ""))
    fitted = f"fitted: {result.inclination_deg:.2f} ± {result.inclination_sigma_deg:.2f}°"
    out(
        f"{'inclination':16s} "
        + (fitted if result.inclination_fitted else f"{inclination:.2f}° ({source_of_inclination})")
    )
    matrix_lines = [vector(row, lambda v: f"{v:+.5f}") for row in result.matrix]
    out(f"{'rotation':16s} {matrix_lines[0]}    body = rotation @ sensor")
    for line in matrix_lines[1:]:
        out(f"{'':16s} {line}")
    roll, pitch, yaw = result.roll_deg, result.pitch_deg, result.yaw_deg
    s_roll, s_pitch, s_yaw = result.sigma_deg
    out(f"{'roll pitch yaw':16s} {roll:+.2f} ± {s_roll:.2f}°, {pitch:+.2f} ± {s_pitch:.2f}°, {yaw:+.2f} ± {s_yaw:.2f}°"
        "  (Rz(yaw) Ry(pitch) Rx(roll), one-sigma)")  # fmt: skip
    out(f"{'dip residual':16s} {result.residual_deg:.2f}° RMS")
    if result.mirror:
        out(f"{'mirror':16s} yes: invert the sensor's {result.inverted_axis} axis; the angles above are after that")
    if recording.mounting is not None:
        out(f"{'log orientation':16s} {recording.mounting_note or 'applied to the samples'}: the rotation to set "
            "combines it with the one found")  # fmt: skip
    out(f"{'verdict':16s} {result.verdict}")
    for warning in result.warnings:
        out(f"{'':16s} {warning}")
    for note in recording.notes:
        out(f"{'note':16s} {note}")
    if result.mirror:
        out(f"{'set':16s} no firmware rotation represents a mirror: fix the axis first; then, for the rotation left:")
    if recording.mounting is not None:  # the nearest entries of the combined rotation
        result = replace(result, nearest=nearest_rotations(total))
    for index, line in enumerate(_parameter_lines(result, total, recording.slot)):
        out(f"{'set' if index == 0 and not result.mirror else '':16s} {line}")
    if result.verdict == "refused":
        warn(f"printed because of --force: {result.warnings[0]}")
