"""A recording opened once into a :class:`~magfit.sources.Source`: :func:`open_source` dispatches, by the
file's kind (:func:`magfit.sources.detect.log_kind`), to its reader; a samples file is read by :mod:`magfit.io`.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..errors import DataFileError, MagfitError
from .detect import log_kind
from .types import LogSamples, Magnetometer, Source

if TYPE_CHECKING:
    from ..io import FileFormat

__all__ = ["open_source", "vehicle_identity"]


def open_source(path: str | os.PathLike[str], *, everything: bool = True) -> Source:
    """Open a recording once and say what it holds.

    Parameters
    ----------
    path : str or path-like
        A PX4 ULog, an ArduPilot DataFlash log, a MAVLink telemetry log (.tlog), a ROS bag, or a samples file
        (text, ``.npy``, ``.npz``); compressed files and standard input (``-``) as :func:`magfit.io.read_samples`
        takes them.
    everything : bool
        False reads only the magnetometer topics of a ULog (``Source.other`` stays empty): what a fit needs,
        at the cost of pyulog reading those topics alone (a log busy with other topics is read in half the
        time or less).

    Raises
    ------
    DataFileError
        An unreadable, truncated or damaged file (one line naming the file and the problem); a ULog without
        the ``pyulog`` package (the install command).
    """
    from ..io.sources import data_file

    kind = log_kind(path)
    if kind == "ulog":
        from .ulog import open_ulog

        return open_ulog(Path(path), data_file(path), everything=everything)
    if kind == "dataflash":
        from .dataflash import open_dataflash

        return open_dataflash(Path(path), data_file(path))
    if kind == "tlog":
        from .tlog import open_tlog

        return open_tlog(Path(path), data_file(path))
    if kind == "rosbag":
        from .rosbag import open_rosbag

        return open_rosbag(path)
    if kind == "mavlogdump":
        from .mavlogdump import open_mavlogdump

        return open_mavlogdump(Path(path), data_file(path))
    return _samples_source(Path(path))


def _samples_source(path: Path) -> Source:
    """A text, npy or npz file as a Source: the three columns :mod:`magfit.io` finds; one magnetometer per
    value of a column that tells several apart (mavlogdump's ``I``, ``device_id``: :mod:`magfit.io.instances`),
    each read with ``--sensor I=1``."""
    from ..io import read_samples, sniff
    from ..io.instances import sensor_listing, value_text

    fmt = sniff(path)
    clock = _file_clock(path, fmt)
    try:
        listing = sensor_listing(path)
        table = read_samples(path) if listing is None or len(listing.counts) == 1 else None
    except DataFileError as error:  # the layout is known, the magnetometer columns are not: say so
        rivals = _rival_sources(path, fmt, clock)
        if rivals is not None:
            return rivals
        unknown = Magnetometer(
            id="columns", description="no magnetometer columns", unit="", n_samples=0, problem=str(error)
        )
        return Source(
            path=path, kind="samples", format=fmt.describe(), time_base=clock.text, magnetometers=(unknown,)
        )

    def read(magnetometer: Magnetometer) -> LogSamples:
        chosen = read_samples(path, sensor=None if magnetometer.id == "columns" else magnetometer.id)
        notes = (chosen.column_note,) if chosen.column_note else ()
        times = np.full(len(chosen.samples), np.nan)  # a samples file has no time base
        return LogSamples(magnetometer, chosen.samples, times, chosen.columns, notes)

    if table is None:  # several magnetometers interleaved: one each, never one cloud
        assert listing is not None
        converter = listing.converter
        ardupilot = converter is not None and converter.name.startswith("ArduPilot") and listing.column == "I"
        magnetometers = tuple(
            Magnetometer(
                id=sensor,
                description=f"{', '.join(listing.columns)} where {listing.column} = {value_text(value)}"
                + (f" ({converter.name})" if converter is not None else ""),
                unit=listing.unit or "",
                n_samples=listing.counts[sensor],
                device_id=int(value) if listing.column.lower().endswith("device_id") else None,
                notes=(converter.note,) if converter is not None and converter.note else (),
                slot=int(value) if ardupilot else None,  # ArduPilot's I is its compass index
            )
            for sensor, value in listing.values.items()
        )
        return Source(
            path=path,
            kind="samples",
            format=fmt.describe(),
            time_base=clock.text,
            magnetometers=magnetometers,
            _reader=read,
        )
    columns = ", ".join(str(c) for c in table.columns)
    note = (f"{table.n_skipped} rows skipped (NaN or inf)",) if table.n_skipped else ()
    one = next(iter(listing.values.values())) if listing is not None else None  # PX4 sensor_mag: its device_id
    magnetometer = Magnetometer(
        id="columns",
        description=columns + (f" ({table.column_note})" if table.column_note else ""),
        unit=table.unit or "",
        n_samples=int(table.samples.shape[0]),
        notes=note,
        start_s=clock.start_s,
        end_s=clock.end_s,
        device_id=int(one) if one is not None and listing and listing.column.lower().endswith("device_id") else None,
    )
    return Source(
        path=path,
        kind="samples",
        format=fmt.describe(),
        time_base=clock.text,
        magnetometers=(magnetometer,),
        _reader=read,
    )


#: A time column whose name says seconds or nothing and that steps by this much or more per row counts
#: microseconds (PX4's ``timestamp``), as the samples' pipeline reads it (magfit.pipeline.table).
MICROSECONDS_STEP = 1000.0


@dataclass(frozen=True)
class _Clock:
    """A samples file's time base in words (``text``), and its first and last stamp in seconds (NaN: none)."""

    text: str
    start_s: float = float("nan")
    end_s: float = float("nan")


def _file_clock(path: Path, fmt: FileFormat) -> _Clock:
    """The time column a samples file's header names (:func:`magfit.io.streams.find_stream_columns`: ``time_s``,
    ``GPS_Time_s``, ``unix_time``, ``TimeUS`` ...) in seconds: its unit from its name, else from its spacing;
    ``none (rows)`` without one. Stamps that do not increase row after row are said (vector's lag and gyro's
    integration refuse them)."""
    from ..io.streams import find_stream_columns, read_stream_columns

    found = find_stream_columns(fmt.header).get("time") if fmt.header is not None else None
    if found is None:
        return _Clock("none (rows)")
    try:
        values = read_stream_columns(path, fmt, {"time": found.indices})["time"][:, 0]
    except (MagfitError, ValueError, OSError):
        return _Clock(f"column {found.describe()} (unreadable as numbers)")
    values = values[np.isfinite(values)]
    if len(values) < 2:
        return _Clock(f"column {found.describe()} (fewer than two stamps)")
    seconds = values * found.scale
    step = float(np.median(np.diff(values)))
    unit = {1.0: "seconds", 1e-3: "milliseconds", 1e-6: "microseconds", 1e-9: "nanoseconds"}.get(found.scale, "")
    how = "its name"
    if found.scale == 1.0:  # the name says seconds or no unit: the spacing tells microseconds
        micro = step >= MICROSECONDS_STEP
        seconds, unit = (values * 1e-6, "microseconds") if micro else (seconds, unit)
        how = f"its name or its spacing, {step:g} per row"
    epoch = "seconds since the epoch, " if seconds[0] >= 1e9 else ""
    text = f"{epoch}column {found.describe()} in {unit} ({how})"
    if not np.all(np.diff(seconds) > 0):
        text += "; it does not increase row after row (repeated or earlier stamps): give another with --time"
    return _Clock(text, float(seconds[0]), float(seconds[-1]))


def _rival_sources(path: Path, fmt: FileFormat, clock: _Clock) -> Source | None:
    """A samples file whose header names several magnetometer triples equally well (``imu_mx..mz`` beside
    ``mag_x..z``: two sensors on one rig): each triple a magnetometer of its own, its id its columns, read and
    fitted one at a time with ``--columns``. None when the header does not name several."""
    from ..io import read_samples
    from ..io.columns import find_magnetometer_columns
    from ..remedy import command_line

    if fmt.header is None:
        return None
    candidates = find_magnetometer_columns(fmt.header)
    best = [triple.names for triple in candidates if triple.score == candidates[0].score] if candidates else []
    if len(best) < 2:
        return None
    by_id = {",".join(names): names for names in best}
    magnetometers = []
    for sensor, names in by_id.items():
        try:
            table = read_samples(path, columns=list(names))
        except DataFileError as error:
            magnetometers.append(Magnetometer(id=sensor, description=f"columns {', '.join(names)}", unit="",
                                              n_samples=0, problem=str(error)))  # fmt: skip
            continue
        fit = command_line("calibrate", path, [("columns", sensor)])
        notes: tuple[str, ...] = (f"one of {len(by_id)} magnetometer column triples: fit it with {fit}",)
        if table.n_skipped:
            notes += (f"{table.n_skipped} rows skipped (NaN or inf)",)
        magnetometers.append(
            Magnetometer(id=sensor, description=f"columns {', '.join(names)}", unit=table.unit or "",
                         n_samples=int(table.samples.shape[0]), notes=notes, start_s=clock.start_s,
                         end_s=clock.end_s)
        )  # fmt: skip

    def read(magnetometer: Magnetometer) -> LogSamples:
        names = by_id[magnetometer.id]
        chosen = read_samples(path, columns=list(names))
        times = np.full(len(chosen.samples), np.nan)  # a samples file has no time base
        return LogSamples(magnetometer, chosen.samples, times, chosen.columns, ())

    return Source(path=path, kind="samples", format=fmt.describe(), time_base=clock.text,
                  magnetometers=tuple(magnetometers), _reader=read)  # fmt: skip


def vehicle_identity(path: str | Path) -> str | None:
    """The board and unique id of the flight controller that wrote the log at ``path``, or None.

    Reads the log for it alone; a log already opened has it as ``Source.identity``.
    """
    from ..io.sources import data_file

    target = Path(path)
    kind = log_kind(target)
    try:
        if kind == "dataflash":
            from .dataflash import DataFlashLog, log_identity

            return log_identity(DataFlashLog(target, data_file(target)))
        if kind == "ulog":
            from pyulog import ULog

            from .identity import ulog_identity

            return ulog_identity(ULog(str(data_file(target)), [], parse_header_only=True).msg_info_dict)
    except (MagfitError, OSError, ValueError, KeyError, ImportError):
        return None
    return None
