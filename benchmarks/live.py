"""Does ``magfit live`` keep up? CPU time per second of input at 100 Hz and 1 kHz, view refreshes, drops.

    .venv/bin/python benchmarks/live.py                 # about 50 s: 15 s of input at each rate, plus fit sizes
    .venv/bin/python benchmarks/live.py --seconds 5     # a quick look

A simulated board's ``Raw:`` lines (:class:`magfit.live.SimulatedBoard`, generated before the clock starts)
are written into a pipe in real time, 10 ms at a time, by a feeder thread; ``magfit live``'s own machinery
(:class:`magfit.live.LiveRun`: the reader thread, the fitting thread) reads the pipe, and the main thread
draws the view (:func:`magfit.live.view.render`) into a string every 0.15 s, as the terminal view does.
Figures, each as CPU seconds per second of input (0.10 = 10 % of one core):

- reader: parsing, the recording left out, the session's statistics and even sampler;
- fitting: the ``auto`` refits of the even subset (the issue's limit: 0.10 at 100 Hz);
- view: drawing the snapshots;
- process: everything the process used meanwhile, less the feeder's own CPU.

Also: the view's refresh rate (target >= 5 per second), samples received against samples sent (no drop),
and the cost of one ``auto`` fit against the size of the subset (how ``FIT_SAMPLES`` was chosen).
Results: ``benchmarks/results/live.md`` (``--output``).
"""

from __future__ import annotations

import argparse
import datetime as _dt
import io
import os
import platform
import sys
import threading
import time

import numpy as np

import magfit
from magfit.live import LineParser, LiveRun, Session, SimulatedBoard, Thresholds, open_source
from magfit.live.session import FIT_SAMPLES
from magfit.live.view import render

REDRAW = 0.15


def feed(write_fd: int, data: bytes, rate_hz: float, line_bytes: list[int], cpu: list[float]) -> None:
    """Write ``data`` (lines of ``line_bytes`` lengths) into the pipe at ``rate_hz`` lines a second."""
    ends = np.cumsum(line_bytes)
    start = time.monotonic()
    sent = 0
    n = len(line_bytes)
    while sent < n:
        due = min(n, int((time.monotonic() - start) * rate_hz) + 1)
        if due > sent:
            lo = 0 if sent == 0 else int(ends[sent - 1])
            os.write(write_fd, data[lo : int(ends[due - 1])])
            sent = due
        time.sleep(0.01)
    os.close(write_fd)
    cpu.append(time.thread_time())


def run_rate(rate_hz: float, seconds: float) -> dict[str, float]:
    board = SimulatedBoard(rate_hz=rate_hz, seed=1)
    n = int(rate_hz * seconds)
    lines = [board.raw_lines(1) for _ in range(n)]
    data = b"".join(lines)
    read_fd, write_fd = os.pipe()
    os.set_blocking(write_fd, True)
    source = open_source(f"/dev/fd/{read_fd}")
    parser = LineParser(first_line_may_be_cut=source.first_line_may_be_cut)
    session = Session(thresholds=Thresholds())
    run = LiveRun(source, parser, session)
    feeder_cpu: list[float] = []
    feeder = threading.Thread(target=feed, args=(write_fd, data, rate_hz, [len(x) for x in lines], feeder_cpu))
    cpu0 = time.process_time()
    wall0 = time.monotonic()
    run.start()
    feeder.start()
    draws = 0
    view_cpu = 0.0
    sink = io.StringIO()
    from rich.console import Console

    screen = Console(file=sink, width=120, force_terminal=True)
    next_draw = time.monotonic()
    while run.reading:
        now = time.monotonic()
        if now >= next_draw:
            t = time.thread_time()
            sink.seek(0)
            sink.truncate()
            screen.print(
                render(session.snapshot(), source="bench", stream=parser.describe(), thresholds=Thresholds(), unit="uT")
            )
            view_cpu += time.thread_time() - t
            draws += 1
            next_draw += REDRAW
        time.sleep(max(0.0, min(0.01, next_draw - time.monotonic())))
    wall = time.monotonic() - wall0
    feeder.join()
    run.close()
    source.close()
    process_cpu = time.process_time() - cpu0 - feeder_cpu[0]
    snapshot = session.snapshot()
    return {
        "rate_hz": rate_hz,
        "seconds": wall,
        "sent": n,
        "received": session.n_samples,
        "junk": parser.counts.junk,
        "reader": run.reader_cpu / wall,
        "fitting": run.fitter_cpu / wall,
        "view": view_cpu / wall,
        "process": process_cpu / wall,
        "refresh_hz": draws / wall,
        "fits": snapshot.fits_done,
        "fit_ms": 1000 * snapshot.fit_cpu_seconds / max(1, snapshot.fits_done),
    }


def fit_sizes(sizes: list[int], repeat: int) -> list[tuple[int, float]]:
    """CPU seconds of one ``auto`` fit (with its diagnostics) on an even subset of each size, best of ``repeat``."""
    board = SimulatedBoard(rate_hz=100, seed=2)
    mag, _, _ = board.readings(60 * 100)  # one minute of turning
    magfit.fit(mag, "auto")  # imports and caches out of the timing
    rows = []
    for size in sizes:
        subset = mag[np.linspace(0, len(mag) - 1, size).astype(int)]
        best = np.inf
        for _ in range(repeat):
            t = time.process_time()
            magfit.fit(subset, "auto")
            best = min(best, time.process_time() - t)
        rows.append((size, best))
    return rows


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=15.0, help="seconds of input at each rate")
    parser.add_argument("--output", help="write the markdown here too")
    args = parser.parse_args()
    started = time.monotonic()
    load = os.getloadavg()
    rows = [run_rate(rate, args.seconds) for rate in (100.0, 1000.0)]
    sizes = fit_sizes([250, 500, 1000, 2000, 4000], repeat=3)
    load_end = os.getloadavg()
    out = [
        "# Live mode benchmark",
        "",
        f"Command: `python benchmarks/live.py --seconds {args.seconds:g}`  ",
        f"Date: {_dt.datetime.now(_dt.timezone.utc):%Y-%m-%d %H:%M} UTC, runtime {time.monotonic() - started:.0f} s  ",
        f"Machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores; Python "
        f"{platform.python_version()}, NumPy {np.__version__}, magfit {magfit.__version__}  ",
        f"Load average (1, 5, 15 min) at the start: {', '.join(f'{x:.1f}' for x in load)}; at the end: "
        f"{', '.join(f'{x:.1f}' for x in load_end)} (other processes share the cores)",
        "",
        "CPU seconds used per second of input (0.10 = 10 % of one core). The board's lines are written into a",
        "pipe in real time; the reader and fitting threads are magfit's own (`LiveRun`); the view is drawn every",
        f"{REDRAW} s into a string. The even subset of each fit holds at most {FIT_SAMPLES} samples.",
        "",
        "| input | samples sent / received | reader | fitting | view | whole process | view refreshes | fits, CPU each"
        " |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        out.append(
            f"| {r['rate_hz']:g} Hz, {r['seconds']:.0f} s | {r['sent']} / {r['received']} | {r['reader']:.3f} | "
            f"{r['fitting']:.3f} | {r['view']:.3f} | {r['process']:.3f} | {r['refresh_hz']:.1f} /s | "
            f"{r['fits']:.0f}, {r['fit_ms']:.0f} ms |"
        )
    out += [
        "",
        "Targets: fitting <= 0.10 at 100 Hz; at 1 kHz no sample dropped and >= 5 view refreshes a second.",
        "",
        "## One `auto` fit (with its diagnostics) against the size of the even subset",
        "",
        "| samples | CPU time, best of 3 |",
        "|---|---|",
    ]
    out += [f"| {size} | {1000 * cost:.0f} ms |" for size, cost in sizes]
    text = "\n".join(out) + "\n"
    sys.stdout.write(text)
    if args.output:
        with open(args.output, "w", encoding="utf-8") as handle:
            handle.write(text)
    failed = [r for r in rows if r["received"] != r["sent"] or r["refresh_hz"] < 5]
    return 1 if failed else 0


if __name__ == "__main__":
    raise SystemExit(main())
