"""Cut a DataFlash log down to the messages a compass fit reads: every FMT, then PARM, MSG, MAG, MAG2, MAG3,
ATT, GPS and IMU (instance 0), in the log's order, each message's bytes unchanged.

    python make_fixture.py log171.bin copter33_log171_trimmed.bin
"""

from __future__ import annotations

import struct
import sys
from pathlib import Path

KEEP = {"FMT", "PARM", "MSG", "MAG", "MAG2", "MAG3", "ATT", "GPS", "IMU"}


def trim(data: bytes) -> bytes:
    lengths = {0x80: 89}
    names = {0x80: "FMT"}
    out = bytearray()
    pos = 0
    while pos + 3 <= len(data):
        if data[pos] != 0xA3 or data[pos + 1] != 0x95 or data[pos + 2] not in lengths:
            pos += 1  # damage: not in these logs, skipped the same way
            continue
        kind = data[pos + 2]
        end = pos + lengths[kind]
        if end > len(data):
            break
        if kind == 0x80:
            defined, length, name = struct.unpack("<BB4s", data[pos + 3 : pos + 9])
            lengths[defined] = length
            names[defined] = name.rstrip(b"\0").decode()
        if names[kind] in KEEP:
            out += data[pos:end]
        pos = end
    return bytes(out)


if __name__ == "__main__":
    source, target = Path(sys.argv[1]), Path(sys.argv[2])
    target.write_bytes(trim(source.read_bytes()))
