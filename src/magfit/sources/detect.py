"""Which kind of recording a file is, by its first bytes, not by its name: :func:`log_kind`.

- PX4 ULog (``ULog\\x01\\x12\\x35``);
- ArduPilot DataFlash ``.bin`` (``0xA3 0x95``, then a FMT message); a DataFlash log without its beginning (the
  second half of a log: message headers ``0xA3 0x95`` from the first bytes on, no FMT first) is one too, which
  its reader refuses with what is missing (:func:`is_headless_dataflash`);
- MAVLink telemetry logs (``.tlog``: each record an 8-byte big-endian UNIX time in microseconds and a MAVLink
  frame, :func:`is_tlog`);
- the text ``mavlogdump.py log.bin`` prints (:func:`is_mavlogdump`);
- ROS 1 bags, MCAP, ROS 2 SQLite bags and bag folders (:func:`magfit.sources.rosbag.bag_kind`);
- anything else is a samples file for :mod:`magfit.io` (None).
"""

from __future__ import annotations

import os
import re

__all__ = [
    "DATAFLASH_MAGIC",
    "TLOG_STAMP_RANGE",
    "ULOG_MAGIC",
    "is_headless_dataflash",
    "is_mavlogdump",
    "is_tlog",
    "log_kind",
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
    if head.startswith(DATAFLASH_MAGIC) or is_headless_dataflash(head):
        return "dataflash"
    if is_tlog(head):
        return "tlog"
    if is_mavlogdump(head):
        return "mavlogdump"
    from .rosbag import bag_kind  # its own magic numbers (ROS 1, MCAP, SQLite); the module imports no extra

    if str(path) != "-" and bag_kind(path) is not None:
        return "rosbag"
    return None


#: A head of DataFlash messages without its FMT: this many message headers at least in the first 4096 bytes (a
#: log holds one every 20-90 bytes; random bytes hold 0xA3 0x95 once in 65 536), the first within this many bytes.
HEADLESS_HEADERS = 8
HEADLESS_FIRST = 512


def is_headless_dataflash(head: bytes) -> bool:
    """True when ``head`` (a file's first bytes, 4096 or all of them) is DataFlash messages whose log does not
    start here: ``0xA3 0x95`` message headers from the first bytes on, and the first message is not a FMT.

    The start of a log is its FMT messages (type 128), which give every other message its length and fields;
    a file cut out of a log's middle (a log split in two, the second part) starts with data messages."""
    if head.startswith(DATAFLASH_MAGIC):
        return False
    first = head.find(DATAFLASH_MAGIC[:2])
    if first < 0 or first > HEADLESS_FIRST or head.count(DATAFLASH_MAGIC[:2]) < HEADLESS_HEADERS:
        return False
    return head[first + 2 : first + 3] != DATAFLASH_MAGIC[2:]


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


#: The date mavlogdump puts before each message, then the message's name and the opening of its fields.
_MAVLOGDUMP_HEAD = re.compile(rb"^\d{4}-\d\d-\d\d \d\d:\d\d:\d\d(?:\.\d+)?: [A-Z][A-Z0-9_]{0,15} \{")


def is_mavlogdump(head: bytes) -> bool:
    """True when the first non-empty line of ``head`` (the file's first bytes) is a mavlogdump message line."""
    for line in head.splitlines():
        if line.strip():
            return bool(_MAVLOGDUMP_HEAD.match(line.lstrip(b"\xef\xbb\xbf")))
    return False
