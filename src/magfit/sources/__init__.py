"""What a recording holds: its magnetometers (ids, units, rates, time spans) and what else was logged.

A flight log carries several compasses, each logged by the firmware in its own way, beside the attitude,
the accelerometer and the GPS. :func:`open_source` reads a file once into a :class:`Source` that says what
it holds; :meth:`Source.read` returns the samples of one magnetometer as the raw field of its sensor (the
firmware's calibration undone where the log says how), with the notes a user must see (a compass logged
too slowly, a calibration undone with the log's parameters).

This package only exports; each module has one job: :mod:`.detect` tells the kind of a file by its first
bytes (:func:`log_kind`), :mod:`.read` opens it with its reader (:func:`open_source`), :mod:`.types` holds
what the readers fill, :mod:`.identity` the vehicle's own identity. The readers, one per format:

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

from .detect import log_kind
from .read import open_source, vehicle_identity
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
    "vehicle_identity",
]
