"""``magfit compare``: the paper's comparison table (section V) for each recording."""

from __future__ import annotations

import csv
import io
import json
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import click
from rich.table import Table
from rich.text import Text

from ..compare import PAPER_METHODS, Comparison, MethodResult, compare
from ._advice import own_options
from ._common import (
    EXIT_FIT_FAILED,
    Nonfinite,
    columns_text,
    console,
    fixed,
    method_names,
    nonfinite_option,
    parse_columns,
    significant,
    vector,
)
from ._logs import read_recordings, sensor_option, with_streams

OUTPUT_FORMATS = ("table", "markdown", "csv", "json")
_CSV_FIELDS = (
    "file",
    "method",
    "status",
    "mean",
    "std",
    "field_strength",
    "semi_axis_x",
    "semi_axis_y",
    "semi_axis_z",
    "offset_x",
    "offset_y",
    "offset_z",
    "error",
    "unit",
)
#: Significant digits of the field strength, semi-axes and offsets: any unit (tesla or counts) reads alike.
DIGITS = 6


def caption(unit: str | None) -> str:
    """The note under the tables: what the numbers are, and their unit."""
    units = unit if unit else "the file's units"
    return (
        "mean, std: signed distance of the calibrated samples to the unit sphere (paper, section V), a fraction "
        f"of the field strength; field strength, semi-axes and offset in {units}"
    )


@dataclass(frozen=True, eq=False)
class FileComparison:
    """One file's comparison and what was read from it."""

    name: str
    columns: tuple[Any, ...]
    n_rows: int
    n_skipped: int
    comparison: Comparison
    unit: str | None = None
    column_note: str | None = None


def parse_methods(ctx: click.Context, param: click.Parameter, value: str | None) -> tuple[str, ...]:
    """``--methods ellipsoid,sphere`` into names, each checked against ``magfit.METHODS``."""
    if value is None:
        return PAPER_METHODS
    names = tuple(item.strip() for item in value.split(",") if item.strip())
    if not names:
        raise click.BadParameter("give at least one method", ctx, param)
    valid = method_names()
    unknown = [name for name in names if name not in valid]
    if unknown:
        raise click.BadParameter(
            f"unknown method {', '.join(map(repr, unknown))}; valid methods: {', '.join(valid)}", ctx, param
        )
    if len(set(names)) != len(names):
        raise click.BadParameter(f"a method is listed twice in {value!r}", ctx, param)
    return names


@click.command("compare")
@click.argument("files", nargs=-1, required=True, type=click.Path(dir_okay=False, path_type=Path))
@click.option(
    "--methods",
    callback=parse_methods,
    metavar="M,M,...",
    help="Comma-separated methods to compare. Default: the paper's ellipsoid,sphere,minmax.",
)
@click.option(
    "--columns",
    callback=parse_columns,
    metavar="X,Y,Z",
    help="The three magnetometer columns of every file: names or 0-based numbers. Default: detected.",
)
@click.option(
    "--format",
    "output_format",
    type=click.Choice(OUTPUT_FORMATS),
    default="table",
    show_default=True,
    help="table (terminal), markdown, csv (one row per file and method) or json (with the calibrations).",
)
@click.option("--unit", help="Name of the samples' unit (uT, mG, counts ...), shown with the numbers.")
@click.option(
    "--force",
    is_flag=True,
    help="Score the fits the samples do not support too (as the paper's tables do), marked NOT SUPPORTED, "
    "instead of listing them as failed with the reason.",
)
@nonfinite_option
@sensor_option
@click.pass_context
def compare_command(
    ctx: click.Context,
    files: tuple[Path, ...],
    methods: tuple[str, ...],
    columns: list[str | int] | None,
    output_format: str,
    unit: str | None,
    force: bool,
    nonfinite: Nonfinite,
    sensor: str | None,
) -> None:
    """Fit several methods to each FILE and compare them as the paper does.

    For each file: the mean and std of the distance of the calibrated samples to the unit sphere, the
    field strength, the ellipsoid semi-axes and the hard-iron offset per method (6 significant digits, in
    the --unit given, else the file's units). A fit the samples do not support is listed as failed with
    the reason, or with --force scored all the same and marked NOT SUPPORTED. A method that cannot
    fit a file shows its reason in the table instead. Exit status 0 when at least one method succeeded
    on every file, 1 when every method failed on some file, 2 when a file cannot be read.

    \b
    Examples:
      magfit compare mag-readings.txt
      magfit compare flight1.csv flight2.csv --methods ellipsoid,sphere,minmax --format markdown
      magfit compare log.txt --columns 0,1,2 --format json > comparison.json
      magfit compare hamagure.csv --unit G
      magfit compare flight.ulg --methods ellipsoid,sphere,auto

    A flight log or bag (ULog, DataFlash, ROS) is compared compass by compass, or for the one --sensor names.
    """
    with own_options(ctx, renamed={"--method": "--methods"}, file=files[0] if len(files) == 1 else "FILE"):
        results = _compared(files, methods, columns, unit, force, nonfinite, sensor)
    render = {"table": _print_tables, "markdown": _print_markdown, "csv": _print_csv, "json": _print_json}
    render[output_format](results)
    if not all(result.comparison.any_succeeded for result in results):
        ctx.exit(EXIT_FIT_FAILED)


def _compared(
    files: tuple[Path, ...],
    methods: tuple[str, ...],
    columns: list[str | int] | None,
    unit: str | None,
    force: bool,
    nonfinite: Nonfinite,
    sensor: str | None,
) -> list[FileComparison]:
    """Each recording's comparison (a log's compasses one by one)."""
    results = []
    for path in files:
        for recording in read_recordings(path, columns=columns, nonfinite=nonfinite, sensor=sensor):
            samples, streams = with_streams(recording, methods, unit, path=path, columns=columns, nonfinite=nonfinite)
            comparison = compare(samples, methods, allow_undetermined=force, streams=streams)
            name = str(path) if recording.sensor is None else f"{path} ({recording.sensor})"
            results.append(
                FileComparison(
                    name,
                    tuple(recording.columns),
                    recording.n_rows,
                    recording.n_skipped,
                    comparison,
                    unit or recording.unit,
                    recording.column_note,
                )
            )
    return results


def _reason(result: MethodResult) -> str:
    """Why a method failed, as this command words it (``--methods sphere``, each reason once)."""
    return str(result.error)


def _refusals(result: MethodResult) -> list[str] | None:
    """Why the samples do not support a fit scored only because of ``--force``; None for a supported one."""
    support = result.calibration.support if result.calibration is not None else None
    if support is None or support.verdict != "refused":
        return None
    return [str(reason) for reason in support.refusals]


def _label(result: MethodResult, mark: str = " (NOT SUPPORTED)") -> str:
    """The method's name, marked for a fit scored only because of ``--force``."""
    return result.method + (mark if _refusals(result) is not None else "")


def _numbers(result: MethodResult) -> list[str]:
    """mean, std (4 decimals of a fraction, as in the paper), field strength, semi-axes, offset (in the
    samples' unit: significant digits, so that data in tesla do not show 0.0000)."""
    assert result.calibration is not None and result.evaluation is not None
    calibration = result.calibration

    def digits(value: float) -> str:
        return significant(value, DIGITS)

    return [
        fixed(result.evaluation.mean),
        fixed(result.evaluation.std),
        digits(calibration.field_strength),
        vector(calibration.semi_axes, digits),
        vector(calibration.offset, digits),
    ]


def _heading(result: FileComparison) -> str:
    skipped = f", {result.n_skipped} skipped" if result.n_skipped else ""
    note = f": {result.column_note}" if result.column_note else ""
    return (
        f"{result.name}: {result.comparison.n_samples} samples "
        f"({result.n_rows} rows{skipped}; columns {columns_text(result.columns)}{note})"
    )


def _headers(unit: str | None) -> tuple[str, ...]:
    suffix = f" ({unit})" if unit else ""
    return ("mean", "std", f"field strength{suffix}", f"semi-axes{suffix}", f"offset{suffix}")


def _print_tables(results: Sequence[FileComparison]) -> None:
    out = console()
    for result in results:
        table = Table(title=_heading(result), title_justify="left", title_style="bold", caption_justify="left")
        table.add_column("method")
        for header in _headers(result.unit):
            table.add_column(header, justify="right")
        reasons = []
        for method_result in result.comparison:
            if method_result.ok:
                table.add_row(_label(method_result, "*"), *_numbers(method_result))
                refusals = _refusals(method_result)
                if refusals is not None:
                    why = "; ".join(refusals)
                    reasons.append(Text(f"{method_result.method}*: NOT SUPPORTED by the samples: {why}", style="red"))
            else:
                table.add_row(method_result.method, "failed", "", "", "", "")
                reasons.append(Text(f"{method_result.method} failed: {_reason(method_result)}", style="red"))
        out.print(table)
        # Below the table, one line each (a reason folded into a narrow column is hard to read); * marks a fit
        # scored only because of --force.
        for reason in reasons:
            out.print(reason, soft_wrap=True)
    out.print(Text(caption(results[0].unit if results else None), style="dim"))


def _markdown_cell(text: str) -> str:
    return text.replace("|", "\\|")


def _print_markdown(results: Sequence[FileComparison]) -> None:
    lines = []
    for result in results:
        lines += [f"### {_markdown_cell(_heading(result))}", ""]
        lines.append("| method | " + " | ".join(_headers(result.unit)) + " | failure reason |")
        lines.append("|---|---:|---:|---:|---:|---:|---|")
        for method_result in result.comparison:
            if method_result.ok:
                cells = [_label(method_result), *_numbers(method_result), ""]
            else:
                cells = [method_result.method, "failed", "", "", "", "", _reason(method_result)]
            lines.append("| " + " | ".join(_markdown_cell(cell) for cell in cells) + " |")
        lines.append("")
    lines.append(caption(results[0].unit if results else None))
    click.echo("\n".join(lines))


def _print_csv(results: Sequence[FileComparison]) -> None:
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(_CSV_FIELDS)
    for result in results:
        for method_result in result.comparison:
            calibration, evaluation = method_result.calibration, method_result.evaluation
            if calibration is None or evaluation is None:
                writer.writerow(
                    [result.name, method_result.method, "failed", *[""] * 9, method_result.error, result.unit or ""]
                )
                continue
            numbers = [
                evaluation.mean,
                evaluation.std,
                calibration.field_strength,
                *calibration.semi_axes,
                *calibration.offset,
            ]
            status = "not supported" if _label(method_result) != method_result.method else "ok"
            row = [result.name, method_result.method, status, *(repr(float(v)) for v in numbers), "", result.unit or ""]
            writer.writerow(row)
    click.echo(buffer.getvalue(), nl=False)


def _print_json(results: Sequence[FileComparison]) -> None:
    document = [
        {
            "file": result.name,
            "columns": list(result.columns),
            "n_rows": result.n_rows,
            "n_skipped": result.n_skipped,
            "unit": result.unit,
            **result.comparison.to_dict(),
        }
        for result in results
    ]
    click.echo(json.dumps(document, indent=2, allow_nan=False))
