"""``magfit calibrate``: fit a recording, print the calibration, save it as JSON or a firmware format.

The work is :func:`magfit.calibrate_file` (the library's pipeline); this module parses the options, draws the
progress bar, prints the summaries and writes the files.
"""

from __future__ import annotations

import datetime
import math
import re
import sys
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import click
from rich.console import Console

from ..calibration import CONVENTION, Calibration
from ..errors import CalibrationError, DataFileError, MagfitError
from ..geomag import parse_date, parse_location
from ..methods import get_method
from ..pipeline import (
    CompassCalibration,
    FileCalibration,
    ModelField,
    RefusedWithAdvice,
    StreamsMissing,
    calibrate_file,
)
from ..pipeline.streaming import Advance
from ..units import conversion_factor, get_unit
from ._common import (
    CommandError,
    FieldStrength,
    FitFailedError,
    Nonfinite,
    RegistryChoice,
    columns_text,
    command_line,
    console,
    default_method,
    export_format_names,
    fail,
    fixed,
    geomag_option,
    method_names,
    nonfinite_option,
    one_line,
    parse_columns,
    parse_stream,
    refuse_overwriting_input,
    same_file,
    significant,
    time_span,
    vector,
    warn,
)
from ._extras import require

#: Formats whose one file holds every compass of a vehicle (``magfit.export.export_several``). JSON is written
#: one file per compass, each a calibration that ``magfit apply`` and ``Calibration.from_json`` read.
SEVERAL_IN_ONE_FILE = ("ardupilot", "px4")


@contextmanager
def progress_bar(description: str, total: int | Callable[[], int] | None = None) -> Iterator[Advance]:
    """A progress bar on stderr, shown only when stderr is a terminal; yields ``advance(rows)`` (a
    :class:`magfit.pipeline.Progress`).

    ``total`` (rows, or a function that estimates them, called only when a bar is drawn) draws a bar
    with the percentage and the time left; without it, a spinner and the rows counted.
    """
    if not sys.stderr.isatty():
        yield lambda rows: None  # no terminal to draw on: a log or a pipe gets no progress noise
        return
    if callable(total):
        total = total()
    from rich.progress import (
        BarColumn,
        Progress,
        SpinnerColumn,
        TaskProgressColumn,
        TextColumn,
        TimeElapsedColumn,
        TimeRemainingColumn,
    )

    measured = (BarColumn(), TaskProgressColumn(), TimeRemainingColumn()) if total else ()
    with Progress(
        SpinnerColumn(),
        TextColumn("{task.description}"),
        *measured,
        TextColumn("{task.completed:,} rows"),
        TimeElapsedColumn(),
        console=console(stderr=True),
        transient=True,
    ) as progress:
        task = progress.add_task(description, total=total or None)
        yield lambda rows: progress.advance(task, rows)


def parse_place(text: str) -> tuple[float, float, float] | str:
    """``--location``: ``LAT,LON[,ALT]`` (:func:`magfit.geomag.parse_location`), or ``log`` (its GNSS fixes)."""
    return "log" if text.strip().lower() == "log" else parse_location(text)


def render_output(
    compass: CompassCalibration,
    export_format: str | None,
    unit: str | None,
    system_id: int | None = None,
    force: bool = False,
) -> str:
    """The text of one calibration: its JSON, or the firmware export (``system_id``: PX4's, for ``px4``;
    ``force``: written although its field strength is no Earth field in its unit)."""
    if export_format is None:
        return compass.calibration.to_json() + "\n"
    from ..export import export

    options = _export_options(compass, export_format, system_id, force)
    return export(compass.calibration, export_format, unit=unit, **options)


def _export_options(
    compass: CompassCalibration, export_format: str, system_id: int | None, force: bool = False
) -> dict[str, Any]:
    """The export's options: PX4's ``system_id``; the model's field for a format that takes it (ArduPilot's
    COMPASS_SCALE, as its own calibrator sets it), in the calibration's unit; ``--force`` writes a field strength
    that is no Earth field in its unit (``allow_unit_mismatch``)."""
    from ..export import FORMATS

    options: dict[str, Any] = {} if system_id is None else {"system_id": system_id}
    if force:
        options["allow_unit_mismatch"] = True
    unit = compass.calibration.unit
    model = compass.model_field
    if model is not None and "expected_field" in FORMATS[export_format].options and unit and get_unit(unit).is_physical:
        options["expected_field"] = model.field.total_in(unit)
    sensor = compass.calibration.sensor
    known = sensor is not None and sensor.device_id is not None
    if export_format == "px4" and compass.sensor is not None and known:  # TC_Mn_* where the log determines it
        from ..temperature import compass_drift

        drift = compass_drift(compass.path, compass.sensor, compass.calibration)
        if drift is not None and drift.determined:
            options["temperature"] = drift
    return options


def safe_name(sensor: str) -> str:
    """A compass id as a piece of a file name: ``sensor_mag/0`` -> ``sensor_mag_0``, ``/imu/mag`` -> ``imu_mag``."""
    return re.sub(r"[^A-Za-z0-9._-]+", "_", sensor).strip("_.") or "compass"


def several_outputs(
    file: Path,
    result: FileCalibration,
    output: Path | None,
    export_format: str | None,
    unit: str | None,
    system_id: int | None,
    force: bool = False,
) -> list[tuple[Path, bytes]]:
    """The files that carry a log's several calibrations: one parameter file holding every compass (ArduPilot,
    PX4), else one file per compass named ``<stem>-<sensor><ext>`` beside ``-o``, none of which may exist."""
    from ..io import STDOUT

    ids = ", ".join(compass.sensor or "?" for compass in result.compasses)
    if export_format in SEVERAL_IN_ONE_FILE:
        from ..export import export_several

        # One expected field for the file: the compasses of a log share its unit.
        units = {compass.calibration.unit for compass in result.compasses}
        options = _export_options(result.compasses[0], export_format, system_id, force)
        if len(units) != 1:
            options.pop("expected_field", None)
        calibrations = [compass.calibration for compass in result.compasses]
        text = export_several(calibrations, export_format, unit=unit, **options)
        return [(output if output is not None else Path(STDOUT), text.encode("utf-8"))]
    what = f"the {export_format} format" if export_format else "a JSON calibration"
    if output is None or str(output) == STDOUT:
        fail(
            f"{file}: holds {len(result.compasses)} compasses ({ids}) and {what} holds one: give -o NAME, and each "
            "goes to NAME-SENSOR with NAME's extension (or choose one with --sensor ID)"
        )
    files = []
    for compass in result.compasses:
        path = output.with_name(f"{output.stem}-{safe_name(compass.sensor or '')}{output.suffix}")
        refuse_overwriting_input(path, [file])
        if path.exists() or path.is_symlink():
            fail(
                f"{path} exists: the calibration of {compass.sensor} would replace it; remove it or give another -o "
                "NAME (a file per compass is never written over)"
            )
        files.append((path, render_output(compass, export_format, unit, system_id, force).encode("utf-8")))
    return files


def check_outputs(file: Path, output: Path | None, plot_path: Path | None) -> None:
    """Refuse, before the fit, outputs that would clobber the input or each other, or cannot be written."""
    from ..io import STDOUT, check_output

    outputs = [path for path in (output, plot_path) if path is not None]
    for path in outputs:
        if str(path) != STDOUT:
            refuse_overwriting_input(path, [file])
        check_output(path)
    if output is not None and plot_path is not None and str(output) != STDOUT and same_file(output, plot_path):
        fail(f"-o and --plot are the same file {output}; give each its own path")


@click.command("calibrate")
@click.argument("file", type=click.Path(path_type=Path))
@click.option(
    "-m",
    "--method",
    type=RegistryChoice("method", method_names),
    default=None,
    help="Calibration method (default: auto when available, else ellipsoid).",
)
@click.option(
    "--columns",
    callback=parse_columns,
    metavar="X,Y,Z",
    help="The three magnetometer columns: names (mx,my,mz) or 0-based numbers (3,4,5). Default: detected.",
)
@click.option(
    "-o",
    "--output",
    type=click.Path(dir_okay=False, path_type=Path),
    help="Write the calibration here (JSON, or the --export format), replacing the file atomically; - for stdout. "
    "A log's several compasses: one ArduPilot or PX4 parameter file holding them all, else one file per compass "
    "named NAME-SENSOR.EXT beside it (never replacing an existing file).",
)
@click.option(
    "--export",
    "export_format",
    type=RegistryChoice("format", export_format_names),
    help="Write a firmware format instead of JSON: to -o, or to stdout without -o.",
)
@click.option("--unit", help="Name of the input unit (uT, mG, counts ...), stored in the calibration and exports.")
@nonfinite_option
@click.option(
    "--field-strength",
    type=FieldStrength(),
    default=None,
    metavar="NUMBER|wmm",
    help="Known magnitude of the local field, in the samples' unit, or 'wmm' for the World Magnetic Model's at "
    "--location (or at a flight log's or bag's own GNSS fixes and date; needs the samples' unit): the corrected "
    "field is scaled to it, the sphere fit pins its radius to it (see docs/methods.md), and an ArduPilot export "
    "fills COMPASS_SCALE from it.",
)
@click.option(
    "--location",
    callback=geomag_option(parse_place),
    metavar="LAT,LON[,ALT]|log",
    help="Where the recording was made (degrees; ALT in km above the WGS-84 ellipsoid, or 500m), or 'log' for a "
    "flight log's or bag's own GNSS fixes: the World Magnetic Model's field is printed beside the fitted one, with a "
    "warning when they differ by more than 10 %.",
)
@click.option(
    "--date",
    "model_date",
    callback=geomag_option(parse_date),
    metavar="YYYY-MM-DD",
    help="When the recording was made, for the World Magnetic Model (default: a log's first GNSS fix, else today).",
)
@click.option(
    "--even",
    is_flag=True,
    help="Fit an even subsample: every direction weighs the same, so a long stay in one attitude does not "
    "pull the fit (see docs/scaling.md). The score still uses every sample.",
)
@click.option(
    "--max-samples",
    type=click.IntRange(min=10),
    default=None,
    help="Most samples an iterative method (ml, robust, auto) holds in memory; a larger file is fitted on an "
    "even subsample of this many; a flight log's compass with more records is read on a regular stride of "
    "them (any method). At least 400 for a samples file (one per cell of directions). Default: 500 000, fewer "
    "when memory is short.",
)
@click.option(
    "--system-id",
    type=click.IntRange(1, 255),
    default=None,
    help="With --export px4: the vehicle's MAV_SYS_ID written in the parameter file (QGroundControl refuses a file "
    "written for another id). Default 1.",
)
@click.option(
    "--plot",
    "plot_path",
    type=click.Path(dir_okay=False, path_type=Path),
    help="Also draw the samples before and after the fit into this figure (.png, .svg, .pdf), as 'magfit plot'.",
)
@click.option(
    "--sensor",
    metavar="ID",
    help="The compass of a flight log to fit (its id or device id, as 'magfit inspect FILE' lists them); needed "
    "when the log holds several.",
)
@click.option(
    "--force",
    is_flag=True,
    help="Return the calibration even when the samples do not support it (exit 0): it is marked NOT SUPPORTED "
    "and the refusal is printed as a warning. To inspect a poor recording, not to use its numbers.",
)
@click.option(
    "--attitude",
    callback=parse_stream,
    metavar="ROLL,PITCH,YAW|W,X,Y,Z",
    help="A samples file's attitude columns for --method vector: roll, pitch, yaw (degrees or radians, detected) "
    "or a quaternion w, x, y, z; names or 0-based numbers as --columns. Default: found by name.",
)
@click.option(
    "--reference",
    callback=parse_stream,
    metavar="N,E,D",
    help="A samples file's reference field columns (north, east, down, in the samples' unit) for --method vector. "
    "Default: found by name (ref_n ...), else the World Magnetic Model at --location or the file's lat/lon columns.",
)
@click.option("--gyro", callback=parse_stream, metavar="GX,GY,GZ", help="A samples file's gyroscope columns (rad/s).")
@click.option("--accel", callback=parse_stream, metavar="AX,AY,AZ", help="A samples file's accelerometer columns.")
@click.option("--time", "time_column", callback=parse_stream, metavar="T", help="A samples file's time column (s).")
@click.option(
    "--attitude-convention",
    type=click.Choice(["ned", "enu"]),
    default="ned",
    show_default=True,
    help="ned: aerospace 3-2-1 (yaw, pitch, roll), body forward-right-down to North-East-Down; enu: ROS's, "
    "forward-left-up to East-North-Up (the reference columns then E, N, U).",
)
@click.option(
    "--angle-unit",
    type=click.Choice(["auto", "deg", "rad"]),
    default="auto",
    show_default=True,
    help="The attitude angles' unit; auto decides from the values and refuses a file they leave ambiguous.",
)
@click.option(
    "--gyro-unit",
    type=click.Choice(["rad/s", "deg/s"]),
    default="rad/s",
    show_default=True,
    help="The gyroscope columns' unit.",
)
@click.option(
    "--motor",
    type=click.Choice(["auto", "current", "throttle", "none"]),
    default="auto",
    show_default=True,
    help="The motors' field in a flight log: fit it with the calibration from the battery current or the throttle "
    "when the log determines it and it matters (auto), from the one named whenever it is determined, or never "
    "(none). Exported as COMPASS_MOT*/COMPASS_MOTCT (ardupilot) or CAL_MAGn_xCOMP/CAL_MAG_COMP_TYP (px4).",
)
def calibrate_command(
    file: Path,
    method: str | None,
    columns: list[str | int] | None,
    output: Path | None,
    export_format: str | None,
    unit: str | None,
    nonfinite: Nonfinite,
    field_strength: float | str | None,
    location: tuple[float, float, float] | str | None,
    model_date: datetime.date | None,
    even: bool,
    max_samples: int | None,
    plot_path: Path | None,
    force: bool,
    system_id: int | None,
    sensor: str | None,
    attitude: list[str | int] | None = None,
    reference: list[str | int] | None = None,
    gyro: list[str | int] | None = None,
    accel: list[str | int] | None = None,
    time_column: list[str | int] | None = None,
    attitude_convention: str = "ned",
    angle_unit: str = "auto",
    gyro_unit: str = "rad/s",
    motor: str = "auto",
) -> None:
    """Fit a calibration to a recording and print it; save it with -o.

    FILE holds raw magnetometer samples recorded while turning the sensor in all directions (CSV, TSV,
    whitespace-separated text, .npy or .npz), or is a flight log or bag (PX4 ULog, ArduPilot DataFlash .bin, MAVLink
    telemetry log .tlog, ROS 1/2 bag, MCAP): each compass of a log is fitted, or the one --sensor names. The summary
    gives the offset, the matrix, the field strength, the ellipsoid semi-axes and the paper's mean/std of the
    distance to the unit sphere (for a log also the time span and the share of directions covered). With --export
    and no -o the export goes to stdout and the summary to stderr.

    \b
    Examples:
      magfit calibrate flight.csv --columns mx,my,mz -o cal.json --unit uT
      magfit calibrate mag.txt --method sphere
      magfit calibrate flight.csv --unit uT --export ardupilot -o mag.param
      magfit calibrate flight.csv --export c > mag_cal.h
      magfit calibrate mag.txt --unit uT --plot mag.png
      magfit calibrate parked_then_tumbled.csv --even
      magfit calibrate boat.csv --unit uT --field-strength 48.2
      magfit calibrate boat.csv --unit uT --field-strength wmm --location 47.4,8.5,0.5 --date 2026-06-01
      magfit calibrate 00000042.BIN --field-strength wmm --export ardupilot -o compasses.param
      magfit calibrate flight.ulg --sensor sensor_mag/0 -o mag0.json
      magfit calibrate flight.csv --unit nT --method vector --attitude roll,pitch,yaw --reference ref_n,ref_e,ref_d
    """
    from ..io import STDOUT, write_all
    from ..sources import log_kind
    if plot_path is not None:
        from .plot import check_figure_path

        require("plot", "'magfit calibrate --plot'", ("matplotlib",))  # before the calibration is written
        check_figure_path(plot_path, "'--plot'")
    check_outputs(file, output, plot_path)
    if system_id is not None and export_format != "px4":
        raise click.UsageError("--system-id goes with --export px4: it is the vehicle id a PX4 parameter file names")
    if file.is_file() and file.stat().st_size == 0:  # said before the options that need what a file holds
        raise DataFileError(f"{file}: is empty (0 bytes); record some samples or give another file")
    is_log = log_kind(file) is not None
    needs_streams = bool(get_method(method or default_method()).needs)  # vector: a file's own lat/lon columns
    if location is None and model_date is not None and field_strength != "wmm" and not needs_streams:
        raise click.UsageError("--date goes with --location: the World Magnetic Model needs the place too")
    if location is None and field_strength == "wmm" and not is_log:
        raise click.UsageError("--field-strength wmm needs --location LAT,LON[,ALT] (where the recording was made)")
    # No --method: the library's default (auto, then a vehicle's own streams when auto refuses it).
    by_default, method = method is None, method or default_method()
    if output is not None and export_format is not None and str(output) != STDOUT:
        _check_extension(output, export_format)
    asked: dict[str, Any] = dict(
        sensor=sensor, columns=columns, unit=unit, field_strength=field_strength, location=location, force=force,
        nonfinite=nonfinite, even=even, max_samples=max_samples, attitude=attitude, reference=reference, gyro=gyro,
        accel=accel, time=time_column, attitude_convention=attitude_convention, angle_unit=angle_unit,
        gyro_unit=gyro_unit, motor=motor,
    )  # fmt: skip
    try:
        result = _calibrate(file, None if by_default and method == "auto" else method, model_date=model_date, **asked)
    except StreamsMissing as error:
        raise CommandError(
            f"{one_line(error.text)}; on the command line: {command_line('calibrate', file, error.remedy)}"
        ) from None
    except CalibrationError as error:
        mixup = _field_in_another_unit(file, method, model_date, asked, error.codes)
        if mixup is not None:
            raise mixup from None
        if not isinstance(error, RefusedWithAdvice):
            raise
        said = "; ".join(f"{reason} ({command_line('calibrate', file, reason.remedy)})" for reason in error.advice)
        works = f"; what works for a vehicle: {said}" if said else ""
        raise FitFailedError(f"{one_line(error.text)}{works}") from None
    if not result.compasses:  # a log's compasses, none fitted: a field strength given in another unit is said
        for failure in result.failures:  # (a log's compasses share its unit: the first compass refused for it)
            if {"unit_mismatch", "field_mismatch"} & set(failure.codes):
                one = {**asked, "sensor": failure.sensor}
                if (mixup := _field_in_another_unit(file, method, model_date, one, failure.codes)) is not None:
                    raise mixup
                break
    several = len(result.compasses) + len(result.failures) > 1
    # Everything is computed before anything is written: a failure leaves every existing file as it was.
    files: list[tuple[Path, bytes]] = []
    wanted = output is not None or export_format is not None
    if several and (wanted or plot_path is not None) and result.failures:
        _print_all(result)
        raise CalibrationError(
            f"{file}: {_failed(result)}; nothing is written (the warnings above say why); write the others one by "
            "one with --sensor ID"
        )
    if several and plot_path is not None:
        ids = ", ".join(compass.sensor or "?" for compass in result.compasses)
        fail(f"{file}: --plot draws one compass: choose it with --sensor ID ({ids})")
    if several and wanted:
        files = several_outputs(file, result, output, export_format, unit, system_id, force)
    elif wanted:
        text = render_output(result.compasses[0], export_format, unit, system_id, force)
        files.append((output if output is not None else Path(STDOUT), text.encode("utf-8")))
    to_stdout = any(str(path) == STDOUT for path, _ in files)
    stdout_text = b"".join(data for path, data in files if str(path) == STDOUT).decode("utf-8")
    files = [(path, data) for path, data in files if str(path) != STDOUT]
    written = [_wrote_line(path, result, export_format) for path, _ in files]
    plot_line = None
    if plot_path is not None:
        compass = result.compasses[0]
        samples = _samples_drawn(file, compass, columns, nonfinite)
        figure, plot_line = plot_calibration(samples, compass.calibration, plot_path, file.name)
        files.append((plot_path, figure))
    write_all(files)
    _print_all(result, stderr=to_stdout)
    if any(compass.magnetometer is not None for compass in result.compasses):  # a log's (imported for logs only)
        from ._consistency import print_log_checks

        print_log_checks(result, stderr=to_stdout)
    summary = console(stderr=to_stdout)
    for line in [*written, plot_line]:
        if line is not None:
            summary.print(line, soft_wrap=True)
    if to_stdout:
        click.echo(stdout_text, nl=not stdout_text.endswith("\n"))
    if result.failures:
        raise CalibrationError(f"{file}: {_failed(result)}; the warnings above say why")


def _calibrate(file: Path, method: str | None, *, model_date: datetime.date | None, **options: Any) -> FileCalibration:
    """:func:`calibrate_file` with the progress bar and the notes as warnings, each said once: a note the
    refusal of its compass repeats (a log's low-rate note, which the library appends for callers not told the
    notes) is left to the refusal, which names the remedy where the failure is; a note of the whole log (a
    last message cut short), which the library tells with each compass, is said once for the file."""
    said: list[str] = []
    try:
        result = calibrate_file(file, method, date=model_date, progress=progress_bar, notify=said.append, **options)
    except Exception as error:  # the notes first, as before: they often say why
        refusal = error.text if isinstance(error, RefusedWithAdvice) else str(error)
        for note in _once(file, [note for note in said if _bare(note) not in refusal], 1):
            warn(note)
        raise
    kept = []
    for note in said:
        compass = next((f for f in result.failures if f"{file} ({f.sensor}): " in note), None)
        if compass is None or _bare(note) not in compass.reason:
            kept.append(note)
    for note in _once(file, kept, len(result.compasses) + len(result.failures)):
        warn(note)
    return result


def _field_in_another_unit(
    file: Path, method: str, model_date: datetime.date | None, asked: dict[str, Any], codes: Sequence[str]
) -> CommandError | None:
    """The usage error of a ``--field-strength`` a power of ten away from the samples' own field (a refusal
    with code ``unit_mismatch`` or ``field_mismatch`` whose ratio is a unit's factor): the value, the likely
    mix-up and the value in the samples' unit; None for any other refusal.

    The samples' own field is the same fit's without the field strength (forced: only its radius is read).
    """
    from ..diagnostics.verdict import unit_mixup

    given = asked.get("field_strength")
    if not isinstance(given, float) or not given > 0 or not {"unit_mismatch", "field_mismatch"} & set(codes):
        return None
    fitted = None
    try:
        free = calibrate_file(file, method, date=model_date, notify=None, **{**asked, "field_strength": None,
                                                                             "force": True})  # fmt: skip
        fitted = free.compasses[0].calibration.field_strength if free.compasses else None
    except MagfitError:
        pass
    if fitted is None or not fitted > 0:
        if "unit_mismatch" not in codes:
            return None
        return CommandError(
            f"{file}: --field-strength {given:g} is a power of ten away from the field the samples show: likely a "
            "unit mix-up; give the field strength in the samples' unit, or leave --field-strength out"
        )
    ratio = fitted / given
    mixup = unit_mixup(ratio)
    if mixup is None:  # a field strength the samples contradict, not by a unit's factor: the refusal stands
        return None
    size = max(ratio, 1 / ratio)
    times = f"{size:,.0f}" if size >= 100 else f"{size:.3g}"
    how = f"{times} times {'smaller' if ratio > 1 else 'larger'}"
    return CommandError(
        f"{file}: --field-strength {given:g} is {how} than the field the samples show ({significant(fitted, 4)}): "
        f"{mixup}; give it in the samples' unit (--field-strength {significant(given * _power_of_ten(ratio), 4)}), "
        "or leave --field-strength out"
    )


def _power_of_ten(ratio: float) -> float:
    """The power of ten nearest ``ratio``: the unit factor of a mix-up."""
    return float(10.0 ** round(math.log10(ratio)))


def _bare(note: str) -> str:
    """A note as the library appends it to a refusal: without its ``<file> (<compass>): `` (as said)."""
    return note.split("): ", 1)[-1]


def _once(file: Path, notes: Sequence[str], n_compasses: int) -> list[str]:
    """``notes`` (each ``<file> (<compass>): <note>``) with a note said of several compasses said once, where
    it is first said: of the file when it was said of every compass, else naming the compasses."""
    compasses: dict[str, list[str]] = {}
    for note in notes:
        compass = note[len(f"{file} (") :].split("): ", 1)[0] if note.startswith(f"{file} (") else ""
        compasses.setdefault(_bare(note), []).append(compass)
    once, seen = [], set()
    for note in notes:
        bare, ids = _bare(note), compasses[_bare(note)]
        if len(ids) < 2:
            once.append(note)
        elif bare not in seen:
            seen.add(bare)
            once.append(f"{file}: {bare}" if len(ids) >= n_compasses else f"{file} ({', '.join(ids)}): {bare}")
    return once


def _wrote_line(path: Path, result: FileCalibration, export_format: str | None) -> str:
    """``wrote the calibration to cal.json``; which compasses when the log holds several."""
    what = f"{export_format} export" if export_format else "calibration"
    if len(result.compasses) == 1:
        return f"wrote the {what} to {path}"
    if export_format in SEVERAL_IN_ONE_FILE:
        return f"wrote the {what} of {', '.join(c.sensor or '?' for c in result.compasses)} to {path}"
    (compass,) = [c for c in result.compasses if path.stem.endswith("-" + safe_name(c.sensor or ""))][:1]
    return f"wrote the {what} of {compass.sensor} to {path}"


def _failed(result: FileCalibration) -> str:
    total = len(result.compasses) + len(result.failures)
    names = ", ".join(failure.sensor for failure in result.failures)
    return f"{len(result.failures)} of {total} magnetometers could not be fitted ({names})"


def _print_all(result: FileCalibration, *, stderr: bool = False) -> None:
    """Each compass's summary in the log's order (one block each, a blank line between), a failure as its
    warning and a line saying it was not fitted."""
    out = console(stderr=stderr)
    fitted = {compass.sensor or "": compass for compass in result.compasses}
    failed = {failure.sensor: failure for failure in result.failures}
    order = result.sensors or tuple(compass.sensor or "" for compass in result.compasses)
    for index, sensor in enumerate(order):
        if index:
            out.print("")
        if sensor in failed:
            warn(failed[sensor].reason)
            _warn_advice(failed[sensor].advice, result.path, "")
            out.print(f"{'sensor':<16} {sensor}: not fitted (the warning above says why)")
            continue
        compass = fitted[sensor]
        if compass.n_skipped:
            lines = ", ".join(map(str, compass.skipped_lines[:5]))
            more = ", ..." if compass.n_skipped > 5 else ""
            warn(
                f"{compass.path}: skipped {compass.n_skipped} of {compass.n_rows} rows with NaN or inf values, values "
                "beyond ±1e150 or a last line cut short (lines "
                f"{lines}{more}); pass --nonfinite error to refuse such files"
            )
        for message in _fit_warnings(compass.calibration):
            warn(message)
        for reason in compass.warnings:  # the unit check (unit_mismatch) and the like
            warn(str(reason))
        _warn_advice(compass.advice, compass.path, " (level with turns)" if compass.magnetometer is None else "")
        print_summary(out, compass)
        if compass.model_field is not None:
            model, unit = compass.model_field, compass.calibration.unit
            physical = unit if unit and get_unit(unit).is_physical else None
            _print_model_field(out, compass.calibration, model, physical)
    if not result.compasses and result.model_field is not None:  # nothing fitted: the model still says what to expect
        field = result.model_field.field
        out.print("")
        out.print(
            f"{'model field':<16} {significant(field.total_in('uT'), 6)} uT ({field.describe()}, inclination "
            f"{field.inclination_deg:.1f}°) at {result.model_field.origin}",
            soft_wrap=True,
        )


def _warn_advice(advice: Sequence[Any], path: Path, why: str) -> None:
    """The methods that work for a vehicle (:class:`magfit.findings.Reason` with remedies), as commands to type."""
    if advice:
        said = "; ".join(f"{reason} ({command_line('calibrate', path, reason.remedy)})" for reason in advice)
        warn(f"{path}: a vehicle's recording{why}; what works for a vehicle: {said}")


def _samples_drawn(
    file: Path, compass: CompassCalibration, columns: Sequence[str | int] | None, nonfinite: Nonfinite
) -> Any:
    """The samples ``--plot`` draws: the file's columns, or the log's compass."""
    if compass.magnetometer is not None:
        from ..sources import open_source

        return open_source(file, everything=False).read(compass.magnetometer.id).samples
    from ..io import read_samples

    return read_samples(file, columns=columns, nonfinite=nonfinite).samples


def plot_calibration(samples: Any, calibration: Calibration, output: Path, title: str) -> tuple[bytes, str]:
    """Draw ``samples`` before and after ``calibration`` for ``output`` (``calibrate --plot``).

    Returns the figure in ``output``'s format (written with the other outputs, so that a failure leaves
    every file as it was) and the line to print.
    """
    from ..plot import calibration_figure
    from .plot import figure_bytes

    figure = calibration_figure(samples, calibration, title=title)
    return figure_bytes(figure, output), f"{figure.get_supxlabel()} Wrote the figure to {output}"


def _print_model_field(out: Console, calibration: Calibration, model: ModelField, unit: str | None) -> None:
    """The model's field (strength and inclination) beside the fitted one, and the library's warning when they
    differ by more than 10 % (``model.mismatch``); where the place came from when it is the log's own fixes."""
    field = model.field
    shown = unit or "uT"
    sigma = field.total_uncertainty
    spread = f" ± {significant(sigma * conversion_factor('nT', shown), 2)}" if sigma else ""
    line = f"{significant(field.total_in(shown), 6)}{spread} {shown} ({field.describe()}, inclination "
    line += f"{field.inclination_deg:.1f}°)"
    fitted = calibration.known_field.fitted if calibration.known_field is not None else None
    if unit is None:
        line += "; not compared with the fit: the samples' unit is unknown (give --unit)"
    elif fitted is not None:
        line += f"; used as the field strength (the samples alone: {significant(fitted, 6)} {unit})"
    out.print(f"{'model field':<16} {line}", soft_wrap=True)
    if model.origin != "the location given":
        out.print(f"{'':<16} at {model.origin}", soft_wrap=True)
    if model.mismatch is not None:
        warn(str(model.mismatch))


def _fit_warnings(calibration: Calibration) -> list[str]:
    """The warnings the fit's diagnostics attached (poor coverage, weak directions ...), if any; each said once
    (a forced auto's refusal quotes its model's own, which is not said again)."""
    diagnostics = calibration.diagnostics
    if diagnostics is None:
        return []
    warnings = [str(message) for message in diagnostics.warnings]
    forced = "NOT SUPPORTED (forced): "
    return [
        warning
        for warning in warnings
        if not warning.startswith(forced)
        or not any(other != warning and warning.removeprefix(forced) in other for other in warnings)
    ]


def _check_extension(output: Path, export_format: str) -> None:
    """Warn when ``-o`` does not carry the export format's usual extension (a likely mix-up)."""
    from ..export import FORMATS

    extension = FORMATS[export_format].extension
    if output.suffix.lower() != extension:
        warn(f"{output}: writing the {export_format} format, whose files usually end in {extension}")


def _choice(calibration: Calibration) -> list[tuple[str, str]]:
    """For a method that chooses among others (``auto``): the method it used and why."""
    choice = calibration.auto
    if choice is None:
        return []
    used, reason = choice.method_used, choice.reason
    model = f"{choice.chosen} model" + (f", maximum-likelihood fit started from {used}" if used else "")
    support = calibration.support
    if support is not None and support.forced and reason in support.refusals:  # said as a warning already
        reason = "forced: the samples determine no model, as the warning above says"
    return [("chose", model + (f" ({reason})" if reason else ""))]


def _verdict(calibration: Calibration) -> list[tuple[str, str]]:
    """Whether the samples support the calibration (``calibration.support``, when the fit reached a verdict)."""
    support = calibration.support
    if support is None:
        return []
    verdict = support.verdict
    if verdict == "refused":
        return [("verdict", "NOT SUPPORTED by the samples, returned because of --force: do not use these numbers")]
    weaknesses = support.weaknesses
    if verdict == "weak" and weaknesses:
        return [("verdict", f"weak: {len(weaknesses)} weakness(es), in the warnings above")]
    return [("verdict", verdict)]


def _uncertainty(run: CompassCalibration) -> list[tuple[str, str]]:
    """The share of directions covered and the heading one-sigma, as the fit's diagnostics state them (the one
    uncertainty the warnings quote; :attr:`magfit.Calibration.diagnostics`); a log's coverage is already on its
    ``directions`` line."""
    diagnostics = run.calibration.diagnostics
    lines = []
    cover = diagnostics.coverage if diagnostics is not None else None
    if run.magnetometer is None and cover is not None:
        lines.append(("coverage", f"{100 * cover.share:.0f} % of the sphere of field directions reached"))
    spread = diagnostics.uncertainty if diagnostics is not None else None
    if spread is not None and spread.heading_sigma_deg is not None:
        worst, inclination = spread.heading_sigma_max_deg, spread.inclination_deg
        text = f"± {spread.heading_sigma_deg:.2g}° one-sigma at level (RMS over headings"
        text += f", worst ± {worst:.2g}°" if worst is not None else ""
        text += f"; inclination {inclination:.0f}°)" if math.isfinite(inclination) else ")"
        lines.append(("heading", text))
    elif (gyro := run.calibration.gyro) is not None and gyro.heading_sigma_deg is not None:
        # gyro's one-sigma is its own (the kinematic fit's covariance, the halves' difference joined): no
        # magnitude-only diagnosis is run on its samples.
        lines.append(("heading", f"± {gyro.heading_sigma_deg:.2g}° one-sigma at level (the gyro fit's)"))
    return lines


def _fitted_on(run: CompassCalibration) -> list[tuple[str, str]]:
    """When the fit used an even subsample: how many samples, and why."""
    if run.subsample is None:
        return []
    used = run.calibration.n_samples
    why = run.subsample  # (said in the command line's words: magfit.remedy)
    kind = "a regular stride" if run.subsample.startswith("stride") else "an even subsample"  # a long log's
    return [("fitted on", f"{kind}: {used} of {run.n_rows - run.n_skipped} samples ({why})")]


def _log_lines(run: CompassCalibration) -> list[tuple[str, str]]:
    """For a log's compass: the time span fitted (a date-time on an epoch time base) and its rate, and the share
    of the sphere of directions the samples reach."""
    if run.magnetometer is None:
        return []
    rate = f", {run.rate_hz:.1f} Hz" if run.rate_hz == run.rate_hz else ""
    lines = [("time", time_span(run.start_s, run.end_s, run.time_base) + rate)]
    if run.coverage is not None:
        lines.append(("directions", f"{100 * run.coverage:.0f} % of the sphere of field directions reached"))
    return lines


def _motor_lines(calibration: Calibration) -> list[tuple[str, str]]:
    """The motors' field, in words, when a log's current or throttle was tried (``details["motor"]``)."""
    facts = calibration.details.get("motor")
    if not isinstance(facts, Mapping) or not facts.get("tried"):
        return []
    tried = [t for t in facts["tried"] if isinstance(t, Mapping)]
    chosen = [t for t in tried if t.get("source") == facts.get("chosen")]
    shown = chosen or tried
    lines = [("motors", str(shown[0].get("summary", "")))]
    if calibration.motor is not None:
        k = vector(calibration.motor.coefficients, lambda v: significant(v, 4))
        per = "A" if calibration.motor.regressor == "current" else "full throttle"
        lines.append(("motor term", f"k = {k} {calibration.unit or 'units'} per {per}, raw axes, before the matrix"))
    return lines


def print_summary(out: Console, run: CompassCalibration) -> None:
    """The calibration and its score, one labelled line each (plain text: easy to read and to grep)."""
    calibration = run.calibration
    unit = f" {calibration.unit}" if calibration.unit else ""
    spec = get_method(calibration.method) if calibration.method in method_names() else None
    matrix_rows = [vector(row, lambda v: f"{v: .6f}") for row in calibration.matrix]
    lines = [
        ("file", f"{run.path} ({run.file_format})"),
        ("columns", columns_text(run.columns) + (f" ({run.column_note})" if run.column_note else "")),
        ("rows", f"{run.n_rows} read, {run.n_skipped} skipped" + (" (streamed)" if run.streamed else "")),
        *_log_lines(run),
        ("method", calibration.method + (f": {spec.summary}" if spec is not None else "")),
        *_choice(calibration),
        *_fitted_on(run),
        ("offset", vector(calibration.offset, lambda v: significant(v, 6)) + unit),
        ("matrix", matrix_rows[0]),
        ("", matrix_rows[1]),
        ("", matrix_rows[2]),
        ("field strength", significant(calibration.field_strength, 6) + unit),
        ("semi-axes", vector(calibration.semi_axes, lambda v: significant(v, 6)) + unit),
        (
            "sphere distance",
            f"mean {fixed(run.evaluation.mean)}  std {fixed(run.evaluation.std)}  "
            f"(paper, section V: fraction of the field strength, n = {run.evaluation.n})",
        ),
        *_uncertainty(run),
        *_motor_lines(calibration),
        *_verdict(calibration),
        ("convention", CONVENTION if calibration.motor is None else CONVENTION[:-1] + " - k c)"),
    ]
    for label, value in lines:
        out.print(f"{label:<16} {value}", soft_wrap=True)
