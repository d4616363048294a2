"""``magfit apply``: correct a recording with a saved calibration."""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING

import click
import numpy as np
from numpy.typing import NDArray

from ..calibration import CONVENTION, Calibration
from ..errors import DataFileError, MagfitError, OptionError
from ..pipeline.motor import column_regressor, log_regressor
from ._common import columns_text, console, parse_columns, refuse_overwriting_input, warn
from ._logs import is_log, read_recordings

if TYPE_CHECKING:
    from ..io import FileFormat


def read_calibration(path: Path) -> Calibration:
    """The calibration saved in ``path`` by ``magfit calibrate -o`` (:meth:`Calibration.to_json`)."""
    from ..io.sources import read_once

    try:
        text = read_once(path).decode("utf-8")  # a named pipe read once, refused when nothing writes into it
    except FileNotFoundError:
        raise DataFileError(f"calibration file {path} does not exist") from None
    except (OSError, UnicodeDecodeError) as error:
        raise DataFileError(f"cannot read the calibration file {path}: {error}") from None
    try:
        return Calibration.from_json(text)
    except MagfitError as error:
        written_by = "a calibration is written by 'magfit calibrate FILE -o cal.json'"
        raise DataFileError(f"{path}: {error} ({written_by})") from None


def remembered_columns(
    calibration: Calibration, fmt: FileFormat | Callable[[], FileFormat]
) -> list[str | int] | None:
    """The x, y, z columns ``magfit calibrate`` fitted (``calibration.source``) as they apply to a file of
    layout ``fmt``: names when the fitted file had a header; positions only for a file without a header and
    with as many columns (a position means nothing in a file of another layout); else None (detected).
    ``fmt`` may be a function that reads the layout: called only for positions, which need it."""
    source = calibration.source
    if source is None:
        return None
    if source.header:
        names = source.columns
        return list(names) if names is not None and len(names) == 3 else None
    indices = source.column_indices
    if indices is None or len(indices) != 3:
        return None
    layout = fmt() if callable(fmt) else fmt
    return list(indices) if layout.header is None and source.n_columns == layout.n_columns else None


@click.command("apply")
@click.argument("calibration_file", metavar="CAL", type=click.Path(dir_okay=False, path_type=Path))
@click.argument("file", type=click.Path(dir_okay=False, path_type=Path))
@click.option(
    "-o",
    "--output",
    required=True,
    type=click.Path(dir_okay=False, path_type=Path),
    help="Where to write the corrected file (same format as FILE; replaced atomically); - for stdout.",
)
@click.option(
    "--columns",
    callback=parse_columns,
    metavar="X,Y,Z",
    help="The three magnetometer columns: names or 0-based numbers. Default: detected.",
)
@click.option(
    "--normalized",
    is_flag=True,
    help="Divide by the field strength: corrected samples on the unit sphere instead of input units.",
)
@click.option(
    "--sensor",
    metavar="ID",
    help="The compass of a flight log or bag to correct. Default: the one CAL was fitted on (or the log's only one).",
)
@click.option(
    "--regressor",
    metavar="COLUMN",
    help="For a CAL with the motors' field: the samples file's current (A) or throttle (0-1) column, a name or "
    "0-based number. Default: found by its name (current, curr, throttle, thr ...). A log's own is always used.",
)
@click.option(
    "--no-motor",
    is_flag=True,
    help="Apply a CAL that holds the motors' field without it (the heading error that leaves is said).",
)
def apply_command(
    calibration_file: Path,
    file: Path,
    output: Path,
    columns: list[str | int] | None,
    normalized: bool,
    sensor: str | None,
    regressor: str | None,
    no_motor: bool,
) -> None:
    """Correct the samples of FILE with the calibration CAL and write them to -o.

    Each sample becomes matrix @ (raw - offset); the file's other columns (time, gyro ...) and its
    format (delimiter, header) are kept. A CAL with the motors' field (fitted with --motor) becomes
    matrix @ (raw - offset - k c), c the log's battery current or throttle, or a samples file's column.
    CAL is a JSON file written by 'magfit calibrate -o'. FILE may be a flight log or bag (ULog, DataFlash,
    ROS): its compass's corrected samples are written as CSV with their time stamps (time_s, then x, y, z),
    or as an (N, 4) array when -o ends in .npy.

    \b
    Examples:
      magfit calibrate flight.csv --columns mx,my,mz -o cal.json
      magfit apply cal.json flight.csv --columns mx,my,mz -o flight_calibrated.csv
      magfit calibrate 00000042.BIN --sensor MAG/0 -o mag0.json
      magfit apply mag0.json 00000042.BIN -o mag0_calibrated.csv
      magfit apply quad.json quad.csv --regressor bat_amps -o quad_calibrated.csv
    """
    from ..io import STDOUT, check_output, iter_sample_chunks, sniff, write_calibrated

    to_stdout = str(output) == STDOUT
    if not to_stdout:
        refuse_overwriting_input(output, [file, calibration_file])
    check_output(output)
    calibration = read_calibration(calibration_file)
    _warn_verdict(calibration, calibration_file)
    calibration = _motor_choice(calibration, calibration_file, regressor, no_motor)
    if is_log(file):
        if regressor is not None:
            raise OptionError(f"--regressor names a samples file's column; {file} is a log, whose own current or "
                              "throttle is used")  # fmt: skip
        _apply_to_log(calibration, calibration_file, file, output, columns, normalized, sensor)
        return
    if sensor is not None:
        raise DataFileError(f"{file}: --sensor chooses a compass of a flight log or bag (ULog, DataFlash, ROS)")
    # Without --columns, the columns the calibration was fitted on (Calibration.source, written by calibrate).
    remembered = remembered_columns(calibration, lambda: sniff(file)) if columns is None else None
    chosen = columns if columns is not None else remembered
    try:  # the one reader of the columns: its first chunk is the check below (the writer reads the file again)
        reader = iter_sample_chunks(file, columns=chosen, chunk_rows=FIRST_ROWS)
    except DataFileError as error:
        if remembered is None:
            raise
        raise DataFileError(
            f"{error} ({calibration_file} was fitted on the columns {columns_text(remembered)}; choose the columns "
            f"of {file} with --columns)"
        ) from None
    _warn_far_from_the_sphere(calibration, calibration_file, file, reader)
    values, motor_note = None, ""
    if calibration.motor is not None:
        values, label = column_regressor(
            file, calibration.motor, _column(regressor), held_by=str(calibration_file),
            cost=omission_text(calibration), magnetometer=reader.column_indices,
        )  # fmt: skip
        found = "--regressor" if regressor is not None else "found by name"
        motor_note = f"; the motors' field with the {calibration.motor.regressor} of {label} ({found})"
    written = write_calibrated(file, calibration, output, columns=chosen, normalized=normalized, regressor=values)
    out = console(stderr=to_stdout)
    scale = "unit sphere" if normalized else f"input units{f' ({calibration.unit})' if calibration.unit else ''}"
    how = "--columns" if columns is not None else f"as fitted, {calibration_file}" if remembered else reader.column_note
    used = f" (columns {columns_text(reader.columns)}{f'; {how}' if how else ''})"
    out.print(
        f"wrote {written}: {file}{used} corrected with {calibration_file} ({calibration.method}), {scale}{motor_note}",
        soft_wrap=True,
    )
    out.print(f"convention: {CONVENTION}")


#: Corrected samples whose median norm is beyond this factor of the calibration's field strength were not
#: recorded by the sensor (or in the unit) the calibration was fitted on.
FAR_FROM_THE_SPHERE = 2.0
#: The rows of the first chunk, which that check reads.
FIRST_ROWS = 10_000


def _warn_far_from_the_sphere(
    calibration: Calibration, calibration_file: Path, file: Path, reader: Iterable[NDArray[np.float64]]
) -> None:
    """Say when a samples file, corrected, lies far from the calibration's sphere: :func:`_warn_far_off` on
    ``reader``'s first chunk (a pipe is read once, by the writer: not checked)."""
    if not Path(file).is_file():
        return
    first = next(iter(reader), None)
    if first is not None:
        _warn_far_off(calibration, calibration_file, file, first)


def _warn_far_off(calibration: Calibration, calibration_file: Path, file: Path | str, raw: NDArray[np.float64]) -> None:
    """Say when the samples ``raw`` (N, 3), corrected, lie far from the calibration's sphere (their median norm
    against its field strength): another unit (gauss for µT is a factor 100) or another sensor."""
    from ..diagnostics.verdict import unit_mixup

    if not len(raw) or not calibration.field_strength > 0:
        return
    # The motors' term left out: a fraction of the field, well within the factor.
    without_motor = replace(calibration, motor=None) if calibration.motor is not None else calibration
    ratio = float(np.median(np.linalg.norm(without_motor.apply(raw), axis=1))) / calibration.field_strength
    if 1 / FAR_FROM_THE_SPHERE <= ratio <= FAR_FROM_THE_SPHERE:
        return
    why = unit_mixup(ratio) or "another sensor, or samples in another unit"
    warn(
        f"{file}, corrected with {calibration_file}, lies at {ratio:.3g} times its field strength "
        f"({calibration.field_strength:.6g}{f' {calibration.unit}' if calibration.unit else ''}): {why}; check that "
        "the file holds the sensor the calibration was fitted on, in the unit it was fitted in"
    )


def omission_text(calibration: Calibration) -> str:
    """What leaving the calibration's motor term out costs, in words."""
    from ..export._motor import omission_deg

    term = calibration.motor
    assert term is not None
    at = f"{term.full_scale:.3g} A" if term.regressor == "current" else "full throttle"
    return f"up to {omission_deg(calibration):.1f} deg of heading error at {at}"


def _motor_choice(
    calibration: Calibration, calibration_file: Path, regressor: str | None, no_motor: bool
) -> Calibration:
    """The calibration as it will be applied: without its motor term under --no-motor (said, with the cost)."""
    if no_motor and regressor is not None:
        raise OptionError("--no-motor leaves the motors' field out and --regressor names its column: give one")
    if calibration.motor is None:
        if regressor is not None:
            raise OptionError(f"--regressor: {calibration_file} holds no motors' field (it was fitted without one)")
        return calibration
    if no_motor:
        warn(f"--no-motor: {calibration_file}'s motors' field ({calibration.motor.regressor}) is left out: "
             f"{omission_text(calibration)}")  # fmt: skip
        return replace(calibration, motor=None)
    return calibration


def _warn_verdict(calibration: Calibration, calibration_file: Path) -> None:
    """A calibration the samples did not support (returned forced) or supported with weaknesses is applied, but
    not without a word: the verdict it was saved with, repeated where it is used."""
    support = calibration.support
    for warning in support.warnings if support is not None else ():  # the verdict's own lines, as calibrate said
        warn(f"{calibration_file}: {warning}")


def _column(regressor: str | None) -> str | int | None:
    """--regressor's column: a 0-based number when it is one, else a name."""
    if regressor is not None and regressor.strip().isdigit():
        return int(regressor)
    return regressor


def fitted_sensor(calibration: Calibration) -> str | None:
    """The log compass ``calibration`` was fitted on (``calibration.sensor.id``, written by calibrate), or None."""
    return calibration.sensor.id if calibration.sensor is not None else None


def _apply_to_log(
    calibration: Calibration,
    calibration_file: Path,
    file: Path,
    output: Path,
    columns: list[str | int] | None,
    normalized: bool,
    sensor: str | None,
) -> None:
    """Correct one compass of a flight log or bag and write it with its time stamps (CSV, or .npy)."""
    import io

    import numpy as np

    from ..io import STDOUT, write_all
    from ..units import get_unit

    fitted = fitted_sensor(calibration)
    chosen = sensor if sensor is not None else fitted
    (recording,) = read_recordings(file, columns=columns, nonfinite="skip", sensor=chosen, every=False)
    if fitted is not None and recording.sensor != fitted:
        warn(f"{calibration_file} was fitted on {fitted}, and is applied to {recording.sensor} of {file}")
    if calibration.unit and recording.unit and get_unit(calibration.unit).name != get_unit(recording.unit).name:
        raise DataFileError(
            f"{calibration_file} is in {calibration.unit} and {file} ({recording.sensor}) logs {recording.unit}: "
            f"fit the calibration on this log ('magfit calibrate {file} --sensor {recording.sensor}')"
        )
    assert recording.time_s is not None
    _warn_far_off(calibration, calibration_file, f"{file} ({recording.sensor})", recording.samples)
    motor_note = ""
    if calibration.motor is not None:
        values, name = log_regressor(file, calibration.motor, recording.time_s, held_by=str(calibration_file),
                                     cost=omission_text(calibration))  # fmt: skip
        corrected = calibration.apply(recording.samples, normalized=normalized, regressor=values)
        motor_note = f"; the motors' field with {name} at {1000 * calibration.motor.lag_s:.0f} ms lag"
    else:
        corrected = calibration.apply(recording.samples, normalized=normalized)
    table = np.column_stack([recording.time_s, corrected])
    if output.suffix.lower() == ".npy" and str(output) != STDOUT:
        buffer = io.BytesIO()
        np.save(buffer, table)
        data = buffer.getvalue()
    else:
        names = ",".join(["time_s", *(str(column) for column in recording.columns)])
        text = io.StringIO()
        np.savetxt(text, table, fmt=["%.6f", "%.9g", "%.9g", "%.9g"], delimiter=",", header=names, comments="")
        data = text.getvalue().encode("utf-8")
    write_all([(output, data)])
    out = console(stderr=str(output) == STDOUT)
    scale = "unit sphere" if normalized else f"input units{f' ({calibration.unit})' if calibration.unit else ''}"
    out.print(
        f"wrote {output}: {len(table)} samples of {recording.name} with their time stamps, corrected with "
        f"{calibration_file} ({calibration.method}), {scale}{motor_note}",
        soft_wrap=True,
    )
    out.print(f"convention: {CONVENTION}")
