"""Which vehicle a log was recorded on, by its own identity: the flight controller's board and unique id.

- ArduPilot DataFlash: at boot the firmware logs a ``MSG`` with the board's name and the processor's 96-bit unique
  id as three hexadecimal words (``Pixhawk4 0047002B 34385105 36363539``; ``PX4v2 004A002F 33345119 32383433`` in
  3.3-era logs).
- PX4 ULog: the ``sys_uuid`` information message, with ``ver_hw`` (``CUBEPILOT_CUBEORANGE``).

Other logs (a tlog's system id is 1 on most vehicles) and samples files have none: None.
"""

from __future__ import annotations

import re
from pathlib import Path

from ..errors import MagfitError

__all__ = ["vehicle_identity"]

_BOARD_ID = re.compile(r"^(\S+) ([0-9A-Fa-f]{8} [0-9A-Fa-f]{8} [0-9A-Fa-f]{8})\s*$")


def vehicle_identity(path: str | Path) -> str | None:
    """The board and unique id of the flight controller that wrote the log at ``path``, or None."""
    from ..io.sources import data_file
    from . import log_kind

    target = Path(path)
    kind = log_kind(target)
    try:
        if kind == "dataflash":
            return _dataflash(target, data_file(target))
        if kind == "ulog":
            return _ulog(data_file(target))
    except (MagfitError, OSError, ValueError, KeyError):
        return None
    return None


def _dataflash(path: Path, file: Path) -> str | None:
    from .dataflash import DataFlashLog

    log = DataFlashLog(path, file)
    if not log.has("MSG"):
        return None
    records = log.messages("MSG")
    if "Message" not in (records.dtype.names or ()):
        return None
    for raw in records["Message"][:64]:  # logged at boot, among the first messages
        text = bytes(raw).rstrip(b"\0").decode("ascii", errors="replace").strip()
        match = _BOARD_ID.match(text)
        if match:
            return f"{match.group(1)} {match.group(2).upper()}"
    return None


def _ulog(file: Path) -> str | None:
    from pyulog import ULog

    info = ULog(str(file), [], parse_header_only=True).msg_info_dict
    uuid = info.get("sys_uuid")
    if not uuid:
        return None
    hardware = info.get("ver_hw")
    return f"{hardware} {uuid}" if hardware else str(uuid)
