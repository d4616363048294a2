"""``magfit align``: the magnetometer's rotation into the vehicle frame, from gravity and the inclination.

The work is :func:`magfit.pipeline.align.align_file` (reading the recording, the starting calibration, the
alignment and its cap); this module parses the options, reads a calibration given, and prints the rotation,
its one-sigma, the nearest rotation of each firmware and the parameter lines to set. A samples file with the
attitude and no accelerometer, or with the attitude and the reference field (given, or both found by name), is
aligned by the vector fit (:func:`magfit.calibrate_file`). Advice names this command's options, and a remedy
only another command has as that command (``magfit calibrate FILE --method vector``).
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import click
import numpy as np
from numpy.typing import NDArray

from ..alignment import Alignment, nearest_rotations
from ..calibration import Calibration
from ..errors import CalibrationError
from ..geomag import parse_date, parse_location
from ..io.layout import sniff
from ..io.streams import find_stream_columns
from ..pipeline import RefusedWithAdvice, StreamsMissing, calibrate_file
from ..pipeline.align import ACCEL_COLUMNS, SECONDS, FileAlignment, align_file, alignment_of_vector, columns_by_name
from ..pipeline.table import StreamSpec
from ..rotations import CUSTOM, custom_angles
from ..sources import log_kind
from ._advice import own_options
from ._common import command_line, fail, geomag_option, one_line, parse_columns, parse_stream, vector, warn

#: The library's keywords in its messages, and the options that set them here.
_OPTIONS = {
    "allow_mirror=False": "--no-mirror",
    "max_tilt_rate_dps": "--max-tilt-rate",
    "max_rate_dps": "--max-rate",
    "allow_undetermined": "--force",
}


def _by_reference(path: Path, attitude: list[str | int] | None, reference: list[str | int] | None) -> bool:
    """Whether a samples file is aligned by the vector fit: attitude or reference columns given (what the user
    asks for wins over accelerometer columns found by name); else attitude columns found by name, with the
    reference field's N/E/D columns found by name too, or with no accelerometer columns found by name.

    A file that names its attitude and its reference field holds all the vector fit needs, as ``magfit calibrate
    --method vector`` finds them: the field expected at each sample pins the rotation, where the gravity path
    first needs a magnitude-only calibration that a vehicle's turns seldom determine (level driving leaves the
    offset along z open). ``--accel-columns`` chooses the gravity path all the same."""
    if attitude is not None or reference is not None:
        return True
    header = sniff(path).header
    if header is None:
        return False
    found = find_stream_columns(header)
    if "attitude" not in found:
        return False
    return "reference" in found or columns_by_name(header, ACCEL_COLUMNS) is None


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
    except StreamsMissing as error:  # the call that would run, as this command: align is the vector fit here
        remedy = [(name, value) for name, value in error.remedy if name != "method"]
        fail(f"{one_line(error.text)}; on the command line: {command_line('align', path, remedy)}")
    except RefusedWithAdvice as error:  # the methods that work, as commands (not the library's Python calls)
        said = "; ".join(f"{reason} ({command_line('calibrate', path, reason.remedy)})" for reason in error.advice)
        raise CalibrationError(f"{one_line(error.text)}; what works for a vehicle: {said}") from None
    compass = result.compasses[0]
    calibration = compass.calibration
    aligned = alignment_of_vector(calibration, compass.n_rows)
    rotation, mirror, inverted, proper = aligned.matrix, aligned.mirror, aligned.inverted_axis, aligned.proper_matrix
    roll, pitch, yaw = aligned.roll_deg, aligned.pitch_deg, aligned.yaw_deg
    sigma, verdict, warnings = float(aligned.sigma_deg[0]), aligned.verdict, aligned.warnings
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
@click.option("--time-unit", type=click.Choice(list(SECONDS)), default="s", show_default=True)
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
    with the vehicle's attitude and the reference field (or a place for the World Magnetic Model), or one
    whose attitude and reference N/E/D columns are both found by name, is aligned by the vector fit instead
    (--accel-columns chooses gravity): the rotation is the polar factor of its matrix. The accelerometer
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
    # The library's remedies in this command's options, or as the command that has them (magfit calibrate FILE
    # --method vector): align has no --method.
    with own_options(click.get_current_context(), file=file):
        if max_rate.strip().lower() == "none":
            max_rate_dps: float | None = None
        else:
            try:
                max_rate_dps = float(max_rate)
            except ValueError:
                fail(f"--max-rate takes a number of °/s or 'none', got {max_rate!r}")
        if inclination is not None and location is not None:
            fail("give --inclination or --location, not both")
        if accel_columns is not None and (attitude is not None or reference is not None):
            fail("give --accel-columns (the rotation from gravity) or --attitude/--reference (from the vector fit), "
                 "not both")  # fmt: skip
        if log_kind(file) is not None and (attitude is not None or reference is not None):
            fail(f"{file}: --attitude and --reference name a samples file's columns; a flight log's streams are its "
                 "own")  # fmt: skip
        if log_kind(file) is None and accel_columns is None and _by_reference(file, attitude, reference):
            spec = StreamSpec(attitude, reference, gyro_columns, None, [time_column] if time_column else None,
                              attitude_convention, angle_unit, gyro_unit)  # type: ignore[arg-type]  # fmt: skip
            _align_by_reference(file, columns, spec, unit, location, date, force)
            return
        calibration = None
        if calibration_path is not None:
            calibration = Calibration.from_json(calibration_path.read_text(encoding="utf-8"))
            if calibration.frame != "sensor":
                fail(f"{calibration_path}: is a vehicle-frame calibration, already aligned; give a magnitude-only one")
        try:
            found = align_file(
                file, sensor=sensor, columns=columns, accel_columns=accel_columns, gyro_columns=gyro_columns,
                gyro_unit=gyro_unit, time_column=time_column, time_unit=time_unit, calibration=calibration,
                inclination_deg=inclination, location=location, date=date, max_rate_dps=max_rate_dps,
                max_tilt_rate_dps=max_tilt_rate, allow_mirror=False if no_mirror else None, allow_undetermined=force,
            )  # fmt: skip
        except CalibrationError as error:  # the library's keywords as this command's options
            message = str(error)
            for keyword, option in _OPTIONS.items():
                message = message.replace(keyword, option)
            raise CalibrationError(message, codes=error.codes, remedy=error.remedy) from None
        _print_alignment(found, calibration_path)


def _print_alignment(found: FileAlignment, calibration_path: Path | None) -> None:
    """What ``magfit align`` prints of :func:`magfit.pipeline.align.align_file`'s result."""
    recording, calibration, result, total = found.recording, found.calibration, found.alignment, found.total
    for message in recording.warnings:
        warn(message)
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
        + (fitted if result.inclination_fitted else f"{found.inclination_deg:.2f}° ({found.inclination_source})")
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
