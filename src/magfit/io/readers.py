"""Reading magnetometer samples from delimited text, ``.npy`` and ``.npz`` files: the entry points.

:func:`read_samples` reads a whole file into a :class:`SampleTable`; :func:`iter_sample_chunks` reads it in
chunks of bounded size. The work is done by one module per job:

- :mod:`magfit.io.sources` — where the bytes come from (standard input, a pipe, a compressed file);
- :mod:`magfit.io.layout` — the layout sniffed from the head (:class:`FileFormat`, :func:`sniff`);
- :mod:`magfit.io.npy` — ``.npy`` / ``.npz`` headers and members;
- :mod:`magfit.io.columns` and :mod:`magfit.io.selection` — which three columns hold the magnetometer;
- :mod:`magfit.io.chunks` — the rows, read in chunks (:class:`ChunkReader`), in pieces on several threads.

Every problem with a file is a :class:`~magfit.DataFileError` whose one-line message names the file, the
line and the column when there is one, and says what to do.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from .._validation import MAX_MAGNITUDE
from ..remedy import option
from .chunks import ChunkReader, PiecesRead, read_pieces
from .layout import FileFormat, sniff
from .sources import display_name, file_error

__all__ = [
    "ChunkReader",
    "FileFormat",
    "PiecesRead",
    "SampleTable",
    "iter_sample_chunks",
    "read_pieces",
    "read_samples",
    "sniff",
]


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
        counter``); for the columns of a known converter, which one and what the firmware did to the field
        (``ArduPilot DataFlash MAG (mavlogdump --format csv), mG; logged after ...``); None otherwise.
    unit : str or None
        The samples' unit as the column names state it (``mag_x_uT``, ``MagX (mG)``) or as the converter that
        wrote them defines it (``magnetometer_ga[0]``: gauss), named as :mod:`magfit.units` names it; None
        when the file does not say.
    sensor : str or None
        The magnetometer read in a file that interleaves several (``I=1``); None otherwise.
    """

    path: Path
    samples: NDArray[np.float64]
    columns: tuple[str, str, str]
    n_rows: int
    n_skipped: int
    skipped_lines: tuple[int, ...]
    format: FileFormat
    column_note: str | None = None
    unit: str | None = None
    sensor: str | None = None


def iter_sample_chunks(
    path: str | os.PathLike[str],
    *,
    columns: Sequence[str | int] | None = None,
    nonfinite: Literal["skip", "error"] = "skip",
    chunk_rows: int = 1_000_000,
    sensor: str | None = None,
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
    sensor : str, optional
        The magnetometer to read in a file that interleaves several (see :func:`read_samples`).

    Returns
    -------
    ChunkReader
        An iterable of (n, 3) float64 arrays; after the iteration its ``n_rows``, ``n_skipped`` and
        ``skipped_lines`` are complete.
    """
    return ChunkReader(path, columns=columns, nonfinite=nonfinite, chunk_rows=chunk_rows, sensor=sensor)


def read_samples(
    path: str | os.PathLike[str],
    *,
    columns: Sequence[str | int] | None = None,
    nonfinite: Literal["skip", "error"] = "skip",
    progress: Callable[[int], object] | None = None,
    sensor: str | None = None,
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
        Rows with a NaN, infinite or empty magnetometer value, or one beyond ±1e150 (whose square overflows
        float64: no magnetometer reads it), are dropped and counted (``"skip"``), or the first one raises
        (``"error"``).
    progress : callable, optional
        Called with the number of rows of each chunk read (finite ones; from several threads for a large
        text file), e.g. to advance a progress bar.
    sensor : str, optional
        In a text file whose rows come from several magnetometers, told apart by a column such as
        mavlogdump's ``I``, ``device_id``, ``instance`` or ``sensor_id`` (:mod:`magfit.io.instances`): the one
        to read, ``"I=1"`` (or ``"1"``). Such a file is refused without it, naming the column and the ids.

    Returns
    -------
    SampleTable
        The finite samples, shape (N, 3), in the file's units, and the bookkeeping of the read.

    Raises
    ------
    DataFileError
        Missing, unreadable or empty file; a header without rows; a cell that is not a number; a row with
        another number of fields; magnetometer columns not found or ambiguous; a column name or index that
        is not in the file; fewer than three columns; every row non-finite; rows of several magnetometers
        and no ``sensor`` chosen, or a ``sensor`` the file does not hold.
    """
    reader = ChunkReader(path, columns=columns, nonfinite=nonfinite, chunk_rows=1_000_000, sensor=sensor)
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
        raise reader.no_rows_error()
    if len(samples) == 0:
        raise file_error(
            reader.path,
            f"all {read.n_rows} rows have no usable value in {', '.join(reader.columns)}: NaN, infinite, empty, or "
            f"beyond ±{MAX_MAGNITUDE:g} (more than float64 can square) "
            f"(first at line {read.skipped_lines[0]}); check the columns ({option('columns', '...')})",
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
        unit=reader.unit,
        sensor=reader.sensor,
    )
