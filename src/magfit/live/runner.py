"""A live run: a reader thread that never waits for a fit, and a fitting thread held to a CPU budget.

The reader takes whatever bytes the source has (:meth:`Source.read` with a short timeout), parses them,
appends the samples to the recording and then to the session; at 1 kHz that is about 15 µs per sample.
The fitting thread refits the session's even subset and then rests for ``cost × (1 / budget − 1)``
seconds, at least ``min_interval``: whatever one fit costs, fitting takes at most ``budget`` of a core
(10 % by default) and never more than five fits a second run. The main thread only looks: it calls
:meth:`LiveRun.poll` and draws snapshots.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from .record import Recorder
from .session import Session
from .source import EndOfStream, Source
from .stream import LineParser

__all__ = ["FIT_BUDGET", "MIN_FIT_INTERVAL", "LiveRun", "StopRule"]

#: Share of one core the fits may use (the issue's limit at 100 Hz input; it holds at any rate).
FIT_BUDGET = 0.10
#: Shortest time between two fits, seconds: a view refreshed 5 times a second needs no more.
MIN_FIT_INTERVAL = 0.2
#: Longest a read waits for bytes, seconds: how fast the reader notices a stop.
READ_TIMEOUT = 0.05
#: Shortest time between two batches handed to the session, seconds. A read returns as soon as one byte
#: is there, so without a pause a 1 kHz board gives batches of one line, and the per-batch work of the
#: statistics and the even sampler (about 0.5 ms) would cost half a core. The OS buffers the bytes
#: meanwhile (20 ms at 1 kHz is under 1 KiB).
BATCH_INTERVAL = 0.02


@dataclass(frozen=True)
class StopRule:
    """When a non-interactive run stops: after ``samples``, after ``duration`` seconds, or once good."""

    samples: int | None = None
    duration: float | None = None
    until_good: bool = False

    @property
    def given(self) -> bool:
        return self.samples is not None or self.duration is not None or self.until_good

    def describe(self) -> str:
        parts = []
        if self.samples is not None:
            parts.append(f"{self.samples} samples")
        if self.duration is not None:
            parts.append(f"{self.duration:g} s")
        if self.until_good:
            parts.append("a good-enough fit")
        return " or ".join(parts) if parts else "the end of the stream"


class LiveRun:
    """The threads of one live session over ``source``; see the module docstring.

    After :meth:`start`, call :meth:`poll` regularly: it returns True once the run is over, and then
    :attr:`stopped_by` (the stop rule that was met), :attr:`ended` (the stream ended first: why) or
    :attr:`error` (a reading error, e.g. a header naming no magnetometer) says why.
    """

    def __init__(
        self,
        source: Source,
        parser: LineParser,
        session: Session,
        *,
        recorder: Recorder | None = None,
        stop: StopRule | None = None,
        budget: float = FIT_BUDGET,
        min_interval: float = MIN_FIT_INTERVAL,
    ) -> None:
        self.source = source
        self.parser = parser
        self.session = session
        self.recorder = recorder
        self.stop = stop or StopRule()
        self.budget = budget
        self.min_interval = min_interval
        self.stopped_by: str | None = None
        self.ended: str | None = None
        self.error: BaseException | None = None
        #: CPU seconds each thread used, set when it ends (for the benchmark).
        self.reader_cpu = 0.0
        self.fitter_cpu = 0.0
        self._reconnections = 0
        self._halt = threading.Event()
        self._reading = threading.Event()  # set while the reader runs
        self._started = time.monotonic()
        self._threads = [
            threading.Thread(target=self._read_loop, name="magfit-live-reader", daemon=True),
            threading.Thread(target=self._fit_loop, name="magfit-live-fitter", daemon=True),
        ]
        self._write_lock = threading.Lock()

    def start(self) -> LiveRun:
        self._started = time.monotonic()
        self._reading.set()
        for thread in self._threads:
            thread.start()
        return self

    @property
    def elapsed(self) -> float:
        return time.monotonic() - self._started

    @property
    def reading(self) -> bool:
        """True while the stream is being read (False once it ended or the run stopped)."""
        return self._reading.is_set()

    def poll(self) -> bool:
        """True once the run is over (a stop rule met, the stream ended, or an error)."""
        if self.stop.duration is not None and self.stopped_by is None and self.elapsed >= self.stop.duration:
            self._finish(f"{self.stop.duration:g} s")
        return self._halt.is_set() or self.ended is not None or self.error is not None

    def _finish(self, reason: str) -> None:
        if self.stopped_by is None:
            self.stopped_by = reason
        self._halt.set()

    def close(self) -> None:
        """Stop both threads, close the recording (the source stays open: a packet may still go out)."""
        self._halt.set()
        for thread in self._threads:
            if thread.is_alive():
                thread.join(timeout=30.0)
        if self.recorder is not None:
            self.recorder.close()

    def send(self, data: bytes) -> None:
        """Write ``data`` to the board (the calibration packet)."""
        with self._write_lock:
            self.source.write(data)

    # ------------------------------------------------------------------ threads

    def _read_loop(self) -> None:
        try:
            while not self._halt.is_set():
                batch_start = time.monotonic()
                try:
                    data = self.source.read(READ_TIMEOUT)
                except EndOfStream as end:
                    self._take(self.parser.finish(last_line_complete=self.source.ends_normally))
                    self.ended = str(end)
                    return
                if self.source.reconnections != self._reconnections:
                    self._reconnections = self.source.reconnections
                    self.parser.reconnected()
                if data:
                    self._take(self.parser.feed(data))
                    self._halt.wait(BATCH_INTERVAL - (time.monotonic() - batch_start))
        except Exception as error:  # reported by the main thread, which owns the messages
            self.error = error
        finally:
            self.reader_cpu = time.thread_time()
            self._reading.clear()

    def _take(self, rows: NDArray[np.float64]) -> None:
        if self.stopped_by is not None:
            return
        limit = self.stop.samples
        if limit is not None:
            rows = rows[: max(0, limit - self.session.n_samples)]
        if self.recorder is not None:
            self.recorder.write(rows, self.parser.unit)
        self.session.add(rows)
        if limit is not None and self.session.n_samples >= limit:
            self._finish(f"{limit} samples")

    def _fit_loop(self) -> None:
        try:
            due = 0.0
            while not self._halt.is_set():
                now = time.monotonic()
                if now < due:
                    self._halt.wait(min(due - now, READ_TIMEOUT))
                    continue
                result = self.session.refit()
                if result is None:
                    if not self._reading.is_set() and self.ended is not None:
                        return  # the stream is over and the last samples are fitted
                    self._halt.wait(READ_TIMEOUT)
                    continue
                # The fit's own CPU time, not its wall time: on a busy machine the wall time grows with the
                # other processes' load, and resting for it would leave the view's fit stale for nothing.
                cost = result.cpu_seconds
                due = time.monotonic() + max(self.min_interval, cost * (1.0 / self.budget - 1.0))
                if self.stop.until_good and self.session.snapshot().verdict.good:
                    self._finish("a good-enough fit")
        except Exception as error:
            self.error = error
        finally:
            self.fitter_cpu = time.thread_time()
