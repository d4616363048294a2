"""Which vehicle a log was recorded on, by its own identity: the flight controller's board and unique id.

- ArduPilot DataFlash: at boot the firmware logs a ``MSG`` with the board's name and the processor's 96-bit unique
  id as three hexadecimal words (``Pixhawk4 0047002B 34385105 36363539``; ``PX4v2 004A002F 33345119 32383433`` in
  3.3-era logs).
- PX4 ULog: the ``sys_uuid`` information message, with ``ver_hw`` (``CUBEPILOT_CUBEORANGE``).

Other logs (a tlog's system id is 1 on most vehicles) and samples files have none: None.

The readers find it in the pass that reads the compasses (:attr:`magfit.sources.Source.identity`):
:func:`board_identity` and :func:`ulog_identity` take what they have already read;
:func:`magfit.sources.read.vehicle_identity` opens a log for it alone.
"""

from __future__ import annotations

import re
from collections.abc import Iterable, Mapping
from typing import Any

__all__ = ["board_identity", "ulog_identity"]

_BOARD_ID = re.compile(r"^(\S+) ([0-9A-Fa-f]{8} [0-9A-Fa-f]{8} [0-9A-Fa-f]{8})\s*$")
#: The boot message is among a log's first MSG messages: so many are looked at.
BOOT_MESSAGES = 64


def board_identity(messages: Iterable[bytes | str]) -> str | None:
    """The board and unique id in ArduPilot's boot ``MSG`` texts (the first :data:`BOOT_MESSAGES`), or None."""
    for count, raw in enumerate(messages):
        if count >= BOOT_MESSAGES:
            break
        text = raw if isinstance(raw, str) else bytes(raw).rstrip(b"\0").decode("ascii", errors="replace")
        match = _BOARD_ID.match(text.strip())
        if match:
            return f"{match.group(1)} {match.group(2).upper()}"
    return None


def ulog_identity(info: Mapping[str, Any]) -> str | None:
    """The hardware and ``sys_uuid`` of a ULog's information messages (pyulog's ``msg_info_dict``), or None."""
    uuid = info.get("sys_uuid")
    if not uuid:
        return None
    hardware = info.get("ver_hw")
    return f"{hardware} {uuid}" if hardware else str(uuid)
