"""Writing a calibrated copy of a samples file.

:func:`write_calibrated` rewrites the input file with the three magnetometer columns replaced by
``calibration.apply(...)`` (``matrix @ (raw - offset)``, ARCHITECTURE.md) and everything else kept: the
preamble, the header, the byte-order mark, the delimiter, the line ends, the other columns and every row.
Text files are rewritten line by line, so a cell that is not a magnetometer value keeps its exact bytes;
npy/npz files keep their other arrays (an npy array becomes float64 as a whole when it was an integer or
float32 array). The output is written atomically (:mod:`magfit.io.atomic`).
"""

from __future__ import annotations

import os
import re
import zipfile
import zlib
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from .._validation import MAX_MAGNITUDE
from ..errors import DataFileError
from ..remedy import option
from .atomic import atomic_open
from .chunks import ChunkReader
from .layout import NA_VALUES
from .npy import BROKEN_NPY, NpyStream, one_line
from .readers import SampleTable
from .sources import check_file, file_error

if TYPE_CHECKING:
    from collections.abc import Sequence

    from ..calibration import Calibration

__all__ = ["write_calibrated"]

#: Significant digits of the calibrated values written to text files (ample for any magnetometer).
SIGNIFICANT_DIGITS = 10
_VALUE_FORMAT = b"%%.%dg" % SIGNIFICANT_DIGITS
_BLOCK_BYTES = 1 << 20
_NA_BYTES = frozenset(value.encode() for value in NA_VALUES)
_NON_SPACE = re.compile(rb"\S+")


def _same_file(first: Path, second: Path) -> bool:
    if os.path.realpath(first) == os.path.realpath(second):  # no error on a link loop
        return True
    try:
        return os.path.samefile(first, second)
    except OSError:
        return False


def write_calibrated(
    source: SampleTable | str | os.PathLike[str],
    calibration: Calibration,
    out_path: str | os.PathLike[str],
    *,
    columns: Sequence[str | int] | None = None,
    normalized: bool = False,
    regressor: NDArray[np.float64] | None = None,
) -> Path:
    """Write ``source`` again with its magnetometer columns calibrated.

    Parameters
    ----------
    source : SampleTable or str or path-like
        The input file, or the table :func:`~magfit.io.read_samples` returned for it (its columns are
        then reused unless ``columns`` is given).
    calibration : magfit.Calibration
        Applied as ``matrix @ (raw - offset)`` to every row whose three values are finite.
    out_path : str or path-like
        The output file; it must not be the input file. Same kind (text, npy, npz) as the input.
    columns : sequence of 3 str or int, optional
        The x, y, z columns (names or 0-based indices); None as in :func:`~magfit.io.read_samples`.
    normalized : bool
        Write values divided by ``field_strength`` (unit sphere) instead of input units.
    regressor : ndarray, shape (N,), optional
        For a calibration with a motor term: the regressor of each data row, in the file's row order
        (``calibration.apply(..., regressor=...)``); a row where it is NaN gets ``nan`` like a non-finite row.

    Returns
    -------
    Path
        ``out_path``.

    Raises
    ------
    DataFileError
        ``out_path`` is the input file; any reading error of :func:`~magfit.io.read_samples`.

    Notes
    -----
    Text values are written with 10 significant digits. Rows whose magnetometer values are NaN,
    infinite or empty get ``nan`` in all three magnetometer columns (their other columns are kept): their
    raw numbers are not calibrated values and must not pass for them.
    """
    if isinstance(source, SampleTable):
        path = source.path
        chosen: Sequence[str | int] | None = columns if columns is not None else source.columns
    else:
        path = check_file(source)
        chosen = columns
    out = Path(out_path)
    if _same_file(path, out):
        suggestion = path.with_name(f"{path.stem}_calibrated{path.suffix}")
        raise DataFileError(
            f"{out}: this is the input file; refusing to overwrite it, write to another name (e.g. {suggestion})"
        )
    reader = ChunkReader(path, columns=chosen)
    kind = reader.format.kind
    rows = _Rows(regressor)
    if kind == "text":
        _write_text(reader, calibration, out, normalized, rows)
    elif kind == "npy":
        _write_npy(reader, calibration, out, normalized, rows)
    else:
        _write_npz(reader, calibration, out, normalized, rows)
    return out


class _Rows:
    """The regressor's values handed out row block by row block, in the order the writers calibrate them."""

    def __init__(self, regressor: NDArray[np.float64] | None) -> None:
        self.values = None if regressor is None else np.asarray(regressor, dtype=np.float64)
        self.position = 0

    def take(self, n: int) -> NDArray[np.float64] | None:
        if self.values is None:
            return None
        if self.position + n > len(self.values):
            raise DataFileError(f"the regressor has {len(self.values)} values, fewer than the file's data rows")
        block = self.values[self.position : self.position + n]
        self.position += n
        return block

    def done(self) -> None:
        """Raise unless every value went to a row (checked before the output is committed)."""
        if self.values is not None and self.position != len(self.values):
            raise DataFileError(
                f"the regressor has {len(self.values)} values and the file {self.position} data rows: they do not "
                "pair row for row"
            )

    def again(self) -> _Rows:
        """A fresh cursor over the same values (an .npz's x, y and z members are each written in one pass)."""
        return _Rows(self.values)


def _calibrate_finite(
    values: NDArray[np.float64], calibration: Calibration, normalized: bool, rows: _Rows | None = None
) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """Calibrated copy of ``values`` (N, 3): rows within ±MAX_MAGNITUDE corrected, the others (NaN, inf, a
    value whose square overflows, all skipped by the readers) all NaN.

    A row with a missing or non-finite value has no corrected value: copying its raw numbers would mix
    raw and calibrated values in the same columns, so all three become NaN.
    """
    finite: NDArray[np.bool_] = np.asarray((np.abs(values) <= MAX_MAGNITUDE).all(axis=1))  # NaN compares False
    regressor = rows.take(len(values)) if rows is not None else None
    if regressor is not None:
        finite &= np.isfinite(regressor)
    result = np.full(np.shape(values), np.nan, dtype=np.float64)
    if finite.any():
        chosen = None if regressor is None else regressor[finite]
        result[finite] = calibration.apply(values[finite], normalized=normalized, regressor=chosen)
    return result, finite


# ---------------------------------------------------------------------------------------------- text


class _TextRewriter:
    """Rewrites the data lines of one text file, block by block, keeping every other byte."""

    def __init__(self, reader: ChunkReader, calibration: Calibration, normalized: bool, rows: _Rows) -> None:
        fmt = reader.format
        self.rows = rows
        assert fmt.delimiter is not None
        self.reader = reader
        self.fmt = fmt
        self.calibration = calibration
        self.normalized = normalized
        self.indices = reader.column_indices
        self.whitespace = fmt.delimiter == "whitespace"
        self.delimiter = b" " if self.whitespace else fmt.delimiter.encode()
        self.split_byte = self.delimiter[:1]
        # One field: quoted parts ("a, b" with "" for a quote) and other bytes, up to the next delimiter.
        other = re.escape(self.split_byte)
        self._quoted_field = re.compile(rb'(?:"(?:[^"]|"")*"|[^"' + other + rb"])*")
        self.encoding = "utf-8" if fmt.encoding == "utf-8-sig" else fmt.encoding

    def _number(self, cell: bytes, line: int, axis: int) -> float:
        text = cell.strip().strip(b'"').strip()
        if text in _NA_BYTES:
            return float("nan")
        try:
            return float(text.replace(b",", b".") if self.fmt.decimal == "," else text)
        except ValueError:
            index = self.indices[axis]
            shown = cell.strip().decode(self.encoding, errors="replace")
            raise file_error(
                self.reader.path,
                f"line {line}, column {self.reader.columns[axis]!r} (column {index + 1}): {shown!r} is not a number; "
                f"fix that cell, or choose other columns with {option('columns', '...')}",
            ) from None

    def _format_all(self, values: NDArray[np.float64]) -> list[bytes]:
        """The text of every value, row by row (one pass: formatting is most of the writer's time)."""
        texts = list(map(_VALUE_FORMAT.__mod__, values.ravel().tolist()))
        if self.fmt.decimal == ",":
            texts = [text.replace(b".", b",") for text in texts]
        return texts

    def _fields(self, body: bytes, line: int) -> tuple[list[bytes], list[tuple[int, int]] | None]:
        """The fields of a line, and for whitespace files their byte spans (to keep the alignment)."""
        if self.whitespace:
            spans = [match.span() for match in _NON_SPACE.finditer(body)]
            fields = [body[start:end] for start, end in spans]
        elif b'"' in body:
            return self._quoted_fields(body, line), None
        else:
            fields = body.split(self.split_byte)
            spans = None
        if len(fields) != self.fmt.n_columns:
            raise self.reader._field_count_error(line, len(fields))
        return fields, spans

    def _quoted_fields(self, body: bytes, line: int) -> list[bytes]:
        """The raw fields of a line with quoted cells (a quoted cell may hold the delimiter), quotes kept."""
        fields, position = [], 0
        while True:
            match = self._quoted_field.match(body, position)
            assert match is not None  # the pattern also matches an empty field
            fields.append(match.group(0))
            position = match.end()
            if position == len(body):
                return fields
            if body[position : position + 1] != self.split_byte:
                raise file_error(
                    self.reader.path,
                    f"line {line}: a quote is not closed or is followed by text ({body[position:][:20]!r}); "
                    "fix the quotes of that line",
                )
            position += 1

    def _parse(self, block: bytes, kept: list[tuple[int, list[bytes], list[tuple[int, int]] | None, bytes, bytes]],
               first_line: int) -> NDArray[np.float64]:  # fmt: skip
        """The magnetometer values of the kept lines: pandas' C parser, as the reader; per cell on trouble."""
        try:
            values = self.reader._parse_block(block)
        except ValueError:
            values = None  # a cell that is not a number: found and named below
        if values is not None and len(values) == len(kept):
            return values
        x, y, z = self.indices
        return np.array(
            [
                (
                    self._number(fields[x], first_line + offset, 0),
                    self._number(fields[y], first_line + offset, 1),
                    self._number(fields[z], first_line + offset, 2),
                )
                for offset, fields, _, _, _ in kept
            ],
            dtype=np.float64,
        )

    def _rewrite_fast(self, block: bytes) -> bytes | None:
        """The common case in a few list passes: one-byte delimiter, no quotes, no blank lines, regular spacing.

        Returns None when the block is not that simple; :meth:`rewrite` then goes line by line.
        """
        if self.whitespace or b'"' in block:
            return None
        crlf = b"\r" in block
        if crlf and block.count(b"\r") != block.count(b"\r\n"):
            return None
        eol = b"\r\n" if crlf else b"\n"
        ended = block.endswith(eol)
        lines = (block[: -len(eol)] if ended else block).split(eol)
        delimiter, n = self.split_byte, self.fmt.n_columns
        codes = np.frombuffer(block, dtype=np.uint8)
        if int(np.count_nonzero(codes == delimiter[0])) != (n - 1) * len(lines):
            return None  # blank lines or a bad row: the slow path skips the former and names the latter
        x, y, z = self.indices
        last = max(x, y, z)
        # Split only up to the last magnetometer column: the rest of the line stays one piece, untouched.
        parts = [line.split(delimiter, last + 1) for line in lines]
        if any(len(f) <= last for f in parts):  # short rows whose missing delimiters another row has too many
            return None
        first = parts[0]
        # The spaces before a magnetometer cell (", " files) are those of the first row, in every row.
        leads = [first[i][: len(first[i]) - len(first[i].lstrip())] for i in (x, y, z)]
        lx, ly, lz = leads
        if any(
            not (f[x].startswith(lx) and f[y].startswith(ly) and f[z].startswith(lz))
            or f[x][-1:].isspace()
            or f[y][-1:].isspace()
            or f[z][-1:].isspace()
            for f in parts
        ):
            return None
        try:
            values = self.reader._parse_block(block)
        except ValueError:
            return None
        if len(values) != len(parts):
            return None
        corrected, _ = _calibrate_finite(values, self.calibration, self.normalized, self.rows)
        texts = self._format_all(corrected)
        for k, fields in enumerate(parts):
            fields[x] = lx + texts[3 * k]
            fields[y] = ly + texts[3 * k + 1]
            fields[z] = lz + texts[3 * k + 2]
        return eol.join([delimiter.join(fields) for fields in parts]) + (eol if ended else b"")

    def rewrite(self, block: bytes, first_line: int) -> bytes:
        fast = self._rewrite_fast(block)
        if fast is not None:
            return fast
        lines = block.split(b"\n")
        kept: list[tuple[int, list[bytes], list[tuple[int, int]] | None, bytes, bytes]] = []
        for offset, raw in enumerate(lines):
            body = raw[:-1] if raw.endswith(b"\r") else raw
            if not body.strip():
                continue
            fields, spans = self._fields(body, first_line + offset)
            kept.append((offset, fields, spans, body, raw[len(body) :]))
        if not kept:
            return block
        corrected, _ = _calibrate_finite(self._parse(block, kept, first_line), self.calibration, self.normalized,
                                         self.rows)  # fmt: skip
        texts = self._format_all(corrected)
        position = 0
        for offset, fields, spans, body, ending in kept:
            new = texts[position : position + 3]
            position += 3
            if spans is not None:
                pieces = bytearray(body)
                for index, text in sorted(zip(self.indices, new, strict=True), reverse=True):
                    start, end = spans[index]
                    pieces[start:end] = text
                lines[offset] = bytes(pieces) + ending
                continue
            for index, text in zip(self.indices, new, strict=True):
                cell = fields[index]
                stripped = cell.strip()
                if stripped[:1] == b'"':  # a quoted number stays quoted
                    text = b'"' + text + b'"'
                if cell[:1].isspace() or cell[-1:].isspace():  # keep the spaces around a cell (", " files)
                    lead = cell[: cell.find(stripped)] if stripped else cell
                    text = lead + text + (cell[len(lead) + len(stripped) :] if stripped else b"")
                fields[index] = text
            lines[offset] = self.split_byte.join(fields) + ending
        return b"\n".join(lines)


def _write_text(reader: ChunkReader, calibration: Calibration, out: Path, normalized: bool, rows: _Rows) -> None:
    rewriter = _TextRewriter(reader, calibration, normalized, rows)
    fmt = reader.format
    with open(reader.path, "rb") as source, atomic_open(out, "wb") as target:
        target.write(source.read(fmt.data_offset))  # byte-order mark, preamble and header, verbatim
        line = fmt.data_line + 1
        while True:
            block = source.read(_BLOCK_BYTES)
            if not block:
                break
            if not block.endswith(b"\n"):
                block += source.readline()
            target.write(rewriter.rewrite(block, line))
            line += block.count(b"\n")
        rows.done()


# ---------------------------------------------------------------------------------------------- npy / npz


def _write_npy(reader: ChunkReader, calibration: Calibration, out: Path, normalized: bool, rows: _Rows) -> None:
    array = np.load(reader.path, mmap_mode="r", allow_pickle=False)
    dtype = np.result_type(array.dtype, np.float64)
    columns = list(reader.column_indices)
    header = {"descr": np.lib.format.dtype_to_descr(dtype), "fortran_order": False, "shape": array.shape}
    with atomic_open(out, "wb") as target:
        np.lib.format.write_array_header_2_0(target, header)
        for start in range(0, array.shape[0], reader.chunk_rows):
            # A copy: for a float64 file ascontiguousarray would return a view of the read-only memory map.
            block = np.array(array[start : start + reader.chunk_rows], dtype=dtype, order="C")
            block[:, columns], _ = _calibrate_finite(block[:, columns], calibration, normalized, rows)
            target.write(block.tobytes(order="C"))
        rows.done()


def _write_npz(reader: ChunkReader, calibration: Calibration, out: Path, normalized: bool, rows: _Rows) -> None:
    """Write the archive again member by member, a chunk of rows at a time: the magnetometer's member(s)
    calibrated, every other member copied byte for byte. Memory stays at a few chunks whatever the size
    (loading every array, as numpy.load does, made a 467 KB archive of 20 million rows take 3.5 GB)."""
    selection = reader._npz
    assert selection is not None
    try:
        with zipfile.ZipFile(reader.path) as archive:
            infos = archive.infolist()
            compressed = any(info.compress_type != zipfile.ZIP_STORED for info in infos)
            method = zipfile.ZIP_DEFLATED if compressed else zipfile.ZIP_STORED
            selected = {f"{key}.npy": axis for axis, key in enumerate(selection.keys)}
            with atomic_open(out, "wb") as target, zipfile.ZipFile(
                target, "w", compression=method, allowZip64=True
            ) as zipped:
                for info in infos:
                    with zipped.open(info.filename, "w", force_zip64=True) as member:
                        if info.filename not in selected:
                            with archive.open(info) as source:
                                while block := source.read(_BLOCK_BYTES):
                                    member.write(block)
                        elif selection.key_columns is None:
                            _write_npz_axis(archive, selection.keys, selected[info.filename], reader, calibration,
                                            normalized, member, rows.again())  # fmt: skip
                        else:
                            _write_npz_matrix(archive, selection.keys[0], list(selection.key_columns), reader,
                                              calibration, normalized, member, rows)  # fmt: skip
    except (zipfile.BadZipFile, zlib.error, *BROKEN_NPY) as error:  # a member damaged past its header
        if isinstance(error, DataFileError):
            raise
        raise file_error(
            reader.path, f"is a damaged .npz archive ({one_line(error)}); re-save it with numpy.savez"
        ) from None


def _write_npz_axis(
    archive: zipfile.ZipFile,
    keys: Sequence[str],
    axis: int,
    reader: ChunkReader,
    calibration: Calibration,
    normalized: bool,
    member: Any,
    rows: _Rows,
) -> None:
    """One of three 1-D members (x, y or z), calibrated: the three read together, a chunk at a time."""
    streams = [NpyStream(archive, key, reader.chunk_rows) for key in keys]
    try:
        total = int(streams[0].shape[0])
        descr = np.lib.format.dtype_to_descr(np.dtype(np.float64))
        np.lib.format.write_array_header_2_0(member, {"descr": descr, "fortran_order": False, "shape": (total,)})
        for _ in range(0, total, reader.chunk_rows):
            raw = np.column_stack([np.asarray(stream.next_rows(), dtype=np.float64) for stream in streams])
            corrected, _ = _calibrate_finite(raw, calibration, normalized, rows)
            member.write(np.ascontiguousarray(corrected[:, axis]).tobytes())
        rows.done()
    finally:
        for stream in streams:
            stream.close()


def _write_npz_matrix(
    archive: zipfile.ZipFile,
    key: str,
    columns: list[int],
    reader: ChunkReader,
    calibration: Calibration,
    normalized: bool,
    member: Any,
    rows: _Rows,
) -> None:
    """The (N, k) member holding the magnetometer's columns, those calibrated, a chunk of rows at a time."""
    stream = NpyStream(archive, key, reader.chunk_rows)
    try:
        shape = tuple(int(n) for n in stream.shape)
        dtype = np.result_type(stream.dtype, np.float64)
        header = {"descr": np.lib.format.dtype_to_descr(dtype), "fortran_order": False, "shape": shape}
        np.lib.format.write_array_header_2_0(member, header)
        for _ in range(0, shape[0], reader.chunk_rows):
            block = np.array(stream.next_rows(), dtype=dtype, order="C")
            block[:, columns], _ = _calibrate_finite(block[:, columns], calibration, normalized, rows)
            member.write(block.tobytes(order="C"))
        rows.done()
    finally:
        stream.close()
