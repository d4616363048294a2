"""ArduPilot logs as text: the output of pymavlink's ``mavlogdump.py log.bin`` (its default format).

Each message is one line, the time the dump computed for it, then the message as ``str()`` of pymavlink's
``DFMessage`` prints it (``DFReader.py``: ``NAME {Field : value, Field : value}``)::

    2023-05-01 10:00:00.12: MAG {TimeUS : 123456, I : 0, MagX : 12, MagY : -40, MagZ : 301, OfsX : ...}
    2023-05-01 10:00:00.12: PARM {TimeUS : 1000, Name : COMPASS_OFS_X, Value : 12.5, Default : 0.0}

The values are printed *after* the format's multipliers (degrees, not 1e-7 degrees; a quiet NaN as
``qnan``), so they are read as they are. The messages are then what a ``.bin`` holds, and the same reader
works on them (:func:`magfit.sources.dataflash.source_from_log`): MAG per instance ``I`` (or MAG, MAG2,
MAG3), its calibration undone with the ``COMPASS_*`` parameters of the PARM lines, ATT/XKQ/AHR2 and IMU for
:meth:`~magfit.sources.Source.read_motion`, GPS for the position. The line's leading date is the dump's
rendering of the log's clock in the local time zone of whoever ran it: not used; ``TimeUS`` is.

A file is recognised by its content: its first non-empty line has that shape.
"""

from __future__ import annotations

import re
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..errors import DataFileError
from .detect import is_mavlogdump  # the format's sniffing lives with the others'
from .types import Source

__all__ = ["MavlogdumpLog", "is_mavlogdump", "open_mavlogdump"]

#: The date mavlogdump puts before each message, then the message's name and its fields.
_LINE = re.compile(r"^\d{4}-\d\d-\d\d \d\d:\d\d:\d\d(?:\.\d+)?: ([A-Z][A-Z0-9_]{0,15}) \{(.*)\}\s*$")
#: The messages whose fields are read; the others are only counted (a MSG's text may hold ", " and " : ").
_READ = frozenset({"MAG", "MAG2", "MAG3", "PARM", "ATT", "AHR2", "XKQ", "IMU", "GPS"})
#: What precedes each value in a message's body: the start or ", ", a field name, " : ".
_FIELD = re.compile(r"(?:^|, )[A-Za-z_][A-Za-z0-9_]* : ")


def _number(text: str) -> float:
    try:
        return float(text)
    except ValueError:
        return float("nan")  # 'qnan' (pymavlink's quiet NaN), or text in a numeric field: no value


class MavlogdumpLog:
    """A mavlogdump text file read once: the messages magfit needs as structured arrays, the others counted.

    It has the interface :func:`magfit.sources.dataflash.source_from_log` reads a log by (``has``, ``count``,
    ``messages``, ``column``, ``value``, ``parameters``, ``names``, ``skipped_bytes``, ``truncated``).
    """

    def __init__(self, path: Path, lines: Any) -> None:
        self.path = path
        self.skipped_bytes = 0
        self.truncated = False
        self.skipped_lines = 0
        self._counts: dict[str, int] = {}
        bodies: dict[str, list[str]] = {}
        for number, line in enumerate(lines, start=1):
            match = _LINE.match(line)
            if match is None:
                if number == 1 and line.startswith("\ufeff"):
                    match = _LINE.match(line[1:])
                if match is None:
                    self.skipped_lines += bool(line.strip())
                    continue
            name = match.group(1)
            if name in ("FMT", "FMTU", "UNIT", "MULT"):
                continue
            self._counts[name] = self._counts.get(name, 0) + 1
            if name in _READ:
                bodies.setdefault(name, []).append(match.group(2))
        if not self._counts:
            raise DataFileError(
                f"{path}: starts like mavlogdump.py's text but holds no message line; dump the log again"
            )
        self._records: dict[str, NDArray[Any]] = {}
        for name, lines_of_type in bodies.items():
            self._records[name] = self._table(lines_of_type)
        self._parameters: dict[str, list[tuple[float, float]]] = {}
        parm = self._records.pop("PARM", None)
        if parm is not None and {"Name", "Value"} <= set(parm.dtype.names or ()):
            times = parm["TimeUS"] / 1e6 if "TimeUS" in (parm.dtype.names or ()) else np.full(len(parm), np.nan)
            for label, value, time in zip(parm["Name"].tolist(), parm["Value"].tolist(), times.tolist(), strict=True):
                self._parameters.setdefault(label, []).append((time, value))

    def _table(self, bodies: list[str]) -> NDArray[Any]:
        """The lines of one message type as a structured array: the fields of its first line, float64 (a PARM's
        Name as text); a line with other fields (damaged, or a format that changed) is skipped and counted."""
        labels = [part.partition(" : ")[0] for part in bodies[0].split(", ")]
        # The values are what lies between " : " and the next ", Label : " (labels are identifiers): one split
        # per line in C, then NumPy converts each column at once.
        split = _FIELD.split
        table = [split(body)[1:] for body in bodies]
        kept = [row for row in table if len(row) == len(labels)]
        self.skipped_lines += len(table) - len(kept)
        text = np.array(kept, dtype=str).reshape(len(kept), len(labels))
        dtype = np.dtype([(label, "U16" if label == "Name" else "<f8") for label in labels])
        records = np.empty(len(kept), dtype=dtype)
        for j, label in enumerate(labels):
            column = text[:, j]
            if label == "Name":
                records[label] = column
                continue
            try:
                records[label] = column.astype(np.float64)
            except ValueError:  # 'qnan' (pymavlink's quiet NaN), or damaged text: those values are NaN
                records[label] = [_number(value) for value in column]
        return records

    def names(self) -> dict[str, int]:
        """Every message type in the file and how many lines of it."""
        return dict(self._counts)

    def has(self, name: str) -> bool:
        return self._counts.get(name, 0) > 0 and (name == "PARM" or name in self._records)

    def count(self, name: str) -> int:
        """How many messages ``name`` were read (the lines of another format skipped)."""
        return len(self._records.get(name, ()))

    def messages(self, name: str, rows: NDArray[np.int64] | None = None) -> NDArray[Any]:
        """The messages ``name`` (those at the indices ``rows``) as a structured array of float64 fields
        (values as printed)."""
        records = self._records.get(name, np.empty(0))
        return records if rows is None else records[rows]

    def column(self, name: str, label: str, rows: NDArray[np.int64] | None = None) -> NDArray[Any]:
        """Field ``label`` of the messages ``name`` (those at ``rows``)."""
        return self.messages(name, rows)[label]

    def value(self, records: NDArray[Any], name: str, label: str) -> NDArray[np.float64]:
        """Field ``label`` as float64: mavlogdump printed it already scaled."""
        return np.asarray(records[label], dtype=np.float64)

    def parameters(self) -> dict[str, list[tuple[float, float]]]:
        """PARM lines: name -> [(time in s, value), ...] in file order."""
        return self._parameters


def open_mavlogdump(path: Path, file: Path) -> Source:
    """Read a mavlogdump text file into a :class:`~magfit.sources.Source` (``file``: its bytes on disk)."""
    from .dataflash import source_from_log

    try:
        with open(file, encoding="utf-8", errors="replace") as handle:
            log = MavlogdumpLog(path, handle)
    except OSError as error:
        raise DataFileError(f"{path}: cannot be read ({error.strerror}); check the file's permissions") from None
    notes = (f"{log.skipped_lines} lines skipped: not a mavlogdump message line",) if log.skipped_lines else ()
    source = source_from_log(path, log, "ArduPilot log as mavlogdump.py text", notes=notes)
    if "PARM" in log.names():
        return source
    # A dump made with --types MAG (a common way to cut a log down) lost the parameters the samples were
    # corrected with: say how to dump again rather than how to log.
    again = (
        "the dump has no PARM lines, so the calibration ArduPilot applied to MagX/Y/Z cannot be undone; dump the "
        "log again with the parameters: mavlogdump.py --types MAG,PARM,ATT,IMU,GPS log.bin"
    )
    magnetometers = tuple(replace(m, problem=again) for m in source.magnetometers)
    return replace(source, magnetometers=magnetometers)
