"""The layout of a samples file, found from its head: text (encoding, line ends, delimiter, decimal mark,
preamble, header, column count), ``.npy`` or ``.npz``.

A text file's layout is sniffed from its first 256 KiB only (more when they hold few lines); the rows are
read later by :mod:`magfit.io.chunks`, which uses the same field splitting and cell classification for its
messages. Every problem is a :class:`~magfit.DataFileError` naming the file and the line.
"""

from __future__ import annotations

import codecs
import csv
import os
import re
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np

from .npy import check_npy_array, npy_info, npz_members
from .sources import check_file, file_error

__all__ = ["FileFormat", "sniff"]

#: The layout is sniffed from this much of the start of a file.
HEAD_BYTES = 256 * 1024
#: The head grows (doubling) until it holds this many lines, up to HEAD_MAX_BYTES.
HEAD_MIN_LINES = 20
HEAD_MAX_BYTES = 64 * 1024 * 1024
#: Cells read as a missing value (NaN); anything else that is not a number is an error.
NA_VALUES = ("", "nan", "NaN", "NAN", "-nan", "-NaN", "NA", "N/A", "n/a", "null", "NULL", "None", "#N/A")
#: Delimiters tried, in this order of preference when several split the rows equally well.
_DELIMITERS = ("\t", ";", ",", "|", "whitespace")
_NA_SET = frozenset(NA_VALUES)
_NUMBER = re.compile(r"^[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?$|^[+-]?(inf|infinity)$", re.IGNORECASE)
_DECIMAL_COMMA = re.compile(r"^[+-]?\d*,\d+([eE][+-]?\d+)?$")
_Kind = Literal["text", "npy", "npz"]


@dataclass(frozen=True)
class FileFormat:
    """The layout of a samples file, as :func:`sniff` found it.

    Attributes
    ----------
    kind : {"text", "npy", "npz"}
        Delimited text, a NumPy array file or a NumPy archive of named arrays.
    delimiter : str or None
        ``","``, ``", "`` (comma and space), ``"\\t"``, ``";"``, ``"|"`` or ``"whitespace"`` (runs of spaces
        or tabs); None for npy/npz and for text with a single column.
    encoding : str
        ``"utf-8"``, ``"utf-8-sig"`` when the file starts with a byte-order mark, ``"latin-1"`` when it is
        not valid UTF-8; ``"binary"`` for npy/npz.
    preamble_lines : int
        Lines before the header (or before the data when there is no header), e.g. ``Fs,50.00``.
    header : tuple of str or None
        Column names (the keys for npz), None when the file has no header.
    n_columns : int
        Fields per row (columns of the array for npy, number of keys for npz).
    decimal : str
        Decimal mark of the numbers: ``"."``, or ``","`` for ``1,5;2,25``-style files.
    data_line : int
        Lines before the first data row (preamble, header and blank lines).
    data_offset : int
        Byte offset of the first data row (after the byte-order mark, if any).
    """

    kind: _Kind
    delimiter: str | None
    encoding: str
    preamble_lines: int
    header: tuple[str, ...] | None
    n_columns: int
    decimal: str = "."
    data_line: int = 0
    data_offset: int = 0

    def column_label(self, index: int) -> str:
        """The name of column ``index`` (0-based) as messages show it: its header name or ``column N``."""
        if self.header is not None and index < len(self.header) and self.header[index]:
            return self.header[index]
        return f"column {index + 1}"

    def describe(self) -> str:
        """A short human description, e.g. ``"text, ', '-separated, 6 columns, no header"``."""
        if self.kind != "text":
            return f"{self.kind}, {self.n_columns} {'keys' if self.kind == 'npz' else 'columns'}"
        if self.delimiter is None:
            parts = ["no delimiter found"]
        elif self.delimiter == "whitespace":
            parts = ["whitespace-separated"]
        else:
            parts = [f"{self.delimiter!r}-separated"]
        parts.append(f"{self.n_columns} columns")
        parts.append("header" if self.header is not None else "no header")
        if self.preamble_lines:
            parts.append(f"{self.preamble_lines} preamble line(s)")
        if self.encoding == "utf-8-sig":
            parts.append("UTF-8 BOM")
        return "text, " + ", ".join(parts)


def text_encoding(fmt: FileFormat) -> str:
    """The codec for the data lines of a text file: past the byte-order mark, ``utf-8-sig`` reads as ``utf-8``."""
    return "utf-8" if fmt.encoding == "utf-8-sig" else fmt.encoding


def pandas_module() -> Any:
    """pandas, which parses the rows of text files (the ``cli`` extra), or a one-line install hint."""
    try:
        import pandas
    except ImportError:  # pragma: no cover - pandas is in the cli extra
        raise ImportError("reading text data files needs pandas: pip install 'magfit[cli]'") from None
    return pandas


def pandas_options(fmt: FileFormat, used: Sequence[int], *, strip_blanks: bool = True) -> dict[str, Any]:
    """``pandas.read_csv`` options for the data lines of a text file: C engine, the columns ``used``, float64.

    ``strip_blanks`` (pandas' ``skipinitialspace``) costs a quarter of the parse; only a missing value
    written with a blank before it (``1, nan, 3``) needs it.
    """
    assert fmt.delimiter is not None
    return {
        "sep": r"\s+" if fmt.delimiter == "whitespace" else fmt.delimiter[0],
        "header": None,
        "usecols": list(used),
        "dtype": np.float64,
        "engine": "c",
        "encoding": text_encoding(fmt),
        "decimal": fmt.decimal,
        "skipinitialspace": strip_blanks,
        "skip_blank_lines": True,
        "na_values": list(NA_VALUES),
        "keep_default_na": False,
    }


def _kind_of(path: Path, head: bytes) -> _Kind:
    if head.startswith(b"\x93NUMPY"):
        return "npy"
    if head.startswith(b"PK\x03\x04") or path.suffix.lower() == ".npz":
        return "npz"
    if path.suffix.lower() == ".npy":
        return "npy"
    return "text"


def read_head(path: Path) -> tuple[bytes, bool]:
    """The first HEAD_BYTES of the file (more when they hold few lines) and whether the file is longer."""
    try:
        with open(path, "rb") as handle:
            size = HEAD_BYTES
            head = handle.read(size + 1)
            # A very long line (a comment, a note column) must not leave the head without data rows.
            while len(head) > size and head.count(b"\n") < HEAD_MIN_LINES and size < HEAD_MAX_BYTES:
                head += handle.read(size)
                size *= 2
    except OSError as error:
        raise file_error(path, f"cannot be read ({error.strerror}); check the file's permissions") from None
    return head[:size], len(head) > size


def _shown(line: str, limit: int = 60) -> str:
    """A line for a message: quoted, and cut when long (a line may be megabytes)."""
    return repr(line) if len(line) <= limit else repr(line[:limit]) + f" ... ({len(line)} characters)"


def cell_kind(cell: str, decimal: str = ".") -> Literal["number", "missing", "text"]:
    """Classify one stripped, unquoted cell."""
    if cell in _NA_SET:
        return "missing"
    if decimal == ",":
        cell = cell.replace(",", ".")
    return "number" if _NUMBER.match(cell) else "text"


def split_fields(line: str, delimiter: str | None) -> list[str]:
    """The stripped, unquoted fields of one text line (used on the head and on error paths only)."""
    if delimiter is None:
        return [line.strip().strip("\"'")]
    if delimiter == "whitespace":
        return [cell.strip("\"'") for cell in line.split()]
    if '"' in line:
        try:
            cells = next(csv.reader([line], delimiter=delimiter[0], skipinitialspace=True), [])
        except csv.Error:  # a quote around a lone carriage return: the plain split names the fields well enough
            cells = line.split(delimiter[0])
        return [cell.strip() for cell in cells]
    return [cell.strip() for cell in line.split(delimiter[0])]


# ---------------------------------------------------------------------------------------------- sniffing


def _mode_count(counts: Sequence[int]) -> tuple[int, float]:
    """The most common field count (the larger one on a tie) and the fraction of lines that have it."""
    tally = Counter(counts)
    best = max(tally.items(), key=lambda item: (item[1], item[0]))
    return best[0], best[1] / len(counts)


def _choose_delimiter(sample: Sequence[str]) -> str | None:
    """The delimiter that splits the sample lines into the most consistent number (>= 2) of fields."""
    best: tuple[bool, float, int, str] | None = None
    for order, delimiter in enumerate(_DELIMITERS):
        counts = [len(split_fields(line, delimiter)) for line in sample]
        mode, share = _mode_count(counts)
        if mode < 2:
            continue
        # Three fields or more first (a magnetometer has three axes), then the most consistent split.
        key = (mode >= 3, share, -order, delimiter)
        if best is None or key[:3] > best[:3]:
            best = key
    if best is None:
        return None
    if best[3] == ",":
        # ", " (comma then space) is kept apart so that a calibrated copy is written the same way.
        spaced = sum(line.count(", ") for line in sample)
        if spaced and spaced >= 0.9 * sum(line.count(",") for line in sample):
            return ", "
    return best[3]


def decode_lines(path: Path, head: bytes, truncated: bool) -> tuple[list[bytes], list[str], str]:
    """Split the head into raw lines (with their line ends) and decoded lines (without)."""
    if head.startswith((codecs.BOM_UTF16_LE, codecs.BOM_UTF16_BE)):
        raise file_error(path, "is UTF-16 encoded; save it as UTF-8 (or plain ASCII) text")
    if b"\x00" in head:
        raise file_error(path, "is a binary file, not delimited text, .npy or .npz; export the samples as CSV")
    if b"\r" in head and b"\n" not in head:
        raise file_error(
            path,
            "ends its lines with a carriage return only (classic Mac OS); convert them to newlines, "
            "e.g. tr '\\r' '\\n' < old.csv > new.csv",
        )
    pieces = head.split(b"\n")
    raw_lines = [piece + b"\n" for piece in pieces[:-1]]
    if pieces[-1]:
        raw_lines.append(pieces[-1])
    if truncated and len(raw_lines) > 1 and not raw_lines[-1].endswith(b"\n"):
        raw_lines.pop()  # cut in the middle by the head size
    encoding = "utf-8-sig" if head.startswith(codecs.BOM_UTF8) else "utf-8"
    try:
        text = b"".join(raw_lines).decode(encoding)
    except UnicodeDecodeError:
        encoding = "latin-1"
        text = b"".join(raw_lines).decode(encoding)
    lines = [line.rstrip("\r") for line in text.split("\n")]
    if text.endswith("\n"):
        lines.pop()
    return raw_lines, lines, encoding


def _numeric_columns_of(rows: list[list[str]], n_columns: int, decimal: str) -> list[int]:
    """Columns whose cells are numbers or missing values in at least 80 % of the rows (and some number)."""
    kinds = [[cell_kind(cell, decimal) for cell in row] for row in rows]
    # A header in a short sample would outvote the few data rows: lines without any number do not vote.
    kinds = [row for row in kinds if "number" in row] or kinds
    return [
        j
        for j in range(n_columns)
        if sum(row[j] != "text" for row in kinds) >= 0.8 * len(kinds) and any(row[j] == "number" for row in kinds)
    ]


def _sniff_text(path: Path, head: bytes, truncated: bool) -> FileFormat:
    raw_lines, lines, encoding = decode_lines(path, head, truncated)
    filled = [i for i, line in enumerate(lines) if line.strip()]
    if not filled:
        raise file_error(path, "is empty; record some samples or give another file")
    # The bottom half of the head is data in any sensible file: it decides delimiter and column count.
    sample = [lines[i] for i in filled[len(filled) // 2 :][-200:]]
    delimiter = _choose_delimiter(sample)
    counts = [len(split_fields(line, delimiter)) for line in sample]
    n_columns, _ = _mode_count(counts)
    rows = [split_fields(line, delimiter) for line in sample]
    rows = [row for row in rows if len(row) == n_columns]
    decimal = "."
    if delimiter not in (",", ", "):
        cells = [cell for row in rows for cell in row if cell]
        if cells and sum(bool(_DECIMAL_COMMA.match(cell)) for cell in cells) >= 0.5 * len(cells):
            decimal = ","
    numeric = _numeric_columns_of(rows, n_columns, decimal)
    if not numeric:  # the bottom half may be all missing values (NaN rows): let the whole head vote
        every_row = [split_fields(lines[i], delimiter) for i in filled]
        numeric = _numeric_columns_of([row for row in every_row if len(row) == n_columns], n_columns, decimal)
    if not numeric:
        shaped = [i for i in filled if len(split_fields(lines[i], delimiter)) == n_columns]
        if len(shaped) == 1:
            raise file_error(path, f"has a header but no data rows (line {shaped[0] + 1}: {_shown(lines[shaped[0]])})")
        raise file_error(path, "has no column of numbers; is it a samples file? Export the magnetometer data as CSV")

    def is_data(fields: list[str]) -> bool:
        if len(fields) != n_columns:
            # A line of numbers only is a damaged data row, not a preamble: the reader reports its field count.
            return all(cell_kind(cell, decimal) != "text" for cell in fields)
        return 2 * sum(cell_kind(fields[j], decimal) == "text" for j in numeric) < len(numeric)

    first_data = next((i for i in filled if is_data(split_fields(lines[i], delimiter))), None)
    if first_data is None:
        raise file_error(path, "has a header but no data rows; record some samples or give another file")
    header: tuple[str, ...] | None = None
    start = first_data
    before = [i for i in filled if i < first_data]
    if before:
        names = split_fields(lines[before[-1]], delimiter)
        # A header has one name per field; trailing empty names (a trailing delimiter) are tolerated.
        if len(names) >= n_columns and not any(names[n_columns:]):
            header = tuple(name.lstrip("\ufeff") for name in names[:n_columns])
            start = before[-1]
        elif len(names) >= 3 and all(cell_kind(name, decimal) == "text" for name in names):
            # A line of names that does not match the rows: reading on without it would silently number
            # the columns, and the no-header rule could then take the wrong three.
            raise file_error(
                path,
                f"line {before[-1] + 1} looks like a header with {len(names)} names, but the rows have {n_columns} "
                "fields; make them match (one name per column)",
            )
    return FileFormat(
        kind="text",
        delimiter=delimiter,
        encoding=encoding,
        preamble_lines=start,
        header=header,
        n_columns=n_columns,
        decimal=decimal,
        data_line=first_data,
        # Past the byte-order mark even when the data start on the first line (no header, no preamble).
        data_offset=max(sum(len(raw) for raw in raw_lines[:first_data]), 3 if encoding == "utf-8-sig" else 0),
    )


def sniff(path: str | os.PathLike[str]) -> FileFormat:
    """Find the layout of a samples file from its head (text) or its array headers (npy/npz).

    Parameters
    ----------
    path : str or path-like
        A delimited text file, a ``.npy`` or an ``.npz`` file (recognised by content, then by suffix).

    Returns
    -------
    FileFormat
        Delimiter, encoding, preamble, header and column count.

    Raises
    ------
    DataFileError
        Missing, unreadable or empty file, a header without rows, no numeric column, a broken npy/npz.
    """
    file = check_file(path)
    head, truncated = read_head(file)
    kind = _kind_of(file, head)
    if kind == "npy":
        info = npy_info(file)
        check_npy_array(file, info)
        return FileFormat("npy", None, "binary", 0, None, info.shape[1])
    if kind == "npz":
        keys = tuple(npz_members(file))
        return FileFormat("npz", None, "binary", 0, keys, len(keys))
    if not head:
        raise file_error(file, "is empty (0 bytes); record some samples or give another file")
    return _sniff_text(file, head, truncated)
