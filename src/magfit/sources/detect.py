"""Which kind of recording a file is, by its first bytes, not by its name: :func:`log_kind`.

- PX4 ULog (``ULog\\x01\\x12\\x35``);
- ArduPilot DataFlash ``.bin`` (``0xA3 0x95``, then a FMT message);
- MAVLink telemetry logs (``.tlog``: each record an 8-byte big-endian UNIX time in microseconds and a MAVLink
  frame, :func:`is_tlog`);
- the text ``mavlogdump.py log.bin`` prints (:func:`magfit.sources.mavlogdump.is_mavlogdump`);
- ROS 1 bags, MCAP, ROS 2 SQLite bags and bag folders (:func:`magfit.sources.rosbag.bag_kind`);
- anything else is a samples file for :mod:`magfit.io` (None).
"""

from __future__ import annotations

import os

__all__ = ["DATAFLASH_MAGIC", "TLOG_STAMP_RANGE", "ULOG_MAGIC", "is_tlog", "log_kind"]

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
    if is_tlog(head):
        return "tlog"
    from .mavlogdump import is_mavlogdump

    if is_mavlogdump(head):
        return "mavlogdump"
    from .rosbag import bag_kind  # its own magic numbers (ROS 1, MCAP, SQLite); the module imports no extra

    if str(path) != "-" and bag_kind(path) is not None:
        return "rosbag"
    return None


#: Plausible tlog time stamps: 2000-01-01 to 2100-01-01, in microseconds since 1970.
TLOG_STAMP_RANGE = (946_684_800_000_000, 4_102_444_800_000_000)


def is_tlog(head: bytes) -> bool:
    """True when ``head`` (a file's first bytes) starts with tlog records: a plausible time stamp, then a
    MAVLink frame's magic byte, three times in a row (or up to the end of ``head`` when the file is that short,
    or cut short: the reader says what it finds)."""
    if len(head) < 10:
        return False
    pos, records, first = 0, 0, None
    while pos + 10 <= len(head) and records < 3:
        stamp = int.from_bytes(head[pos : pos + 8], "big")
        plausible = TLOG_STAMP_RANGE[0] <= stamp <= TLOG_STAMP_RANGE[1]
        if not plausible or (first is not None and abs(stamp - first) > 86_400e6):
            return False
        first = stamp if first is None else first
        magic, length = head[pos + 8], head[pos + 9]
        if magic == 0xFE:
            size = length + 8
        elif magic == 0xFD and pos + 11 <= len(head) and head[pos + 10] <= 1:
            size = length + 12 + (13 if head[pos + 10] & 1 else 0)
        else:
            return False
        pos += 8 + size
        records += 1
    return records == 3 or pos + 10 > len(head)  # or the records run to the end: a short or cut-short file
