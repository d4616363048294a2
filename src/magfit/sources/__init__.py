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
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from ..errors import DataFileError, OptionError

if TYPE_CHECKING:
    from .motion import Motion

__all__ = [
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
#: Below this rate a magnetometer is flagged as logged too slowly for a fit (a tumble lasts about a minute:
#: at 1 Hz that is 60 samples, too few to tell the directions apart).
SLOW_RATE_HZ = 5.0


@dataclass(frozen=True)
class Magnetometer:
    """One magnetometer stream in a recording.

    Attributes
    ----------
    id : str
        What ``--sensor`` takes: ``sensor_mag/0`` (ULog topic/instance), ``MAG/1`` (DataFlash compass index,
        0-based), ``columns`` for a samples file.
    description : str
        What it is, in words (``raw sensor_mag, device_id 592905``).
    unit : str
        The unit of its samples (``G``, ``mG``, or empty for an unknown unit).
    n_samples : int
        Samples in the recording.
    start_s, end_s : float
        First and last time stamp, in seconds on the recording's time base (NaN when it has none).
    device_id : int or None
        The firmware's device id, which the exported calibration must be written for.
    raw : bool
        True when the samples are the sensor's raw field as logged; False when :meth:`Source.read` undoes
        the firmware's calibration with the log's parameters (``notes`` says with which).
    notes : tuple of str
        What a user must know about this stream (too slow, calibration undone, motor compensation ...).
    problem : str or None
        Why the stream cannot be fitted (a calibration that cannot be undone), or None.
    slot : int or None
        The firmware's calibration slot its calibration is written to, 0-based: ArduPilot's compass index
        (``COMPASS_OFS_*`` is 0, ``COMPASS_OFS2_*`` is 1), PX4's ``CAL_MAGn`` index (the one whose
        ``CAL_MAGn_ID`` is this device, else the first free one). None when unknown (a samples file).
    calibration_in_use : str or None
        Set when the samples carry the firmware's calibration and the log does not say which (a telemetry log
        without the parameters): why, in words. A fit on them is a residual correction on top of that
        calibration, which no firmware export may write in its place.
    """

    id: str
    description: str
    unit: str
    n_samples: int
    start_s: float = float("nan")
    end_s: float = float("nan")
    device_id: int | None = None
    raw: bool = True
    notes: tuple[str, ...] = ()
    problem: str | None = None
    slot: int | None = None
    calibration_in_use: str | None = None

    @property
    def span_s(self) -> float:
        """Seconds between the first and the last sample (NaN without time stamps)."""
        return self.end_s - self.start_s

    @property
    def rate_hz(self) -> float:
        """Mean sample rate over the span (NaN without time stamps or with fewer than two samples)."""
        span = self.span_s
        if self.n_samples < 2 or not np.isfinite(span) or span <= 0:
            return float("nan")
        return (self.n_samples - 1) / span


@dataclass(frozen=True)
class LogSamples:
    """The samples of one magnetometer, read from a recording.

    Attributes
    ----------
    magnetometer : Magnetometer
        Which stream they are.
    samples : ndarray, shape (N, 3)
        The sensor's field, in ``magnetometer.unit`` (the firmware's calibration undone when it was applied).
    time_s : ndarray, shape (N,)
        Their time stamps in seconds (the recording's time base).
    columns : tuple of str
        The fields the samples came from (``x, y, z`` or ``MagX, MagY, MagZ``).
    notes : tuple of str
        What was done to them (the calibration undone, and with which parameters).
    every : int
        One record in every ``every`` of the stream was read (``max_samples``, or a reader's own bound on
        a long log; the notes say which); 1 when every record was.
    """

    magnetometer: Magnetometer
    samples: NDArray[np.float64]
    time_s: NDArray[np.float64]
    columns: tuple[str, ...]
    notes: tuple[str, ...] = ()
    every: int = 1


@dataclass(frozen=True)
class Position:
    """Where and when a log was recorded, from its own GNSS fixes (for the World Magnetic Model).

    Attributes
    ----------
    lat_deg, lon_deg : float
        The median of the 3-D fixes, geodetic degrees.
    alt_km : float
        Their median altitude above mean sea level, km (the model's ellipsoid height differs by the geoid's
        tens of metres: nothing for the field).
    time_s : float
        UTC seconds since 1970 of the first fix with a time, NaN when the receiver gave none.
    n_fixes : int
        How many 3-D fixes the medians are taken over.
    """

    lat_deg: float
    lon_deg: float
    alt_km: float
    time_s: float
    n_fixes: int


def median_position(
    lat_deg: NDArray[np.float64], lon_deg: NDArray[np.float64], alt_m: NDArray[np.float64], time_s: NDArray[np.float64]
) -> Position | None:
    """The :class:`Position` of the fixes given (already the 3-D ones), or None when there is no finite one."""
    good = np.isfinite(lat_deg) & np.isfinite(lon_deg) & (np.abs(lat_deg) <= 90) & (np.abs(lon_deg) <= 180)
    good &= ~((lat_deg == 0) & (lon_deg == 0))  # a receiver without a fix reports 0, 0
    if not np.any(good):
        return None
    altitude = alt_m[good][np.isfinite(alt_m[good])]
    times = time_s[good][np.isfinite(time_s[good]) & (time_s[good] > 0)]
    return Position(
        lat_deg=float(np.median(lat_deg[good])),
        lon_deg=float(np.median(lon_deg[good])),
        alt_km=float(np.median(altitude)) / 1000 if len(altitude) else 0.0,
        time_s=float(times[0]) if len(times) else float("nan"),
        n_fixes=int(np.count_nonzero(good)),
    )


@dataclass(frozen=True)
class Source:
    """What a recording holds: its format, magnetometers and other logged streams.

    Attributes
    ----------
    path : Path
        The file, as the user named it.
    kind : str
        ``"ulog"``, ``"dataflash"``, ``"tlog"`` or ``"samples"`` (text, npy, npz: read by :mod:`magfit.io`).
    format : str
        The format in words (``PX4 ULog, PX4 v1.14.0``).
    time_base : str
        What the time stamps count (``microseconds since boot``).
    magnetometers : tuple of Magnetometer
        Every magnetometer stream, fit-able or not (see ``Magnetometer.problem``).
    other : tuple of str
        The other streams logged, with their sample counts (``vehicle_attitude (2 310)``).
    notes : tuple of str
        What a user must know about the whole file (bytes skipped as damaged ...).
    position : Position or None
        Where and when, from the log's own 3-D GNSS fixes (flight logs), or None.

    :meth:`read` gives a magnetometer's samples; :meth:`read_motion` gives them with the attitude, gyroscope
    and accelerometer at their time stamps (:class:`magfit.sources.motion.Motion`).
    """

    path: Path
    kind: str
    format: str
    time_base: str
    magnetometers: tuple[Magnetometer, ...]
    other: tuple[str, ...] = ()
    notes: tuple[str, ...] = ()
    position: Position | None = None
    _reader: Callable[[Magnetometer], LogSamples] | None = field(default=None, repr=False, compare=False)
    _motion: Callable[[Magnetometer], Motion] | None = field(default=None, repr=False, compare=False)
    #: A reader that reads only a regular stride of a long stream's records (``max_samples``), when the
    #: format can (DataFlash, ULog); other sources are read whole and thinned after.
    _bounded_reader: Callable[[Magnetometer, int | None], LogSamples] | None = field(
        default=None, repr=False, compare=False
    )

    def magnetometer(self, sensor: str | None) -> Magnetometer:
        """The magnetometer ``sensor`` names (its id, or its device id), or the only usable one when None.

        Raises
        ------
        DataFileError
            No such sensor (the ids listed); several usable and none chosen (``--sensor`` asked for); none
            usable (each one's reason).
        """
        listing = "; ".join(f"{m.id} ({m.description})" for m in self.magnetometers)
        if sensor is not None:
            for candidate in self.magnetometers:
                if sensor == candidate.id or (candidate.device_id is not None and sensor == str(candidate.device_id)):
                    return candidate
            raise DataFileError(f"{self.path}: holds no magnetometer {sensor!r}; it holds: {listing or 'none'}")
        usable = [m for m in self.magnetometers if m.problem is None and m.n_samples > 0]
        if len(usable) == 1:
            return usable[0]
        if not usable:
            if not self.magnetometers:
                raise DataFileError(f"{self.path}: this {self.format} holds no magnetometer data")
            reasons = "; ".join(f"{m.id}: {m.problem or 'no samples'}" for m in self.magnetometers)
            raise DataFileError(f"{self.path}: no magnetometer in this {self.format} can be fitted ({reasons})")
        ids = ", ".join(m.id for m in usable)
        raise DataFileError(
            f"{self.path}: holds {len(usable)} magnetometers that can be fitted ({listing}); choose one with "
            f"--sensor ID (one of {ids})"
        )

    def read(self, sensor: str | None = None, *, max_samples: int | None = None) -> LogSamples:
        """The samples of the magnetometer ``sensor`` names (see :meth:`magnetometer`).

        ``max_samples``: at most this many, a regular stride over the whole recording (every k-th record, k
        the least that keeps within it; the notes say so); None reads every one. A DataFlash log or a ULog
        reads only those records, so the memory grows with ``max_samples``, not with the log.

        Raises
        ------
        DataFileError
            As :meth:`magnetometer`, or the stream's ``problem`` (a calibration that cannot be undone).
        OptionError
            ``max_samples`` below 1.
        """
        chosen = self.magnetometer(sensor)
        if chosen.problem is not None:
            raise DataFileError(f"{self.path}: {chosen.id} cannot be fitted: {chosen.problem}")
        if max_samples is not None and max_samples < 1:
            raise OptionError(f"max_samples must be a positive number of samples, not {max_samples}")
        if self._bounded_reader is not None:
            return self._bounded_reader(chosen, max_samples)
        if self._reader is None:
            raise DataFileError(f"{self.path}: is a samples file; read it with magfit.io.read_samples")
        return strided(self._reader(chosen), max_samples)

    def read_motion(self, sensor: str | None = None) -> Motion:
        """The samples of magnetometer ``sensor`` with the vehicle's attitude, gyroscope and accelerometer at
        their time stamps, each with its frame (see :mod:`magfit.sources.motion`).

        Raises
        ------
        DataFileError
            As :meth:`read`; a samples file (it holds no other streams).
        """
        chosen = self.magnetometer(sensor)
        if chosen.problem is not None:
            raise DataFileError(f"{self.path}: {chosen.id} cannot be fitted: {chosen.problem}")
        if self._motion is None:
            raise DataFileError(
                f"{self.path}: is a samples file, which holds no attitude, gyroscope or accelerometer stream beside "
                "the magnetometer; give a flight log or a bag"
            )
        return self._motion(chosen)


def strided(read: LogSamples, max_samples: int | None) -> LogSamples:
    """``read`` thinned to a regular stride of at most ``max_samples`` samples (every k-th), said in its notes;
    ``read`` itself when it holds no more."""
    n = len(read.samples)
    if max_samples is None or n <= max_samples:
        return read
    every = -(-n // max_samples)
    note = (
        f"one sample in every {every} kept ({len(range(0, n, every))} of {n}): the stream holds more than "
        f"max_samples={max_samples}, so a regular stride over the whole recording is fitted"
    )
    return LogSamples(
        read.magnetometer,
        read.samples[::every],
        read.time_s[::every],
        read.columns,
        (*read.notes, note),
        every=read.every * every,
    )


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
