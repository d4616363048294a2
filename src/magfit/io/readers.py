"""Reading magnetometer samples from delimited text, ``.npy`` and ``.npz`` files.

The layout of a text file (delimiter, encoding, preamble lines, header, number of columns) is sniffed
from its first 256 KiB only; the rows are then parsed by pandas' C reader, three columns at a time, in
blocks whose size bounds the memory whatever the file's length. Every block is also checked for rows with
a different number of fields: pandas accepts those silently when it reads only some of the columns.
Which three columns hold the magnetometer is decided by :mod:`magfit.io.columns` (names) or by the
``columns`` argument (names or 0-based positions, in x, y, z order).

Every problem with a file is a :class:`~magfit.DataFileError` whose one-line message names the file, the
line and the column when there is one, and says what to do.
"""

from __future__ import annotations

import codecs
import copy
import csv
import functools
import io
import itertools
import math
import os
import re
import stat
import tokenize
import warnings
import zipfile
import zlib
from collections import Counter
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any, Literal, TypeVar

import numpy as np
from numpy.typing import NDArray

from .._validation import MAX_MAGNITUDE
from ..errors import DataFileError, OptionError
from .columns import (
    _MAG_LETTERS,
    _MAG_WORDS,
    CONTENT_ROWS,
    ContentChoice,
    choose_columns_by_content,
    find_magnetometer_columns,
    name_words,
    normalise_name,
)
from .sources import STDIN, data_file, display_name

__all__ = ["ChunkReader", "FileFormat", "SampleTable", "iter_sample_chunks", "read_samples", "sniff"]

#: How many skipped rows are remembered by line number (all of them are counted).
MAX_REPORTED_LINES = 10
#: The layout is sniffed from this much of the start of a file.
HEAD_BYTES = 256 * 1024
#: The head grows (doubling) until it holds this many lines, up to HEAD_MAX_BYTES.
HEAD_MIN_LINES = 20
HEAD_MAX_BYTES = 64 * 1024 * 1024
#: Text files from this size are parsed in pieces on several threads (:meth:`ChunkReader.parallel_pieces`);
#: below it the threads would cost more than they save.
PARALLEL_BYTES = 32 << 20
#: At most this many pieces (threads) for one file.
MAX_PIECES = 4
#: Cells read as a missing value (NaN); anything else that is not a number is an error.
NA_VALUES = ("", "nan", "NaN", "NAN", "-nan", "-NaN", "NA", "N/A", "n/a", "null", "NULL", "None", "#N/A")
#: Delimiters tried, in this order of preference when several split the rows equally well.
_DELIMITERS = ("\t", ";", ",", "|", "whitespace")
_NA_SET = frozenset(NA_VALUES)
_NUMBER = re.compile(r"^[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?$|^[+-]?(inf|infinity)$", re.IGNORECASE)
_DECIMAL_COMMA = re.compile(r"^[+-]?\d*,\d+([eE][+-]?\d+)?$")
_NPZ_COLUMN_LABEL = re.compile(r"^(.*)\[:,\s*(\d+)\]$")
_COLUMN_LABEL = re.compile(r"^column (\d+)$")
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


@dataclass(frozen=True, eq=False)
class SampleTable:
    """The magnetometer samples of one file, with what was read and what was skipped.

    Attributes
    ----------
    path : Path
        The file read.
    samples : ndarray, shape (N, 3), float64
        x, y, z in the order of ``columns``, in the file's units; only rows whose three values are finite.
    columns : tuple of 3 str
        The columns used: header names, ``"column 1"``-style labels (1-based) when there is no header,
        NPZ keys, or ``"key[:, 0]"`` for the columns of one 2-D NPZ array. Passing them back as
        ``columns=`` selects the same data.
    n_rows : int
        Data rows read (including the skipped ones).
    n_skipped : int
        Rows dropped because a magnetometer value is NaN, infinite or empty.
    skipped_lines : tuple of int
        1-based file line numbers (row numbers for npy/npz) of the first few skipped rows.
    format : FileFormat
        The file's layout.
    column_note : str or None
        For a file without a header, why its columns were chosen (``column 1 is monotonic: time or a
        counter``); None when there was no choice to make or it was given.
    """

    path: Path
    samples: NDArray[np.float64]
    columns: tuple[str, str, str]
    n_rows: int
    n_skipped: int
    skipped_lines: tuple[int, ...]
    format: FileFormat
    column_note: str | None = None


# ---------------------------------------------------------------------------------------------- small helpers


def _error(path: Path, message: str) -> DataFileError:
    return DataFileError(f"{display_name(path)}: {message}")  # a temporary copy is named as the user gave it


def _pandas() -> Any:
    try:
        import pandas
    except ImportError:  # pragma: no cover - pandas is in the cli extra
        raise ImportError("reading text data files needs pandas: pip install 'magfit[cli]'") from None
    return pandas


def _check_file(path: str | os.PathLike[str]) -> Path:
    """The regular file to read ``path`` from, after checking that it is readable: the file itself, or the
    decompressed copy of standard input (``-``), a pipe or a compressed file (:func:`magfit.io.sources.data_file`)."""
    if str(path) == STDIN:
        return data_file(path)
    file = Path(path)
    if not file.exists():
        raise _error(file, "no such file; check the path and the current directory")
    if file.is_dir():
        raise _error(file, "is a directory, not a data file; give the path of a file inside it")
    if not file.is_file() and not stat.S_ISFIFO(file.stat().st_mode):  # a pipe is copied, as standard input
        raise _error(
            file,
            "is a device or a socket, not a regular file: magfit reads a file more than once (its layout, then "
            "its rows); save the data to a file first",
        )
    if not os.access(file, os.R_OK):
        raise _error(file, "permission denied; make the file readable (chmod +r) or copy it")
    return data_file(file)


def _kind_of(path: Path, head: bytes) -> _Kind:
    if head.startswith(b"\x93NUMPY"):
        return "npy"
    if head.startswith(b"PK\x03\x04") or path.suffix.lower() == ".npz":
        return "npz"
    if path.suffix.lower() == ".npy":
        return "npy"
    return "text"


def _read_head(path: Path) -> tuple[bytes, bool]:
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
        raise _error(path, f"cannot be read ({error.strerror}); check the file's permissions") from None
    return head[:size], len(head) > size


def _shown(line: str, limit: int = 60) -> str:
    """A line for a message: quoted, and cut when long (a line may be megabytes)."""
    return repr(line) if len(line) <= limit else repr(line[:limit]) + f" ... ({len(line)} characters)"


def _cell_kind(cell: str, decimal: str = ".") -> Literal["number", "missing", "text"]:
    """Classify one stripped, unquoted cell."""
    if cell in _NA_SET:
        return "missing"
    if decimal == ",":
        cell = cell.replace(",", ".")
    return "number" if _NUMBER.match(cell) else "text"


def _split_fields(line: str, delimiter: str | None) -> list[str]:
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
        counts = [len(_split_fields(line, delimiter)) for line in sample]
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


def _decode_lines(path: Path, head: bytes, truncated: bool) -> tuple[list[bytes], list[str], str]:
    """Split the head into raw lines (with their line ends) and decoded lines (without)."""
    if head.startswith((codecs.BOM_UTF16_LE, codecs.BOM_UTF16_BE)):
        raise _error(path, "is UTF-16 encoded; save it as UTF-8 (or plain ASCII) text")
    if b"\x00" in head:
        raise _error(path, "is a binary file, not delimited text, .npy or .npz; export the samples as CSV")
    if b"\r" in head and b"\n" not in head:
        raise _error(
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
    kinds = [[_cell_kind(cell, decimal) for cell in row] for row in rows]
    # A header in a short sample would outvote the few data rows: lines without any number do not vote.
    kinds = [row for row in kinds if "number" in row] or kinds
    return [
        j
        for j in range(n_columns)
        if sum(row[j] != "text" for row in kinds) >= 0.8 * len(kinds) and any(row[j] == "number" for row in kinds)
    ]


def _sniff_text(path: Path, head: bytes, truncated: bool) -> FileFormat:
    raw_lines, lines, encoding = _decode_lines(path, head, truncated)
    filled = [i for i, line in enumerate(lines) if line.strip()]
    if not filled:
        raise _error(path, "is empty; record some samples or give another file")
    # The bottom half of the head is data in any sensible file: it decides delimiter and column count.
    sample = [lines[i] for i in filled[len(filled) // 2 :][-200:]]
    delimiter = _choose_delimiter(sample)
    counts = [len(_split_fields(line, delimiter)) for line in sample]
    n_columns, _ = _mode_count(counts)
    rows = [_split_fields(line, delimiter) for line in sample]
    rows = [row for row in rows if len(row) == n_columns]
    decimal = "."
    if delimiter not in (",", ", "):
        cells = [cell for row in rows for cell in row if cell]
        if cells and sum(bool(_DECIMAL_COMMA.match(cell)) for cell in cells) >= 0.5 * len(cells):
            decimal = ","
    numeric = _numeric_columns_of(rows, n_columns, decimal)
    if not numeric:  # the bottom half may be all missing values (NaN rows): let the whole head vote
        every_row = [_split_fields(lines[i], delimiter) for i in filled]
        numeric = _numeric_columns_of([row for row in every_row if len(row) == n_columns], n_columns, decimal)
    if not numeric:
        shaped = [i for i in filled if len(_split_fields(lines[i], delimiter)) == n_columns]
        if len(shaped) == 1:
            raise _error(path, f"has a header but no data rows (line {shaped[0] + 1}: {_shown(lines[shaped[0]])})")
        raise _error(path, "has no column of numbers; is it a samples file? Export the magnetometer data as CSV")

    def is_data(fields: list[str]) -> bool:
        if len(fields) != n_columns:
            # A line of numbers only is a damaged data row, not a preamble: the reader reports its field count.
            return all(_cell_kind(cell, decimal) != "text" for cell in fields)
        return 2 * sum(_cell_kind(fields[j], decimal) == "text" for j in numeric) < len(numeric)

    first_data = next((i for i in filled if is_data(_split_fields(lines[i], delimiter))), None)
    if first_data is None:
        raise _error(path, "has a header but no data rows; record some samples or give another file")
    header: tuple[str, ...] | None = None
    start = first_data
    before = [i for i in filled if i < first_data]
    if before:
        names = _split_fields(lines[before[-1]], delimiter)
        # A header has one name per field; trailing empty names (a trailing delimiter) are tolerated.
        if len(names) >= n_columns and not any(names[n_columns:]):
            header = tuple(name.lstrip("\ufeff") for name in names[:n_columns])
            start = before[-1]
        elif len(names) >= 3 and all(_cell_kind(name, decimal) == "text" for name in names):
            # A line of names that does not match the rows: reading on without it would silently number
            # the columns, and the no-header rule could then take the wrong three.
            raise _error(
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


@dataclass(frozen=True)
class _NpyInfo:
    shape: tuple[int, ...]
    dtype: np.dtype[Any]
    fortran: bool


#: What numpy's header parser raises on a damaged .npy header (it evaluates the header's Python literal).
_BROKEN_NPY = (ValueError, OSError, EOFError, SyntaxError, TypeError, RecursionError, tokenize.TokenError)


def _one_line(error: BaseException) -> str:
    return " ".join(str(error).split())[:200]


def _read_npy_header(handle: Any) -> _NpyInfo:
    version = np.lib.format.read_magic(handle)
    with warnings.catch_warnings():  # numpy's "created on Python 2" advice: the header is read all the same
        warnings.simplefilter("ignore", UserWarning)
        if version == (1, 0):
            shape, fortran, dtype = np.lib.format.read_array_header_1_0(handle)
        else:
            shape, fortran, dtype = np.lib.format.read_array_header_2_0(handle)
    return _NpyInfo(tuple(shape), np.dtype(dtype), bool(fortran))


def _npz_members(path: Path) -> dict[str, _NpyInfo]:
    """Shapes and dtypes of the arrays of an npz file, read from their headers only."""
    members: dict[str, _NpyInfo] = {}
    try:
        with zipfile.ZipFile(path) as archive:
            for info in archive.infolist():
                if not info.filename.endswith(".npy"):
                    continue
                with archive.open(info) as handle:
                    members[info.filename[: -len(".npy")]] = _read_npy_header(handle)
    except (zipfile.BadZipFile, zlib.error, *_BROKEN_NPY) as error:
        raise _error(
            path, f"is not a readable .npz archive ({_one_line(error)}); re-save it with numpy.savez"
        ) from None
    if not members:
        raise _error(path, "is an .npz archive without arrays; save the samples with numpy.savez")
    return members


def _npy_info(path: Path) -> _NpyInfo:
    try:
        with open(path, "rb") as handle:
            info = _read_npy_header(handle)
            data_offset = handle.tell()
    except _BROKEN_NPY as error:
        raise _error(path, f"is not a readable .npy file ({_one_line(error)}); re-save it with numpy.save") from None
    # A truncated copy would otherwise fail inside numpy's memory map, with no word about the file.
    expected = info.dtype.itemsize * math.prod(info.shape)
    available = path.stat().st_size - data_offset
    if info.dtype != object and available < expected:
        raise _error(
            path,
            f"is truncated: its header announces {info.dtype} values of shape {info.shape} ({expected} bytes) but the "
            f"file holds {max(available, 0)}; copy it again or re-save it with numpy.save",
        )
    return info


def _check_npy_array(path: Path, info: _NpyInfo) -> None:
    """Refuse an npy array that cannot hold samples: not numbers, not 2-D, or one sample per column."""
    if not _is_numeric_dtype(info.dtype):
        raise _error(path, f"holds an array of dtype {info.dtype}, not numbers; save the samples as floats")
    if len(info.shape) != 2:
        raise _error(path, f"holds an array of shape {info.shape}; save the samples as an (N, 3) array, one per row")
    if info.shape[0] == 3 and info.shape[1] > 3:
        raise _error(path, f"holds an array of shape {info.shape}: one sample per column; save its transpose (arr.T)")


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
    file = _check_file(path)
    head, truncated = _read_head(file)
    kind = _kind_of(file, head)
    if kind == "npy":
        info = _npy_info(file)
        _check_npy_array(file, info)
        return FileFormat("npy", None, "binary", 0, None, info.shape[1])
    if kind == "npz":
        keys = tuple(_npz_members(file))
        return FileFormat("npz", None, "binary", 0, keys, len(keys))
    if not head:
        raise _error(file, "is empty (0 bytes); record some samples or give another file")
    return _sniff_text(file, head, truncated)


# ---------------------------------------------------------------------------------------------- columns


def _ambiguity(path: Path, candidates: Sequence[Any]) -> DataFileError:
    listed = "; ".join(f"({triple.describe()})" for triple in candidates[:6])
    example = ", ".join(repr(name) for name in candidates[0].names)
    return _error(path, f"several magnetometer column triples match: {listed}; choose one with columns=[{example}]")


def _check_columns_option(columns: Sequence[str | int]) -> list[str | int]:
    if isinstance(columns, (str, bytes)):
        raise OptionError(f"columns must be a sequence of three names or 0-based indices, got the string {columns!r}")
    chosen = list(columns)
    for item in chosen:
        if isinstance(item, bool) or not isinstance(item, (str, int, np.integer)):
            raise OptionError(f"columns must hold names (str) or 0-based indices (int), got {item!r}")
    if len(set(chosen)) != len(chosen):
        raise OptionError(f"columns must name three different columns, got {chosen}")
    return [int(item) if isinstance(item, np.integer) else item for item in chosen]


def _match_name(path: Path, wanted: str, labels: Sequence[str], has_header: bool) -> int:
    """Index of the column called ``wanted``: exact name, then case-insensitive, then a ``column N`` label."""
    stripped = wanted.strip()
    exact = [i for i, label in enumerate(labels) if label == stripped]
    if len(exact) == 1:
        return exact[0]
    folded = [i for i, label in enumerate(labels) if label.casefold() == stripped.casefold()]
    if len(folded) == 1:
        return folded[0]
    if len(exact) > 1 or len(folded) > 1:
        raise _error(path, f"several columns are named {wanted!r}; choose them by 0-based index instead")
    label = _COLUMN_LABEL.match(stripped.lower())
    if label and 1 <= int(label.group(1)) <= len(labels):
        return int(label.group(1)) - 1
    seen = ", ".join(labels) if has_header else f"none, the file has no header ({len(labels)} columns)"
    raise _error(path, f"no column named {wanted!r}; the columns are: {seen}; use one of them or a 0-based index")


def _resolve_table_columns(
    path: Path, fmt: FileFormat, columns: Sequence[str | int] | None, content: ContentChoice | None = None
) -> tuple[tuple[int, int, int], tuple[str, str, str]]:
    """The 0-based positions and labels of the x, y, z columns of a text or npy file (``content``: the
    choice by content for a file without a header, :func:`magfit.io.columns.choose_columns_by_content`)."""
    n = fmt.n_columns
    labels = [fmt.column_label(i) for i in range(n)]
    where = (
        ("column" if fmt.kind == "npy" else "field")
        + ("" if n == 1 else "s")
        + ("" if fmt.kind == "npy" else " per row")
    )
    if n < 3:
        raise _error(
            path,
            f"has {n} {where} ({fmt.describe()}); a magnetometer needs three (x, y, z): check the delimiter "
            "or export all three axes",
        )
    if columns is None:
        if fmt.header is not None:
            candidates = find_magnetometer_columns(fmt.header)
            if not candidates:
                raise _error(
                    path,
                    f"no magnetometer columns found among: {', '.join(labels)}; name the x, y, z columns with "
                    "columns=[...]",
                )
            best = [triple for triple in candidates if triple.score == candidates[0].score]
            if len(best) > 1:
                raise _ambiguity(path, best)
            indices = best[0].indices
        else:
            # No header: chosen by what the columns hold (time and counters passed over), and reported.
            choice = content or ContentChoice((0, 1, 2))
            if choice.rivals:
                found = "; ".join(
                    "(" + ", ".join(labels[i] for i in triple) + ")" for triple in (choice.indices, *choice.rivals)
                )
                raise _error(
                    path,
                    f"has no header and several column triples look like a magnetometer: {found}; choose one with "
                    f"columns=[{', '.join(str(i) for i in choice.indices)}] (0-based)",
                )
            indices = choice.indices
    else:
        chosen = _check_columns_option(columns)
        if len(chosen) != 3:
            raise OptionError(f"columns must give exactly three columns (x, y, z), got {len(chosen)}: {chosen}")
        positions = []
        for item in chosen:
            if isinstance(item, int):
                if not 0 <= item < n:
                    raise _error(
                        path, f"column index {item} is out of range: the file has {n} columns, 0 to {n - 1} (0-based)"
                    )
                positions.append(item)
            else:
                positions.append(_match_name(path, item, labels, fmt.header is not None))
        if len(set(positions)) != 3:
            raise OptionError(f"columns {chosen} name the same column twice; give three different columns")
        indices = (positions[0], positions[1], positions[2])
    return indices, (labels[indices[0]], labels[indices[1]], labels[indices[2]])


@dataclass(frozen=True)
class _NpzSelection:
    """Where the x, y, z values of an npz file are: three 1-D keys, or three columns of one 2-D key."""

    keys: tuple[str, ...]
    key_columns: tuple[int, int, int] | None
    n_rows: int

    @property
    def labels(self) -> tuple[str, str, str]:
        if self.key_columns is None:
            return (self.keys[0], self.keys[1], self.keys[2])
        key = self.keys[0]
        first, second, third = (f"{key}[:, {i}]" for i in self.key_columns)
        return (first, second, third)


def _is_numeric_dtype(dtype: np.dtype[Any]) -> bool:
    return bool(np.issubdtype(dtype, np.floating) or np.issubdtype(dtype, np.integer))


def _looks_magnetic(key: str) -> bool:
    words = name_words(normalise_name(key))
    return any(word in _MAG_WORDS or word in _MAG_LETTERS or word.startswith("mag") for word in words)


def _resolve_npz_columns(
    path: Path, members: dict[str, _NpyInfo], columns: Sequence[str | int] | None
) -> _NpzSelection:
    listing = ", ".join(f"{key} {members[key].shape}" for key in members)
    vectors = {key: info for key, info in members.items() if len(info.shape) == 1 and _is_numeric_dtype(info.dtype)}
    matrices = {
        key: info
        for key, info in members.items()
        if len(info.shape) == 2 and info.shape[1] >= 3 and _is_numeric_dtype(info.dtype)
    }

    def from_vectors(keys: Sequence[str]) -> _NpzSelection:
        lengths = {members[key].shape[0] for key in keys}
        if len(lengths) != 1:
            shapes = ", ".join(f"{key} {members[key].shape}" for key in keys)
            raise _error(path, f"the arrays {shapes} have different lengths; x, y and z need one value per sample")
        return _NpzSelection(tuple(keys), None, lengths.pop())

    def from_matrix(key: str, cols: tuple[int, int, int]) -> _NpzSelection:
        return _NpzSelection((key,), cols, members[key].shape[0])

    if columns is None:
        candidates = find_magnetometer_columns(list(vectors))
        if candidates:
            best = [triple for triple in candidates if triple.score == candidates[0].score]
            if len(best) > 1:
                raise _ambiguity(path, best)
            return from_vectors(best[0].names)
        triples = [key for key, info in matrices.items() if info.shape[1] == 3]
        if len(triples) > 1:
            triples = [key for key in triples if _looks_magnetic(key)] or triples
        if len(triples) == 1:
            return from_matrix(triples[0], (0, 1, 2))
        if len(triples) > 1:
            raise _error(
                path,
                f"several (N, 3) arrays could be the samples: {', '.join(triples)}; choose one with columns=['key']",
            )
        raise _error(
            path,
            f"no magnetometer arrays found among the keys: {listing}; name them with columns=['mag_x', 'mag_y', "
            "'mag_z'] (three 1-D keys) or columns=['key'] (one (N, 3) key)",
        )
    chosen = _check_columns_option(columns)
    if len(chosen) == 1 and isinstance(chosen[0], str):
        key = chosen[0]
        if key not in members:
            raise _error(path, f"no array named {key!r}; the keys are: {listing}")
        if key not in matrices or members[key].shape[1] != 3:
            raise _error(
                path,
                f"array {key!r} has shape {members[key].shape}, not (N, 3); give three columns, e.g. "
                f"columns=['{key}[:, 0]', '{key}[:, 1]', '{key}[:, 2]']",
            )
        return from_matrix(key, (0, 1, 2))
    if len(chosen) != 3:
        raise OptionError(f"columns must give three keys (x, y, z) or one (N, 3) key, got {len(chosen)}: {chosen}")
    if all(isinstance(item, int) for item in chosen):
        if len(matrices) != 1:
            raise _error(
                path, f"column indices need exactly one 2-D array in the file; name the keys instead: {listing}"
            )
        key = next(iter(matrices))
        width = members[key].shape[1]
        for item in chosen:
            if not 0 <= int(item) < width:
                raise _error(path, f"column index {item} is out of range: {key!r} has columns 0 to {width - 1}")
        return from_matrix(key, (int(chosen[0]), int(chosen[1]), int(chosen[2])))
    labels = [_NPZ_COLUMN_LABEL.match(str(item)) for item in chosen]
    if all(labels):
        keys = {label.group(1) for label in labels if label}
        key = keys.pop()
        if keys or key not in matrices:
            raise _error(path, f"columns {chosen} must all be columns of one 2-D array; the keys are: {listing}")
        cols = [int(label.group(2)) for label in labels if label]
        width = members[key].shape[1]
        if max(cols) >= width:
            raise _error(path, f"column index {max(cols)} is out of range: {key!r} has {width} columns")
        return from_matrix(key, (cols[0], cols[1], cols[2]))
    for item in chosen:
        if not isinstance(item, str) or item not in members:
            raise _error(path, f"no array named {item!r}; the keys are: {listing}")
        if item not in vectors:
            raise _error(path, f"array {item!r} has shape {members[item].shape}; x, y and z keys must be 1-D numbers")
    return from_vectors([str(item) for item in chosen])


# ---------------------------------------------------------------------------------------------- reading


def _nonfinite_word(value: float) -> str:
    return "empty or NaN" if np.isnan(value) else ("inf" if value > 0 else "-inf")


class ChunkReader:
    """Iterate over the magnetometer samples of a file in chunks of at most ``chunk_rows`` rows.

    Created by :func:`iter_sample_chunks`. Each item is an (n, 3) float64 array of finite samples. The
    layout and the columns are resolved on creation (so errors about them come at once); errors in the
    rows come during iteration. Memory is bounded by the chunk (and pandas' read buffer of a few hundred
    KiB), never by the file.

    Attributes
    ----------
    columns : tuple of 3 str
        The columns read, in x, y, z order (see :class:`SampleTable`).
    format : FileFormat
        The file's layout.
    n_rows, n_skipped, skipped_lines
        As in :class:`SampleTable`; complete once the iteration has finished.
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        *,
        columns: Sequence[str | int] | None = None,
        nonfinite: Literal["skip", "error"] = "skip",
        chunk_rows: int = 1_000_000,
        block_bytes: int | None = None,
    ) -> None:
        if nonfinite not in ("skip", "error"):
            raise OptionError(f"nonfinite must be 'skip' or 'error', got {nonfinite!r}")
        if isinstance(chunk_rows, bool) or not isinstance(chunk_rows, (int, np.integer)) or chunk_rows < 1:
            raise OptionError(f"chunk_rows must be a positive integer, got {chunk_rows!r}")
        self.path = _check_file(path)
        self.format = sniff(self.path)
        self.nonfinite = nonfinite
        self.chunk_rows = int(chunk_rows)
        self._block_bytes = block_bytes
        self._byte_range: tuple[int, int] | None = None  # set by split(): a part of a text file
        self._npz: _NpzSelection | None = None
        self._indices: tuple[int, int, int] = (0, 1, 2)
        self.n_rows = 0
        self.n_skipped = 0
        self.skipped_lines: tuple[int, ...] = ()
        self._skipped: list[int] = []
        self.column_note: str | None = None
        if self.format.kind == "npz":
            self._npz = _resolve_npz_columns(self.path, _npz_members(self.path), columns)
            self.columns = self._npz.labels
        elif self.format.kind == "npy":
            self._check_npy_shape()
            content = self._npy_content_choice() if columns is None and self.format.n_columns > 3 else None
            self._indices, self.columns = _resolve_table_columns(self.path, self.format, columns, content)
            if content is not None:
                self.column_note = content.describe([self.format.column_label(i) for i in range(self.format.n_columns)])
        else:
            headerless = columns is None and self.format.header is None and self.format.n_columns >= 3
            content = self._content_choice() if headerless else None
            self._indices, self.columns = _resolve_table_columns(self.path, self.format, columns, content)
            if content is not None:
                self.column_note = content.describe([self.format.column_label(i) for i in range(self.format.n_columns)])

    @property
    def column_indices(self) -> tuple[int, int, int]:
        """0-based positions of the x, y, z columns (text and npy; for npz, of the columns of its 2-D key)."""
        if self._npz is not None:
            return self._npz.key_columns or (0, 1, 2)
        return self._indices

    def split(self, parts: int) -> list[ChunkReader]:
        """Readers of ``parts`` consecutive pieces of a text file, cut at line ends, to read in parallel.

        Each piece is read like the whole file (same layout, columns, checks and error messages, with the
        file's own line numbers); its ``n_rows`` and ``skipped_lines`` are its own. npy and npz files, and
        text files too small to cut, give ``[self]``.
        """
        if self.format.kind != "text" or parts < 2 or self._byte_range is not None:
            return [self]
        start, end = self.format.data_offset, self.path.stat().st_size
        cuts = [start]
        with open(self.path, "rb") as handle:
            for k in range(1, parts):
                handle.seek(max(start + (end - start) * k // parts - 1, cuts[-1]))
                handle.readline()  # to the start of the next line
                cuts.append(max(min(handle.tell(), end), cuts[-1]))
        cuts.append(end)
        pieces = []
        for low, high in itertools.pairwise(cuts):
            if high > low:
                piece = copy.copy(self)
                piece._byte_range = (low, high)
                pieces.append(piece)
        return pieces or [self]

    def parallel_pieces(self) -> list[ChunkReader]:
        """:meth:`split` into one piece per core (up to :data:`MAX_PIECES`) for a text file of at least
        :data:`PARALLEL_BYTES`; ``[self]`` otherwise. pandas parses without holding Python's lock, so the
        pieces read on threads take about 1/k of the time on k cores."""
        workers = min(os.cpu_count() or 1, MAX_PIECES)
        if self.format.kind != "text" or workers < 2 or self.path.stat().st_size < PARALLEL_BYTES:
            return [self]
        return self.split(workers)

    # .................................................................. shared bookkeeping

    def _npy_content_choice(self) -> ContentChoice:
        """The x, y, z columns of an (N, k > 3) .npy array, chosen from its first rows (as for headerless text)."""
        head = np.asarray(np.load(self.path, mmap_mode="r", allow_pickle=False)[:CONTENT_ROWS], dtype=np.float64)
        return choose_columns_by_content(head, range(self.format.n_columns))

    def _rows_further_in(self, per_window: int) -> list[list[str]]:
        """Up to ``per_window`` rows at each of 1/4, 1/2 and 3/4 of a file longer than its head, in file order."""
        fmt = self.format
        size = self.path.stat().st_size
        rows: list[list[str]] = []
        with open(self.path, "rb") as handle:
            for quarter in (1, 2, 3):
                handle.seek(fmt.data_offset + (size - fmt.data_offset) * quarter // 4)
                text = handle.read(HEAD_BYTES // 4).decode(self._text_encoding, errors="replace")
                lines = text.split("\n")[1:-1]  # the first and last are cut by the window
                fields = (_split_fields(line.rstrip("\r"), fmt.delimiter) for line in lines[:per_window])
                rows += [row for row in fields if len(row) == fmt.n_columns]
        return rows

    def _content_choice(self) -> ContentChoice:
        """The x, y, z columns of a text file without a header, chosen from the values of its rows (the first
        ones, and for a file longer than its head, rows from further in as well)."""
        fmt = self.format
        head, truncated = _read_head(self.path)
        _, lines, _ = _decode_lines(self.path, head, truncated)
        rows = [_split_fields(line, fmt.delimiter) for line in lines[fmt.data_line :][:CONTENT_ROWS]]
        rows = [row for row in rows if len(row) == fmt.n_columns]
        if truncated:  # half from the head, half from further in: a recording may start at rest (a warm-up)
            rows = rows[: CONTENT_ROWS // 2] + self._rows_further_in(CONTENT_ROWS // 6)
        # Columns of numbers in the first 50 rows (a leading date or label column is passed over).
        numeric = [
            j
            for j in range(fmt.n_columns)
            if rows and all(_cell_kind(row[j], fmt.decimal) != "text" for row in rows[:50])
        ]

        def number(cell: str) -> float:
            if _cell_kind(cell, fmt.decimal) != "number":
                return np.nan
            return float(cell.replace(",", ".") if fmt.decimal == "," else cell)

        head_values = np.full((len(rows), fmt.n_columns), np.nan)
        for j in numeric:
            cells = [row[j] for row in rows]
            try:  # the usual column of plain numbers, at once
                if fmt.decimal != ".":
                    raise ValueError("decimal commas")
                head_values[:, j] = np.asarray(cells, dtype=np.float64)
            except ValueError:  # missing values, decimal commas: cell by cell
                head_values[:, j] = [number(cell) for cell in cells]
        return choose_columns_by_content(head_values, numeric)

    def _check_npy_shape(self) -> None:
        _check_npy_array(self.path, _npy_info(self.path))

    def _filter(
        self, values: NDArray[np.float64], to_line: Callable[[NDArray[np.int64]], NDArray[np.int64]]
    ) -> NDArray[np.float64]:
        """Count and drop the non-finite rows of a chunk; ``to_line`` maps its row numbers to line numbers."""
        first_row = self.n_rows
        self.n_rows += len(values)
        if values.size and -MAX_MAGNITUDE <= values.min() and values.max() <= MAX_MAGNITUDE:
            return values  # the usual chunk, in two reductions (NaN fails both comparisons)
        too_large = np.isfinite(values) & (np.abs(values) > MAX_MAGNITUDE)
        if too_large.any():  # refused here, where the file's line is known, rather than by Statistics
            row, axis = (int(i) for i in np.argwhere(too_large)[0])
            place = "line" if self.format.kind == "text" else "row"
            line = int(to_line(np.array([first_row + row]))[0])
            raise _error(
                self.path,
                f"{place} {line}, column {self.columns[axis]!r}: {values[row, axis]:.3g} is beyond ±{MAX_MAGNITUDE:g}, "
                "more than float64 can square; fix or delete that row, or rescale the file",
            )
        finite = np.isfinite(values).all(axis=1)
        if finite.all():
            return values
        bad = np.flatnonzero(~finite)
        if self.nonfinite == "error":
            row = bad[0]
            axis = int(np.flatnonzero(~np.isfinite(values[row]))[0])
            place = "line" if self.format.kind == "text" else "row"
            line = int(to_line(np.array([first_row + row]))[0])
            raise _error(
                self.path,
                f"{place} {line}, column {self.columns[axis]!r}: the value is "
                f"{_nonfinite_word(values[row, axis])}; fix or delete that row, or skip such rows (nonfinite='skip')",
            )
        self.n_skipped += bad.size
        room = MAX_REPORTED_LINES - len(self._skipped)
        if room > 0:
            self._skipped.extend(int(line) for line in to_line(first_row + bad[:room]))
        return np.ascontiguousarray(values[finite])

    def __iter__(self) -> Iterator[NDArray[np.float64]]:
        self.n_rows = 0
        self.n_skipped = 0
        self._skipped = []
        self.skipped_lines = ()
        if self.format.kind == "text":
            chunks = self._iter_text()
        elif self.format.kind == "npy":
            chunks = self._iter_npy()
        else:
            chunks = self._iter_npz()
        for chunk in chunks:
            self.skipped_lines = tuple(self._skipped)
            if len(chunk):
                yield chunk
        self.skipped_lines = tuple(self._skipped)
        if self.n_rows == 0 and self._byte_range is None:  # a piece may hold blank lines only
            raise _error(self.path, "has no data rows; record some samples or give another file")

    # .................................................................. npy / npz

    def _iter_npy(self) -> Iterator[NDArray[np.float64]]:
        try:
            with warnings.catch_warnings():  # as in _read_npy_header
                warnings.simplefilter("ignore", UserWarning)
                array = np.load(self.path, mmap_mode="r", allow_pickle=False)
        except _BROKEN_NPY as error:  # changed since it was sniffed
            raise _error(self.path, f"is not a readable .npy file ({error}); re-save it with numpy.save") from None
        if array.shape[0] == 0:
            raise _error(self.path, "holds an array with no rows; record some samples")
        for start in range(0, array.shape[0], self.chunk_rows):
            block = np.asarray(array[start : start + self.chunk_rows][:, list(self._indices)], dtype=np.float64)
            yield self._filter(block, _next_row)

    def _iter_npz(self) -> Iterator[NDArray[np.float64]]:
        selection = self._npz
        assert selection is not None
        if selection.n_rows == 0:
            raise _error(self.path, f"the arrays {', '.join(selection.keys)} are empty; record some samples")
        with zipfile.ZipFile(self.path) as archive:
            streams: list[_NpyStream] = []
            try:
                start = 0
                while start < selection.n_rows:
                    # A damaged member shows only while it is inflated (bad deflate data, a CRC, a short array).
                    try:
                        if not streams:
                            streams = [_NpyStream(archive, key, self.chunk_rows) for key in selection.keys]
                        parts = [stream.next_rows() for stream in streams]
                        if selection.key_columns is None:
                            block = np.column_stack([np.asarray(part, dtype=np.float64) for part in parts])
                        else:
                            block = np.asarray(parts[0][:, list(selection.key_columns)], dtype=np.float64)
                    except (zipfile.BadZipFile, zlib.error, *_BROKEN_NPY) as error:
                        raise _error(
                            self.path, f"is a damaged .npz archive ({_one_line(error)}); re-save it with numpy.savez"
                        ) from None
                    yield self._filter(block, _next_row)
                    start += len(block)
            finally:
                for stream in streams:
                    stream.close()

    # .................................................................. text

    def _field_count_error(self, line: int, count: int) -> DataFileError:
        fmt = self.format
        rows = "the header and the first rows have" if fmt.header is not None else "the first rows have"
        return _error(
            self.path,
            f"line {line} has {count} fields but {rows} {fmt.n_columns} (delimiter {fmt.delimiter!r}); "
            "fix or delete that line",
        )

    def _bad_cell_error(self, detail: str) -> DataFileError:
        """Find the first magnetometer cell that is not a number (rescanning the file), for the message."""
        fmt = self.format
        with open(self.path, "rb") as raw:
            raw.seek(fmt.data_offset)
            for number, raw_line in enumerate(raw, start=fmt.data_line + 1):  # lines end at "\n" only, as here
                line = raw_line.decode(self._text_encoding, errors="replace")
                if not line.strip():
                    continue
                if "\r" in line.rstrip("\r\n"):  # pandas ends a line there too: the rows no longer line up
                    return _error(
                        self.path,
                        f"line {number} holds a carriage return (\\r) inside the line; delete it (line ends are "
                        "\\n or \\r\\n)",
                    )
                fields = _split_fields(line.rstrip("\r\n"), fmt.delimiter)
                for axis, index in enumerate(self._indices):
                    cell = fields[index] if index < len(fields) else ""
                    if _cell_kind(cell, fmt.decimal) == "text":
                        return _error(
                            self.path,
                            f"line {number}, column {self.columns[axis]!r} (column {index + 1}): {cell!r} is not "
                            "a number; fix that cell, or choose other columns with columns=[...]",
                        )
        return _error(self.path, f"cannot read the numbers ({detail}); check the file's format")

    def _parse_block(self, block: bytes) -> NDArray[np.float64]:
        """The x, y, z values of a block of whole data lines (blank lines skipped), as the reader parses them."""
        used = sorted(set(self._indices))
        frame = _pandas().read_csv(io.BytesIO(block), **self._read_options(used))
        return np.asarray(frame.to_numpy(dtype=np.float64)[:, [used.index(i) for i in self._indices]])

    def _read_options(self, used: list[int]) -> dict[str, Any]:
        """pandas.read_csv options for the data lines: C engine, only the magnetometer columns, float64."""
        fmt = self.format
        assert fmt.delimiter is not None
        return {
            "sep": r"\s+" if fmt.delimiter == "whitespace" else fmt.delimiter[0],
            "header": None,
            "usecols": used,
            "dtype": np.float64,
            "engine": "c",
            "encoding": self._text_encoding,
            "decimal": fmt.decimal,
            "skipinitialspace": self._blank_led_cells,
            "skip_blank_lines": True,
            "na_values": list(NA_VALUES),
            "keep_default_na": False,
        }

    @functools.cached_property
    def _blank_led_cells(self) -> bool:
        """Whether cells may start with blanks, as in ``1, nan, 3``: pandas must then strip them
        (``skipinitialspace``), which costs a quarter of the parse. Numbers parse either way; only a missing
        value written with a blank before it needs the stripping. Decided on the first data lines."""
        fmt = self.format
        if fmt.delimiter is None or fmt.delimiter == "whitespace" or len(fmt.delimiter) > 1:
            return True
        head, truncated = _read_head(self.path)
        _, lines, _ = _decode_lines(self.path, head, truncated)
        blanks = " \t".replace(fmt.delimiter, "")
        return any(blank in line for line in lines[fmt.data_line :] for blank in blanks)

    @property
    def _text_encoding(self) -> str:
        return "utf-8" if self.format.encoding == "utf-8-sig" else self.format.encoding

    def _iter_text(self) -> Iterator[NDArray[np.float64]]:
        pandas = _pandas()
        fmt = self.format
        assert fmt.delimiter is not None
        used = sorted(set(self._indices))
        order = [used.index(index) for index in self._indices]
        with open(self.path, "rb") as handle:
            start, stop = self._byte_range if self._byte_range is not None else (fmt.data_offset, None)
            handle.seek(start)
            source = _CheckedSource(self, _Bounded(handle, stop), self._block_bytes, start)
            try:
                reader = pandas.read_csv(source, chunksize=self.chunk_rows, **self._read_options(used))
            except pandas.errors.EmptyDataError:  # blank lines only (a piece of a file can be): no rows
                return
            except (ValueError, TypeError) as error:  # pandas checks the first line when it opens
                if isinstance(error, DataFileError):
                    raise
                raise self._bad_cell_error(str(error)) from None
            with reader:
                while True:
                    try:
                        frame = next(reader)
                    except StopIteration:
                        break
                    except (ValueError, TypeError) as error:
                        if isinstance(error, DataFileError):
                            raise
                        raise self._bad_cell_error(str(error)) from None
                    values = frame.to_numpy(dtype=np.float64)
                    if order != list(range(len(order))):  # columns asked in another order than the file's
                        values = values[:, order]
                    yield self._filter(values, source.line_of_rows)


class _Bounded:
    """A binary file read up to byte ``stop`` (None: to its end), as if it ended there."""

    def __init__(self, handle: IO[bytes], stop: int | None) -> None:
        self._handle = handle
        self._stop = stop

    def read(self, size: int = -1) -> bytes:
        if self._stop is None:
            return self._handle.read(size)
        left = max(self._stop - self._handle.tell(), 0)
        return self._handle.read(left if size < 0 else min(size, left))


def _count_lines(path: Path, start: int, stop: int) -> int:
    """Line ends between byte offsets ``start`` and ``stop`` of a file."""
    count = 0
    with open(path, "rb") as handle:
        handle.seek(start)
        left = stop - start
        while left > 0:
            block = handle.read(min(left, 1 << 24))
            if not block:
                break
            count += block.count(b"\n")
            left -= len(block)
    return count


def _next_row(rows: NDArray[np.int64]) -> NDArray[np.int64]:
    """1-based row numbers (npy/npz have no lines)."""
    return rows + 1


class _CheckedSource(io.RawIOBase):
    """The data lines of a text file as pandas reads them, each line's field count checked on the way.

    pandas reads only the magnetometer columns, and then accepts rows with surplus fields and fills
    missing ones with NaN without a word. This wrapper counts delimiters (or whitespace-separated
    tokens) in each piece pandas reads: one byte count per piece when every line has the expected count;
    only a piece that does not add up is split into lines, to find the bad line or the blank lines.
    """

    def __init__(self, reader: ChunkReader, handle: _Bounded, max_read: int | None, start: int) -> None:
        super().__init__()
        fmt = reader.format
        assert fmt.delimiter is not None
        self._reader = reader
        self._handle = handle
        self._max_read = max_read
        self._start = start  # byte offset of the first line read: the data's, or a piece's (ChunkReader.split)
        self._n = fmt.n_columns
        self._whitespace = fmt.delimiter == "whitespace"
        self._delimiter_code = ord(fmt.delimiter[0])
        self._line = 0  # lines before the unchecked tail, counted from the first line read
        self._tail = b""  # bytes after the last newline seen: the start of a line not yet complete
        self._blank_rows: list[int] = []  # for each blank line, how many rows come before it

    @functools.cached_property
    def _first_line(self) -> int:
        """File line number (1-based) of the first line read. Only messages need it: a piece that starts
        in the middle of the file counts the lines before it (a tenth of a second per 100 MB) only then."""
        fmt = self._reader.format
        return fmt.data_line + 1 + _count_lines(self._reader.path, fmt.data_offset, self._start)

    def readable(self) -> bool:
        return True

    def read(self, size: int | None = -1) -> bytes:
        if size is None or size < 0:
            size = -1
        if self._max_read is not None and (size < 0 or size > self._max_read):
            size = self._max_read
        data = self._handle.read(size)
        if not data:
            if self._tail.strip():
                self._check(self._tail, 1)  # a last line without a line end
            self._tail = b""
            return data
        last = data.rfind(b"\n")
        if last < 0:
            self._tail += data
            return data
        segment = self._tail + data[: last + 1]
        self._tail = data[last + 1 :]
        self._check(segment)
        return data

    def readinto(self, buffer: Any) -> int:
        data = self.read(len(buffer))
        buffer[: len(data)] = data
        return len(data)

    def _check(self, segment: bytes, n_lines: int | None = None) -> None:
        # NumPy on pieces of a few hundred KiB (in cache) counts bytes about 5x faster than bytes.count.
        codes = np.frombuffer(segment, dtype=np.uint8)
        if n_lines is None:
            n_lines = int(np.count_nonzero(codes == 10))
        if self._whitespace:
            space = (codes == 32) | (codes == 9) | (codes == 10) | (codes == 13)
            tokens = int(np.count_nonzero(space[:-1] & ~space[1:])) + int(not space[0])
            consistent = tokens == self._n * n_lines
        else:
            consistent = int(np.count_nonzero(codes == self._delimiter_code)) == (self._n - 1) * n_lines
        # pandas also ends a line at a lone \r: only none, or one per line (\r\n), keeps its rows on the lines.
        carriage_returns = int(np.count_nonzero(codes == 13))
        if not consistent or carriage_returns not in (0, n_lines):
            self._scan(segment)
        self._line += n_lines

    def _scan(self, segment: bytes) -> None:
        """Line by line: raise at the first line with another field count, note the blank lines."""
        lines = segment.decode(self._reader._text_encoding, errors="replace").split("\n")
        if lines[-1] == "":
            lines.pop()
        for offset, line in enumerate(lines):
            index = self._line + offset  # lines before this one, from the first line read
            if not line.strip():
                self._blank_rows.append(index - len(self._blank_rows))
                continue
            if "\r" in line.rstrip("\r"):
                raise _error(
                    self._reader.path,
                    f"line {self._first_line + index} holds a carriage return (\\r) inside the line; delete it "
                    "(line ends are \\n or \\r\\n)",
                )
            count = len(_split_fields(line.rstrip("\r"), self._reader.format.delimiter))
            if count != self._n:
                raise self._reader._field_count_error(self._first_line + index, count)

    def line_of_rows(self, rows: NDArray[np.int64]) -> NDArray[np.int64]:
        """File line numbers (1-based) of data rows (0-based, blank lines not counted)."""
        shift = np.searchsorted(np.asarray(self._blank_rows, dtype=np.int64), rows, side="right")
        return np.asarray(self._first_line + rows + shift, dtype=np.int64)


@dataclass
class _NpyStream:
    """Rows of one array of an npz archive, read a chunk at a time (C order) or loaded whole (Fortran)."""

    archive: zipfile.ZipFile
    key: str
    chunk_rows: int
    _handle: Any = field(init=False)
    _info: _NpyInfo = field(init=False)
    _whole: NDArray[Any] | None = field(init=False, default=None)
    _position: int = field(init=False, default=0)

    def __post_init__(self) -> None:
        self._handle = self.archive.open(f"{self.key}.npy")
        self._info = _read_npy_header(self._handle)
        if self._info.fortran and len(self._info.shape) > 1:
            self._handle.close()
            with self.archive.open(f"{self.key}.npy") as handle:
                self._whole = np.lib.format.read_array(handle, allow_pickle=False)

    def next_rows(self) -> NDArray[Any]:
        total = self._info.shape[0]
        count = min(self.chunk_rows, total - self._position)
        start = self._position
        self._position += count
        if self._whole is not None:
            return self._whole[start : start + count]
        row_shape = self._info.shape[1:]
        row_bytes = self._info.dtype.itemsize * int(np.prod(row_shape, dtype=np.int64))
        data = self._handle.read(count * row_bytes)
        return np.frombuffer(data, dtype=self._info.dtype).reshape((count, *row_shape))

    def close(self) -> None:
        if self._whole is None:
            self._handle.close()


_Result = TypeVar("_Result")


@dataclass(frozen=True)
class PiecesRead:
    """The bookkeeping of the pieces of one file (:meth:`ChunkReader.parallel_pieces`), read as one reader
    would report it: rows and skipped rows summed, the first :data:`MAX_REPORTED_LINES` skipped lines."""

    pieces: Sequence[ChunkReader]

    @property
    def n_rows(self) -> int:
        return sum(piece.n_rows for piece in self.pieces)

    @property
    def n_skipped(self) -> int:
        return sum(piece.n_skipped for piece in self.pieces)

    @property
    def skipped_lines(self) -> tuple[int, ...]:
        return tuple(line for piece in self.pieces for line in piece.skipped_lines)[:MAX_REPORTED_LINES]

    @property
    def columns(self) -> tuple[str, str, str]:
        return self.pieces[0].columns

    @property
    def format(self) -> FileFormat:
        return self.pieces[0].format


def read_pieces(
    pieces: Sequence[ChunkReader], work: Callable[[ChunkReader, Callable[[], bool]], _Result]
) -> list[_Result]:
    """``work(piece, stopped)`` for each piece of :meth:`ChunkReader.parallel_pieces`, one thread each;
    the results in the pieces' order.

    Errors come as one reader of the whole file would raise them: the first piece's first. A piece that
    fails asks the pieces after it to stop (their ``stopped()`` turns true; ``work`` should check it
    between chunks), since their rows will not be used; the pieces before it go on, as one of them may
    hold an earlier error.
    """
    if len(pieces) == 1:
        return [work(pieces[0], lambda: False)]
    first_failed = [len(pieces)]  # index of the first piece known to have failed

    def run(index: int, piece: ChunkReader) -> _Result:
        try:
            return work(piece, lambda: first_failed[0] < index)
        except BaseException:
            first_failed[0] = min(first_failed[0], index)
            raise

    with ThreadPoolExecutor(len(pieces)) as pool:
        futures = [pool.submit(run, index, piece) for index, piece in enumerate(pieces)]
    return [future.result() for future in futures]  # the first piece's error first


def iter_sample_chunks(
    path: str | os.PathLike[str],
    *,
    columns: Sequence[str | int] | None = None,
    nonfinite: Literal["skip", "error"] = "skip",
    chunk_rows: int = 1_000_000,
) -> ChunkReader:
    """Read the magnetometer samples of a file chunk by chunk (bounded memory).

    Parameters
    ----------
    path : str or path-like
        Delimited text, ``.npy`` or ``.npz`` (see :func:`read_samples`).
    columns : sequence of 3 str or int, optional
        The x, y, z columns, by name or 0-based index, in that order; None finds them by name.
    nonfinite : {"skip", "error"}
        Rows with a NaN, infinite or empty magnetometer value are dropped and counted, or an error.
    chunk_rows : int
        Maximum rows per chunk.

    Returns
    -------
    ChunkReader
        An iterable of (n, 3) float64 arrays; after the iteration its ``n_rows``, ``n_skipped`` and
        ``skipped_lines`` are complete.
    """
    return ChunkReader(path, columns=columns, nonfinite=nonfinite, chunk_rows=chunk_rows)


def read_samples(
    path: str | os.PathLike[str],
    *,
    columns: Sequence[str | int] | None = None,
    nonfinite: Literal["skip", "error"] = "skip",
    progress: Callable[[int], object] | None = None,
) -> SampleTable:
    """Read the magnetometer samples of a file.

    Parameters
    ----------
    path : str or path-like
        Delimited text (comma, ``", "``, tab, semicolon, pipe or runs of spaces; optional preamble lines,
        header and UTF-8 BOM; any extra columns), a ``.npy`` array of shape (N, k >= 3), or an ``.npz``
        archive with three 1-D keys (``mag_x``, ``mag_y``, ``mag_z`` ...) or one (N, 3) key.
    columns : sequence of 3 str or int, optional
        The x, y, z columns, by name (case-insensitive) or 0-based index, always in the order x, y, z
        (for a file whose columns are z, y, x, pass ``[2, 1, 0]``). None finds them by name
        (:mod:`magfit.io.columns`); without a header, three columns are x, y, z and with more, the first
        three numeric ones are used (``SampleTable.columns`` says which).
    nonfinite : {"skip", "error"}
        Rows with a NaN, infinite or empty magnetometer value are dropped and counted (``"skip"``), or
        the first one raises (``"error"``).
    progress : callable, optional
        Called with the number of rows of each chunk read (finite ones; from several threads for a large
        text file), e.g. to advance a progress bar.

    Returns
    -------
    SampleTable
        The finite samples, shape (N, 3), in the file's units, and the bookkeeping of the read.

    Raises
    ------
    DataFileError
        Missing, unreadable or empty file; a header without rows; a cell that is not a number; a row with
        another number of fields; magnetometer columns not found or ambiguous; a column name or index that
        is not in the file; fewer than three columns; every row non-finite.
    """
    reader = ChunkReader(path, columns=columns, nonfinite=nonfinite, chunk_rows=1_000_000)
    pieces = reader.parallel_pieces()

    def collect(piece: ChunkReader, stopped: Callable[[], bool]) -> list[NDArray[np.float64]]:
        chunks = []
        for chunk in piece:
            if stopped():
                break
            chunks.append(chunk)
            if progress is not None:
                progress(len(chunk))
        return chunks

    chunks = [chunk for part in read_pieces(pieces, collect) for chunk in part]
    samples = np.concatenate(chunks) if chunks else np.empty((0, 3))
    read = PiecesRead(pieces)
    if read.n_rows == 0:
        raise _error(reader.path, "has no data rows; record some samples or give another file")
    if len(samples) == 0:
        raise _error(
            reader.path,
            f"all {read.n_rows} rows have a NaN, infinite or empty value in {', '.join(reader.columns)} "
            f"(first at line {read.skipped_lines[0]}); check the columns (columns=[...])",
        )
    return SampleTable(
        path=Path(display_name(reader.path)),
        samples=samples,
        columns=reader.columns,
        n_rows=read.n_rows,
        n_skipped=read.n_skipped,
        skipped_lines=read.skipped_lines,
        format=reader.format,
        column_note=reader.column_note,
    )
