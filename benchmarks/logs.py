"""How much does magfit add to reading a flight log? Its reading of each compass against the format library's own.

    .venv/bin/python benchmarks/logs.py             # about half a minute on 2 cores
    .venv/bin/python benchmarks/logs.py --small     # the committed fixtures only, a few seconds
    .venv/bin/python benchmarks/logs.py --big       # 1 GB logs: peak memory and time, about 3 minutes
    .venv/bin/python benchmarks/logs.py --big --before /path/to/other/checkout/src   # and a before, ~6 minutes

pymavlink is no magfit dependency; install it *outside* the project's virtual environment, since it ships a
script ``magfit.py`` that, once in ``.venv/bin``, shadows the magfit package for ``.venv/bin/magfit``:

    .venv/bin/pip install --target /tmp/pymavlink pymavlink
    PYTHONPATH=/tmp/pymavlink .venv/bin/python benchmarks/logs.py

The target: reading a log into samples costs at most 2x what its library alone needs to read the same
topics. Both sides are timed in the same run, taking turns, best of ``--repeat`` (the least disturbed):

- **ULog**: magfit (``magfit.sources.open_source(path, everything=False)``, then ``Source.read`` of every
  compass: the raw field in an (N, 3) array, a calibrated stream undone with the log's parameters) against
  ``pyulog.ULog(path, topics)`` on the topics magfit asks pyulog for (the magnetometers and the GNSS).
- **DataFlash**: magfit's own reader (the same two steps) against pymavlink's ``DFReader_binary`` walking the
  MAG, PARM and GPS messages with ``recv_match`` (the way a pymavlink script reads them), when pymavlink is
  installed; and against the floor of magfit's reader, its one pass over the message headers
  (``DataFlashLog``), which any reader of the format must make.

Files: the fixtures in ``tests/data`` (PX4's sample log from pyulog's repository, a real ArduPilot SITL log
with three compasses; ``synthetic/ulog_pyulog_loops.ulg`` is a damaged log for the error tests, left out)
and, without ``--small``, larger synthetic logs written here by the test suite's writers
(``tests/test_sources_ulog.py``, ``tests/test_sources_dataflash.py``). Results:
``benchmarks/results/logs.md`` and ``logs.json``.

``--big`` (the target: a 1 GB log read in about 300 MB at most): a DataFlash log and a ULog of 1 GB
built in a temporary folder by repeating a real log's data messages (time stamps moved on each copy), read in
a fresh interpreter each as ``calibrate`` reads them, their peak resident memory and time beside a plain read
of the file's bytes in the same run. Results: ``benchmarks/results/logs-big.md`` and ``.json``.
"""

from __future__ import annotations

import argparse
import datetime as _dt
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / "tests" / "data"
RESULTS = ROOT / "benchmarks" / "results"
#: At most this many times the library's own reading.
TARGET = 2.0


def magfit_read(path: Path) -> int:
    """magfit's reading of every usable compass of ``path``: the samples a fit gets. Returns the samples read."""
    from magfit.sources import open_source

    source = open_source(path, everything=False)
    total = 0
    for magnetometer in source.magnetometers:
        if magnetometer.problem is None and magnetometer.n_samples > 0:
            total += len(source.read(magnetometer.id).samples)
    return total


def pyulog_read(path: Path) -> int:
    """pyulog alone on the topics magfit asks it for (``magfit.sources.ulog``: magnetometers and GNSS)."""
    import pyulog

    from magfit.sources import ulog

    topics = [*ulog._FIELDS, *ulog._GPS_TOPICS]
    parsed = pyulog.ULog(str(path), topics)
    return sum(len(data.data["timestamp"]) for data in parsed.data_list if data.name in ulog._FIELDS)


def pymavlink_read(path: Path) -> int:
    """pymavlink's DFReader on the messages magfit reads (MAG, MAG2, MAG3, PARM, GPS), fields collected."""
    from pymavlink import DFReader

    log = DFReader.DFReader_binary(str(path), zero_time_base=True)
    samples = 0
    wanted = ["MAG", "MAG2", "MAG3", "PARM", "GPS"]
    while (message := log.recv_match(type=wanted)) is not None:
        if message.get_type().startswith("MAG"):
            _ = (message.TimeUS, message.MagX, message.MagY, message.MagZ)
            samples += 1
    return samples


def header_walk(path: Path) -> int:
    """The floor: magfit's one pass over the DataFlash message headers, no payload decoded."""
    from magfit.sources.dataflash import DataFlashLog

    try:
        return sum(DataFlashLog(path, path).names().values())  # walked from the file, in blocks
    except TypeError:  # a checkout before the streamed reader (--before): it took the file's bytes
        return sum(DataFlashLog(path, path.read_bytes()).names().values())


def best_of(functions: dict[str, Callable[[Path], int]], path: Path, repeat: int) -> dict[str, float]:
    """Each function's best time over ``repeat`` rounds, the functions taking turns (the same load on each)."""
    best = dict.fromkeys(functions, float("inf"))
    for _ in range(repeat):
        for name, function in functions.items():
            start = time.perf_counter()
            function(path)
            best[name] = min(best[name], time.perf_counter() - start)
    return best


def synthetic_logs(folder: Path, n: int) -> list[Path]:
    """A ULog (two sensor_mag instances, vehicle_magnetometer, vehicle_attitude at 50 Hz) and a DataFlash log
    (two compasses and ATT at 20 Hz) of ``n`` samples each, written by the test suite's writers."""
    sys.path.insert(0, str(ROOT / "tests"))
    from test_sources_dataflash import write_new_style
    from test_sources_ulog import write_log

    ulog, dataflash = folder / f"synthetic_{n}.ulg", folder / f"synthetic_{n}.bin"
    write_log(ulog, n=n)
    write_new_style(dataflash, n=n)
    return [ulog, dataflash]


# --- A 1 GB log: memory and time (``--big``) ---------------------------------------------------------------

#: The bound: a 1 GB log read in at most about this much memory (peak resident set, MB).
BIG_TARGET_MB = 300.0
#: The real logs repeated (tests/data: their READMEs give the origin and licence).
BIG_DATAFLASH = DATA / "ardupilot_real" / "copter33_log171_trimmed.bin"
BIG_ULOG = DATA / "px4_pyulog" / "sample_log_small.ulg"

_MEASURE = """
import json, sys, time
path, what = sys.argv[1], sys.argv[2]
start = time.perf_counter()
n = 0
if what == "bytes":  # the reference: a plain read of the file's bytes, in 8 MB blocks
    with open(path, "rb") as handle:
        while handle.read(1 << 23):
            pass
elif what == "import":  # the interpreter with magfit's reading modules imported, reading nothing
    import magfit.sources, magfit.sources.dataflash, magfit.sources.ulog, pyulog  # noqa
elif what == "calibrate":  # the whole default calibrate of every compass (auto), refusals counted
    import magfit
    from magfit.errors import CalibrationError
    try:
        result = magfit.calibrate_file(path, notify=lambda note: None)
        n = sum(compass.n_rows for compass in result.compasses)
    except CalibrationError:
        n = 0
else:  # magfit: open_source, then every usable compass read as calibrate reads it (max_samples or all)
    from magfit.sources import open_source
    source = open_source(path, everything=False)
    for magnetometer in source.magnetometers:
        if magnetometer.problem is None and magnetometer.n_samples:
            if what == "all":  # (as a checkout without max_samples reads)
                n += len(source.read(magnetometer.id).samples)
            else:
                n += len(source.read(magnetometer.id, max_samples=int(what)).samples)
seconds = time.perf_counter() - start
# The peak of this program alone: VmHWM (ru_maxrss keeps the parent's resident size from before the exec).
with open("/proc/self/status") as status:
    peak = next(int(line.split()[1]) for line in status if line.startswith("VmHWM:")) / 1024  # kB
print(json.dumps({"seconds": seconds, "peak_mb": peak, "samples": n}))
"""


def measure(path: Path, what: str, source: Path | None = None) -> dict[str, float]:
    """Peak RSS (MB) and seconds of one reading of ``path`` in a fresh interpreter; ``source``: the ``src``
    folder to import magfit from (another checkout's, for a before/after), else this one's."""
    env = dict(os.environ, PYTHONPATH=str(source or ROOT / "src"))
    done = subprocess.run(
        [sys.executable, "-c", _MEASURE, str(path), what], env=env, capture_output=True, text=True, check=False
    )
    if done.returncode:
        return {"seconds": float("nan"), "peak_mb": float("nan"), "samples": 0, "error": done.stderr[-300:]}
    return json.loads(done.stdout.splitlines()[-1])


def build_big_dataflash(source: Path, out: Path, size_bytes: int) -> int:
    """Write ``out``: ``source``'s head (every message before its first compass record: the formats, the
    parameters), then its later messages (FMT left out) again and again, each copy's TimeUS/TimeMS moved on
    by the log's span, up to ``size_bytes``. Returns the number of copies."""
    from magfit.sources.dataflash import DataFlashLog

    data = source.read_bytes()
    log = DataFlashLog(source, data)  # from bytes: every message's offset
    compasses = [log._offsets[log._by_name[n]] for n in ("MAG", "MAG2", "MAG3") if n in log._by_name]
    first = min(int(offsets[0]) for offsets in compasses if len(offsets))
    starts = np.sort(np.concatenate([o for type_id, o in log._offsets.items() if type_id != 0x80]))
    pieces, stamps, at, times = [], {8: [], 4: []}, 0, []
    for start in starts[starts >= first].tolist():
        fmt = log.formats[data[start + 2]]
        piece = data[start : start + fmt.length]
        if fmt.dtype is not None and fmt.labels and fmt.labels[0] in ("TimeUS", "TimeMS"):
            width = 8 if fmt.labels[0] == "TimeUS" else 4
            stamps[width].append(at + 3)
            times.append(int.from_bytes(piece[3 : 3 + width], "little") * (1 if width == 8 else 1000))
        pieces.append(piece)
        at += len(piece)
    body = np.frombuffer(b"".join(pieces), dtype=np.uint8)
    span_us = max(times) - min(times) + 100_000
    return _repeat(out, data[:first], body, stamps, span_us, size_bytes)


def build_big_ulog(source: Path, out: Path, size_bytes: int) -> int:
    """Write ``out``: ``source`` without its data messages (the definitions, subscriptions, parameters and
    logged text, in order; parameter changes after the first data message left out), then its data messages
    again and again, each copy's timestamps moved on by the log's span, up to ``size_bytes``."""
    import struct

    import pyulog

    data = source.read_bytes()
    formats = pyulog.ULog(str(source), [], parse_header_only=True)._message_formats
    head, pieces, stamps, at, times, offsets = [data[:16]], [], {8: []}, 0, [], {}
    pos, seen_data = 16, False
    while pos + 3 <= len(data):
        size, kind = struct.unpack_from("<HB", data, pos)
        message = data[pos : pos + 3 + size]
        if kind == ord("A"):
            added = pyulog.ULog._MessageAddLogged(message[3:], None, formats)
            offsets[added.msg_id] = added.timestamp_offset
        if kind == ord("D"):
            seen_data = True
            msg_id = int.from_bytes(message[3:5], "little")
            if msg_id in offsets:
                stamps[8].append(at + 5 + offsets[msg_id])
                times.append(int.from_bytes(message[5 + offsets[msg_id] : 13 + offsets[msg_id]], "little"))
            pieces.append(message)
            at += len(message)
        elif not (seen_data and kind == ord("P")):
            head.append(message)
        pos += 3 + size
    body = np.frombuffer(b"".join(pieces), dtype=np.uint8)
    span_us = max(times) - min(t for t in times if t > 0) + 100_000
    return _repeat(out, b"".join(head), body, stamps, span_us, size_bytes)


def _repeat(
    out: Path, head: bytes, body: NDArray[np.uint8], stamps: dict[int, list[int]], span_us: int, size: int
) -> int:
    """``head``, then ``body`` until ``size`` bytes, the little-endian stamps at ``stamps[width]`` (8: µs, 4:
    ms) of copy k moved on by k spans."""
    index = {width: np.asarray(at, dtype=np.int64)[:, None] + np.arange(width) for width, at in stamps.items() if at}
    copies = 0
    with open(out, "wb") as handle:
        handle.write(head)
        written = len(head)
        while written < size:
            copy = body.copy()
            for width, where in index.items():
                kind, shift = ("<u8", copies * span_us) if width == 8 else ("<u4", copies * span_us // 1000)
                moved = np.ascontiguousarray(copy[where]).view(kind) + np.array(shift, dtype=kind)
                copy[where] = moved.view(np.uint8).reshape(where.shape)
            handle.write(copy.tobytes())
            written += len(copy)
            copies += 1
    return copies


def big_rows(folder: Path, size_mb: float, before: Path | None, dense_mb: float) -> list[dict[str, Any]]:
    """The 1 GB case: a DataFlash log and a ULog built by repeating real logs' data messages, each read in a
    fresh interpreter as ``calibrate`` reads it (at most 500 000 samples a compass: the default), against a
    plain read of its bytes and the interpreter with the readers imported, in the same run; ``before``: a
    ``src`` folder of another checkout measured the same way, on the 1 GB logs and on logs a tenth the size.
    A third ULog, ``dense_mb`` of the test suite's synthetic log repeated (two sensor_mag at 50 Hz), shows the
    thinning of a topic beyond 2^19 messages (the real sample log logs its compass at about 1 Hz)."""
    rows: list[dict[str, Any]] = []
    dense = synthetic_logs(folder, 30_000)[0]  # sensor_mag at 50 Hz: the real ULog logs its compass at 1 Hz
    for source, build, suffix, largest in (
        (BIG_DATAFLASH, build_big_dataflash, ".bin", size_mb),
        (BIG_ULOG, build_big_ulog, ".ulg", size_mb),
        (dense, build_big_ulog, ".ulg", dense_mb),
    ):
        if not largest:
            continue
        sizes = [largest] + ([largest / 10] if before is not None and source != dense else [])
        for mb in sizes:
            path = folder / f"big_{source.stem}_{mb:.0f}MB{suffix}"
            started = time.perf_counter()
            copies = build(source, path, int(mb * 1e6))
            print(f"built {path.name}: {copies} copies of {source.name}'s data, {time.perf_counter() - started:.0f} s",
                  flush=True)  # fmt: skip
            bytes_read = measure(path, "bytes")
            imported = measure(path, "import")
            readers = [("magfit (this tree)", None)] + ([("magfit (before)", before)] if before is not None else [])
            for label, src in readers:
                if src is not None:
                    whats: tuple[str, ...] = ("all",)
                elif mb != largest or source == dense:
                    whats = ("500000", "all")
                else:
                    whats = ("500000", "calibrate")
                for what in whats:
                    got = measure(path, what, src)
                    row = {
                        "file": path.name,
                        "source": source.name,
                        "copies": copies,
                        "size_mb": round(path.stat().st_size / 1e6, 1),
                        "reader": label,
                        "max_samples": {"all": None, "calibrate": "calibrate"}.get(what, what),
                        "samples": got["samples"],
                        "seconds": got["seconds"],
                        "peak_mb": got["peak_mb"],
                        "bytes_seconds": bytes_read["seconds"],
                        "import_peak_mb": imported["peak_mb"],
                        "time_ratio": got["seconds"] / bytes_read["seconds"],
                        "error": got.get("error"),
                    }
                    rows.append(row)
                    print(f"  {label:20s} max_samples={what:7s} {row['seconds']:7.1f} s ({row['time_ratio']:.0f}x the "
                          f"bytes' read)  peak {row['peak_mb']:6.0f} MB (import {row['import_peak_mb']:.0f} MB)",
                          flush=True)  # fmt: skip
            path.unlink()
    return rows


def write_big(rows: list[dict[str, Any]], output: Path) -> str:
    """``logs-big.md`` and ``.json``: the 1 GB case's table and verdict."""
    from magfit import __version__

    full = [r for r in rows if r["reader"] == "magfit (this tree)" and r["size_mb"] >= 900]
    ok = bool(full) and all(r["peak_mb"] <= BIG_TARGET_MB for r in full)
    verdict = "PASS" if ok else "FAIL"
    lines = [
        "# A 1 GB flight log: peak memory and time (benchmarks/logs.py --big)",
        "",
        f"{_dt.date.today().isoformat()}, magfit {__version__}, Python {platform.python_version()}, "
        f"{os.cpu_count()} cores, load average {os.getloadavg()[0]:.2f}; one run each, in a fresh interpreter.",
        "",
        f"Target: a 1 GB log read in at most about {BIG_TARGET_MB:.0f} MB. **{verdict}** "
        f"(peaks {', '.join(str(round(r['peak_mb'])) + ' MB' for r in full)}).",
        "",
        "| file | MB | reader | max_samples | samples | s | × bytes' read | peak MB | import MB |",
        "|---|---:|---|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        lines.append(
            f"| {r['file']} | {r['size_mb']:.0f} | {r['reader']} | {r['max_samples'] or 'all'} | {r['samples']} | "
            f"{r['seconds']:.1f} | {r['time_ratio']:.0f} | {r['peak_mb']:.0f} | {r['import_peak_mb']:.0f} |"
        )
    lines += [
        "",
        "Files: the real logs' data messages repeated, each copy's time stamps moved on by the log's span "
        "(`build_big_dataflash`, `build_big_ulog`): copter33_log171_trimmed.bin (a real ArduCopter 3.3 flight, "
        "CC BY-SA 3.0, tests/data/ardupilot_real/README.md) and PX4's sample_log_small.ulg (pyulog's repository, "
        "BSD-3-Clause, tests/data/px4_pyulog/LICENSE), whose compass is logged at about 1 Hz (14 000 samples "
        "in 1 GB); and, for a topic beyond the 2^19 messages a ULog reader keeps, the test suite's synthetic "
        "ULog (`synthetic_30000`: two sensor_mag at 50 Hz, vehicle_magnetometer, vehicle_attitude) repeated. "
        "Built in a temporary folder, deleted after.",
        "",
        "Reading: `open_source(path, everything=False)` and `Source.read(id, max_samples=...)` of every usable "
        "compass (`all`: `Source.read(id)`, as the readers before took it), in a fresh interpreter; peak: its "
        "`VmHWM` (`ru_maxrss` would carry the benchmark's own resident size from before the exec). `calibrate`: "
        "the whole default `magfit.calibrate_file(path)` (auto, every compass; its "
        "samples: those fitted, 0 when every compass was refused). References in the same run: a plain read of the "
        "file's bytes in 8 MB blocks (the time ratio), and the interpreter with magfit's readers and pyulog "
        "imported, reading nothing (import MB: the floor under every peak).",
        "",
    ]
    output.write_text("\n".join(lines))
    output.with_suffix(".json").write_text(json.dumps({"target_mb": BIG_TARGET_MB, "rows": rows}, indent=2) + "\n")
    print(f"wrote {output}: {verdict}")
    return verdict


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--small", action="store_true", help="only the committed fixtures")
    parser.add_argument("--samples", type=int, default=30_000, help="samples per compass of the synthetic logs")
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--output", type=Path, default=RESULTS / "logs.md")
    parser.add_argument("--big", action="store_true", help="only the 1 GB case (results: logs-big.md)")
    parser.add_argument("--big-mb", type=float, default=1000.0, help="size of the big logs, MB")
    parser.add_argument("--before", type=Path, help="a src folder of another checkout, measured the same way")
    parser.add_argument("--dense-mb", type=float, default=150.0, help="size of the dense synthetic ULog, MB (0: none)")
    args = parser.parse_args(argv)
    if args.big:
        with tempfile.TemporaryDirectory() as folder:
            rows = big_rows(Path(folder), args.big_mb, args.before, args.dense_mb)
        return 0 if write_big(rows, RESULTS / "logs-big.md") == "PASS" else 1
    try:
        import pymavlink  # noqa: F401

        have_pymavlink = True
    except ImportError:
        have_pymavlink = False
    files = [
        DATA / "px4_pyulog" / "sample_log_small.ulg",
        DATA / "ardupilot_sitl" / "sitl_three_compasses.bin",
    ]
    rows: list[dict[str, Any]] = []
    with tempfile.TemporaryDirectory() as folder:
        if not args.small:
            files += synthetic_logs(Path(folder), args.samples)
        for path in files:
            if path.suffix == ".ulg":
                references: dict[str, Callable[[Path], int]] = {"pyulog.ULog": pyulog_read}
            else:
                references = {"header walk (floor)": header_walk}
                if have_pymavlink:
                    references["pymavlink DFReader"] = pymavlink_read
            times = best_of({"magfit": magfit_read, **references}, path, args.repeat)
            samples = magfit_read(path)
            for name in references:
                rows.append(
                    {
                        "file": path.name,
                        "size_mb": round(path.stat().st_size / 1e6, 3),
                        "samples": samples,
                        "magfit_s": times["magfit"],
                        "reference": name,
                        "reference_s": times[name],
                        "ratio": times["magfit"] / times[name],
                    }
                )
                print(
                    f"{path.name:34s} {rows[-1]['size_mb']:7.2f} MB  magfit {times['magfit']:.4f} s  "
                    f"{name} {times[name]:.4f} s  ratio {rows[-1]['ratio']:.2f}",
                    flush=True,
                )
    write_results(rows, args, have_pymavlink)
    library = [row for row in rows if row["reference"] != "header walk (floor)"]
    return 0 if all(row["ratio"] <= TARGET for row in library) else 1


def write_results(rows: list[dict[str, Any]], args: argparse.Namespace, have_pymavlink: bool) -> None:
    """``logs.md`` (the table and the verdict) and ``logs.json`` (every number) beside it."""
    from importlib.metadata import version

    from magfit import __version__

    library = [row for row in rows if row["reference"] != "header walk (floor)"]
    verdict = "PASS" if library and all(row["ratio"] <= TARGET for row in library) else "FAIL"
    worst = max((row["ratio"] for row in library), default=float("nan"))
    versions = f"pyulog {version('pyulog')}"
    if have_pymavlink:  # not a magfit dependency: installed apart for the comparison (see the docstring)
        versions += f", pymavlink {version('pymavlink')} (installed apart for this comparison, no magfit dependency)"
    lines = [
        "# Reading flight logs: magfit against the format libraries (benchmarks/logs.py)",
        "",
        f"{_dt.date.today().isoformat()}, magfit {__version__}, Python {platform.python_version()}, {versions}, "
        f"{os.cpu_count()} cores, load average {os.getloadavg()[0]:.2f}; best of {args.repeat}, both sides in the "
        "same run taking turns.",
        "",
        f"Target: magfit's reading at most {TARGET:g}x the library's own reading of the same topics. "
        f"**{verdict}** (worst ratio {worst:.2f}).",
        "",
        "| file | MB | samples | magfit (s) | reference | reference (s) | ratio |",
        "|---|---:|---:|---:|---|---:|---:|",
    ]
    for row in rows:
        lines.append(
            f"| {row['file']} | {row['size_mb']:.2f} | {row['samples']} | {row['magfit_s']:.4f} | {row['reference']} | "
            f"{row['reference_s']:.4f} | {row['ratio']:.2f} |"
        )
    lines += [
        "",
        "magfit: `open_source(path, everything=False)` and `Source.read` of every usable compass (the raw field, a "
        "calibrated stream undone with the log's parameters). pyulog.ULog: the same topics (magnetometers, GNSS). "
        "pymavlink DFReader: `recv_match` over MAG*, PARM and GPS, the fields read. Header walk: the one Python "
        "pass over the DataFlash message headers magfit's reader makes before NumPy decodes each type's payloads "
        "(a floor, not a library: the ratio says what decoding and undoing the calibration add).",
        "",
    ]
    args.output.parent.mkdir(parents=True, exist_ok=True)
    args.output.write_text("\n".join(lines))
    args.output.with_suffix(".json").write_text(json.dumps({"target": TARGET, "rows": rows}, indent=2) + "\n")
    print(f"wrote {args.output} and {args.output.with_suffix('.json').name}: {verdict}")


if __name__ == "__main__":
    raise SystemExit(main())
