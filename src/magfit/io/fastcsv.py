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

import numpy as np
from numpy.typing import NDArray

from .layout import NA_VALUES, FileFormat

__all__ = ["READERS", "READER_VARIABLE", "BlockParser", "block_parser", "reader_name"]

#: Parses the bytes of whole data lines into an (n_lines, k) float64 array, or returns None (see above).
BlockParser = Callable[[bytes], "NDArray[np.float64] | None"]
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


def _line_ends_agree(block: bytes, n_lines: int) -> bool:
    """Whether a block's carriage returns are none or one per line (``\\r\\n``), as the pandas path requires:
    pyarrow would end a line at a lone ``\\r`` where that path names it."""
    return b"\r" not in block or block.count(b"\r") == n_lines


def _blank_line(block: bytes) -> bool:
    """Whether a block of whole lines holds an empty line (pyarrow would read it as a row of missing values,
    where pandas skips it; a line of blanks is another field count, which pyarrow refuses)."""
    return block.startswith((b"\n", b"\r\n")) or b"\n\n" in block or b"\n\r\n" in block


def _arrow_parser(fmt: FileFormat, used: Sequence[int]) -> BlockParser:
    """pyarrow's reader, strict about field counts itself; empty lines are kept (and such a block refused:
    :func:`_blank_line`) so that every row is one line."""
    import pyarrow
    import pyarrow.csv

    assert fmt.delimiter is not None
    names = [f"c{index}" for index in range(fmt.n_columns)]
    parse_options = pyarrow.csv.ParseOptions(delimiter=fmt.delimiter, ignore_empty_lines=False)
    convert_options = pyarrow.csv.ConvertOptions(
        include_columns=[names[index] for index in used],
        column_types={names[index]: pyarrow.float64() for index in used},
        null_values=list(NA_VALUES),
        strings_can_be_null=False,
        quoted_strings_can_be_null=True,
    )
    pool = pyarrow.system_memory_pool()  # a block's memory goes back to the system (jemalloc's would stay)

    def parse(block: bytes) -> NDArray[np.float64] | None:
        if _blank_line(block):
            return None
        quoted = b'"' in block
        n_lines = block.count(b"\n") if quoted or b"\r" in block else -1
        if n_lines >= 0 and not _line_ends_agree(block, n_lines):
            return None
        read_options = pyarrow.csv.ReadOptions(column_names=names, use_threads=False, block_size=len(block) + 1)
        try:
            table = pyarrow.csv.read_csv(
                pyarrow.py_buffer(block),
                read_options=read_options,
                parse_options=parse_options,
                convert_options=convert_options,
                memory_pool=pool,
            )
        except (pyarrow.ArrowInvalid, pyarrow.ArrowNotImplementedError):
            return None
        if quoted and table.num_rows != n_lines:  # a quoted cell held a line end
            return None
        values = np.empty((table.num_rows, len(used)))
        for column in range(len(used)):
            values[:, column] = table.column(column).to_numpy(zero_copy_only=False)
        return values

    return parse
