"""Blocks of whole CSV lines parsed by pyarrow, or refused to pandas.

pandas' C reader parses one block at a time and needs every block's field counts checked in Python
(:class:`magfit.io.chunks._CheckedSource`): pandas accepts a row with another number of fields silently
when it reads only some columns. pyarrow's reader is strict about field counts itself and parses a block
of bytes without Python's lock, so blocks parse on one thread per core. A :data:`BlockParser` returns the
float64 values of the columns asked, or None whenever its reading could differ from the pandas path's: a
cell that is not a number, a line with another number of fields, a blank line, a quoted line end, a lone
carriage return. The caller then reads that part of the file with pandas, which names the problem and its
line, or parses what it accepts (a blank line, ``" NA"``). Which reader is used: :func:`block_parser`.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .layout import NA_VALUES, FileFormat

__all__ = ["READERS", "READER_VARIABLE", "BlockParser", "block_parser", "reader_name"]

#: Parses the first ``end`` bytes of ``data`` (whole data lines) into an (n_lines, k) float64 array, or
#: returns None (see above): ``parse(data, end)``. (A prefix, not a slice: slicing would copy the block.)
BlockParser = Callable[[bytes, int], "NDArray[np.float64] | None"]
#: The block readers, in the order they are tried. (polars parsed the same blocks in about the same CPU time,
#: without the field-count check: docs/scaling.md, "Reading a large CSV".)
READERS = ("pyarrow",)
#: The environment variable that chooses the reader of large CSV files: ``pyarrow`` or ``pandas`` (pandas' C
#: reader alone, as for small files). Unset: the first of :data:`READERS` installed.
READER_VARIABLE = "MAGFIT_CSV_READER"
#: The text encodings whose data bytes pyarrow takes as they are (digits, signs, delimiters in ASCII).
_ENCODINGS = frozenset({"utf-8", "utf-8-sig", "latin-1"})


def reader_name() -> str | None:
    """The block reader to use: :data:`READER_VARIABLE`'s choice when it is installed, else the first of
    :data:`READERS` installed; None for pandas (chosen, or nothing else installed)."""
    import importlib.util

    chosen = os.environ.get(READER_VARIABLE, "").strip().lower()
    if chosen == "pandas":
        return None
    for name in (chosen,) if chosen in READERS else READERS:
        if importlib.util.find_spec(name) is not None:
            return name
    return None


def block_parser(fmt: FileFormat, used: Sequence[int]) -> BlockParser | None:
    """A parser of the columns ``used`` (0-based, ascending) of ``fmt``'s data lines, or None when pandas must
    read the file: pyarrow not installed or not chosen, or a layout only the pandas path reads alike (a
    delimiter of several characters or runs of blanks, a decimal comma, an encoding other than UTF-8 or
    Latin-1)."""
    if fmt.delimiter is None or len(fmt.delimiter) != 1 or fmt.decimal != "." or fmt.encoding not in _ENCODINGS:
        return None
    return _arrow_parser(fmt, used) if reader_name() == "pyarrow" else None


def _lone_carriage_return(data: bytes, end: int) -> bool:
    """Whether a block holds a carriage return that does not end a line (``\\r`` not before ``\\n``): pyarrow
    would end a line there, where the pandas path names it. (NumPy counts; ``bytes.count`` of a two-byte
    pattern is several times slower.)"""
    if data.find(b"\r", 0, end) < 0:  # memchr: the usual block costs nothing more
        return False
    codes = np.frombuffer(data, dtype=np.uint8, count=end)
    returns = codes == 13
    return int(np.count_nonzero(returns)) != int(np.count_nonzero(returns[:-1] & (codes[1:] == 10)))


def _n_lines(data: bytes, end: int) -> int:
    return int(np.count_nonzero(np.frombuffer(data, dtype=np.uint8, count=end) == 10))


def _blank_line(data: bytes, end: int) -> bool:
    """Whether a block of whole lines holds an empty line (pyarrow reads it as a row of missing values, where
    pandas skips it; a line of blanks is another field count, which pyarrow refuses). Asked only of a block
    with a row whose values are all missing."""
    codes = np.frombuffer(data, dtype=np.uint8, count=end)
    ends = np.flatnonzero(codes == 10)
    starts = np.concatenate(([0], ends[:-1] + 1))
    length = ends - starts
    return bool(np.any((length == 0) | ((length == 1) & (codes[np.maximum(ends - 1, 0)] == 13))))


def _fill_column(out: NDArray[np.float64], chunk: Any) -> None:
    """Write a pyarrow float64 array into ``out``, a missing value as NaN, straight from its buffers.

    (``Array.to_numpy`` imports pandas, even for a copy it need not make: a sixth of a second, once.)
    The values buffer holds anything at a missing value's place; the validity bitmap (bit ``i``, least
    significant first, counted from the array's offset) tells which those are.
    """
    validity, data = chunk.buffers()
    out[:] = np.frombuffer(data, dtype=np.float64, count=len(chunk), offset=chunk.offset * 8)
    if validity is not None and chunk.null_count:
        bits = np.unpackbits(np.frombuffer(validity, dtype=np.uint8), bitorder="little")
        out[~bits[chunk.offset : chunk.offset + len(chunk)].astype(bool)] = np.nan


def _arrow_parser(fmt: FileFormat, used: Sequence[int]) -> BlockParser:
    """pyarrow's reader, strict about field counts itself; empty lines are kept (and such a block refused:
    :func:`_blank_line`) so that every row is one line."""
    import pyarrow
    import pyarrow.csv

    assert fmt.delimiter is not None
    names = [f"c{index}" for index in range(fmt.n_columns)]
    parse_options = pyarrow.csv.ParseOptions(delimiter=fmt.delimiter, ignore_empty_lines=False)

    def convert_options(null_values: Sequence[str]) -> pyarrow.csv.ConvertOptions:
        return pyarrow.csv.ConvertOptions(
            include_columns=[names[index] for index in used],
            column_types={names[index]: pyarrow.float64() for index in used},
            null_values=list(null_values),
            strings_can_be_null=False,
            quoted_strings_can_be_null=True,
        )

    # Every cell is matched against the missing-value words before it is converted: with all of NA_VALUES a
    # fifth of the parse. pyarrow converts the NaN words ("nan", "NaN", "NAN", "-nan", "-NaN") to NaN itself,
    # the value a missing one gets here, so a block is first parsed with only the empty cell as missing; a
    # block that holds another word ("NA", "null", ...) fails that conversion and is parsed again with every
    # word, as are the blocks after it (the file writes its missing values so).
    tries = [convert_options([""]), convert_options(NA_VALUES)]
    tried = [0]  # the first of ``tries`` to use
    pool = pyarrow.system_memory_pool()  # a block's memory goes back to the system (jemalloc's would stay)

    def parse(data: bytes, end: int) -> NDArray[np.float64] | None:
        if _lone_carriage_return(data, end):
            return None
        quoted = data.find(b'"', 0, end) >= 0
        read_options = pyarrow.csv.ReadOptions(column_names=names, use_threads=False, block_size=end + 1)
        table = None
        for first in range(tried[0], len(tries)):
            try:
                table = pyarrow.csv.read_csv(
                    pyarrow.py_buffer(memoryview(data)[:end]),
                    read_options=read_options,
                    parse_options=parse_options,
                    convert_options=tries[first],
                    memory_pool=pool,
                )
                break
            except (pyarrow.ArrowInvalid, pyarrow.ArrowNotImplementedError):
                tried[0] = len(tries) - 1  # every word from now on (the same value from any thread)
        if table is None:
            return None
        if quoted and table.num_rows != _n_lines(data, end):  # a quoted cell held a line end
            return None
        values = np.empty((table.num_rows, len(used)))
        for column in range(len(used)):
            row = 0
            for chunk in table.column(column).chunks:
                _fill_column(values[row : row + len(chunk), column], chunk)
                row += len(chunk)
        if all(table.column(column).null_count for column in range(len(used))):  # a row may be a blank line
            if np.isnan(values).all(axis=1).any() and _blank_line(data, end):
                return None
        return values

    return parse
