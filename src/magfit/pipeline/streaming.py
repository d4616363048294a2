"""A samples file (text, npy, npz) read and fitted within bounded memory: in memory, streamed, or subsampled.

Methods that need only the :class:`~magfit.Statistics` stream the file in chunks (two passes: the statistics,
then the score and a strided subsample for the diagnostics); methods that need the samples load a file that
fits in memory, and fit an even subsample of a larger one (docs/scaling.md). :func:`fit_samples_file` chooses.
"""

from __future__ import annotations

import functools
import itertools
import os
import shutil
import tempfile
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from contextlib import AbstractContextManager, contextmanager
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any, Literal, Protocol

import numpy as np
from numpy.typing import NDArray

from ..calibration import Calibration
from ..diagnostics.settle import settle
from ..errors import DataFileError, MagfitError, OptionError
from ..evaluate import Evaluation, evaluate
from ..fit import fit
from ..methods import get_method
from ..remedy import option
from ..statistics import Statistics

if TYPE_CHECKING:
    from ..io import ChunkReader, FileFormat
    from ..sampling import EvenSampler

#: What to do with rows holding NaN or inf (the readers' ``nonfinite`` argument).
Nonfinite = Literal["skip", "error"]
#: Reports progress: called with the number of rows just processed.
Advance = Callable[[int], None]


class Progress(Protocol):
    """Shows the progress of one pass over a file: ``with progress("reading x.csv", total) as advance: ...``.

    ``total`` is the rows expected, or a function that estimates them (called only when it is shown), or None.
    The command line draws a bar on a terminal; the default, :func:`no_progress`, shows nothing.
    """

    def __call__(
        self, description: str, total: int | Callable[[], int] | None = None
    ) -> AbstractContextManager[Advance]: ...


@contextmanager
def no_progress(description: str, total: int | Callable[[], int] | None = None) -> Iterator[Advance]:
    """A :class:`Progress` that shows nothing."""
    yield lambda rows: None


#: Rows per chunk when streaming. Measured on a 4-million-row CSV: peak memory 204 MB with 250 000 rows
#: against 329 MB with the reader's default of 1 000 000 (153 MB for a tiny file), at the same CPU time;
#: on a 10-million-row CSV, 100 000 rows peak 30 MB below 250 000, at the same CPU time (50 000: 5 % more).
STREAM_CHUNK_ROWS = 100_000
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
#: A file thinned to ``limit`` samples has every k-th row binned by direction, k chosen so that about this
#: many times ``limit`` rows are binned: enough for the densest directions to give way first.
SAMPLE_POOL = 2
#: ... and when the pool's sparse directions would have added more than this fraction of ``limit`` rows from
#: the whole file (a recording parked in one attitude), every row is binned instead (docs/scaling.md).
POOL_DEFICIT = 0.02
#: Rows of the pool offered to the sampler at a time. Measured on 1 million rows kept to 500 000: 0.23 s
#: in blocks of 50 000, 0.26 s of 20 000, 0.45 s of 10 000 (one strided chunk of the file), 0.8 s of 100 000.
POOL_BLOCK_ROWS = 50_000
#: The pool's rows are gathered while the file is first read, for every step that the file's estimated rows
#: (:func:`_rows_spread`) within this fraction either way would give; the sampler then reads them from memory
#: instead of the spill. Any other step (rows skipped, a poor estimate) reads the spill, as before.
POOL_ESTIMATE_MARGIN = 0.01
#: ... as long as those pools hold at most this many bytes together (auto's pools: about 2.4 MB each).
POOL_GATHER_BYTES = 16 << 20


@dataclass(frozen=True, eq=False)
class FileFit:
    """A samples file's fit and what was read: see :func:`fit_samples_file`."""

    calibration: Calibration
    evaluation: Evaluation
    read: _ReadResult
    streamed: bool
    subsample: str | None
    statistics: Statistics | None = None  # of every sample, when the fit was made from them alone (streamed)


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


@dataclass(frozen=True)
class SamplesFileFit:
    """What to fit to a samples file, as :func:`fit_samples_file` and its three ways of reading take it.

    ``columns`` and ``nonfinite`` choose and clean the samples (:func:`magfit.io.read_samples`); ``options`` are
    the method's (and :func:`magfit.fit`'s: ``allow_undetermined``); ``even`` fits the direction-even subsample;
    ``max_samples`` bounds the rows a method that needs the samples holds (default
    :func:`memory_sample_limit`); ``progress`` reports each pass.
    """

    path: Path
    method: str
    columns: Sequence[str | int] | None = None
    nonfinite: Nonfinite = "skip"
    options: Mapping[str, Any] = field(default_factory=dict)
    even: bool = False
    max_samples: int | None = None
    progress: Progress = no_progress


def fit_samples_file(request: SamplesFileFit) -> FileFit:
    """Fit ``request.method`` to the samples of ``request.path`` and score it, within bounded memory.

    Methods whose ``METHODS[method].data`` is ``"statistics"`` read the file in chunks into a
    :class:`~magfit.Statistics` (a first pass), fit, then score the fit in a second pass over the chunks:
    only one chunk is ever in memory. Methods that need the samples load the whole file when it fits in
    memory (at most ``max_samples`` rows, default :func:`memory_sample_limit`), and otherwise stream it
    and fit a spatially even subsample of ``max_samples`` rows. ``even`` fits the even subsample of
    :func:`magfit.sampling.even_subsample` (every direction weighs the same) with any method.
    ``FileFit.subsample`` says why an even subsample was fitted (None when every sample was).
    """
    spec = get_method(request.method)
    limit = memory_sample_limit() if request.max_samples is None else request.max_samples
    subsample = option("even", True) if request.even else None
    if spec.data == "statistics" and not request.even:
        calibration, evaluation, read, statistics = _fit_streaming(request)
        return FileFit(calibration, evaluation, read, True, subsample, statistics)
    if _estimated_rows(request.path) <= limit:
        calibration, evaluation, read = _fit_in_memory(request)
        return FileFit(calibration, evaluation, read, False, subsample)
    # A method whose fit reads at most fit_rows samples (auto) gets no more by default: the rows beyond would
    # not enter its fit, only the uncertainty stated for it, and they cost a longer pass to sample them.
    rows = limit if request.max_samples is not None or spec.fit_rows is None else min(limit, spec.fit_rows)
    calibration, evaluation, read, limited = _fit_subsample(request, rows)
    if limited:
        bound = f"the file has more rows than {option('max_samples', limit)}"
        if request.max_samples is None:
            default = f"{DEFAULT_FIT_SAMPLES:,}".replace(",", " ")
            bound += f", the default: {default} or half the available memory"
            if rows < limit:
                bound += f"; {request.method}'s fit reads at most {rows:,}".replace(",", " ")
        subsample = f"{option('even', True)}; {bound}" if request.even else bound
    return FileFit(calibration, evaluation, read, True, subsample)


def how_read(path: Path) -> str:
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


def log_read_limit(max_samples: int | None) -> int:
    """The most records a log's compass is read with: ``max_samples``, default :func:`memory_sample_limit`.

    A log is read into memory (the fit of a log's compass holds its samples, with their stamps for the
    methods that align the log's other streams), so every method is bounded as the iterative fit of a
    samples file is, by a regular stride over the whole log (:meth:`magfit.sources.Source.read`).
    """
    return memory_sample_limit() if max_samples is None else max_samples


def log_subsample(n_records: int, every: int, max_samples: int | None, even: bool) -> str | None:
    """What ``CompassCalibration.subsample`` says of a log's compass read one record in every ``every``
    (``LogSamples.every``) of its ``n_records``; None when every record was read and ``even`` is off."""
    if every <= 1:
        return option("even", True) if even else None
    limit = log_read_limit(max_samples)
    bound = f"stride: one in every {every} of {n_records} records read, "
    if n_records > limit:
        bound += f"more than {option('max_samples', limit)}"
        if max_samples is None:
            bound += f", the default: {DEFAULT_FIT_SAMPLES:,} or half the available memory".replace(",", " ")
    else:
        bound += "more than the log's reader keeps of one topic"
    return f"{option('even', True)}; {bound}" if even else bound


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


#: Places of a text file whose line lengths :func:`_rows_spread` reads, and the bytes read at each.
_PROBES, _PROBE_BYTES = 32, 1 << 16


def _rows_spread(path: Path, fmt: FileFormat) -> int:
    """Data rows (line ends) of a text file, estimated from the line lengths at :data:`_PROBES` places spread
    over the file: rows = Σ (bytes of a stretch) / (its mean line length), the stretches equal. Unlike the
    head alone (:func:`_rows_in`) it follows lines that lengthen through the file (a growing time stamp: 7 %
    fewer rows than the head said in a 10-million-row CSV; 0.3 % this way)."""
    size = path.stat().st_size - fmt.data_offset
    with open(path, "rb") as handle:
        if size <= _PROBES * _PROBE_BYTES:
            handle.seek(fmt.data_offset)
            return handle.read().count(b"\n")
        per_byte = []
        for probe in range(_PROBES):
            handle.seek(fmt.data_offset + (size - _PROBE_BYTES) * probe // (_PROBES - 1))
            block = handle.read(_PROBE_BYTES)
            first, last = block.find(b"\n"), block.rfind(b"\n")
            if last > first >= 0:
                per_byte.append((block.count(b"\n") - 1) / (last - first))
    if not per_byte:  # lines longer than a probe
        return _rows_in(path, fmt)
    return int(size * sum(per_byte) / len(per_byte))


def _fit_in_memory(request: SamplesFileFit) -> tuple[Calibration, Evaluation, _ReadResult]:
    from ..io import read_samples

    path = request.path
    with request.progress(f"reading {path.name}", lambda: _estimated_rows(path)) as advance:
        table = read_samples(path, columns=request.columns, nonfinite=request.nonfinite, progress=advance)
    _require_rows(path, table.samples.shape[0], table)
    samples = samples_for_fit(table.samples, request.even)
    calibration = fit(samples, method=request.method, **request.options)
    return calibration, evaluate(calibration, table.samples), table


def samples_for_fit(samples: NDArray[np.float64], even: bool) -> NDArray[np.float64]:
    """The samples the fit uses: all of them, or with ``--even`` the even subsample (docs/scaling.md).

    The score is still computed on every sample.
    """
    if not even:
        return samples
    from ..sampling import even_subsample

    return samples[even_subsample(samples)]


def _fit_subsample(request: SamplesFileFit, limit: int) -> tuple[Calibration, Evaluation, _ReadResult, bool]:
    """Stream a file too large for memory: statistics, an even subsample of at most ``limit`` rows, fit, score.

    The last item returned is true when ``limit`` thinned the samples (not only ``even``).

    The directions of the subsample start from the ellipsoid fit of the whole file's statistics
    (:func:`magfit.sampling.direction_frame`); without ``even`` the cells are capped only as far as
    ``limit`` requires, so the densest directions give way first (:func:`magfit.sampling.even_subsample_chunks`).
    """
    from ..io import iter_sample_chunks
    from ..sampling import direction_frame, even_subsample_chunks

    path, method, options, even, progress = (
        request.path,
        request.method,
        request.options,
        request.even,
        request.progress,
    )

    def chunks() -> ChunkReader:
        return iter_sample_chunks(
            path, columns=request.columns, nonfinite=request.nonfinite, chunk_rows=STREAM_CHUNK_ROWS
        )

    with _FirstPass(chunks, progress, None if even else SAMPLE_POOL * limit) as first:
        statistics, reader, source = first.statistics, first.read, first.source
        _require_rows(path, statistics.n, reader)
        centre, shape = direction_frame(statistics)
        # Without --even, first only every step-th row is binned (a pool of about SAMPLE_POOL x limit rows):
        # binning every row was most of the command's time. When the pool's sparse directions would have
        # given more than POOL_DEFICIT of the subsample from the whole file, every row is binned after all.
        pool_step = 1 if even else max(1, statistics.n // (SAMPLE_POOL * limit))
        with progress(f"sampling {path.name} evenly") as advance:
            for step in dict.fromkeys((pool_step, 1)):  # the pool, then every row if the pool will not do
                try:
                    sampler = even_subsample_chunks(
                        functools.partial(_pooled_rows, first.gathered(step) or source, advance, step),
                        centre=centre,
                        shape=shape,
                        max_samples=limit,
                        cap_at_median=even,
                    )
                except OptionError:
                    # A budget below the cells of directions filled: the pool fills fewer cells than the whole
                    # file, so the least budget to advise is counted on every row (with it, any pool fits).
                    if step == 1:
                        raise
                    continue
                if step == 1 or _pool_deficit(sampler, step) <= POOL_DEFICIT * limit:
                    break
        samples = sampler.samples
        limited = sampler.max_samples == limit and len(samples) < statistics.n
        del sampler  # its cells' blocks: up to twice the samples kept, freed before the fit's own arrays
        calibration = fit(samples, method=method, **options)
        with progress(f"scoring the fit on {path.name}", statistics.n) as advance:
            evaluation = first.score(calibration, advance)[0]
    return calibration, evaluation, reader, limited


class _FirstPass:
    """Pass 1 over a file: its :class:`~magfit.Statistics`, and the samples spilled for the later passes.

    A large text file is cut into pieces at line ends, one per core (``ChunkReader.parallel_pieces``),
    read on threads: pandas parses without holding the GIL, and the pieces' statistics merge exactly
    (``Statistics.merge``), so the result is that of one reader, in about half the time on two cores.
    Errors come as one reader would raise them: the first piece's first.
    """

    def __init__(self, chunks: Callable[[], ChunkReader], progress: Progress, pool_rows: int | None = None) -> None:
        from ..io.readers import PiecesRead

        self._chunks = chunks
        self._progress = progress
        self._pieces = chunks().parallel_pieces()
        self._spills = [_Spill(piece) for piece in self._pieces]
        # Every k-th row for the k that about ``pool_rows`` rows would need (read in order: one piece only).
        steps = _pool_steps(self._pieces[0], pool_rows) if pool_rows and len(self._pieces) == 1 else []
        self._pools = {step: _Gathered(step) for step in steps}
        self.statistics = Statistics()
        self.read = PiecesRead(self._pieces)

    def __enter__(self) -> _FirstPass:
        from ..io.readers import read_pieces
        from ..io.sources import display_name

        try:
            reader = self._pieces[0]
            name = Path(display_name(reader.path)).name  # not the name of a decompressed temporary copy
            with self._progress(f"reading {name}", lambda: _rows_in(reader.path, reader.format)) as advance:
                parts = read_pieces(
                    self._pieces,
                    lambda piece, stopped: self._read(
                        piece, self._spills[self._pieces.index(piece)], advance, stopped, list(self._pools.values())
                    ),
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
    def _read(
        piece: ChunkReader,
        spill: _Spill,
        advance: Advance,
        stopped: Callable[[], bool],
        pools: Sequence[_Gathered] = (),
    ) -> Statistics:
        statistics = Statistics()
        for chunk in piece:
            if stopped():  # an earlier piece failed: its error is what the user sees
                break
            statistics.update(chunk)
            spill.write(chunk)
            for pool in pools:
                pool.add(chunk)
            advance(len(chunk))
        return statistics

    def gathered(self, step: int) -> _Gathered | None:
        """Rows 0, step, 2 step ... of the samples, when they were gathered in this pass (else None)."""
        return self._pools.get(step)

    def score(self, calibration: Calibration, advance: Advance) -> tuple[Evaluation, NDArray[np.float64]]:
        """The paper's metric over every sample, and at most :data:`DIAGNOSE_SAMPLES` rows evenly strided.

        The spilled samples are cut into one run of rows per core (a file parsed in blocks has one spill,
        a file parsed in pieces one per piece), scored on threads (NumPy computes without the GIL, the rows
        are read with ``os.pread``), and their metrics pooled; the stride continues across the runs.
        """
        from ..compare import evaluate_chunks

        total = self.statistics.n
        spills = [spill for spill in self._spills if spill.rows]
        workers = min(os.cpu_count() or 1, 4)
        if not spills or not all(spill.complete for spill in self._spills) or (workers < 2 and len(spills) < 2):
            strided = _Strided(total, DIAGNOSE_SAMPLES)
            return evaluate_chunks(calibration, strided.collect(_counted(self.source(), advance))), strided.samples()
        runs: list[tuple[_Spill, int, int, int]] = []  # (spill, first row, end row, rows before it in the file)
        before = 0
        for spill in spills:
            runs_per_spill = max(1, -(-workers // len(spills)))
            cuts = [spill.rows * k // runs_per_spill for k in range(runs_per_spill + 1)]
            runs += [(spill, low, high, before + low) for low, high in itertools.pairwise(cuts) if high > low]
            before += spill.rows

        def one(run: tuple[_Spill, int, int, int]) -> tuple[Evaluation, NDArray[np.float64]]:
            spill, low, high, offset = run
            strided = _Strided(total, DIAGNOSE_SAMPLES)
            strided.seen = offset  # rows before this run: the stride continues across runs
            chunks = _counted(spill.chunks(low, high), advance)
            return evaluate_chunks(calibration, strided.collect(chunks)), strided.samples()

        from concurrent.futures import ThreadPoolExecutor  # (its import, with logging's, only for a big file)

        with ThreadPoolExecutor(len(runs)) as pool:
            parts = list(pool.map(one, runs))
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

    def chunks(self, first: int = 0, end: int | None = None) -> Iterator[NDArray[np.float64]]:
        """Rows ``first`` to ``end`` (default: all) in chunks of :data:`STREAM_CHUNK_ROWS`; several threads may
        read one spill at once (``os.pread``: no shared file position)."""
        assert self._file is not None
        self._file.flush()
        descriptor = self._file.fileno()
        end = self.rows if end is None else end
        for start in range(first, end, STREAM_CHUNK_ROWS):
            size = min(STREAM_CHUNK_ROWS, end - start) * 24
            block = os.pread(descriptor, size, start * 24)
            yield np.frombuffer(block, dtype=np.float64).reshape(-1, 3)


def _fit_streaming(request: SamplesFileFit) -> tuple[Calibration, Evaluation, _ReadResult, Statistics]:
    from ..io import iter_sample_chunks

    path, method, options, progress = request.path, request.method, request.options, request.progress

    def chunks() -> ChunkReader:
        return iter_sample_chunks(
            path, columns=request.columns, nonfinite=request.nonfinite, chunk_rows=STREAM_CHUNK_ROWS
        )

    # Pass 1: the sufficient statistics of eq. (4), one chunk at a time (a text file's samples are spilled
    # to a temporary binary file on the way, so that pass 2 does not parse the text again).
    with _FirstPass(chunks, progress) as first:
        statistics, reader = first.statistics, first.read
        _require_rows(path, statistics.n, reader)
        calibration = fit(statistics, method=method, **options)
        # Pass 2: the paper's metric needs the final calibration, so the samples are read again; on the way,
        # keep an evenly strided subsample (bounded) for the diagnostics, which need samples, not statistics.
        with progress(f"scoring the fit on {path.name}", statistics.n) as advance:
            evaluation, subsample = first.score(calibration, advance)
    forced = bool(options.get("allow_undetermined", False))
    return _with_diagnostics(calibration, subsample, statistics.n, forced), evaluation, reader, statistics


def _counted(chunks: Iterable[NDArray[np.float64]], advance: Advance) -> Iterator[NDArray[np.float64]]:
    for chunk in chunks:
        advance(len(chunk))
        yield chunk


def _pool_deficit(sampler: EvenSampler, step: int) -> float:
    """Rows the directions left uncapped in a pool of every ``step``-th row would have added from the whole file.

    A cell the pool fills below the sampler's cap keeps all its pool rows; the whole file holds about
    ``step`` times as many there, and would have kept up to the cap of them. The sum over such cells
    overstates what binning every row would change (the cap of the whole file is at most the pool's).
    """
    counts = sampler._counts  # rows offered per cell (sampling.py has no public view of them)
    sparse = counts[(counts > 0) & (counts < sampler.cap)]
    return float(np.sum(np.minimum(step * sparse, sampler.cap) - sparse))


def _pooled_rows(
    source: Callable[[], Iterable[NDArray[np.float64]]] | _Gathered, advance: Advance, step: int
) -> Iterator[NDArray[np.float64]]:
    """Every ``step``-th row of a fresh pass over ``source``, the progress counting every row read; or the
    rows a :class:`_Gathered` pool already holds (counted as the rows they stand for)."""
    if isinstance(source, _Gathered):
        advance(source.seen)
        return _every(source, step)
    return _every(_counted(source(), advance), step)


class _Gathered:
    """Rows 0, step, 2 step ... of a stream of chunks, gathered one chunk at a time (:meth:`add`), kept as
    the pieces :func:`_every` would cut from those chunks (copies: a view would pin the whole chunk)."""

    def __init__(self, step: int) -> None:
        self.step = step
        self.seen = 0
        self.pieces: list[NDArray[np.float64]] = []

    def add(self, chunk: NDArray[np.float64]) -> None:
        first = (-self.seen) % self.step  # index in this chunk of the next row to keep
        self.seen += len(chunk)
        if first < len(chunk):
            self.pieces.append(chunk[first :: self.step].copy() if self.step > 1 else chunk)


def _every(chunks: Iterable[NDArray[np.float64]] | _Gathered, step: int) -> Iterator[NDArray[np.float64]]:
    """Rows 0, step, 2 step ... of a stream of chunks (the stream itself when ``step`` is 1), or of a pool
    gathered with that step while the stream was first read.

    The rows kept are passed on in blocks of about :data:`POOL_BLOCK_ROWS`, not one small block per chunk
    read: the sampler's cost per block has a part per cell.
    """
    if isinstance(chunks, _Gathered):
        assert chunks.step == step
        pieces: Iterable[NDArray[np.float64]] = chunks.pieces
    elif step == 1:
        yield from chunks
        return
    else:
        pool = _Gathered(step)
        pieces = _cut(chunks, pool)
    if step == 1:
        yield from pieces
        return
    kept: list[NDArray[np.float64]] = []
    n_kept = 0
    for piece in pieces:
        if len(piece):
            kept.append(piece)
            n_kept += len(piece)
        if n_kept >= POOL_BLOCK_ROWS:
            yield np.concatenate(kept)
            kept, n_kept = [], 0
    if kept:
        yield np.concatenate(kept)


def _cut(chunks: Iterable[NDArray[np.float64]], pool: _Gathered) -> Iterator[NDArray[np.float64]]:
    """The pieces ``pool`` cuts from each chunk as it is read (an empty one when a chunk holds no row to keep),
    handed on at once, so that no chunk is held."""
    for chunk in chunks:
        before = len(pool.pieces)
        pool.add(chunk)
        yield pool.pieces.pop() if len(pool.pieces) > before else chunk[:0]


def _pool_steps(reader: ChunkReader, pool_rows: int) -> list[int]:
    """The steps of the pools to gather while ``reader`` is first read: each ``n // pool_rows`` for ``n``
    within :data:`POOL_ESTIMATE_MARGIN` of its estimated rows, when they hold at most
    :data:`POOL_GATHER_BYTES` together; none for an npz file (its estimate is only a bound)."""
    fmt = reader.format
    if fmt.kind == "text":
        estimate = _rows_spread(reader.path, fmt)
    elif fmt.kind == "npy":
        estimate = _rows_in(reader.path, fmt)
    else:
        return []
    low = max(1, int(estimate * (1 - POOL_ESTIMATE_MARGIN)) // pool_rows)
    high = max(1, int(estimate * (1 + POOL_ESTIMATE_MARGIN)) // pool_rows)
    steps = list(range(low, high + 1))
    if sum(24 * estimate * (1 + POOL_ESTIMATE_MARGIN) / step for step in steps) > POOL_GATHER_BYTES:
        return []
    return steps


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
    and its verdict (``calibration.support``), settled by the one verdict step
    (:func:`magfit.diagnostics.settle.settle`).

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
    if report.support is None:
        return replace(calibration, details={**calibration.details, "diagnostics": report.to_dict()})
    return settle(calibration, report.support, allow_undetermined=allow_undetermined, report=report)


def _require_rows(path: Path, n_samples: int, read: _ReadResult) -> None:
    if n_samples > 0:
        return
    if read.n_skipped:
        raise DataFileError(
            f"{path}: all {read.n_skipped} data rows hold NaN or inf values; nothing is left to calibrate"
        )
    raise DataFileError(f"{path}: the file holds no data rows")
