"""Turning the bytes a board prints into magnetometer samples, whatever the serial line did to them.

Three line formats are read:

- MotionCal's ``Raw:ax,ay,az,gx,gy,gz,mx,my,mz``: exactly nine integers, the magnetometer in units of
  0.1 µT. MotionCal (PJRC, ``serialdata.c``) accepts nothing else on such a line, and multiplies the last
  three by ``UT_PER_COUNT = 0.1`` (``imuread.h``); so does this parser.
- ``Uni:ax,ay,az,gx,gy,gz,mx,my,mz``: the same nine values in SI units as Adafruit's calibration sketches
  print them (magnetometer in µT, as floats).
- Plain delimited lines of three or more numbers (commas, semicolons, tabs or spaces), with an optional
  header line; the magnetometer columns are chosen as for files (:mod:`magfit.io.columns`): by name from
  the header, else the first three fields, or given by the caller.

The first line that holds a sample fixes the format (a *dialect*) for the rest of the stream: later lines
of another format are not samples. Adafruit's sketches print every sample twice, a ``Raw:`` and a ``Uni:``
line; the tag seen first is read and the other ignored, so no sample counts twice.

What a serial line carries besides samples is expected, not fatal: a line cut when the port was opened
(the first line from a device is dropped), boot banners and bytes of noise after a reset, a sample line
cut by a reboot and glued to what follows. Each such line is counted as junk; a tagged line with noise
before its tag is read from its last tag. The ``Cal1:`` / ``Cal2:`` lines with which the sketches echo
their stored calibration are kept, to confirm a calibration sent to the board.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from .._validation import MAX_MAGNITUDE
from ..errors import DataFileError, OptionError
from ..io.columns import find_magnetometer_columns

__all__ = ["MOTIONCAL_UT_PER_COUNT", "LineParser", "StreamCounts"]

#: MotionCal's ``UT_PER_COUNT`` (imuread.h): the magnetometer integers of a ``Raw:`` line are 0.1 µT.
MOTIONCAL_UT_PER_COUNT = 0.1
#: The longest line kept while waiting for its end: a stream with no line ends (wrong baud rate, binary
#: data) must not grow without bound.
MAX_LINE_BYTES = 4096
#: Junk lines quoted in messages (the first few; all are counted).
_QUOTED_JUNK = 3

_TAG = re.compile(r"(Raw|Uni|Cal1|Cal2):")
_FIELD_SPLIT = re.compile(r"[,;\s]+")
_INTEGER = re.compile(r"[+-]?\d+\Z")
#: How many values follow each tag (MotionCal's ascii_parse: 9 for Raw, 10 for Cal1, 9 for Cal2).
_TAG_FIELDS = {"Raw": 9, "Uni": 9, "Cal1": 10, "Cal2": 9}


@dataclass
class StreamCounts:
    """What the parser has seen so far (all counts since the stream opened).

    Attributes
    ----------
    lines : int
        Complete lines read.
    samples : int
        Samples taken from them.
    junk : int
        Lines that were neither a sample, an ignored second tag, a header nor a blank line.
    interruptions : int
        Runs of junk lines between samples: each is a reset, a reboot or noise on the line.
    other_tag : int
        Lines of the tag not read (the ``Uni:`` twin of each ``Raw:`` line, or the reverse).
    dropped_first : bool
        True when the first line was dropped as possibly cut (a device opened mid-line).
    junk_examples : list of str
        The first few junk lines, shortened, for messages.
    """

    lines: int = 0
    samples: int = 0
    junk: int = 0
    interruptions: int = 0
    other_tag: int = 0
    dropped_first: bool = False
    junk_examples: list[str] = field(default_factory=list)


class LineParser:
    """Split a byte stream into lines and the lines into (x, y, z) magnetometer samples.

    Parameters
    ----------
    columns : sequence of 3 str or int, optional
        For plain lines: the x, y, z columns by header name or 0-based index. By default they are found
        from the header's names (:func:`magfit.io.find_magnetometer_columns`), else the first three.
    first_line_may_be_cut : bool
        True for a device or socket opened while the board was already printing: the first line is then
        dropped. False for a file or a pipe that starts at a line's start.

    Feed bytes with :meth:`feed`; it returns the samples completed by those bytes, shape (n, 3), in
    :attr:`unit` (µT for the MotionCal formats, the stream's own unit for plain lines).
    """

    def __init__(self, *, columns: Sequence[str | int] | None = None, first_line_may_be_cut: bool = False) -> None:
        if columns is not None and len(columns) != 3:
            raise OptionError(f"columns must name three columns (x, y, z), got {list(columns)!r}")
        self._columns_option = None if columns is None else list(columns)
        self._skip_next = first_line_may_be_cut
        self._pending = b""
        self.counts = StreamCounts()
        #: "Raw", "Uni" or "plain" once the first sample fixed it; None before.
        self.dialect: str | None = None
        self._header: list[str] | None = None
        self._field_count = 0
        self._indices: tuple[int, int, int] = (0, 1, 2)
        self._in_junk = False
        #: The last ``Cal1:`` (10 values) and ``Cal2:`` (9 values) lines the board printed, if any.
        self.cal1: tuple[float, ...] | None = None
        self.cal2: tuple[float, ...] | None = None
        #: Column names or labels of the plain dialect (for the recording and messages).
        self.column_names: tuple[str, str, str] | None = None

    def reconnected(self) -> None:
        """The connection was lost and is back: the line in progress is lost, the next one may be cut."""
        if self._pending:
            self._junk(self._pending[:80].decode("utf-8", "replace"))
        self._pending = b""
        self._skip_next = True

    @property
    def unit(self) -> str | None:
        """``"uT"`` for the MotionCal formats; None (unknown) for plain lines or before the first sample."""
        return "uT" if self.dialect in ("Raw", "Uni") else None

    def describe(self) -> str:
        """The format read, in words."""
        if self.dialect == "Raw":
            return "MotionCal Raw: lines (magnetometer in 0.1 uT)"
        if self.dialect == "Uni":
            return "Uni: lines (magnetometer in uT)"
        if self.dialect == "plain":
            names = ", ".join(self.column_names or ())
            return f"plain lines of {self._field_count} numbers, columns {names}"
        return "no sample yet"

    # ------------------------------------------------------------------ bytes -> lines

    def feed(self, data: bytes) -> NDArray[np.float64]:
        """Parse ``data`` (any cut of the stream); returns the samples of the lines it completed, (n, 3)."""
        text = self._pending + data
        # MotionCal ends a line at CR and ignores LF; boards print CR LF, LF or CR: any of them ends a line.
        parts = re.split(rb"\r\n|\r|\n", text)
        self._pending = parts.pop()
        if len(self._pending) > MAX_LINE_BYTES:
            self._junk(self._pending[:80].decode("utf-8", "replace"))
            self._pending = b""
        rows: list[tuple[float, float, float]] = []
        for raw in parts:
            self._line(raw, rows)
        return np.array(rows, dtype=np.float64).reshape(-1, 3)

    def finish(self, *, last_line_complete: bool) -> NDArray[np.float64]:
        """At the end of the stream: the samples of an unterminated last line when it is complete (a file)."""
        rows: list[tuple[float, float, float]] = []
        if self._pending and last_line_complete:
            self._line(self._pending, rows)
        elif self._pending:
            self._junk(self._pending[:80].decode("utf-8", "replace"))
        self._pending = b""
        return np.array(rows, dtype=np.float64).reshape(-1, 3)

    # ------------------------------------------------------------------ one line

    def _line(self, raw: bytes, rows: list[tuple[float, float, float]]) -> None:
        if self._skip_next:
            self._skip_next = False
            self.counts.dropped_first = True
            return
        text = raw.decode("utf-8", "replace").strip().lstrip("\ufeff")
        if not text:
            return
        self.counts.lines += 1
        sample = self._tagged(text) if _TAG.search(text) else self._plain(text)
        if sample is None:
            return
        rows.append(sample)
        self.counts.samples += 1
        self._in_junk = False

    def _junk(self, text: str) -> None:
        self.counts.junk += 1
        if not self._in_junk and self.counts.samples:
            self.counts.interruptions += 1
        self._in_junk = True
        if len(self.counts.junk_examples) < _QUOTED_JUNK:
            self.counts.junk_examples.append(text[:60])

    def _tagged(self, text: str) -> tuple[float, float, float] | None:
        # Noise after a reset may precede the tag on the same line: read from the last tag.
        *_, match = _TAG.finditer(text)
        tag = match.group(1)
        fields = text[match.end() :].split(",")
        values = _numbers(fields, integers=tag == "Raw")
        if values is None or len(values) != _TAG_FIELDS[tag]:
            self._junk(text)
            return None
        if tag == "Cal1":
            self.cal1 = tuple(values)
            return None
        if tag == "Cal2":
            self.cal2 = tuple(values)
            return None
        if self.dialect is None:
            self.dialect = tag
        elif self.dialect != tag:
            if self.dialect == "plain":
                self._junk(text)
            else:
                self.counts.other_tag += 1
            return None
        if tag == "Raw":
            if any(not -32768 <= v <= 32767 for v in values):  # MotionCal stores them as int16
                self._junk(text)
                return None
            return (
                values[6] * MOTIONCAL_UT_PER_COUNT,
                values[7] * MOTIONCAL_UT_PER_COUNT,
                values[8] * MOTIONCAL_UT_PER_COUNT,
            )
        return (values[6], values[7], values[8])

    def _plain(self, text: str) -> tuple[float, float, float] | None:
        fields = [f for f in _FIELD_SPLIT.split(text) if f]
        values = _numbers(fields, integers=False)
        if values is None:
            # A line of names before the first sample may be the header; anything else is junk.
            if self.dialect is None and len(fields) >= 3 and all(_is_name(f) for f in fields):
                self._header = fields
            else:
                self._junk(text)
            return None
        if self.dialect is None:
            if len(values) < 3:
                self._junk(text)
                return None
            self._start_plain(len(values))
        elif self.dialect != "plain" or len(values) != self._field_count:
            # Another format, or a line cut short (or glued to the next) by a reset.
            self._junk(text)
            return None
        i, j, k = self._indices
        return (values[i], values[j], values[k])

    def _start_plain(self, count: int) -> None:
        """Fix the plain dialect on its first data line: the field count and the x, y, z columns."""
        header = self._header if self._header is not None and len(self._header) == count else None
        labels = header or [f"column {i + 1}" for i in range(count)]
        if self._columns_option is not None:
            indices = [self._column_index(item, header, count) for item in self._columns_option]
            if len(set(indices)) != 3:
                raise OptionError(f"--columns {self._columns_option} names the same column twice")
        elif header is not None:
            candidates = find_magnetometer_columns(header)
            best = [c for c in candidates if candidates and c.score == candidates[0].score]
            if not best:
                raise DataFileError(
                    f"the stream's header names no magnetometer columns ({', '.join(header)}); "
                    "name the x, y, z columns with --columns"
                )
            if len(best) > 1:
                choices = "; ".join(c.describe() for c in best)
                raise DataFileError(f"the stream's header has several magnetometers ({choices}); choose with --columns")
            indices = list(best[0].indices)
        else:
            indices = [0, 1, 2]
        self.dialect = "plain"
        self._field_count = count
        self._indices = (indices[0], indices[1], indices[2])
        self.column_names = (labels[indices[0]], labels[indices[1]], labels[indices[2]])

    @staticmethod
    def _column_index(item: str | int, header: list[str] | None, count: int) -> int:
        if isinstance(item, int):
            if not 0 <= item < count:
                raise OptionError(f"column index {item} is out of range: the lines have {count} fields (0-based)")
            return item
        if header is None:
            raise OptionError(f"no column named {item!r}: the stream has no header line; give 0-based indices")
        folded = [name.casefold() for name in header]
        if item.casefold() not in folded:
            raise OptionError(f"no column named {item!r}; the stream's columns are: {', '.join(header)}")
        return folded.index(item.casefold())


def _numbers(fields: Sequence[str], *, integers: bool) -> list[float] | None:
    """The fields as numbers within ±MAX_MAGNITUDE, or None when any is not one (integers only for ``Raw:``):
    the line is then junk, counted and skipped."""
    values = []
    for text in fields:
        text = text.strip()
        if integers:
            if not _INTEGER.match(text):
                return None
            values.append(float(int(text)))
            continue
        try:
            value = float(text)
        except ValueError:
            return None
        if not abs(value) <= MAX_MAGNITUDE:  # NaN, inf, or beyond what float64 can square: no sample, a glitch
            return None
        values.append(value)
    return values


def _is_name(text: str) -> bool:
    """A header field: starts with a letter or underscore (``mx``, ``mag_x``, ``MagX(uT)``)."""
    return bool(text) and (text[0].isalpha() or text[0] == "_")
