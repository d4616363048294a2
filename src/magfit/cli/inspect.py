"""``magfit inspect``: what a recording holds — its magnetometers (ids, units, rates, spans) and what else."""

from __future__ import annotations

import datetime
import math
from pathlib import Path

import click

from ..remedy import command_line
from ..sources import Magnetometer, Source, open_source
from ._advice import own_options
from ._common import console, time_span
from ._consistency import inspect_lines


def _number(value: float, digits: int = 1) -> str:
    return "-" if not math.isfinite(value) else f"{value:.{digits}f}"


def _magnetometer_lines(magnetometer: Magnetometer, time_base: str = "") -> list[tuple[str, str]]:
    unit = magnetometer.unit or "unit not recorded"
    timing = ""
    if math.isfinite(magnetometer.span_s):  # a bag's epoch stamps as a UTC date-time, a boot clock in seconds
        span = time_span(magnetometer.start_s, magnetometer.end_s, time_base)
        timing = f", {span}, {_number(magnetometer.rate_hz)} Hz"
    lines = [(magnetometer.id, f"{magnetometer.description}: {magnetometer.n_samples} samples in {unit}{timing}")]
    lines += [("", f"note: {note}") for note in magnetometer.notes]
    if magnetometer.problem is not None:
        lines.append(("", f"cannot be fitted: {magnetometer.problem}"))
    return lines


def source_lines(source: Source) -> list[tuple[str, str]]:
    """The labelled lines ``inspect`` prints for ``source``."""
    lines = [("file", f"{source.path} ({source.format})"), ("time base", source.time_base)]
    if not source.magnetometers:
        lines.append(("magnetometers", "none"))
    for index, magnetometer in enumerate(source.magnetometers):
        described = _magnetometer_lines(magnetometer, source.time_base)
        label, text = described[0]
        lines.append(("magnetometers" if index == 0 else "", f"{label}  {text}"))
        lines += [("", f"{' ' * len(label)}  {more}") for _, more in described[1:]]
    for index, other in enumerate(source.other):
        lines.append(("also logged" if index == 0 else "", other))
    if source.position is not None:
        where = source.position
        when = ""
        if math.isfinite(where.time_s):
            when = datetime.datetime.fromtimestamp(where.time_s, tz=datetime.timezone.utc).strftime(
                ", %Y-%m-%d %H:%M UTC"
            )
        lines.append(
            (
                "position",
                f"{where.lat_deg:.5f}, {where.lon_deg:.5f}, {where.alt_km:.3f} km{when} (median of {where.n_fixes} "
                "3-D GNSS fixes)",
            )
        )
    lines += [("note", note) for note in source.notes]
    usable = [m.id for m in source.magnetometers if m.problem is None and m.n_samples > 0]
    if source.kind != "samples" and len(usable) > 1:
        each = command_line("calibrate", source.path, [])
        which = ", ".join(usable)
        lines.append(("calibrate", f"{each} fits each (-o writes every one), with --sensor ID one ({which})"))
    return lines


def column_lines(path: Path) -> list[tuple[str, str]]:
    """For a samples file without a header: each group of columns the content rule looked at and what it
    took it for (time, angles, a reference field, the magnetometer, a rival); nothing for other files."""
    from ..errors import MagfitError
    from ..io import sniff
    from ..io.selection import npy_content_choice, text_content_choice

    try:
        fmt = sniff(path)
        if fmt.header is not None and fmt.kind in ("text", "npz"):
            return _stream_lines(fmt.header, path)
        if fmt.header is not None or fmt.kind == "npz" or fmt.n_columns <= 3:
            return []
        choice = text_content_choice(path, fmt) if fmt.kind == "text" else npy_content_choice(path, fmt)
    except (MagfitError, OSError, ValueError):
        return []  # the source's own lines say what is wrong with the file
    labels = [fmt.column_label(i) for i in range(fmt.n_columns)]
    return [
        ("columns" if index == 0 else "", f"{names}: {what}") for index, (names, what) in enumerate(choice.what(labels))
    ]


def _uses(name: str, path: Path) -> str:
    """What a stream of the samples file ``path`` is for, with the command that reads it."""
    method = {"attitude": "vector", "reference": "vector", "gyro": "gyro"}.get(name)
    uses = {
        "attitude": "and magfit align",
        "reference": "and magfit align",
        "gyro": "and vector's still-sample gate",
        "accel": "vector, gyro, magfit align: gravity",
        "time": "vector's lag, gyro's integration",
        "place": "the World Magnetic Model's reference field",
    }[name]
    return uses if method is None else f"{command_line('calibrate', path, [('method', method)])} {uses}"


def _stream_lines(header: tuple[str, ...], path: Path) -> list[tuple[str, str]]:
    """The streams a header names beside the magnetometer (docs/file-formats.md, "The other streams")."""
    from ..io.streams import find_stream_columns

    found = find_stream_columns(header)
    return [
        ("streams" if index == 0 else "", f"{name}: {columns.describe()} ({_uses(name, path)})")
        for index, (name, columns) in enumerate(found.items())
    ]


@click.command("inspect")
@click.argument("file", type=click.Path(dir_okay=False, path_type=Path))
@click.pass_context
def inspect_command(ctx: click.Context, file: Path) -> None:
    """List what a recording holds: its magnetometers and what else is logged.

    FILE is a PX4 ULog (.ulg, needs pip install 'magfit[ulog]'), an ArduPilot DataFlash log (.bin), a MAVLink
    telemetry log (.tlog, Mission Planner's or QGroundControl's) or a samples file (CSV, text, .npy, .npz);
    the format is recognised by its first bytes. For each magnetometer: the id that 'magfit calibrate
    --sensor' takes, its unit, sample count, time span and rate, and what stands in the way of a fit (a
    compass logged too slowly, a calibration that cannot be undone).

    \b
    Examples:
      magfit inspect flight.ulg
      magfit inspect 00000042.BIN
      magfit inspect mag.csv
    """
    out = console()
    with own_options(ctx, file=file):  # inspect takes no option: a remedy is said as magfit calibrate FILE ...
        source = open_source(file)
        lines = source_lines(source)
        if source.kind == "samples":
            lines += column_lines(file)
        lines += inspect_lines(source)
    for label, value in lines:
        out.print(f"{label:<16} {value}", soft_wrap=True)
