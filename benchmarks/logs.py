"""How much does magfit add to reading a flight log? Its reading of each compass against the format library's own.

    .venv/bin/python benchmarks/logs.py             # about half a minute on 2 cores
    .venv/bin/python benchmarks/logs.py --small     # the committed fixtures only, a few seconds

pymavlink is no magfit dependency; install it *outside* the project's virtual environment, since it ships a
script ``magfit.py`` that, once in ``.venv/bin``, shadows the magfit package for ``.venv/bin/magfit``:

    .venv/bin/pip install --target /tmp/pymavlink pymavlink
    PYTHONPATH=/tmp/pymavlink .venv/bin/python benchmarks/logs.py

Issue 13's target: reading a log into samples costs at most 2x what its library alone needs to read the same
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
"""

from __future__ import annotations

import argparse
import datetime as _dt
import json
import os
import platform
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / "tests" / "data"
RESULTS = ROOT / "benchmarks" / "results"
#: Issue 13: at most this many times the library's own reading.
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


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--small", action="store_true", help="only the committed fixtures")
    parser.add_argument("--samples", type=int, default=30_000, help="samples per compass of the synthetic logs")
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--output", type=Path, default=RESULTS / "logs.md")
    args = parser.parse_args(argv)
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
        f"Target (issue 13): magfit's reading at most {TARGET:g}x the library's own reading of the same topics. "
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
