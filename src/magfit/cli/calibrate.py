"""``magfit calibrate``: fit one recording, print the calibration, save it as JSON or a firmware format."""

from __future__ import annotations

import datetime
import itertools
import os
import shutil
import sys
import tempfile
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from dataclasses import dataclass, replace
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any, Protocol

import click
import numpy as np
from numpy.typing import NDArray
from rich.console import Console

from ..calibration import CONVENTION, Calibration
from ..errors import CalibrationError, DataFileError, MagfitError
from ..evaluate import Evaluation, evaluate
from ..fit import fit
from ..geomag import Field, compare_fitted, field_at, parse_date, parse_location
from ..methods import get_method
from ..statistics import Statistics
from ..units import conversion_factor, get_unit
from ._common import (
    FieldStrength,
    Nonfinite,
    RegistryChoice,
    columns_text,
    console,
    default_method,
    export_format_names,
    fail,
    fixed,
    geomag_option,
    method_names,
    nonfinite_option,
    parse_columns,
    refuse_overwriting_input,
    same_file,
    significant,
    vector,
    warn,
)
from ._extras import require
from ._wording import columns_used, without_own_advice

if TYPE_CHECKING:
    from ..io import ChunkReader, FileFormat

#: Reports progress: called with the number of rows just processed.
Advance = Callable[[int], None]

#: Rows per chunk when streaming. Measured on a 4-million-row CSV: peak memory 204 MB with 250 000 rows
#: against 329 MB with the reader's default of 1 000 000 (153 MB for a tiny file), at the same CPU time.
STREAM_CHUNK_ROWS = 250_000
#: Most rows a streamed fit keeps for its diagnostics (2.4 MB); more only sharpen the uncertainty figures.
DIAGNOSE_SAMPLES = 100_000
#: Memory an iterative fit (ml, robust, auto) needs per sample, all told: the float64 samples (24 bytes),
#: the reader's parse of the whole file (about 60 with pandas) and the method's working arrays (up to
#: about 90, robust on 1 M samples). A file estimated above half the available memory at this rate is
#: fitted on an even subsample (docs/scaling.md).
BYTES_PER_FIT_SAMPLE = 256
#: ... and never more than this many samples: auto's own fits use a stride of at most 200 000 of them and
#: ml fits a million in about a second; more only costs memory (a 10-million-row CSV fitted whole by auto
#: peaked at 675 MB; on an even subsample of a million at 310 MB; the issue-10 target is 300 MB).
DEFAULT_FIT_SAMPLES = 500_000


@dataclass(frozen=True, eq=False)
class CalibrationRun:
    """What ``calibrate`` did: the calibration, its score and what was read from the file.

    Attributes
    ----------
    path : Path
        The recording.
    calibration : Calibration
        The fit (labelled with ``--unit`` when given).
    evaluation : Evaluation
        The paper's sphere-distance metric over every sample read (dimensionless).
    columns : tuple
        The three columns used (names, or 0-based indices for files without a header).
    n_rows, n_skipped : int
        Data rows in the file, and rows skipped because a value was NaN or infinite.
    skipped_lines : tuple of int
        Line numbers (1-based) of skipped rows, as reported by the reader (possibly only the first few).
    file_format : str
        The layout the reader found (``FileFormat.describe()``: delimiter, header, preamble ...).
    streamed : bool
        True when the file was read in chunks (a method that needs only the statistics).
    subsample : str or None
        None when the fit used every sample; else why it used an even subsample (``--even``, or a file
        too large for memory), ``calibration.n_samples`` being how many.
    column_note : str or None
        For a file without a header, why these columns (``column 1 is monotonic: time or a counter``).
    """

    path: Path
    calibration: Calibration
    evaluation: Evaluation
    columns: tuple[Any, ...]
    n_rows: int
    n_skipped: int
    skipped_lines: tuple[int, ...]
    file_format: str
    streamed: bool
    subsample: str | None = None
    column_note: str | None = None


class _ReadResult(Protocol):
    """The part of magfit.io's SampleTable / ChunkReader that ``calibrate`` reports."""

    @property
    def n_rows(self) -> int: ...
    @property
    def n_skipped(self) -> int: ...
    @property
    def skipped_lines(self) -> Sequence[int]: ...
    @property
    def columns(self) -> Sequence[Any]: ...
    @property
    def format(self) -> Any: ...


def run_calibration(
    path: Path,
    *,
    method: str,
    columns: Sequence[str | int] | None = None,
    nonfinite: Nonfinite = "skip",
    unit: str | None = None,
    even: bool = False,
    max_samples: int | None = None,
    options: Mapping[str, Any] | None = None,
    allow_undetermined: bool = False,
    sensor: str | None = None,
) -> CalibrationRun:
    """Read ``path``, fit ``method`` and score the fit; memory stays bounded for streaming methods.

    Methods whose ``METHODS[method].data`` is ``"statistics"`` read the file in chunks into a
    :class:`~magfit.Statistics` (a first pass), fit, then score the fit in a second pass over the chunks:
    only one chunk is ever in memory. Methods that need the samples load the whole file when it fits in
    memory (at most ``max_samples`` rows, default :func:`memory_sample_limit`), and otherwise stream it
    and fit a spatially even subsample of ``max_samples`` rows. ``even`` fits the even subsample of
    :func:`magfit.sampling.even_subsample` (every direction weighs the same) with any method. ``options``
    are the method's keyword options (e.g. ``field_strength``), passed to :func:`magfit.fit`;
    ``allow_undetermined`` (``--force``) returns a calibration the samples do not support, marked so.
    """
    from ..io import ChunkReader
    from ..sources import log_kind

    spec = get_method(method)
    options = dict(options or {})
    if allow_undetermined:  # fit's own keyword, passed with the method's options
        options["allow_undetermined"] = True
    if log_kind(path) is not None:  # a flight log: one compass's samples, read through magfit.sources
        return _run_log(path, sensor, method, options, unit=unit, even=even)
    if sensor is not None:
        raise DataFileError(f"{path}: --sensor chooses a compass of a flight log or bag (ULog, DataFlash, ROS)")
    limit = memory_sample_limit() if max_samples is None else max_samples
    subsample = "--even" if even else None
    # The columns first (cheap: the file's head): every message, a refusal too, says which were used.
    chosen = ChunkReader(path, columns=columns, nonfinite=nonfinite)  # not iterated: layout and columns only
    try:
        if spec.data == "statistics" and not even:
            calibration, evaluation, read = _fit_streaming(path, method, columns, nonfinite, options)
            streamed = True
        elif _estimated_rows(path) <= limit:
            calibration, evaluation, read = _fit_in_memory(path, method, columns, nonfinite, options, even=even)
            streamed = False
        else:
            calibration, evaluation, read, limited = _fit_subsample(
                path, method, columns, nonfinite, options, even=even, limit=limit
            )
            streamed = True
            if limited:
                bound = f"the file has more rows than --max-samples {limit}"
                if max_samples is None:
                    default = f"{DEFAULT_FIT_SAMPLES:,}".replace(",", " ")
                    bound += f", the default: {default} or half the available memory"
                subsample = f"--even; {bound}" if even else bound
    except CalibrationError as error:
        raise CalibrationError(f"{path} ({columns_used(chosen.columns, chosen.column_note)}): {error}") from None
    if unit is not None:
        calibration = calibration.with_unit(unit)
    # Where the samples came from, so that `magfit apply` reads the same columns (details["source"]).
    source = {
        "file": path.name,
        "columns": list(chosen.columns),
        "column_indices": list(chosen.column_indices),
        "header": chosen.format.header is not None,
        "n_columns": chosen.format.n_columns,
        "unit": unit if unit is not None else calibration.unit,
    }
    calibration = replace(calibration, details={**calibration.details, "source": source})
    return CalibrationRun(
        path=path,
        calibration=calibration,
        evaluation=evaluation,
        columns=tuple(read.columns),
        n_rows=int(read.n_rows),
        n_skipped=int(read.n_skipped),
        skipped_lines=tuple(int(line) for line in read.skipped_lines),
        file_format=_how_read(path) + read.format.describe(),
        streamed=streamed,
        subsample=subsample,
        column_note=chosen.column_note,
    )


def _several_compasses(path: Path) -> list[str]:
    """The ids of a log's magnetometers that can be fitted, when there are several; else an empty list."""
    if not _is_log(path):
        return []
    from ..sources import open_source

    source = open_source(path, everything=False)
    usable = [m.id for m in source.magnetometers if m.problem is None and m.n_samples > 0]
    return usable if len(usable) > 1 else []


def _calibrate_each(
    file: Path,
    sensors: Sequence[str],
    method: str,
    unit: str | None,
    even: bool,
    max_samples: int | None,
    options: Mapping[str, Any],
    force: bool,
    model: tuple[Field, str | None] | None,
) -> None:
    """Fit every compass of a log, one summary each (its 'file' line names the compass); exit 1 if one failed."""
    out = console()
    failed = []
    for index, sensor in enumerate(sensors):
        if index:
            out.print("")
        try:
            run = run_calibration(
                file,
                method=method,
                unit=unit,
                even=even,
                max_samples=max_samples,
                options=options,
                allow_undetermined=force,
                sensor=sensor,
            )
        except CalibrationError as error:
            failed.append(sensor)
            warn(str(error))
            out.print(f"{'sensor':<16} {sensor}: not fitted (the warning above says why)")
            continue
        for message in _fit_warnings(run.calibration):
            warn(without_own_advice(message, run.calibration.method))
        print_summary(out, run)
        if model is not None:
            _print_model_field(out, run.calibration, *model)
    if failed:
        raise CalibrationError(
            f"{file}: {len(failed)} of {len(sensors)} magnetometers could not be fitted ({', '.join(failed)}); the "
            "warnings above say why"
        )


def _is_log(path: Path) -> bool:
    from ..sources import log_kind

    return log_kind(path) is not None


def _run_log(
    path: Path, sensor: str | None, method: str, options: Mapping[str, Any], *, unit: str | None, even: bool
) -> CalibrationRun:
    """Fit one magnetometer of a flight log (docs/file-formats.md): its raw field, read by magfit.sources."""
    from ..sources import open_source

    source = open_source(path, everything=False)  # the magnetometers only: what is logged beside is for inspect
    read = source.read(sensor)
    chosen = read.magnetometer
    for note in (*source.notes, *read.notes):
        warn(f"{path} ({chosen.id}): {note}")
    where = f"{path} ({chosen.id}, {chosen.description})"
    if len(read.samples) == 0:
        raise DataFileError(f"{where}: holds no finite samples")
    try:
        calibration = fit(_samples_for_fit(read.samples, even), method=method, **options)
    except CalibrationError as error:
        advice = "".join(f"; {note}" for note in chosen.notes if "logged at only" in note or "only " in note)
        raise CalibrationError(f"{where}: {error}{advice}") from None
    calibration = calibration.with_unit(unit or chosen.unit) if (unit or chosen.unit) else calibration
    source_details = {"file": path.name, "sensor": chosen.id, "device_id": chosen.device_id, "unit": calibration.unit}
    calibration = replace(calibration, details={**calibration.details, "source": source_details})
    span = f"{chosen.span_s:.1f} s" if np.isfinite(chosen.span_s) else "no time stamps"
    return CalibrationRun(
        path=path,
        calibration=calibration,
        evaluation=evaluate(calibration, read.samples),
        columns=read.columns,
        n_rows=len(read.samples),
        n_skipped=0,
        skipped_lines=(),
        file_format=f"{source.format}; {chosen.id}: {chosen.description}, {span}",
        streamed=False,
        subsample="--even" if even else None,
    )


def _how_read(path: Path) -> str:
    """``"gzip-compressed; "`` (or ``standard input``, ``a pipe``) before the layout; empty for a plain file."""
    from ..io.sources import describe_source

    how = describe_source(path)
    return f"{how}; " if how else ""


def memory_sample_limit() -> int:
    """Most samples an iterative fit holds: :data:`DEFAULT_FIT_SAMPLES`, or half the available memory at
    :data:`BYTES_PER_FIT_SAMPLE` each when that is less."""
    available = 4 << 30  # when the system does not say
    try:
        with open("/proc/meminfo", encoding="ascii") as meminfo:
            for line in meminfo:
                if line.startswith("MemAvailable:"):
                    available = int(line.split()[1]) * 1024
                    break
    except (OSError, ValueError):
        try:
            available = os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
        except (ValueError, OSError, AttributeError):
            pass
    return min(DEFAULT_FIT_SAMPLES, max(100_000, available // 2 // BYTES_PER_FIT_SAMPLE))


def _estimated_rows(path: Path) -> int:
    """Data rows in ``path``, estimated without reading it all: exact for npy, from the line lengths for text."""
    from ..io import sniff
    from ..io.sources import data_file

    file = data_file(path)  # standard input, a pipe or a compressed file: their decompressed copy
    return _rows_in(file, sniff(file))


def _rows_in(path: Path, fmt: FileFormat) -> int:
    """:func:`_estimated_rows` for a file whose layout is known."""
    if fmt.kind == "npy":
        return int(np.load(path, mmap_mode="r").shape[0])
    if fmt.kind == "npz":  # an upper bound: every member, uncompressed, as float64 triples
        import zipfile

        with zipfile.ZipFile(path) as archive:
            return sum(info.file_size for info in archive.infolist()) // 24
    size = path.stat().st_size - fmt.data_offset
    with open(path, "rb") as handle:
        handle.seek(fmt.data_offset)
        head = handle.read(1 << 20)
    return int(size * max(head.count(b"\n"), 1) / max(len(head), 1))


def _fit_in_memory(
    path: Path,
    method: str,
    columns: Sequence[str | int] | None,
    nonfinite: Nonfinite,
    options: Mapping[str, Any],
    *,
    even: bool = False,
) -> tuple[Calibration, Evaluation, _ReadResult]:
    from ..io import read_samples

    with _progress(f"reading {path.name}", lambda: _estimated_rows(path)) as advance:
        table = read_samples(path, columns=columns, nonfinite=nonfinite, progress=advance)
    _require_rows(path, table.samples.shape[0], table)
    samples = _samples_for_fit(table.samples, even)
    calibration = fit(samples, method=method, **options)
    return calibration, evaluate(calibration, table.samples), table


def _samples_for_fit(samples: NDArray[np.float64], even: bool) -> NDArray[np.float64]:
    """The samples the fit uses: all of them, or with ``--even`` the even subsample (docs/scaling.md).

    The score is still computed on every sample.
    """
    if not even:
        return samples
    from ..sampling import even_subsample

    return samples[even_subsample(samples)]


def _fit_subsample(
    path: Path,
    method: str,
    columns: Sequence[str | int] | None,
    nonfinite: Nonfinite,
    options: Mapping[str, Any],
    *,
    even: bool,
    limit: int,
) -> tuple[Calibration, Evaluation, _ReadResult, bool]:
    """Stream a file too large for memory: statistics, an even subsample of at most ``limit`` rows, fit, score.

    The last item returned is true when ``limit`` thinned the samples (not only ``even``).

    The directions of the subsample start from the ellipsoid fit of the whole file's statistics
    (:func:`magfit.sampling.direction_frame`); without ``even`` the cells are capped only as far as
    ``limit`` requires, so the densest directions give way first (:func:`magfit.sampling.even_subsample_chunks`).
    """
    from ..compare import evaluate_chunks
    from ..io import iter_sample_chunks
    from ..sampling import direction_frame, even_subsample_chunks

    def chunks() -> ChunkReader:
        return iter_sample_chunks(path, columns=columns, nonfinite=nonfinite, chunk_rows=STREAM_CHUNK_ROWS)

    with _FirstPass(chunks) as first:
        statistics, reader, source = first.statistics, first.read, first.source
        _require_rows(path, statistics.n, reader)
        centre, shape = direction_frame(statistics)
        with _progress(f"sampling {path.name} evenly") as advance:
            sampler = even_subsample_chunks(
                lambda: _counted(source(), advance), centre=centre, shape=shape, max_samples=limit, cap_at_median=even
            )
        calibration = fit(sampler.samples, method=method, **options)
        with _progress(f"scoring the fit on {path.name}", statistics.n) as advance:
            evaluation = evaluate_chunks(calibration, _counted(source(), advance))
    limited = sampler.max_samples == limit and len(sampler.indices) < statistics.n
    return calibration, evaluation, reader, limited


class _FirstPass:
    """Pass 1 over a file: its :class:`~magfit.Statistics`, and the samples spilled for the later passes.

    A large text file is cut into pieces at line ends, one per core (``ChunkReader.parallel_pieces``),
    read on threads: pandas parses without holding the GIL, and the pieces' statistics merge exactly
    (``Statistics.merge``), so the result is that of one reader, in about half the time on two cores.
    Errors come as one reader would raise them: the first piece's first.
    """

    def __init__(self, chunks: Callable[[], ChunkReader]) -> None:
        from ..io.readers import PiecesRead

        self._chunks = chunks
        self._pieces = chunks().parallel_pieces()
        self._spills = [_Spill(piece) for piece in self._pieces]
        self.statistics = Statistics()
        self.read = PiecesRead(self._pieces)

    def __enter__(self) -> _FirstPass:
        from ..io.readers import read_pieces
        from ..io.sources import display_name

        try:
            reader = self._pieces[0]
            name = Path(display_name(reader.path)).name  # not the name of a decompressed temporary copy
            with _progress(f"reading {name}", lambda: _rows_in(reader.path, reader.format)) as advance:
                parts = read_pieces(
                    self._pieces,
                    lambda piece, stopped: self._read(piece, self._spills[self._pieces.index(piece)], advance, stopped),
                )
        except BaseException:
            self.__exit__()
            raise
        self.statistics = sum(parts, Statistics())
        return self

    def __exit__(self, *exc: object) -> None:
        for spill in self._spills:
            spill.close()

    @staticmethod
    def _read(piece: ChunkReader, spill: _Spill, advance: Advance, stopped: Callable[[], bool]) -> Statistics:
        statistics = Statistics()
        for chunk in piece:
            if stopped():  # an earlier piece failed: its error is what the user sees
                break
            statistics.update(chunk)
            spill.write(chunk)
            advance(len(chunk))
        return statistics

    def score(self, calibration: Calibration, advance: Advance) -> tuple[Evaluation, NDArray[np.float64]]:
        """The paper's metric over every sample, and at most :data:`DIAGNOSE_SAMPLES` rows evenly strided.

        Spilled pieces are scored on threads (NumPy computes without the GIL) and their metrics pooled.
        """
        from ..compare import evaluate_chunks

        total = self.statistics.n
        spills = [spill for spill in self._spills if spill.rows]
        if len(spills) < 2 or not all(spill.complete for spill in self._spills):
            strided = _Strided(total, DIAGNOSE_SAMPLES)
            return evaluate_chunks(calibration, strided.collect(_counted(self.source(), advance))), strided.samples()
        offsets = np.cumsum([0] + [spill.rows for spill in spills[:-1]])

        def one(spill: _Spill, offset: int) -> tuple[Evaluation, NDArray[np.float64]]:
            strided = _Strided(total, DIAGNOSE_SAMPLES)
            strided.seen = offset  # rows of the earlier pieces: the stride continues across pieces
            return evaluate_chunks(calibration, strided.collect(_counted(spill.chunks(), advance))), strided.samples()

        with ThreadPoolExecutor(len(spills)) as pool:
            parts = list(pool.map(one, spills, (int(offset) for offset in offsets)))
        return _pooled([part[0] for part in parts]), np.concatenate([part[1] for part in parts])

    def source(self) -> Iterator[NDArray[np.float64]]:
        """The samples again, in file order: from the spills, or by reading the file once more."""
        if all(spill.complete for spill in self._spills):
            return itertools.chain.from_iterable(spill.chunks() for spill in self._spills)
        return iter(self._chunks())


def _pooled(parts: Sequence[Evaluation]) -> Evaluation:
    """The metric of the union of disjoint sample sets, from each set's (exact up to round-off)."""
    n = sum(part.n for part in parts)
    weights = np.array([part.n / n for part in parts])
    means = np.array([part.mean for part in parts])
    mean = float(weights @ means)
    variance = float(weights @ (np.array([part.std for part in parts]) ** 2 + (means - mean) ** 2))
    return Evaluation(
        n=n,
        mean=mean,
        std=float(np.sqrt(variance)),
        mean_abs=float(weights @ np.array([part.mean_abs for part in parts])),
        rms=float(np.sqrt(weights @ np.array([part.rms for part in parts]) ** 2)),
        max_abs=max(part.max_abs for part in parts),
    )


class _Spill:
    """The samples of a first pass over a text file, kept as raw float64 in a temporary file.

    Later passes (scoring, sampling) read 24 bytes a row back instead of parsing the text again, which is
    most of the time of a pass. Only for text files (npy/npz are read as fast as the spill), and only
    while the temporary folder has room for it: when a write fails the passes read the file again.
    """

    def __init__(self, reader: ChunkReader) -> None:
        self.complete = reader.format.kind == "text"
        self.rows = 0
        self._file: IO[bytes] | None = None
        if self.complete:
            room = shutil.disk_usage(tempfile.gettempdir()).free
            self.complete = _rows_in(reader.path, reader.format) * 24 < room // 2
        if self.complete:
            self._file = tempfile.TemporaryFile()

    def __enter__(self) -> _Spill:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        if self._file is not None:
            self._file.close()

    def write(self, chunk: NDArray[np.float64]) -> None:
        if not self.complete or self._file is None:
            return
        try:
            self._file.write(np.ascontiguousarray(chunk, dtype=np.float64).data)  # no copy to bytes
            self.rows += len(chunk)
        except OSError:  # the disk filled up: the later passes read the file again
            self.complete = False

    def chunks(self) -> Iterator[NDArray[np.float64]]:
        assert self._file is not None
        self._file.seek(0)
        while block := self._file.read(STREAM_CHUNK_ROWS * 24):
            yield np.frombuffer(block, dtype=np.float64).reshape(-1, 3)


def _fit_streaming(
    path: Path, method: str, columns: Sequence[str | int] | None, nonfinite: Nonfinite, options: Mapping[str, Any]
) -> tuple[Calibration, Evaluation, _ReadResult]:
    from ..io import iter_sample_chunks

    def chunks() -> ChunkReader:
        return iter_sample_chunks(path, columns=columns, nonfinite=nonfinite, chunk_rows=STREAM_CHUNK_ROWS)

    # Pass 1: the sufficient statistics of eq. (4), one chunk at a time (a text file's samples are spilled
    # to a temporary binary file on the way, so that pass 2 does not parse the text again).
    with _FirstPass(chunks) as first:
        statistics, reader = first.statistics, first.read
        _require_rows(path, statistics.n, reader)
        calibration = fit(statistics, method=method, **options)
        # Pass 2: the paper's metric needs the final calibration, so the samples are read again; on the way,
        # keep an evenly strided subsample (bounded) for the diagnostics, which need samples, not statistics.
        with _progress(f"scoring the fit on {path.name}", statistics.n) as advance:
            evaluation, subsample = first.score(calibration, advance)
    forced = bool(options.get("allow_undetermined", False))
    return _with_diagnostics(calibration, subsample, statistics.n, forced), evaluation, reader


def _counted(chunks: Iterable[NDArray[np.float64]], advance: Advance) -> Iterator[NDArray[np.float64]]:
    for chunk in chunks:
        advance(len(chunk))
        yield chunk


class _Strided:
    """Every k-th row of a stream of chunks, k chosen from the known total so that at most ``cap`` are kept."""

    def __init__(self, total: int, cap: int) -> None:
        self.step = max(1, -(-total // cap))  # ceil(total / cap)
        self.seen = 0
        self.kept: list[NDArray[np.float64]] = []

    def collect(self, chunks: Iterable[NDArray[np.float64]]) -> Iterator[NDArray[np.float64]]:
        for chunk in chunks:
            first = (-self.seen) % self.step  # index in this chunk of the next row to keep
            self.kept.append(np.array(chunk[first :: self.step], dtype=np.float64))
            self.seen += len(chunk)
            yield chunk

    def samples(self) -> NDArray[np.float64]:
        return np.concatenate(self.kept) if self.kept else np.empty((0, 3))


def _with_diagnostics(
    calibration: Calibration, subsample: NDArray[np.float64], n_total: int, allow_undetermined: bool = False
) -> Calibration:
    """``calibration`` with :func:`magfit.diagnose` of the strided subsample in ``details["diagnostics"]``,
    and its verdict in ``details["support"]``.

    A fit from Statistics carries no coverage or uncertainty (they need samples); the stream provides
    them. Above :data:`DIAGNOSE_SAMPLES` rows the uncertainty is that of the subsample: conservative. The
    samples' verdict is the one an in-memory fit reaches: a refusal raises, unless ``allow_undetermined``
    (``--force``), which returns the calibration marked as forced, as :func:`magfit.fit` does.
    """
    from ..fit import diagnose

    try:
        report = diagnose(calibration, subsample)
    except (MagfitError, np.linalg.LinAlgError) as error:  # the fit stands; say why there is no diagnosis
        return replace(
            calibration,
            details={**calibration.details, "diagnostics_error": f"the diagnostics could not be computed: {error}"},
        )
    if subsample.shape[0] < n_total:
        note = (
            f"Streamed: diagnosed on one row in {-(-n_total // subsample.shape[0])} ({subsample.shape[0]} of "
            f"{n_total}); the uncertainty is that of the subsample (conservative)."
        )
        report = replace(report, notes=(*report.notes, note))
    details = {**calibration.details}
    support = report.support
    if support is not None:
        if support.verdict == "refused":
            if not allow_undetermined:
                raise CalibrationError(support.message(calibration.method))
            support = replace(support, forced=True)
            report = replace(report, support=support, warnings=support.warnings)
        details["support"] = support.to_dict()
    details["diagnostics"] = report.to_dict()
    return replace(calibration, details=details)


def _require_rows(path: Path, n_samples: int, read: _ReadResult) -> None:
    if n_samples > 0:
        return
    if read.n_skipped:
        raise DataFileError(
            f"{path}: all {read.n_skipped} data rows hold NaN or inf values; nothing is left to calibrate"
        )
    raise DataFileError(f"{path}: the file holds no data rows")


@contextmanager
def _progress(description: str, total: int | Callable[[], int] | None = None) -> Iterator[Advance]:
    """A progress bar on stderr, shown only when stderr is a terminal; yields ``advance(rows)``.

    ``total`` (rows, or a function that estimates them, called only when a bar is drawn) draws a bar
    with the percentage and the time left; without it, a spinner and the rows counted.
    """
    if not sys.stderr.isatty():
        yield lambda rows: None  # no terminal to draw on: a log or a pipe gets no progress noise
        return
    if callable(total):
        total = total()
    from rich.progress import (
        BarColumn,
        Progress,
        SpinnerColumn,
        TaskProgressColumn,
        TextColumn,
        TimeElapsedColumn,
        TimeRemainingColumn,
    )

    measured = (BarColumn(), TaskProgressColumn(), TimeRemainingColumn()) if total else ()
    with Progress(
        SpinnerColumn(),
        TextColumn("{task.description}"),
        *measured,
        TextColumn("{task.completed:,} rows"),
        TimeElapsedColumn(),
        console=console(stderr=True),
        transient=True,
    ) as progress:
        task = progress.add_task(description, total=total or None)
        yield lambda rows: progress.advance(task, rows)


def render_output(
    run: CalibrationRun, export_format: str | None, unit: str | None, system_id: int | None = None
) -> str:
    """The text of the calibration: its JSON, or the firmware export (``system_id``: PX4's, for ``px4``)."""
    if export_format is not None:
        from ..export import export

        return export(run.calibration, export_format, unit=unit, system_id=system_id)
    return run.calibration.to_json() + "\n"


def check_outputs(file: Path, output: Path | None, plot_path: Path | None) -> None:
    """Refuse, before the fit, outputs that would clobber the input or each other, or cannot be written."""
    from ..io import STDOUT, check_output

    outputs = [path for path in (output, plot_path) if path is not None]
    for path in outputs:
        if str(path) != STDOUT:
            refuse_overwriting_input(path, [file])
        check_output(path)
    if output is not None and plot_path is not None and str(output) != STDOUT and same_file(output, plot_path):
        fail(f"-o and --plot are the same file {output}; give each its own path")


@click.command("calibrate")
@click.argument("file", type=click.Path(path_type=Path))
@click.option(
    "-m",
    "--method",
    type=RegistryChoice("method", method_names),
    default=None,
    help="Calibration method (default: auto when available, else ellipsoid).",
)
@click.option(
    "--columns",
    callback=parse_columns,
    metavar="X,Y,Z",
    help="The three magnetometer columns: names (mx,my,mz) or 0-based numbers (3,4,5). Default: detected.",
)
@click.option(
    "-o",
    "--output",
    type=click.Path(dir_okay=False, path_type=Path),
    help="Write the calibration here (JSON, or the --export format), replacing the file atomically; - for stdout.",
)
@click.option(
    "--export",
    "export_format",
    type=RegistryChoice("format", export_format_names),
    help="Write a firmware format instead of JSON: to -o, or to stdout without -o.",
)
@click.option("--unit", help="Name of the input unit (uT, mG, counts ...), stored in the calibration and exports.")
@nonfinite_option
@click.option(
    "--field-strength",
    type=FieldStrength(),
    default=None,
    metavar="NUMBER|wmm",
    help="Known magnitude of the local field, in the samples' unit, or 'wmm' for the World Magnetic Model's at "
    "--location (or at a ROS bag's own GNSS fixes; needs the samples' unit): the corrected field is scaled to it, "
    "and the sphere fit pins its radius to it (see docs/methods.md).",
)
@click.option(
    "--location",
    callback=geomag_option(parse_location),
    metavar="LAT,LON[,ALT]",
    help="Where the recording was made (degrees; ALT in km above the WGS-84 ellipsoid, or 500m): the World Magnetic "
    "Model's field is printed beside the fitted one, with a warning when they differ by more than 10 %.",
)
@click.option(
    "--date",
    "model_date",
    callback=geomag_option(parse_date),
    metavar="YYYY-MM-DD",
    help="When the recording was made, for the World Magnetic Model (default: today).",
)
@click.option(
    "--even",
    is_flag=True,
    help="Fit an even subsample: every direction weighs the same, so a long stay in one attitude does not "
    "pull the fit (see docs/scaling.md). The score still uses every sample.",
)
@click.option(
    "--max-samples",
    type=click.IntRange(min=10),
    default=None,
    help="Most samples an iterative method (ml, robust, auto) holds in memory; a larger file is fitted on an "
    "even subsample of this many. Default: 500 000, fewer when memory is short.",
)
@click.option(
    "--system-id",
    type=click.IntRange(1, 255),
    default=None,
    help="With --export px4: the vehicle's MAV_SYS_ID written in the parameter file (QGroundControl refuses a file "
    "written for another id). Default 1.",
)
@click.option(
    "--plot",
    "plot_path",
    type=click.Path(dir_okay=False, path_type=Path),
    help="Also draw the samples before and after the fit into this figure (.png, .svg, .pdf), as 'magfit plot'.",
)
@click.option(
    "--sensor",
    metavar="ID",
    help="The compass of a flight log to fit (its id or device id, as 'magfit inspect FILE' lists them); needed "
    "when the log holds several.",
)
@click.option(
    "--force",
    is_flag=True,
    help="Return the calibration even when the samples do not support it (exit 0): it is marked NOT SUPPORTED "
    "and the refusal is printed as a warning. To inspect a poor recording, not to use its numbers.",
)
def calibrate_command(
    file: Path,
    method: str | None,
    columns: list[str | int] | None,
    output: Path | None,
    export_format: str | None,
    unit: str | None,
    nonfinite: Nonfinite,
    field_strength: float | str | None,
    location: tuple[float, float, float] | None,
    model_date: datetime.date | None,
    even: bool,
    max_samples: int | None,
    plot_path: Path | None,
    force: bool,
    system_id: int | None,
    sensor: str | None,
) -> None:
    """Fit a calibration to a recording and print it; save it with -o.

    FILE holds raw magnetometer samples recorded while turning the sensor in all directions (CSV, TSV,
    whitespace-separated text, .npy or .npz). The summary gives the offset, the matrix, the field
    strength, the ellipsoid semi-axes and the paper's mean/std of the distance to the unit sphere.
    With --export and no -o the export goes to stdout and the summary to stderr.

    \b
    Examples:
      magfit calibrate flight.csv --columns mx,my,mz -o cal.json --unit uT
      magfit calibrate mag.txt --method sphere
      magfit calibrate flight.csv --unit uT --export ardupilot -o mag.param
      magfit calibrate flight.csv --export c > mag_cal.h
      magfit calibrate mag.txt --unit uT --plot mag.png
      magfit calibrate parked_then_tumbled.csv --even
      magfit calibrate boat.csv --unit uT --field-strength 48.2
      magfit calibrate boat.csv --unit uT --field-strength wmm --location 47.4,8.5,0.5 --date 2026-06-01
    """
    from ..io import STDOUT, write_all
    from .plot import check_figure_path, plot_calibration

    if plot_path is not None:
        require("plot", "'magfit calibrate --plot'", ("matplotlib",))  # before the calibration is written
        check_figure_path(plot_path, "'--plot'")
    check_outputs(file, output, plot_path)
    if plot_path is not None and _is_log(file):
        fail(f"{file}: --plot does not draw a flight log's samples yet; fit without --plot")
    if system_id is not None and export_format != "px4":
        raise click.UsageError("--system-id goes with --export px4: it is the vehicle id a PX4 parameter file names")
    method = method or default_method()
    if output is not None and export_format is not None and str(output) != STDOUT:
        _check_extension(output, export_format)
    model = _model_field(file, field_strength, location, model_date, unit, sensor)  # before any work
    if field_strength == "wmm" and model is not None and model[1] is not None:  # (the unit is checked physical)
        field_strength = model[0].total_in(model[1])
    options = {} if field_strength is None else {"field_strength": field_strength}
    if sensor is None and (several := _several_compasses(file)):
        if output is not None or export_format is not None:
            fail(
                f"{file}: holds {len(several)} magnetometers ({', '.join(several)}); -o and --export write one "
                "calibration: choose it with --sensor ID"
            )
        _calibrate_each(file, several, method, unit, even, max_samples, options, force, model)
        return
    run = run_calibration(
        file,
        method=method,
        columns=columns,
        nonfinite=nonfinite,
        unit=unit,
        even=even,
        max_samples=max_samples,
        options=options,
        allow_undetermined=force,
        sensor=sensor,
    )
    # Everything is computed before anything is written: a failure leaves every existing file as it was.
    text = (
        render_output(run, export_format, unit, system_id) if output is not None or export_format is not None else None
    )
    to_stdout = text is not None and (output is None or str(output) == STDOUT)
    files: list[tuple[Path, bytes]] = []
    if output is not None and text is not None and not to_stdout:
        files.append((output, text.encode("utf-8")))
    plot_line = None
    if plot_path is not None:
        figure, plot_line = plot_calibration(file, run.calibration, plot_path, columns=columns, nonfinite=nonfinite)
        files.append((plot_path, figure))
    write_all(files)
    summary = console(stderr=to_stdout)
    if run.n_skipped:
        lines = ", ".join(map(str, run.skipped_lines[:5]))
        more = ", ..." if run.n_skipped > 5 else ""
        warn(
            f"{file}: skipped {run.n_skipped} of {run.n_rows} rows with NaN or inf values (lines {lines}{more}); "
            "pass --nonfinite error to refuse such files"
        )
    for message in _fit_warnings(run.calibration):
        warn(without_own_advice(message, run.calibration.method))  # "prefer method='auto'" after auto: no advice
    print_summary(summary, run)
    if model is not None:
        _print_model_field(summary, run.calibration, *model)
    if output is not None and not to_stdout:
        what = f"{export_format} export" if export_format else "calibration"
        summary.print(f"wrote the {what} to {output}")
    if plot_line is not None:
        summary.print(plot_line)
    if to_stdout and text is not None:
        click.echo(text, nl=not text.endswith("\n"))


def _model_field(
    file: Path,
    field_strength: float | str | None,
    location: tuple[float, float, float] | None,
    date: datetime.date | None,
    unit: str | None,
    sensor: str | None,
) -> tuple[Field, str | None] | None:
    """The World Magnetic Model's field at ``--location`` and the samples' unit (None when unknown), or None
    without ``--location``; refuses ``--field-strength wmm`` without a place or a physical unit."""
    if location is None and field_strength == "wmm":
        location, date = _bag_position(file, date)  # a ROS bag may carry its own GNSS fixes
    if location is None:
        if field_strength == "wmm":
            raise click.UsageError("--field-strength wmm needs --location LAT,LON[,ALT] (where the recording was made)")
        if date is not None:
            raise click.UsageError("--date goes with --location: the World Magnetic Model needs the place too")
        return None
    if unit is None:
        from ..sources import log_kind, open_source

        if log_kind(file) is not None:  # a flight log says its unit (read once more: only with --location)
            unit = open_source(file).magnetometer(sensor).unit or None
    physical = unit is not None and get_unit(unit).is_physical
    if field_strength == "wmm" and not physical:
        raise click.UsageError(
            "--field-strength wmm needs the samples' physical unit (--unit uT, G, mG ...): the model gives the field "
            "in tesla units, and raw counts have no known scale"
        )
    return field_at(*location, date=date), unit if physical else None


def _bag_position(
    file: Path, date: datetime.date | None
) -> tuple[tuple[float, float, float] | None, datetime.date | None]:
    """The median GNSS fix of a ROS bag and, unless ``--date`` says otherwise, the date of its first fix."""
    from ..sources import log_kind

    if log_kind(file) != "rosbag":
        return None, date
    from ..sources.rosbag import read_bag_contents

    position = read_bag_contents(file).position()
    if position is None:
        return None, date
    lat, lon, alt_km, time_s = position
    when = datetime.datetime.fromtimestamp(time_s, tz=datetime.timezone.utc).date()
    return (lat, lon, alt_km), date or when


def _print_model_field(out: Console, calibration: Calibration, field: Field, unit: str | None) -> None:
    """The model's field beside the fitted one, and a warning when they differ by more than 10 %."""
    shown = unit or "uT"
    sigma = field.total_uncertainty
    spread = f" ± {significant(sigma * conversion_factor('nT', shown), 2)}" if sigma else ""
    line = f"{significant(field.total_in(shown), 6)}{spread} {shown} ({field.describe()}, inclination "
    line += f"{field.inclination_deg:.1f}°)"
    fitted = calibration.details.get("fitted_field_strength")
    if unit is None:
        line += "; not compared with the fit: the samples' unit is unknown (give --unit)"
    elif calibration.details.get("field_strength_given") and isinstance(fitted, float):
        line += f"; used as the field strength (the samples alone: {significant(fitted, 6)} {unit})"
    out.print(f"{'model field':<16} {line}", soft_wrap=True)
    if unit is not None:
        mismatch = compare_fitted(fitted if isinstance(fitted, float) else calibration.field_strength, unit, field)
        if mismatch is not None:
            warn(mismatch)


def _fit_warnings(calibration: Calibration) -> list[str]:
    """The warnings the fit's diagnostics attached (poor coverage, weak directions ...), if any."""
    diagnostics = calibration.details.get("diagnostics")
    if not isinstance(diagnostics, Mapping):
        return []
    return [str(message) for message in diagnostics.get("warnings") or []]


def _check_extension(output: Path, export_format: str) -> None:
    """Warn when ``-o`` does not carry the export format's usual extension (a likely mix-up)."""
    from ..export import FORMATS

    extension = FORMATS[export_format].extension
    if output.suffix.lower() != extension:
        warn(f"{output}: writing the {export_format} format, whose files usually end in {extension}")


def _choice(calibration: Calibration) -> list[tuple[str, str]]:
    """For a method that chooses among others (``auto``): the method it used and why."""
    chosen = calibration.details.get("chosen")
    if chosen is None:
        return []
    used = calibration.details.get("method_used")
    model = f"{chosen} model" + (f", maximum-likelihood fit started from {used}" if used else "")
    reason = calibration.details.get("reason")
    return [("chose", model + (f" ({reason})" if reason else ""))]


def _verdict(calibration: Calibration) -> list[tuple[str, str]]:
    """Whether the samples support the calibration (``details["support"]``, when the fit reached a verdict)."""
    support = calibration.details.get("support")
    if not isinstance(support, Mapping) or "verdict" not in support:
        return []
    verdict = str(support["verdict"])
    if verdict == "refused":
        return [("verdict", "NOT SUPPORTED by the samples, returned because of --force: do not use these numbers")]
    weaknesses = support.get("weaknesses") or []
    if verdict == "weak" and weaknesses:
        return [("verdict", f"weak: {len(weaknesses)} weakness(es), in the warnings above")]
    return [("verdict", verdict)]


def _fitted_on(run: CalibrationRun) -> list[tuple[str, str]]:
    """When the fit used an even subsample: how many samples, and why."""
    if run.subsample is None:
        return []
    used = run.calibration.n_samples
    return [("fitted on", f"an even subsample: {used} of {run.n_rows - run.n_skipped} samples ({run.subsample})")]


def print_summary(out: Console, run: CalibrationRun) -> None:
    """The calibration and its score, one labelled line each (plain text: easy to read and to grep)."""
    calibration = run.calibration
    unit = f" {calibration.unit}" if calibration.unit else ""
    spec = get_method(calibration.method) if calibration.method in method_names() else None
    matrix_rows = [vector(row, lambda v: f"{v: .6f}") for row in calibration.matrix]
    lines = [
        ("file", f"{run.path} ({run.file_format})"),
        ("columns", columns_text(run.columns) + (f" ({run.column_note})" if run.column_note else "")),
        ("rows", f"{run.n_rows} read, {run.n_skipped} skipped" + (" (streamed)" if run.streamed else "")),
        ("method", calibration.method + (f": {spec.summary}" if spec is not None else "")),
        *_choice(calibration),
        *_fitted_on(run),
        ("offset", vector(calibration.offset, lambda v: significant(v, 6)) + unit),
        ("matrix", matrix_rows[0]),
        ("", matrix_rows[1]),
        ("", matrix_rows[2]),
        ("field strength", significant(calibration.field_strength, 6) + unit),
        ("semi-axes", vector(calibration.semi_axes, lambda v: significant(v, 6)) + unit),
        (
            "sphere distance",
            f"mean {fixed(run.evaluation.mean)}  std {fixed(run.evaluation.std)}  "
            f"(paper, section V: fraction of the field strength, n = {run.evaluation.n})",
        ),
        *_verdict(calibration),
        ("convention", CONVENTION),
    ]
    for label, value in lines:
        out.print(f"{label:<16} {value}", soft_wrap=True)
