"""``magfit apply``: correct a recording with a saved calibration."""

from __future__ import annotations

from pathlib import Path

import click

from ..calibration import CONVENTION, Calibration
from ..errors import DataFileError, MagfitError
from ._common import columns_text, console, parse_columns, refuse_overwriting_input


def read_calibration(path: Path) -> Calibration:
    """The calibration saved in ``path`` by ``magfit calibrate -o`` (:meth:`Calibration.to_json`)."""
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise DataFileError(f"calibration file {path} does not exist") from None
    except (OSError, UnicodeDecodeError) as error:
        raise DataFileError(f"cannot read the calibration file {path}: {error}") from None
    try:
        return Calibration.from_json(text)
    except MagfitError as error:
        raise DataFileError(f"{path}: {error}; write it with 'magfit calibrate FILE -o {path.name}'") from None


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
def apply_command(
    calibration_file: Path, file: Path, output: Path, columns: list[str | int] | None, normalized: bool
) -> None:
    """Correct the samples of FILE with the calibration CAL and write them to -o.

    Each sample becomes matrix @ (raw - offset); the file's other columns (time, gyro ...) and its
    format (delimiter, header) are kept. CAL is a JSON file written by 'magfit calibrate -o'.

    \b
    Example:
      magfit calibrate flight.csv --columns mx,my,mz -o cal.json
      magfit apply cal.json flight.csv --columns mx,my,mz -o flight_calibrated.csv
    """
    from ..io import STDOUT, check_output, write_calibrated

    to_stdout = str(output) == STDOUT
    if not to_stdout:
        refuse_overwriting_input(output, [file, calibration_file])
    check_output(output)
    calibration = read_calibration(calibration_file)
    written = write_calibrated(file, calibration, output, columns=columns, normalized=normalized)
    out = console(stderr=to_stdout)
    scale = "unit sphere" if normalized else f"input units{f' ({calibration.unit})' if calibration.unit else ''}"
    used = f" (columns {columns_text(columns)})" if columns else ""
    out.print(f"wrote {written}: {file}{used} corrected with {calibration_file} ({calibration.method}), {scale}")
    out.print(f"convention: {CONVENTION}")
