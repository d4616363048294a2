"""What a recording holds: its magnetometers (ids, units, rates, time spans) and what else was logged.

A flight log carries several compasses, each logged by the firmware in its own way, beside the attitude,
the accelerometer and the GPS. :func:`open_source` reads a file once into a :class:`Source` that says what
it holds; :meth:`Source.read` returns the samples of one magnetometer as the raw field of its sensor (the
firmware's calibration undone where the log says how), with the notes a user must see (a compass logged
too slowly, a calibration undone with the log's parameters).

Formats are recognised by their first bytes, not by their names:

- PX4 ULog (``ULog\\x01\\x12\\x35``): :mod:`magfit.sources.ulog`, needs ``pyulog`` (the ``ulog`` extra);
- ArduPilot DataFlash ``.bin`` (``0xA3 0x95``, then a FMT message): :mod:`magfit.sources.dataflash`, a small
  reader built on the format's own FMT messages (no extra);
- ROS 1 bags, MCAP and ROS 2 SQLite bags: :mod:`magfit.sources.rosbag`, needs ``rosbags`` (the ``ros`` extra);
- MAVLink telemetry logs (``.tlog``, each record an 8-byte big-endian UNIX time in microseconds and a MAVLink
  frame): :mod:`magfit.sources.tlog`, a small reader of the frames (no extra);
- the text ``mavlogdump.py log.bin`` prints (``2023-05-01 10:00:00.12: MAG {TimeUS : ...}`` lines):
  :mod:`magfit.sources.mavlogdump`, read as the DataFlash log it came from (no extra);
- anything else is a samples file for :mod:`magfit.io` (text, ``.npy``, ``.npz``).

(:mod:`magfit.io.sources` is another thing: where a file's bytes come from — a pipe, a compressed copy.)
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ..errors import DataFileError
from .types import SLOW_RATE_HZ, LogSamples, Magnetometer, Position, Source, median_position, strided

__all__ = [
    "SLOW_RATE_HZ",
    "LogSamples",
    "Magnetometer",
    "Position",
    "Source",
    "log_kind",
    "median_position",
    "open_source",
    "strided",
]

#: First bytes of a PX4 ULog file (the version byte and the timestamp follow).
ULOG_MAGIC = b"ULog\x01\x12\x35"
#: First bytes of every ArduPilot DataFlash message; the first message of a log is a FMT (type 128).
DATAFLASH_MAGIC = b"\xa3\x95\x80"


def log_kind(path: str | os.PathLike[str]) -> str | None:
    """``"ulog"``, ``"dataflash"``, ``"tlog"``, ``"rosbag"`` or ``"mavlogdump"`` when the file's first bytes are
    those of a log, else None.

    A missing or unreadable file is None too: the samples readers report it with their own message.
    """
    from ..io.sources import data_file

    if os.path.isdir(path):  # a ROS 2 bag is a folder (metadata.yaml beside its storage files)
        from .rosbag import bag_kind

        return "rosbag" if bag_kind(path) == "folder" else None
    try:
        with open(data_file(path), "rb") as handle:
            head = handle.read(4096)
    except OSError:
        return None
    if head.startswith(ULOG_MAGIC):
        return "ulog"
    if head.startswith(DATAFLASH_MAGIC):
        return "dataflash"
    from .tlog import is_tlog

    if is_tlog(head):
        return "tlog"
    from .mavlogdump import is_mavlogdump

    if is_mavlogdump(head):
        return "mavlogdump"
    from .rosbag import bag_kind  # its own magic numbers (ROS 1, MCAP, SQLite); the module imports no extra

    if str(path) != "-" and bag_kind(path) is not None:
        return "rosbag"
    return None


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
    try:
        listing = sensor_listing(path)
        table = read_samples(path) if listing is None or len(listing.counts) == 1 else None
    except DataFileError as error:  # the layout is known, the magnetometer columns are not: say so
        unknown = Magnetometer(
            id="columns", description="no magnetometer columns", unit="", n_samples=0, problem=str(error)
        )
        return Source(
            path=path, kind="samples", format=fmt.describe(), time_base="none (rows)", magnetometers=(unknown,)
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
            time_base="none (rows)",
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
        device_id=int(one) if one is not None and listing and listing.column.lower().endswith("device_id") else None,
    )
    return Source(
        path=path,
        kind="samples",
        format=fmt.describe(),
        time_base="none (rows)",
        magnetometers=(magnetometer,),
        _reader=read,
    )
