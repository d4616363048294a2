"""Reading a samples file's x, y, z columns in chunks of bounded size, and in pieces on several threads.

The rows of a text file are parsed by pandas' C reader, three columns at a time, in blocks whose size
bounds the memory whatever the file's length. Every block is also checked for rows with a different
number of fields (:class:`_CheckedSource`): pandas accepts those silently when it reads only some of the
columns. A large plain file is parsed by pyarrow when it is installed (:mod:`magfit.io.fastcsv`,
:meth:`ChunkReader._iter_blocks`): blocks of whole lines on one thread per core; a block pyarrow does not
read as one row of numbers per line (a bad cell, a blank line, a cut last line), and the rest of the file
after it, are read by the pandas path, which names the problem and the line. ``.npy`` files are
memory-mapped and ``.npz`` members inflated a chunk at a time. Rows with a NaN or an infinite
magnetometer value are counted and dropped (or refused), by line number.
"""

from __future__ import annotations

import copy
import functools
import io
import itertools
import os
import warnings
import zlib
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import IO, Any, Literal, TypeVar

import numpy as np
from numpy.typing import NDArray

from .._validation import MAX_MAGNITUDE
from ..errors import DataFileError, OptionError
from ..remedy import option
from .fastcsv import BlockParser, block_parser
from .instances import (
    SensorColumn,
    choose,
    head_values,
    instance_column,
    interleaved_error,
    sensor_id,
    value_text,
)
from .layout import (
    FileFormat,
    cell_kind,
    decode_lines,
    pandas_module,
    pandas_options,
    read_head,
    sniff,
    split_fields,
    text_encoding,
)
from .npy import BROKEN_NPY, NpyStream, check_npy_array, npy_info, npz_members, one_line
from .selection import (
    NpzSelection,
    columns_origin,
    npy_content_choice,
    resolve_npz_columns,
    resolve_table_columns,
    text_content_choice,
)
from .sources import check_file, file_error

__all__ = [
    "BLOCK_BYTES",
    "BLOCK_READER_BYTES",
    "MAX_PIECES",
    "MAX_REPORTED_LINES",
    "PARALLEL_BYTES",
    "SMALL_TEXT_BYTES",
    "ChunkReader",
    "PiecesRead",
    "read_pieces",
]

#: How many skipped rows are remembered by line number (all of them are counted).
MAX_REPORTED_LINES = 10
#: Text files from this size are parsed in pieces on several threads (:meth:`ChunkReader.parallel_pieces`);
#: below it the threads would cost more than they save.
PARALLEL_BYTES = 32 << 20
#: At most this many pieces (threads) for one file.
MAX_PIECES = 4
#: Text files (or pieces) up to this size are parsed here, line by line, rather than by pandas: importing
#: pandas takes several times longer than parsing this much in Python (docs/scaling.md, "Measured speed").
SMALL_TEXT_BYTES = 256 * 1024
#: Text files from this size are parsed by pyarrow when it is installed (:mod:`magfit.io.fastcsv`): importing
#: it costs more than it saves on smaller files.
BLOCK_READER_BYTES = 32 << 20
#: Bytes of whole lines per block of that reader: each is parsed on one thread, and the blocks in flight (one
#: per thread, and one more) bound the memory (docs/scaling.md, "Reading a large CSV").
BLOCK_BYTES = 4 << 20


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
    unit, column_note, sensor
        As in :class:`SampleTable`.
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
        sensor: str | None = None,
    ) -> None:
        if nonfinite not in ("skip", "error"):
            raise OptionError(f"nonfinite must be 'skip' or 'error', got {nonfinite!r}")
        if isinstance(chunk_rows, bool) or not isinstance(chunk_rows, (int, np.integer)) or chunk_rows < 1:
            raise OptionError(f"chunk_rows must be a positive integer, got {chunk_rows!r}")
        self.path = check_file(path)
        self.format = sniff(self.path)
        self.nonfinite = nonfinite
        self.chunk_rows = int(chunk_rows)
        self._block_bytes = block_bytes
        self._byte_range: tuple[int, int] | None = None  # set by split(): a part of a text file
        self._npz: NpzSelection | None = None
        self._indices: tuple[int, int, int] = (0, 1, 2)
        self.n_rows = 0
        self.n_skipped = 0
        self.skipped_lines: tuple[int, ...] = ()
        self._skipped: list[int] = []
        self.column_note: str | None = None
        self.unit: str | None = None  # as the column names (or the converter that wrote them) say
        self.sensor: str | None = None  # the magnetometer read, in a file that interleaves several (I=1)
        self._sensor_column: SensorColumn | None = None
        if self.format.kind == "npz":
            self._npz = resolve_npz_columns(self.path, npz_members(self.path), columns)
            self.columns = self._npz.labels
            if self._npz.key_columns is None:  # three 1-D keys, named like columns (mag_x_uT)
                self.unit, _ = columns_origin(self._npz.keys, self.format.header)
        elif self.format.kind == "npy":
            self._check_npy_shape()
            content = (
                npy_content_choice(self.path, self.format) if columns is None and self.format.n_columns > 3 else None
            )
            self._indices, self.columns = resolve_table_columns(self.path, self.format, columns, content)
            if content is not None:
                self.column_note = content.describe([self.format.column_label(i) for i in range(self.format.n_columns)])
        else:
            headerless = columns is None and self.format.header is None and self.format.n_columns >= 3
            content = text_content_choice(self.path, self.format) if headerless else None
            self._indices, self.columns = resolve_table_columns(self.path, self.format, columns, content)
            if content is not None:
                self.column_note = content.describe([self.format.column_label(i) for i in range(self.format.n_columns)])
            self.unit, converter = columns_origin(self.columns, self.format.header)
            if converter is not None:  # what the tool that wrote them says: the unit, a calibration already applied
                self.column_note = converter.describe()
            self._sensor_column = self._choose_sensor(sensor)
        if sensor is not None and self._sensor_column is None:
            raise file_error(
                self.path,
                "has no column that tells magnetometers apart (I, instance, device_id, sensor_id ...): "
                f"{option('sensor', 'ID')} chooses one of a file that interleaves several; this one is read whole "
                "without it",
            )

    def _choose_sensor(self, sensor: str | None) -> SensorColumn | None:
        """The instance column of a text file (:mod:`magfit.io.instances`) and the magnetometer to read.

        Several values in the head and none chosen is refused here, at once: the rows of two compasses
        are not one cloud. One value is read with a guard against others further in (:meth:`_sensor_rows`).
        """
        found = instance_column(self.path, self.format, self._indices)
        if found is None:
            return None
        column, values = found
        assert self.format.header is not None
        name = self.format.header[column]
        if sensor is None:
            if len(values) > 1:
                raise interleaved_error(self.path, name, values)
            return SensorColumn(column, name, None, values[0] if values else None)
        value = choose(self.path, name, sensor, values)
        self.sensor = sensor_id(name, value)
        return SensorColumn(column, name, value)

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
        if self._block_parser() is not None:  # the blocks are parsed on one thread per core
            return [self]
        return self.split(workers)

    # .................................................................. shared bookkeeping

    def _check_npy_shape(self) -> None:
        check_npy_array(self.path, npy_info(self.path))

    def _filter(
        self, values: NDArray[np.float64], to_line: Callable[[NDArray[np.int64]], NDArray[np.int64]]
    ) -> NDArray[np.float64]:
        """Count and drop the non-finite rows of a chunk; ``to_line`` maps its row numbers to line numbers."""
        first_row = self.n_rows
        self.n_rows += len(values)
        if values.size and -MAX_MAGNITUDE <= values.min() and values.max() <= MAX_MAGNITUDE:
            return values  # the usual chunk, in two reductions (NaN fails both comparisons)
        # A value beyond ±MAX_MAGNITUDE (its square overflows float64) measures nothing a magnetometer can: such
        # a row is skipped and counted as a NaN's is (a glitch on a serial line, a damaged row), or named.
        usable = (np.abs(values) <= MAX_MAGNITUDE).all(axis=1)
        if usable.all():
            return values
        bad = np.flatnonzero(~usable)
        if self.nonfinite == "error":
            row = bad[0]
            axis = int(np.flatnonzero(~(np.abs(values[row]) <= MAX_MAGNITUDE))[0])
            place = "line" if self.format.kind == "text" else "row"
            line = int(to_line(np.array([first_row + row]))[0])
            value = values[row, axis]
            problem = (
                f"{value:.3g} is beyond ±{MAX_MAGNITUDE:g}, more than float64 can square; fix or delete that row, or "
                f"skip such rows ({option('nonfinite', 'skip')})"
                if np.isfinite(value)
                else f"the value is {_nonfinite_word(value)}; fix or delete that row, or skip such rows "
                f"({option('nonfinite', 'skip')})"
            )
            raise file_error(self.path, f"{place} {line}, column {self.columns[axis]!r}: {problem}")
        self.n_skipped += bad.size
        room = MAX_REPORTED_LINES - len(self._skipped)
        if room > 0:
            self._skipped.extend(int(line) for line in to_line(first_row + bad[:room]))
        return np.ascontiguousarray(values[usable])

    def __iter__(self) -> Iterator[NDArray[np.float64]]:
        self.n_rows = 0
        self.n_skipped = 0
        self._skipped = []
        self.skipped_lines = ()
        if self.format.kind == "text":
            parse = self._block_parser()
            chunks = self._iter_text() if parse is None else self._iter_blocks(parse)
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
            raise self.no_rows_error()

    # .................................................................. npy / npz

    def _iter_npy(self) -> Iterator[NDArray[np.float64]]:
        try:
            with warnings.catch_warnings():  # as in read_npy_header
                warnings.simplefilter("ignore", UserWarning)
                array = np.load(self.path, mmap_mode="r", allow_pickle=False)
        except BROKEN_NPY as error:  # changed since it was sniffed
            raise file_error(self.path, f"is not a readable .npy file ({error}); re-save it with numpy.save") from None
        if array.shape[0] == 0:
            raise file_error(self.path, "holds an array with no rows; record some samples")
        for start in range(0, array.shape[0], self.chunk_rows):
            block = np.asarray(array[start : start + self.chunk_rows][:, list(self._indices)], dtype=np.float64)
            yield self._filter(block, _next_row)

    def _iter_npz(self) -> Iterator[NDArray[np.float64]]:
        selection = self._npz
        assert selection is not None
        if selection.n_rows == 0:
            raise file_error(self.path, f"the arrays {', '.join(selection.keys)} are empty; record some samples")
        import zipfile

        with zipfile.ZipFile(self.path) as archive:
            streams: list[NpyStream] = []
            try:
                start = 0
                while start < selection.n_rows:
                    # A damaged member shows only while it is inflated (bad deflate data, a CRC, a short array).
                    try:
                        if not streams:
                            streams = [NpyStream(archive, key, self.chunk_rows) for key in selection.keys]
                        parts = [stream.next_rows() for stream in streams]
                        if selection.key_columns is None:
                            block = np.column_stack([np.asarray(part, dtype=np.float64) for part in parts])
                        else:
                            block = np.asarray(parts[0][:, list(selection.key_columns)], dtype=np.float64)
                    except (zipfile.BadZipFile, zlib.error, *BROKEN_NPY) as error:
                        raise file_error(
                            self.path, f"is a damaged .npz archive ({one_line(error)}); re-save it with numpy.savez"
                        ) from None
                    yield self._filter(block, _next_row)
                    start += len(block)
            finally:
                for stream in streams:
                    stream.close()

    # .................................................................. text, in blocks (pyarrow)

    def _block_parser(self) -> BlockParser | None:
        """The block reader of :mod:`magfit.io.fastcsv` for this reader's rows, or None: pandas parses them.

        Only for a whole plain text file of at least :data:`BLOCK_READER_BYTES` whose rows come from one
        magnetometer (and not when ``block_bytes`` sets pandas' reads, as tests do).
        """
        fmt = self.format
        if (
            fmt.kind != "text"
            or self._byte_range is not None
            or self._block_bytes is not None
            or self._sensor_column is not None
            or self.path.stat().st_size < BLOCK_READER_BYTES
        ):
            return None
        return block_parser(fmt, sorted(set(self._indices)))

    def _iter_blocks(self, parse: BlockParser) -> Iterator[NDArray[np.float64]]:
        """The rows of a large plain text file, parsed in blocks of whole lines on one thread per core.

        The blocks are read in order; at most one per thread and one more are in flight, which bounds the
        memory. The first block that ``parse`` refuses (None: see :mod:`magfit.io.fastcsv`), and the rest of
        the file after it, are read as one piece by the pandas path (:meth:`_iter_text`): it names the problem
        and its line, or reads what pandas accepts. Before that block every row is one line, so the line of
        row ``i`` is ``data_line + 1 + i``.
        """
        fmt = self.format
        used = sorted(set(self._indices))
        order = [used.index(index) for index in self._indices]
        first_line = fmt.data_line + 1

        def to_line(rows: NDArray[np.int64]) -> NDArray[np.int64]:
            return rows + first_line

        from concurrent.futures import Future, ThreadPoolExecutor

        workers = max(1, min(os.cpu_count() or 1, MAX_PIECES))
        rest: int | None = None  # byte offset from which the pandas path reads the file
        end = self.path.stat().st_size
        with open(self.path, "rb") as handle, ThreadPoolExecutor(workers) as executor:
            offset = fmt.data_offset  # of the first byte not yet handed to a block
            pending: list[tuple[int, Future[NDArray[np.float64] | None]]] = []
            try:
                while True:
                    size = BLOCK_BYTES
                    while len(pending) <= workers:
                        handle.seek(offset)
                        data = handle.read(size)
                        cut = data.rfind(b"\n") + 1
                        if cut == 0:  # no line end: a line longer than the block, or the last line's end
                            if len(data) == size:
                                size *= 2
                                continue
                            break
                        pending.append((offset, executor.submit(parse, data, cut)))
                        offset += cut  # the bytes after the last line end are read again with the next block
                        size = BLOCK_BYTES
                    if not pending:
                        if offset < end:  # the last line has no line end: pandas' path says if it is cut short
                            rest = offset
                        break
                    start, future = pending.pop(0)
                    values = future.result()
                    if values is None:
                        rest = start
                        break
                    if order != list(range(len(order))):
                        values = values[:, order]
                    for first in range(0, len(values), self.chunk_rows):
                        yield self._filter(values[first : first + self.chunk_rows], to_line)
            finally:
                for _, future in pending:
                    future.cancel()
        if rest is None:
            return
        piece = copy.copy(self)
        piece._byte_range = (rest, end)
        yield from piece
        self.n_rows += piece.n_rows
        self.n_skipped += piece.n_skipped
        self._skipped.extend(piece.skipped_lines[: max(MAX_REPORTED_LINES - len(self._skipped), 0)])

    # .................................................................. text

    def _field_count_error(self, line: int, count: int) -> DataFileError:
        fmt = self.format
        rows = "the header and the first rows have" if fmt.header is not None else "the first rows have"
        return file_error(
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
                    return file_error(
                        self.path,
                        f"line {number} holds a carriage return (\\r) inside the line; delete it (line ends are "
                        "\\n or \\r\\n)",
                    )
                fields = split_fields(line.rstrip("\r\n"), fmt.delimiter)
                for axis, index in enumerate(self._indices):
                    cell = fields[index] if index < len(fields) else ""
                    if cell_kind(cell, fmt.decimal) == "text":
                        return file_error(
                            self.path,
                            f"line {number}, column {self.columns[axis]!r} (column {index + 1}): {cell!r} is not "
                            f"a number; fix that cell, or choose other columns with {option('columns', '...')}",
                        )
                instance = self._sensor_column
                if (
                    instance is not None
                    and instance.index < len(fields)
                    and cell_kind(fields[instance.index]) == "text"
                ):
                    return file_error(
                        self.path,
                        f"line {number}, column {instance.name!r} (column {instance.index + 1}): "
                        f"{fields[instance.index]!r} is not a number, so the row's magnetometer is unknown; fix "
                        "that cell",
                    )
        return file_error(self.path, f"cannot read the numbers ({detail}); check the file's format")

    def _parse_block(self, block: bytes) -> NDArray[np.float64]:
        """The x, y, z values of a block of whole data lines (blank lines skipped), as the reader parses them."""
        used = sorted(set(self._indices))
        frame = pandas_module().read_csv(io.BytesIO(block), **self._read_options(used))
        return np.asarray(frame.to_numpy(dtype=np.float64)[:, [used.index(i) for i in self._indices]])

    def _read_options(self, used: list[int]) -> dict[str, Any]:
        """pandas.read_csv options for the data lines: C engine, only the columns ``used``, float64."""
        return pandas_options(self.format, used, strip_blanks=self._blank_led_cells)

    @functools.cached_property
    def _blank_led_cells(self) -> bool:
        """Whether cells may start with blanks, as in ``1, nan, 3``: pandas must then strip them
        (``skipinitialspace``), which costs a quarter of the parse. Numbers parse either way; only a missing
        value written with a blank before it needs the stripping. Decided on the first data lines."""
        fmt = self.format
        if fmt.delimiter is None or fmt.delimiter == "whitespace" or len(fmt.delimiter) > 1:
            return True
        head, truncated = read_head(self.path)
        _, lines, _ = decode_lines(self.path, head, truncated)
        blanks = " \t".replace(fmt.delimiter, "")
        return any(blank in line for line in lines[fmt.data_line :] for blank in blanks)

    @property
    def _text_encoding(self) -> str:
        return text_encoding(self.format)

    def _iter_text(self) -> Iterator[NDArray[np.float64]]:
        fmt = self.format
        assert fmt.delimiter is not None
        instance = self._sensor_column
        used = sorted({*self._indices, *([instance.index] if instance is not None else [])})
        order = [used.index(index) for index in self._indices]
        rows_before = 0  # data rows parsed so far (all sensors'), for the line numbers
        with open(self.path, "rb") as handle:
            start, stop = self._byte_range if self._byte_range is not None else (fmt.data_offset, None)
            handle.seek(start)
            source = _CheckedSource(self, _Bounded(handle, stop), self._block_bytes, start)
            end = self.path.stat().st_size if stop is None else stop
            small = end - start <= SMALL_TEXT_BYTES
            for values in self._parse_small(source, used) if small else self._parse_pandas(source, used):
                to_line = source.line_of_rows
                n_parsed = len(values)
                if instance is not None:
                    kept = self._sensor_rows(values[:, used.index(instance.index)], rows_before, to_line)
                    if kept is not None:  # this sensor's rows; their line numbers through the rows kept
                        to_line = functools.partial(_kept_lines, to_line, rows_before + kept, self.n_rows)
                        values = values[kept]
                    rows_before += n_parsed
                if order != list(range(len(order))):  # columns asked in another order than the file's
                    values = values[:, order]
                yield self._filter(values, to_line)
        if source.cut_line is not None:  # counted as a skipped row (and refused by nonfinite="error")
            if self.nonfinite == "error":
                raise file_error(
                    self.path,
                    f"line {source.cut_line} is cut short (fields missing, no line end): the recording was "
                    f"interrupted; delete that line, or skip it ({option('nonfinite', 'skip')})",
                )
            self.n_rows += 1
            self.n_skipped += 1
            if len(self._skipped) < MAX_REPORTED_LINES:
                self._skipped.append(source.cut_line)

    def _parse_pandas(self, source: _CheckedSource, used: list[int]) -> Iterator[NDArray[np.float64]]:
        """The ``used`` columns of the checked lines, parsed by pandas' C reader in chunks of ``chunk_rows``."""
        pandas = pandas_module()
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
                yield frame.to_numpy(dtype=np.float64)

    def _parse_small(self, source: _CheckedSource, used: list[int]) -> Iterator[NDArray[np.float64]]:
        """The ``used`` columns of a small file's checked lines, parsed here (no pandas to import).

        The cells are those the messages see (:func:`~magfit.io.layout.split_fields`: stripped, unquoted),
        classified by :func:`~magfit.io.layout.cell_kind`: a missing value is NaN, a number is parsed by
        ``float``, anything else is the error :meth:`_bad_cell_error` names. Blank lines are skipped, as
        pandas skips them (the checked source has noted them for the line numbers).
        """
        fmt = self.format
        data = b"".join(iter(lambda: source.read(-1), b""))
        decimal = fmt.decimal
        rows: list[list[float]] = []
        for line in data.decode(self._text_encoding, errors="replace").split("\n"):
            if not line.strip():
                continue
            fields = split_fields(line.rstrip("\r"), fmt.delimiter)
            row = []
            for index in used:
                cell = fields[index] if index < len(fields) else ""
                kind = cell_kind(cell, decimal)
                if kind == "text":
                    raise self._bad_cell_error(f"{cell!r} is not a number")
                row.append(float(cell.replace(",", ".") if decimal == "," else cell) if kind == "number" else np.nan)
            rows.append(row)
        for first in range(0, len(rows), self.chunk_rows):
            yield np.array(rows[first : first + self.chunk_rows], dtype=np.float64).reshape(-1, len(used))

    def _sensor_rows(
        self,
        instance: NDArray[np.float64],
        rows_before: int,
        to_line: Callable[[NDArray[np.int64]], NDArray[np.int64]],
    ) -> NDArray[np.int64] | None:
        """The rows of a chunk from the magnetometer read (None: all of them), or an error when a file read
        whole turns out to interleave several further in than its head."""
        column = self._sensor_column
        assert column is not None
        if column.value is not None:
            return np.flatnonzero(instance == column.value)
        expected = column.expected
        if expected is None:  # no value in the head (all missing): the first one seen is the one
            seen = instance[np.isfinite(instance)]
            if not seen.size:
                return None
            expected = float(seen[0])
            self._sensor_column = replace(column, expected=expected)
        other = np.flatnonzero(np.isfinite(instance) & (instance != expected))
        if other.size:
            line = int(to_line(np.array([rows_before + other[0]]))[0])
            found = float(instance[other[0]])
            raise interleaved_error(
                self.path,
                column.name,
                sorted({expected, found}),
                f"line {line}: column {column.name!r} changes from {value_text(expected)} to {value_text(found)}; "
                "the file ",
            )
        return None

    def no_rows_error(self) -> DataFileError:
        """The error of a read that found no data rows (for the magnetometer chosen, in an interleaved file)."""
        if self._sensor_column is not None and self._sensor_column.value is not None:
            name = self._sensor_column.name
            found = head_values(self.path, self.format, self._sensor_column.index)
            held = ", ".join(sensor_id(name, value) for value in found) or "none in its first rows"
            return file_error(self.path, f"has no rows with {self.sensor}; it holds {held}: choose one of them")
        return file_error(self.path, "has no data rows; record some samples or give another file")


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


def _kept_lines(
    line_of_rows: Callable[[NDArray[np.int64]], NDArray[np.int64]],
    kept: NDArray[np.int64],
    first: int,
    rows: NDArray[np.int64],
) -> NDArray[np.int64]:
    """Line numbers of the rows a reader counted (from ``first``) among the data rows ``kept`` of a chunk."""
    return line_of_rows(kept[rows - first])


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
        self._ready = b""  # checked whole lines not yet passed on
        self._done = False
        #: File line number of a last line cut short (left out), else None.
        self.cut_line: int | None = None

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
        # Only whole, checked lines are passed on; the bytes after the last line end wait for the next read.
        while not self._ready and not self._done:
            self._fill(size)
        if size < 0:
            data, self._ready = self._ready, b""
        else:
            data, self._ready = self._ready[:size], self._ready[size:]
        return data

    def _fill(self, size: int) -> None:
        data = self._handle.read(size)
        if not data:
            self._done = True
            tail, self._tail = self._tail, b""
            if not tail.strip():
                self._ready += tail
                return
            line = tail.decode(self._reader._text_encoding, errors="replace").rstrip("\r")
            if len(split_fields(line, self._reader.format.delimiter)) < self._n:
                # A last line without a line end and with fields missing: a recording cut mid-row (a full
                # disk, a pulled cable). It is left out and counted; any other bad line is refused.
                self.cut_line = self._first_line + self._line
                return
            self._check(tail, 1)
            self._ready += tail
            return
        last = data.rfind(b"\n")
        if last < 0:
            self._tail += data
            return
        segment = self._tail + data[: last + 1]
        self._tail = data[last + 1 :]
        self._check(segment)
        self._ready += segment

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
                raise file_error(
                    self._reader.path,
                    f"line {self._first_line + index} holds a carriage return (\\r) inside the line; delete it "
                    "(line ends are \\n or \\r\\n)",
                )
            count = len(split_fields(line.rstrip("\r"), self._reader.format.delimiter))
            if count != self._n:
                raise self._reader._field_count_error(self._first_line + index, count)

    def line_of_rows(self, rows: NDArray[np.int64]) -> NDArray[np.int64]:
        """File line numbers (1-based) of data rows (0-based, blank lines not counted)."""
        shift = np.searchsorted(np.asarray(self._blank_rows, dtype=np.int64), rows, side="right")
        return np.asarray(self._first_line + rows + shift, dtype=np.int64)


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

    from concurrent.futures import ThreadPoolExecutor  # (with logging's import: only for a big file)

    with ThreadPoolExecutor(len(pieces)) as pool:
        futures = [pool.submit(run, index, piece) for index, piece in enumerate(pieces)]
    return [future.result() for future in futures]  # the first piece's error first
