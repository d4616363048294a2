"""ArduPilot DataFlash logs (``.bin``): the compasses, their calibration undone with the log's own parameters.

The format describes itself. Every message is ``0xA3 0x95 <type>`` and a packed little-endian payload; the
FMT messages (type 128, 89 bytes) give each type's name, length, field types (one letter each) and field
names. This reader walks the messages once, in blocks, to learn their formats and where the messages a fit
reads start, then reads those of a wanted type (all, or a regular stride of a long compass) as one NumPy
structured array, window by window: the memory grows with the records read, not with the log
(:class:`DataFlashLog`). It is a small reader of the format, not
pymavlink's DFReader: that one is a 7 MB wheel (93 MB installed, with lxml) to read six messages, and
magfit reads the same MAG and PARM messages about 10x faster (docs/file-formats.md has the measurement).

The compasses: ``MAG`` with an instance field ``I`` (ArduPilot 4.0 and later), or ``MAG``, ``MAG2`` and
``MAG3`` in older logs. ``MagX, MagY, MagZ`` are milligauss **after** the firmware's current calibration
(``AP_Compass_Backend::correct_field``, after the board rotation)::

    logged = M · (s · (raw + ofs)) + motor_offset

with ``ofs`` = COMPASS_OFS*_X/Y/Z, ``s`` = COMPASS_SCALE* (applied only between 0.85 and 1.4, as the
firmware's ``have_scale_factor``), ``M`` the symmetric matrix of COMPASS_DIA*_X/Y/Z (diagonal) and
COMPASS_ODI*_X/Y/Z (off-diagonal: xy, xz, yz), and ``motor_offset`` the motor compensation (COMPASS_MOTCT
1 throttle / 2 current, or COMPASS_PMOT_EN per motor), which the log records per sample in ``MOX, MOY,
MOZ``. :func:`undo_calibration` inverts it to the field in the board frame, the frame in which ArduPilot's
own calibration (and magfit's ArduPilot export) is expressed. Logged values are truncated to whole
milligauss (int16): the undone field carries up to 1 mG of that rounding. Every record is undone with the
calibration in effect when it was logged, the parameters a firmware did not have at their defaults, and a
damaged record skipped (:mod:`magfit.sources.ardupilot`); ``OfsX/Y/Z``, logged with each record, are the
offsets it was corrected with.

Parameters of compass k (0-based) are ``COMPASS_OFS_X`` (k = 0), ``COMPASS_OFS2_X`` (k = 1),
``COMPASS_OFS3_X`` (k = 2), and so on. Since ArduPilot 4.1 the logged instance is a *priority* slot: slot i
holds the compass whose ``COMPASS_DEV_ID{k}`` equals ``COMPASS_PRIO{i+1}_ID`` (``Compass::_get_state_id``);
this reader maps it the same way when the log has those parameters.
"""

from __future__ import annotations

import io
import struct
from array import array
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np
from numpy.typing import NDArray

from ..errors import DataFileError
from ..remedy import option
from .ardupilot import (
    compass_mounting,
    compass_parameters,
    describe_parameters,
    parameter_suffix,
    undo_calibration,
    undo_records,
    untrimmed,
    without_damaged_changes,
)
from .detect import is_headless_dataflash
from .identity import BOOT_MESSAGES, board_identity
from .motion import Motion, Stream, align, euler_quaternions, quaternion_wxyz
from .types import SLOW_RATE_HZ, LogSamples, Magnetometer, Position, Source, median_position

__all__ = ["DataFlashLog", "log_identity", "open_dataflash", "undo_calibration"]

_HEAD = b"\xa3\x95"
_FMT_TYPE = 0x80
_FMT_LENGTH = 89  # header 3 + Type B + Length B + Name 4s + Format 16s + Labels 64s
#: Field letters: numpy type, and the factor that turns the stored integer into the value.
_LETTERS: dict[str, tuple[str, float | None]] = {
    "a": ("(32,)<i2", None),
    "b": ("i1", None),
    "B": ("u1", None),
    "h": ("<i2", None),
    "H": ("<u2", None),
    "i": ("<i4", None),
    "I": ("<u4", None),
    "f": ("<f4", None),
    "d": ("<f8", None),
    "g": ("<f2", None),
    "n": ("S4", None),
    "N": ("S16", None),
    "Z": ("S64", None),
    "c": ("<i2", 0.01),
    "C": ("<u2", 0.01),
    "e": ("<i4", 0.01),
    "E": ("<u4", 0.01),
    "L": ("<i4", 1e-7),
    "M": ("u1", None),
    "q": ("<i8", None),
    "Q": ("<u8", None),
}
#: Bytes read at a time: by the walk over the headers, and per window of :meth:`DataFlashLog.messages`.
_BLOCK = 1 << 23
#: Most messages gathered at a time (the gather index is ``_GATHER x width`` int64).
_GATHER = 1 << 14
#: The types whose offsets the first walk keeps: what a fit reads (the compasses, their parameters, the GNSS).
#: PARM messages read at a time (the parameters' changes kept).
_PARM_WINDOW = 1 << 18
_INDEXED = frozenset(("MAG", "MAG2", "MAG3", "PARM", "GPS", "MSG"))
#: Types walked for together when one of them is first asked for (``read_motion`` reads them in turn).
_WALKED_TOGETHER = (frozenset(("ATT", "XKQ", "AHR2", "IMU")),)
#: Most GNSS records the position's medians are taken over (a regular stride beyond).
_MAX_FIXES = 100_000
#: Messages listed by `magfit inspect` beside the compasses, when present.
_ALSO = ("ATT", "AHR2", "XKQ", "IMU", "GPS", "BARO", "PARM", "MODE", "BAT", "CURR", "RCOU")


@dataclass(frozen=True)
class _Format:
    name: str
    length: int
    letters: str
    labels: tuple[str, ...]
    dtype: np.dtype[Any] | None  # None: a letter this reader does not know (the messages are skipped)


def _format_from(payload: bytes) -> tuple[int, _Format] | None:
    """The (type, format) a FMT payload defines, or None when it is not a sane FMT (garbage)."""
    type_id, length, name, letters, labels = struct.unpack("<BB4s16s64s", payload)
    try:
        name_text = name.rstrip(b"\x00").decode("ascii")
        letters_text = letters.rstrip(b"\x00").decode("ascii")
        label_list = tuple(labels.rstrip(b"\x00").decode("ascii").split(","))
    except UnicodeDecodeError:
        return None
    if length < 3 or not name_text.isprintable():
        return None
    dtype: np.dtype[Any] | None = None
    if (
        len(label_list) == len(letters_text)
        and all(c in _LETTERS for c in letters_text)
        and len(set(label_list)) == len(label_list)
    ):
        candidate = np.dtype([(label, _LETTERS[c][0]) for label, c in zip(label_list, letters_text, strict=False)])
        if candidate.itemsize == length - 3:
            dtype = candidate
    return type_id, _Format(name_text, length, letters_text, label_list, dtype)


class DataFlashLog:
    """A DataFlash log walked once: the formats, how many messages of each type, where the wanted ones start.

    The file is read in blocks of :data:`_BLOCK` bytes, never whole: the walk keeps the formats, a count per
    type, and the byte offsets (8 bytes a message) of the types a fit reads (:data:`_INDEXED`: the compasses,
    PARM, GPS). Another type is found by a second walk when it is first asked for (the attitude and IMU of
    ``read_motion``, in one walk together). :meth:`messages` reads the records it is asked for, window by
    window, so a 1 GB log is read in memory that grows with the records returned, not with the file.

    Parameters
    ----------
    path : Path
        The name messages give.
    data : bytes or Path
        The file's bytes, or the file to read them from (in blocks).

    Raises
    ------
    DataFileError
        No DataFlash message at all, or no FMT message before the data.
    """

    def __init__(self, path: Path, data: bytes | Path) -> None:
        self.path = path
        self._source = data
        self.formats: dict[int, _Format] = {}
        self.skipped_bytes = 0
        self.truncated = False
        self._counts: dict[int, int] = {}
        self._offsets: dict[int, NDArray[np.int64] | NDArray[np.uint32]] = {}
        # Bytes already in memory: every type's offsets kept (tests rewrite logs by them); a file: the wanted ones.
        self._everything = not isinstance(data, Path)
        self._indexed: set[str] = set(_INDEXED)
        with self._open() as handle:
            if is_headless_dataflash(handle.read(4096)):
                raise DataFileError(
                    f"{path}: is an ArduPilot DataFlash log whose beginning is missing (its FMT messages, which give "
                    "every message its fields): a part of a log cut from its middle; use the whole log as the "
                    "flight controller wrote it (download it again, or join the parts in order: cat part1 part2)"
                )
        self._walk(None if self._everything else self._indexed, first=True)
        self._by_name = {fmt.name: type_id for type_id, fmt in self.formats.items()}

    def _open(self) -> BinaryIO:
        if isinstance(self._source, (bytes, bytearray, memoryview)):
            return io.BytesIO(self._source)
        try:
            return open(self._source, "rb")
        except OSError as error:
            message = f"{self.path}: cannot be read ({error.strerror}); check the file's permissions"
            raise DataFileError(message) from None

    def _size(self) -> int:
        if isinstance(self._source, Path):
            try:
                return self._source.stat().st_size
            except OSError:
                return 0
        return len(self._source)

    def _walk(self, names: set[str] | None, *, first: bool) -> None:
        """One pass over the message headers, in blocks: the offsets of the messages named ``names`` (None:
        of every message, FMT too); on the ``first`` pass the formats, the counts, and the damage (bytes
        skipped, a last message cut short)."""
        lengths = [0] * 256
        lengths[_FMT_TYPE] = _FMT_LENGTH
        counts = [0] * 256
        keep: dict[int, array[int]] = {}
        wide = self._size() >= 1 << 32  # offsets in 4 bytes each, 8 beyond 4 GB
        code, kind = ("q", np.int64) if wide else ("I", np.uint32)
        wanted = [names is None] * 256
        formats: dict[int, _Format] = {}
        skipped = 0
        truncated = False
        data = b""
        base = 0  # the file offset of data[0]
        eof = False
        with self._open() as handle:
            while not eof:
                block = handle.read(_BLOCK)
                eof = not block
                data += block
                n = len(data)
                pos = 0
                # One pass in Python over the message headers (the payloads are read later by NumPy, per type).
                # A byte that does not start a known message is damage: skip to the next 0xA3 0x95, and count it.
                while pos + 3 <= n:
                    if data[pos] == 0xA3 and data[pos + 1] == 0x95:
                        type_id = data[pos + 2]
                        length = lengths[type_id]
                        if length:
                            end = pos + length
                            if end > n:
                                if eof:
                                    truncated = True
                                    pos = n
                                break  # the rest of it is in the next block
                            if type_id == _FMT_TYPE:
                                defined = _format_from(data[pos + 3 : end])
                                if defined is None:  # a damaged FMT: not a message after all
                                    found = data.find(_HEAD, pos + 1)
                                    if found < 0 and not eof:
                                        skipped += n - 1 - pos
                                        pos = n - 1
                                        break
                                    found = n if found < 0 else found
                                    skipped += found - pos
                                    pos = found
                                    continue
                                new_type, fmt = defined
                                old = formats.get(new_type)
                                if old is not None and old.length != fmt.length:  # two layouts: unusable
                                    fmt = _Format(fmt.name, fmt.length, fmt.letters, fmt.labels, None)
                                formats[new_type] = fmt
                                if new_type != _FMT_TYPE:
                                    lengths[new_type] = fmt.length
                                    wanted[new_type] = names is None or fmt.name in names
                            counts[type_id] += 1
                            if wanted[type_id]:
                                offsets = keep.get(type_id)
                                if offsets is None:
                                    offsets = keep[type_id] = array(code)
                                offsets.append(base + pos)
                            pos = end
                            continue
                    found = data.find(_HEAD, pos + 1)
                    if found < 0 and not eof:  # keep the last byte: it may be the first of a header
                        skipped += n - 1 - pos
                        pos = n - 1
                        break
                    found = n if found < 0 else found
                    skipped += found - pos
                    pos = found
                if eof:
                    break
                base += pos
                data = data[pos:]
        if first:
            if not formats:
                raise DataFileError(
                    f"{self.path}: starts like an ArduPilot DataFlash log but holds no readable FMT message; the "
                    "file is damaged: download the log from the vehicle again"
                )
            self.formats, self.skipped_bytes, self.truncated = formats, skipped, truncated
            self._counts = {type_id: count for type_id, count in enumerate(counts) if count}
        for type_id in set(formats) | set(keep):
            if names is None or (type_id in formats and formats[type_id].name in names):
                self._offsets[type_id] = np.frombuffer(keep.get(type_id, array(code)), dtype=kind)

    def _offsets_of(self, name: str) -> NDArray[np.int64] | NDArray[np.uint32]:
        """The byte offsets of every message ``name``: walked again for a type the first walk did not keep."""
        if not self._everything and name not in self._indexed:
            group = next((g for g in _WALKED_TOGETHER if name in g), frozenset((name,)))
            self._indexed |= group
            self._walk(set(group), first=False)
        return self._offsets.get(self._by_name[name], np.empty(0, dtype=np.int64))

    def names(self) -> dict[str, int]:
        """Every message type in the log and how many messages of it (FMT excluded)."""
        counts = {}
        for type_id, fmt in self.formats.items():
            if type_id != _FMT_TYPE:
                count = self._counts.get(type_id, 0)
                if count:
                    counts[fmt.name] = count
        return counts

    def has(self, name: str) -> bool:
        return name in self._by_name and self._counts.get(self._by_name[name], 0) > 0

    def count(self, name: str) -> int:
        """How many messages ``name`` the log holds (0 for a type it does not define)."""
        return self._counts.get(self._by_name[name], 0) if name in self._by_name else 0

    def messages(self, name: str, rows: NDArray[np.int64] | None = None) -> NDArray[Any]:
        """Every message ``name`` as a structured array (fields by their labels, stored values unscaled), or
        the ones at the increasing indices ``rows`` among them.

        Raises
        ------
        DataFileError
            The type's format uses a field letter this reader does not know, or was defined twice differently.
        """
        type_id = self._by_name.get(name)
        if type_id is None:
            return np.empty(0)
        fmt = self.formats[type_id]
        if fmt.dtype is None:
            raise DataFileError(
                f"{self.path}: the {name} messages' format ({fmt.letters!r}, {fmt.length} bytes) cannot be read: a "
                "field type magfit does not know, or two different definitions; please report the log"
            )
        offsets = self._offsets_of(name)
        if rows is not None:
            offsets = offsets[rows]
        return self._gather(offsets, 3, fmt.length - 3).view(fmt.dtype).reshape(-1)

    def column(self, name: str, label: str, rows: NDArray[np.int64] | None = None) -> NDArray[Any]:
        """Field ``label`` of every message ``name`` (or of those at ``rows``), stored values unscaled: one
        field's bytes read, not the whole records'."""
        records = np.empty(0, dtype=self._dtype(name))
        field, start = records.dtype.fields[label][:2]
        offsets = self._offsets_of(name)
        if rows is not None:
            offsets = offsets[rows]
        return self._gather(offsets, 3 + start, field.itemsize).view(field).reshape(-1)

    def _dtype(self, name: str) -> np.dtype[Any]:
        fmt = self.formats[self._by_name[name]]
        if fmt.dtype is None:
            self.messages(name, np.empty(0, dtype=np.int64))  # raises the error that says why
        assert fmt.dtype is not None
        return fmt.dtype

    def _gather(self, offsets: NDArray[np.int64] | NDArray[np.uint32], skip: int, width: int) -> NDArray[np.uint8]:
        """``width`` bytes at ``offsets + skip``, an (n, width) array: read window by window (at most
        :data:`_BLOCK` bytes and :data:`_GATHER` messages at a time), so the index never grows with the log."""
        out = np.empty((len(offsets), width), dtype=np.uint8)
        if not len(offsets) or not width:
            return out
        columns = np.arange(width, dtype=np.int64) + skip
        with self._open() as handle:
            i = 0
            while i < len(offsets):
                start = int(offsets[i])
                j = int(np.searchsorted(offsets, start + _BLOCK - skip - width, side="right"))
                j = min(max(j, i + 1), i + _GATHER)
                end = int(offsets[j - 1]) + skip + width
                handle.seek(start)
                window = np.frombuffer(handle.read(end - start), dtype=np.uint8)
                out[i:j] = window[(offsets[i:j].astype(np.int64) - start)[:, None] + columns]
                i = j
        return out

    def value(self, records: NDArray[Any], name: str, label: str) -> NDArray[np.float64]:
        """Field ``label`` of ``name``'s records as float64, with its letter's factor (centi-units, 1e-7 deg)."""
        fmt = self.formats[self._by_name[name]]
        factor = _LETTERS[fmt.letters[fmt.labels.index(label)]][1]
        values = records[label].astype(np.float64)
        return values * factor if factor is not None else values

    def parameters(self) -> dict[str, list[tuple[float, float]]]:
        """PARM messages: name -> [(time in s, value), ...] in log order, each name's value where it changes
        (a value logged again as it was says nothing new: a log that repeats its parameters is read in memory
        that does not grow with them). Read :data:`_PARM_WINDOW` messages at a time."""
        if not self.has("PARM"):
            return {}
        if not {"Name", "Value"} <= set(self._dtype("PARM").names or ()):
            raise DataFileError(
                f"{self.path}: the PARM messages' format has no Name and Value fields: the log is damaged, so the "
                "parameters its compasses were corrected with are unknown"
            )
        table: dict[str, list[tuple[float, float]]] = {}
        last: dict[bytes, bytes] = {}
        count = self.count("PARM")
        for begin in range(0, count, _PARM_WINDOW):
            records = self.messages("PARM", np.arange(begin, min(count, begin + _PARM_WINDOW), dtype=np.int64))
            names, raw = records["Name"], records["Value"]
            order = np.argsort(names, kind="stable")  # by name, each name's messages in log order
            first = np.ones(len(order), dtype=bool)
            first[1:] = names[order][1:] != names[order][:-1]
            changed = first.copy()
            bits = np.ascontiguousarray(raw[order]).view(np.uint8).reshape(len(order), -1)
            changed[1:] |= np.any(bits[1:] != bits[:-1], axis=1)
            starts = np.flatnonzero(first).tolist()
            for at, end in zip(starts, [*starts[1:], len(order)], strict=True):
                name = bytes(names[order[at]])
                if last.get(name) == bits[at].tobytes():
                    changed[at] = False  # the value in effect, logged again
                last[name] = bits[end - 1].tobytes()
            kept = np.sort(order[changed])
            records = records[kept]
            times = _time_s(self, "PARM", records)
            with np.errstate(invalid="ignore"):  # a damaged value is NaN or inf: refused where it is used
                values = records["Value"].astype(np.float64)
            for name, value, time in zip(records["Name"], values, times, strict=False):
                key = name.rstrip(b"\x00").decode("ascii", "replace")
                table.setdefault(key, []).append((float(time), float(value)))
        return table


def _time_s(log: Any, name: str, records: NDArray[Any]) -> NDArray[np.float64]:
    """The messages' time stamps in seconds: TimeUS (microseconds since boot), or TimeMS in older logs."""
    labels = records.dtype.names or ()
    if "TimeUS" in labels:
        return records["TimeUS"].astype(np.float64) / 1e6
    if "TimeMS" in labels:
        return records["TimeMS"].astype(np.float64) / 1e3
    return np.full(len(records), np.nan)


def open_dataflash(path: Path, file: Path) -> Source:
    """Read an ArduPilot DataFlash log into a :class:`~magfit.sources.Source` (``file``: its bytes on disk, read
    in blocks)."""
    try:
        with open(file, "rb"):
            pass
    except OSError as error:
        raise DataFileError(f"{path}: cannot be read ({error.strerror}); check the file's permissions") from None
    return source_from_log(path, DataFlashLog(path, file), "ArduPilot DataFlash log")


@dataclass(frozen=True)
class _Stream:
    """One compass's messages: ``name`` (MAG, MAG2, MAG3), the value of MAG's instance field ``I`` (None: every
    message of ``name``), how many, and the field labels."""

    name: str
    instance: int | None
    count: int
    labels: tuple[str, ...]


def source_from_log(path: Path, log: Any, described: str, *, notes: tuple[str, ...] = ()) -> Source:
    """The :class:`~magfit.sources.Source` of a DataFlash log already read: a :class:`DataFlashLog`, or anything
    with its ``has``, ``count``, ``messages``, ``column``, ``value``, ``parameters``, ``names``,
    ``skipped_bytes`` and ``truncated`` (the text of ``mavlogdump.py``, :mod:`magfit.sources.mavlogdump`);
    ``notes``: what to say of the file.

    Only what describes each compass is read here (its count, first and last stamps, its Health field); its
    records are read when :meth:`Source.read` asks, a regular stride of them when ``max_samples`` says.
    """
    parameters, damaged = without_damaged_changes(log.parameters())
    streams, instances = _compass_streams(log)
    magnetometers = []
    for slot, stream in enumerate(streams):
        magnetometers.append(_describe(log, parameters, slot, stream, instances))
    said = list(notes)
    if damaged:
        said.append(f"{damaged} PARM messages skipped as damaged (a value that is not a number)")
    if log.skipped_bytes:
        said.append(f"{log.skipped_bytes} bytes skipped as damaged (no message starts there)")
    if log.truncated:
        said.append("the last message is cut short (the log was not closed): it is ignored")
    counts = log.names()
    other = tuple(f"{name} ({counts[name]})" for name in _ALSO if name in counts)
    rest = sorted(set(counts) - set(_ALSO) - {"MAG", "MAG2", "MAG3"})
    if rest:
        other += (f"{len(rest)} other message types: {', '.join(rest)}",)
    position = _position(log)
    identity = log_identity(log)

    def read(magnetometer: Magnetometer, max_samples: int | None = None) -> LogSamples:
        slot = int(magnetometer.id.split("/")[1])
        return _read(log, parameters, magnetometer, streams[slot], instances, max_samples)

    def motion(magnetometer: Magnetometer) -> Motion:
        return _motion(log, parameters, read(magnetometer), position)

    return Source(
        path=path,
        position=position,
        identity=identity,
        kind="dataflash",
        format=described,
        time_base=_time_base(streams),
        magnetometers=tuple(magnetometers),
        other=other,
        notes=tuple(said),
        _reader=read,
        _motion=motion,
        _bounded_reader=read,
    )


def log_identity(log: Any) -> str | None:
    """The board and unique id in the log's boot ``MSG`` messages (:func:`magfit.sources.identity.board_identity`),
    or None: the first messages only are read."""
    if not log.has("MSG"):
        return None
    count = min(log.count("MSG"), BOOT_MESSAGES)
    try:
        records = log.messages("MSG", np.arange(count, dtype=np.int64))
    except DataFileError:
        return None
    if "Message" not in (records.dtype.names or ()) or records.dtype["Message"].kind != "S":
        return None  # (the text of mavlogdump.py holds numbers only)
    return board_identity(records["Message"])


def _time_base(streams: list[_Stream]) -> str:
    """What the compasses' time stamps count: TimeUS (3.4 on), TimeMS (before), or nothing (before 3.1)."""
    labels = set(streams[0].labels) if streams else {"TimeUS"}
    if "TimeUS" in labels:
        return "seconds since boot (TimeUS)"
    if "TimeMS" in labels:
        return "seconds since boot (TimeMS)"
    return "none: the compass messages carry no time stamp"


def _first_instance(records: NDArray[Any]) -> NDArray[Any]:
    """The messages of instance 0 (field ``I``) or core 0 (``C``, the EKF's), when the type has one."""
    labels = records.dtype.names or ()
    for key in ("I", "C"):
        if key in labels and len(records):
            return records[records[key] == np.min(records[key])]
    return records


def _attitude_stream(log: Any) -> Stream | None:
    """ATT (the attitude the vehicle flew by: Roll, Pitch, Yaw in degrees), else XKQ (EKF3 core 0's quaternion,
    Q1..Q4 = w, x, y, z), else AHR2 (the backup DCM estimate: its quaternion, or its angles).

    ArduPilot's Euler angles are 3-2-1, body -> NED: ``Matrix3f::from_euler(roll, pitch, yaw)`` is
    ``Rz(yaw) · Ry(pitch) · Rx(roll)`` (libraries/AP_Math/matrix3.cpp), the DCM ``AP_AHRS`` logs from
    (libraries/AP_AHRS/AP_AHRS_Logging.cpp, Write_Attitude). XKQ logs ``NavEKF3_core::getQuaternion``, whose
    ``rotation_matrix()`` is the body -> NED matrix (``getRotationBodyToNED``,
    libraries/AP_NavEKF3/AP_NavEKF3_Outputs.cpp), though the comment there calls it "NED to body".
    """
    for name in ("ATT", "XKQ", "AHR2"):
        if not log.has(name):
            continue
        records = _first_instance(log.messages(name))
        labels = set(records.dtype.names or ())
        time = _time_s(log, name, records)
        with np.errstate(invalid="ignore"):
            if name != "ATT" and {"Q1", "Q2", "Q3", "Q4"} <= labels:
                quaternions = quaternion_wxyz(
                    np.column_stack([log.value(records, name, q) for q in ("Q1", "Q2", "Q3", "Q4")])
                )
                return Stream(f"{name} Q1..Q4", time, quaternions, "body (FRD)")
            if {"Roll", "Pitch", "Yaw"} <= labels:
                roll, pitch, yaw = (log.value(records, name, a) for a in ("Roll", "Pitch", "Yaw"))
                finite = np.isfinite(roll) & np.isfinite(pitch) & np.isfinite(yaw)
                quaternions = np.full((len(records), 4), np.nan)
                if np.any(finite):
                    quaternions[finite] = euler_quaternions(roll[finite], pitch[finite], yaw[finite])
                return Stream(f"{name} Roll/Pitch/Yaw", time, quaternions, "body (FRD)")
    return None


def _imu_streams(log: Any) -> tuple[Stream | None, Stream | None]:
    """IMU instance 0: GyrX/Y/Z (rad/s) and AccX/Y/Z (m/s²), in the body frame: AP_InertialSensor rotates every
    IMU by its board orientation (AHRS_ORIENTATION) before it is logged (AP_InertialSensor_Backend::
    _rotate_and_correct_gyro / _accel, libraries/AP_InertialSensor/AP_InertialSensor_Backend.cpp)."""
    if not log.has("IMU"):
        return None, None
    records = _first_instance(log.messages("IMU"))
    labels = set(records.dtype.names or ())
    time = _time_s(log, "IMU", records)
    found: list[Stream | None] = []
    for prefix, what in (("Gyr", "GyrX/Y/Z"), ("Acc", "AccX/Y/Z")):
        axes = [f"{prefix}{a}" for a in "XYZ"]
        if set(axes) <= labels:
            with np.errstate(invalid="ignore"):
                values = np.column_stack([log.value(records, "IMU", a) for a in axes])
            found.append(Stream(f"IMU[0] {what}", time, values, "body (FRD)"))
        else:
            found.append(None)
    return found[0], found[1]


def _motion(
    log: Any, parameters: dict[str, list[tuple[float, float]]], read: LogSamples, position: Position | None
) -> Motion:
    slot = read.magnetometer.slot
    mounting, note = compass_mounting(parameters, slot if slot is not None else 0)
    gyro, accel = _imu_streams(log)
    return align(
        read.magnetometer.id,
        read.magnetometer.unit,
        read.time_s,
        read.samples,
        magnetometer_frame="body",
        attitude=untrimmed(_attitude_stream(log), parameters),
        gyro=gyro,
        accel=accel,
        mounting=mounting,
        mounting_note=note,
        position=position,
        notes=(
            "magnetometer: MAG is logged in the body frame (FRD), after the board or COMPASS_ORIENT rotation "
            f"(AP_Compass_Backend::rotate_field); mounting: {note}",
        ),
    )


#: GPS time starts at 1980-01-06 00:00 UTC; it runs ahead of UTC by the leap seconds since (18 from 2017).
_GPS_EPOCH_S = 315_964_800.0
_GPS_LEAP_S = 18.0


def _position(log: Any) -> Position | None:
    """The median of the first GPS's 3-D fixes (Status >= 3) and the UTC time of the first (GWk, GMS)."""
    try:
        return _gps_position(log)
    except (DataFileError, TypeError, ValueError):  # a damaged GPS format: the log has no position to give
        return None


def _gps_position(log: Any) -> Position | None:
    if not log.has("GPS"):
        return None
    count = log.count("GPS")
    every = -(-count // _MAX_FIXES)  # a regular stride over a long log's fixes: their medians barely move
    records = log.messages("GPS", np.arange(0, count, every) if every > 1 else None)
    labels = set(records.dtype.names or ())
    if not {"Status", "Lat", "Lng"} <= labels:
        return None
    if "I" in labels:
        records = records[records["I"] == 0]
    records = records[records["Status"] >= 3]
    with np.errstate(invalid="ignore"):
        lat, lon = log.value(records, "GPS", "Lat"), log.value(records, "GPS", "Lng")
        alt = log.value(records, "GPS", "Alt") if "Alt" in labels else np.full(len(records), np.nan)
        # GWk, GMS (ArduPilot 3.4 on); Week, TimeMS before (TimeMS was the GPS time of week then, T the boot time)
        week_ms = ("GWk", "GMS") if {"GWk", "GMS"} <= labels else ("Week", "TimeMS")
        if set(week_ms) <= labels:
            weeks, ms = records[week_ms[0]].astype(np.float64), records[week_ms[1]].astype(np.float64)
            time = np.where(weeks > 0, _GPS_EPOCH_S + weeks * 604_800 + ms / 1000 - _GPS_LEAP_S, np.nan)
        else:
            time = np.full(len(records), np.nan)
    return median_position(lat, lon, alt, time)


def _compass_streams(log: Any) -> tuple[list[_Stream], NDArray[Any] | None]:
    """The compass slots: MAG split by its instance field I (and that field, one byte a record), else MAG,
    MAG2, MAG3."""
    if not log.has("MAG"):
        return [], None
    labels = _labels(log, "MAG")
    if "I" in labels:
        instances = log.column("MAG", "I")
        values, counts = np.unique(instances, return_counts=True)
        return [_Stream("MAG", int(v), int(c), labels) for v, c in zip(values, counts, strict=True)], instances
    streams = [_Stream("MAG", None, log.count("MAG"), labels)]
    for name in ("MAG2", "MAG3"):
        if log.has(name):
            streams.append(_Stream(name, None, log.count(name), _labels(log, name)))
    return streams, None


def _labels(log: Any, name: str) -> tuple[str, ...]:
    return tuple(log.messages(name, np.empty(0, dtype=np.int64)).dtype.names or ())


def _rows(stream: _Stream, instances: NDArray[Any] | None, every: int = 1) -> NDArray[np.int64] | None:
    """The indices of the stream's records among its type's (every ``every``-th), None for all of them."""
    if stream.instance is not None and instances is not None:
        return np.flatnonzero(instances == stream.instance)[::every]
    return np.arange(0, stream.count, every, dtype=np.int64) if every > 1 else None


def _describe(
    log: Any,
    parameters: dict[str, list[tuple[float, float]]],
    slot: int,
    stream: _Stream,
    instances: NDArray[Any] | None,
) -> Magnetometer:
    name, labels = stream.name, stream.labels
    rows = _rows(stream, instances)
    ends = rows[[0, -1]] if rows is not None and len(rows) else np.array([0, stream.count - 1], dtype=np.int64)
    times = _time_s(log, name, log.messages(name, ends)) if stream.count else np.empty(0)
    clock = _clock_label(labels)
    jumps = None
    if clock is not None and stream.count and {"MagX", "MagY", "MagZ"} <= set(labels):
        fields = np.column_stack([log.column(name, axis, rows) for axis in ("MagX", "MagY", "MagZ")])
        jumps = _time_jumps(log.column(name, clock[0], rows) * clock[1], fields)
    if jumps is not None:  # the span and the rate over the stamps as they are, each once
        times = np.array([jumps.start_s, jumps.end_s])
    first = float(times[0]) if len(times) else float("nan")
    compass, problem = compass_parameters(parameters, slot, first)
    notes: list[str] = [] if jumps is None else [jumps.describe()]
    if compass is not None:
        notes.extend(
            ("MagX/Y/Z are logged after ArduPilot's calibration; " + note if i == 0 else note)
            for i, note in enumerate(describe_parameters(compass, "from the log's parameters"))
        )
        if any(change.endswith("(no time)") for change in compass.changes) and not _has_offsets(labels):
            problem = (
                "the compass offsets changed during the log, its PARM messages carry no time and its MAG records "
                "not the offsets applied (OfsX/Y/Z), so which records were corrected with which offsets is unknown; "
                "fit a log recorded after the change"
            )
        if compass.motor_compensation:
            if _motor_labels(labels) is not None:
                notes.append("motor compensation was active: undone with the motor offsets logged per sample (MOX/Y/Z)")
            else:
                problem = (
                    "motor compensation was active (COMPASS_MOTCT or COMPASS_PMOT_EN) and this log does not record "
                    "the motor offsets it added (no MOX/MOY/MOZ), so the raw field cannot be recovered; record with "
                    "COMPASS_MOTCT 0, or use the onboard calibrator (COMPASS_CAL_FIT)"
                )
    if "Health" in labels and stream.count and not np.any(log.column(name, "Health", rows)):
        problem = (
            f"the compass was unhealthy (Health 0) in every {name} record: the field it logged is stale, not a "
            "measurement; check its connection and record again"
        )
    missing = [axis for axis in ("MagX", "MagY", "MagZ") if axis not in labels]
    if missing:
        problem = f"the {name} messages have no {', '.join(missing)} field"
    device = ""
    if compass is not None and compass.device_id:
        device = f", COMPASS_DEV_ID{parameter_suffix(compass.index)} {compass.device_id}"
    magnetometer = Magnetometer(
        id=f"MAG/{slot}",
        description=f"compass {slot + 1} ({name}"
        + (f", I={slot})" if name == "MAG" and "I" in labels else ")")
        + device,
        unit="mG",
        n_samples=stream.count - (jumps.repeated if jumps is not None else 0),
        start_s=first,
        end_s=float(times[-1]) if len(times) else float("nan"),
        device_id=compass.device_id if compass else None,
        slot=compass.index if compass else slot,
        raw=False,
        notes=tuple(notes),
        problem=problem,
    )
    rate = magnetometer.rate_hz
    if np.isfinite(rate) and rate < SLOW_RATE_HZ:
        notes.append(
            f"logged at only {rate:.1f} Hz: too slow for a fit over a short tumble; enable the compass in LOG_BITMASK "
            "(COMPASS bit) for 10 Hz or more, or use the onboard calibrator (COMPASS_CAL_FIT)"
        )
        magnetometer = replace(magnetometer, notes=tuple(notes))
    return magnetometer


def _read(
    log: Any,
    parameters: dict[str, list[tuple[float, float]]],
    magnetometer: Magnetometer,
    stream: _Stream,
    instances: NDArray[Any] | None,
    max_samples: int | None = None,
) -> LogSamples:
    """The compass's raw field: its records (every k-th, k the least that keeps at most ``max_samples``), the
    calibration each was logged with undone, the damaged and stale ones skipped."""
    slot = int(magnetometer.id.split("/")[1])
    compass, problem = compass_parameters(parameters, slot, magnetometer.start_s)
    if compass is None:  # _describe set the problem; Source.read refuses it before calling here
        raise DataFileError(f"{log.path}: {magnetometer.id} cannot be fitted: {problem}")
    every = -(-stream.count // max_samples) if max_samples is not None and 0 < max_samples < stream.count else 1
    name, records = stream.name, log.messages(stream.name, _rows(stream, instances, every))
    with np.errstate(invalid="ignore"):  # damaged values become NaN: dropped below as non-finite samples
        logged = np.column_stack([log.value(records, name, axis) for axis in ("MagX", "MagY", "MagZ")])
        labels = records.dtype.names or ()
        motor = None
        motor_labels = _motor_labels(labels)
        if compass.motor_compensation and motor_labels is not None:
            motor = np.column_stack([log.value(records, name, axis) for axis in motor_labels])
        used = None
        if _has_offsets(labels):  # the offsets each record was corrected with (whole mG)
            used = np.column_stack([log.value(records, name, axis) for axis in ("OfsX", "OfsY", "OfsZ")])
    times = _time_s(log, name, records)
    once = _first_copies(times, logged)
    if once is not None:  # a log joined to a copy of itself: each record once (_describe's note says so)
        records, logged, times = records[once], logged[once], times[once]
        motor = motor[once] if motor is not None else None
        used = used[once] if used is not None else None
    undone = undo_records(
        logged, times, parameters=parameters, compass=compass, motor_offsets=motor, logged_offsets=used
    )
    samples = undone.samples
    finite = np.all(np.isfinite(samples), axis=1) & ~undone.damaged
    notes = [*magnetometer.notes]
    if every > 1:
        notes.append(
            f"one record in every {every} read ({len(records)} of {stream.count}): the compass logged more than "
            f"{option('max_samples', max_samples)}, so a regular stride over the whole log is fitted"
        )
    notes += undone.notes
    if "Health" in labels:  # AP_Compass's healthy(): an unhealthy compass logs its last field again, stale
        unhealthy = records["Health"] == 0
        if np.any(unhealthy):
            finite &= ~unhealthy
            notes.append(
                f"{int(np.count_nonzero(unhealthy))} of {len(records)} records skipped: the compass was unhealthy "
                "(Health 0) when they were logged, so the field they carry is stale"
            )
    return LogSamples(
        magnetometer=magnetometer,
        samples=samples[finite],
        time_s=times[finite],
        columns=("MagX", "MagY", "MagZ"),
        notes=tuple(notes),
        every=every,
    )


def _clock_label(labels: tuple[str, ...]) -> tuple[str, float] | None:
    """The time stamp field of a message and its seconds per unit: TimeUS, or TimeMS in older logs."""
    if "TimeUS" in labels:
        return "TimeUS", 1e-6
    if "TimeMS" in labels:
        return "TimeMS", 1e-3
    return None


@dataclass(frozen=True)
class _TimeJumps:
    """A compass's time stamps that go back: how often, the first place (seconds after boot, before and after
    the jump), the stamps that repeat an earlier one, and the span of the stamps once each."""

    backs: int
    at_s: float
    to_s: float
    repeated: int
    start_s: float
    end_s: float

    def describe(self) -> str:
        where = f"its time stamps go back at {self.at_s:.1f} s after boot (to {self.to_s:.1f} s)"
        where += f", {self.backs} times" if self.backs > 1 else ""
        if self.repeated:
            return (
                f"{where}, and {self.repeated} records repeat earlier ones: the log holds the same recording more "
                "than once (files joined); each record is read once. Fit the log as the flight controller wrote it"
            )
        return (
            f"{where}: the file holds more than one recording (logs joined, or the board rebooted); their samples "
            "are fitted together, but their stamps are not one clock (vector's lag, the motors' current): give "
            "each recording apart (a log per boot)"
        )


def _time_jumps(times: NDArray[np.float64], fields: NDArray[Any]) -> _TimeJumps | None:
    """Where ``times`` (seconds, in log order) go back, or None when they never do (a log of one boot); a record
    repeats an earlier one when its stamp and its ``fields`` (N, 3) are the same."""
    steps = np.diff(times)
    backs = np.flatnonzero(steps < 0)
    if not len(backs):
        return None
    once = _first_copies(times, np.asarray(fields, dtype=np.float64))
    kept = times if once is None else times[once]
    first = int(backs[0])
    return _TimeJumps(
        len(backs), float(times[first]), float(times[first + 1]), len(times) - len(kept),
        float(np.min(kept)), float(np.max(kept)),
    )  # fmt: skip


def _first_copies(times: NDArray[np.float64], logged: NDArray[np.float64]) -> NDArray[np.int64] | None:
    """The records to keep when the stamps go back: each (stamp, field) once, in log order; None when they do
    not go back (every record kept)."""
    if len(times) < 2 or np.all(np.diff(times) >= 0):
        return None
    keys = np.column_stack([times, logged])
    _, first = np.unique(keys, axis=0, return_index=True)
    return np.sort(first) if len(first) < len(times) else None


def _has_offsets(labels: tuple[str, ...]) -> bool:
    return {"OfsX", "OfsY", "OfsZ"} <= set(labels)


def _motor_labels(labels: tuple[str, ...]) -> tuple[str, str, str] | None:
    """MAG's motor compensation fields: MOX/MOY/MOZ, or MOfsX/MOfsY/MOfsZ in logs before ArduPilot 3.5."""
    for names in (("MOX", "MOY", "MOZ"), ("MOfsX", "MOfsY", "MOfsZ")):
        if set(names) <= set(labels):
            return names
    return None
