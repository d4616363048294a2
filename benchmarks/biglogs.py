"""A 1 GB telemetry log (and DataFlash log, and ULog) read in bounded memory: peak memory and time.

    .venv/bin/python benchmarks/biglogs.py                 # tlog, DataFlash and ULog of 1 GB, a few minutes
    .venv/bin/python benchmarks/biglogs.py --mb 200 --only tlog

The target: a 1 GB log read in at most about 300 MB. Each big log is built in a temporary folder by
repeating a real log's records (deleted after; never committed), then read in a fresh interpreter as
``calibrate`` reads it (``open_source(path, everything=False)`` and ``Source.read`` of every usable compass,
at most 500 000 samples each: the default), its peak resident memory (``VmHWM``) and time beside a plain read
of the file's bytes and the interpreter with the readers imported (the floor under every peak), in the same run:

- **tlog**: tests/data/ardupilot_real/fs_batt_2016.tlog (a real ArduCopter flight's telemetry, CC BY-SA 3.0,
  tests/data/ardupilot_real/README.md), its records again and again, each copy's tlog time stamps moved on by
  the log's span (the messages' own boot stamps are left: each copy is a reboot to the reader);
- **DataFlash**: tests/data/ardupilot_real/copter462_head_80k.bin (the head of a real ArduCopter 4.6 log, same
  README), by :func:`benchmarks.logs.build_big_dataflash`;
- **ULog**: tests/data/px4_pyulog/sample_log_small.ulg (pyulog's repository, BSD-3-Clause), by
  :func:`benchmarks.logs.build_big_ulog`.

Results: ``benchmarks/results/biglogs.md`` with ``--write``.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))

import logs

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / "tests" / "data"
TLOG = DATA / "ardupilot_real" / "fs_batt_2016.tlog"
DATAFLASH = DATA / "ardupilot_real" / "copter462_head_80k.bin"
ULOG = DATA / "px4_pyulog" / "sample_log_small.ulg"
TARGET_MB = 300.0


def tlog_records(data: bytes) -> list[tuple[int, int]]:
    """(start, end) of each record of a clean tlog: its 8-byte stamp, then one MAVLink frame."""
    records, pos = [], 0
    while pos + 10 <= len(data):
        magic, length = data[pos + 8], data[pos + 9]
        size = length + 8 if magic == 0xFE else length + 12 + (13 if data[pos + 10] & 1 else 0)
        records.append((pos, pos + 8 + size))
        pos += 8 + size
    return records


def build_big_tlog(source: Path, out: Path, size_bytes: int) -> int:
    """Write ``out``: ``source``'s records again and again up to ``size_bytes``, each copy's record stamps
    (big-endian microseconds) moved on by the log's span. Returns the number of copies."""
    import numpy as np

    data = source.read_bytes()
    records = tlog_records(data)
    body = np.frombuffer(data[: records[-1][1]], dtype=np.uint8).copy()
    starts = np.array([start for start, _ in records], dtype=np.int64)
    stamps = body[starts[:, None] + np.arange(8)].copy().view(">u8").reshape(-1)
    span = int(stamps.max() - stamps.min()) + 100_000
    copies, written = 0, 0
    with open(out, "wb") as handle:
        while written < size_bytes:
            moved = (stamps + np.uint64(copies * span)).astype(">u8")
            body[starts[:, None] + np.arange(8)] = moved.view(np.uint8).reshape(-1, 8)
            handle.write(body.tobytes())
            written += len(body)
            copies += 1
    return copies


def rows_for(kind: str, source: Path, build: Any, suffix: str, folder: Path, mb: float) -> list[dict[str, Any]]:
    path = folder / f"big_{source.stem}_{mb:.0f}MB{suffix}"
    started = time.perf_counter()
    copies = build(source, path, int(mb * 1e6))
    print(f"built {path.name}: {copies} copies, {time.perf_counter() - started:.0f} s", flush=True)
    plain = logs.measure(path, "bytes")
    floor = logs.measure(path, "import")
    got = logs.measure(path, "500000")
    row = {
        "kind": kind,
        "file": path.name,
        "source": source.name,
        "copies": copies,
        "size_mb": round(path.stat().st_size / 1e6, 1),
        "samples": got["samples"],
        "seconds": got["seconds"],
        "peak_mb": got["peak_mb"],
        "bytes_seconds": plain["seconds"],
        "import_peak_mb": floor["peak_mb"],
        "error": got.get("error"),
    }
    print(f"  {kind}: {row['seconds']:.1f} s, peak {row['peak_mb']:.0f} MB (import {row['import_peak_mb']:.0f} MB)"
          f"{' error ' + str(row['error']) if row['error'] else ''}", flush=True)  # fmt: skip
    path.unlink()
    return [row]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--mb", type=float, default=1000.0, help="size of each big log, MB")
    parser.add_argument("--only", choices=("tlog", "dataflash", "ulog"), action="append")
    parser.add_argument("--write", action="store_true")
    args = parser.parse_args(argv)
    cases = [("tlog", TLOG, build_big_tlog, ".tlog"), ("dataflash", DATAFLASH, logs.build_big_dataflash, ".bin"),
             ("ulog", ULOG, logs.build_big_ulog, ".ulg")]  # fmt: skip
    rows: list[dict[str, Any]] = []
    with tempfile.TemporaryDirectory() as folder:
        for kind, source, build, suffix in cases:
            if args.only and kind not in args.only:
                continue
            rows += rows_for(kind, source, build, suffix, Path(folder), args.mb)
    worst = max((row["peak_mb"] for row in rows), default=float("nan"))
    verdict = "PASS" if all(not row["error"] and row["peak_mb"] <= TARGET_MB for row in rows) else "FAIL"
    load = ", ".join(f"{v:.1f}" for v in os.getloadavg())
    lines = [
        "# A 1 GB log of each kind: peak memory and time (benchmarks/biglogs.py)",
        "",
        f"`python benchmarks/biglogs.py --mb {args.mb:g}`; {os.cpu_count()} cores, load average {load}; one run "
        "each, in a fresh interpreter.",
        "",
        f"Target: a 1 GB log read in at most about {TARGET_MB:.0f} MB. **{verdict}** (worst peak "
        f"{worst:.0f} MB).",
        "",
        "| kind | file | MB | copies | samples read | s | × bytes' read | peak MB | import MB |",
        "|---|---|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for row in rows:
        lines.append(
            f"| {row['kind']} | {row['file']} | {row['size_mb']:.0f} | {row['copies']} | {row['samples']} | "
            f"{row['seconds']:.1f} | {row['seconds'] / row['bytes_seconds']:.0f} | {row['peak_mb']:.0f} | "
            f"{row['import_peak_mb']:.0f} |"
        )
    lines += ["", "Files: built from the real logs named in the module docstring (their licences in tests/data), "
              "in a temporary folder, deleted after. Reading: `open_source(path, everything=False)`, then "
              "`Source.read(id, max_samples=500000)` of every usable compass; peak: the fresh interpreter's "
              "`VmHWM`.", ""]  # fmt: skip
    text = "\n".join(lines)
    print(text)
    if args.write:
        (ROOT / "benchmarks" / "results" / "biglogs.md").write_text(text, encoding="utf-8")
    return 0 if verdict == "PASS" else 1


if __name__ == "__main__":
    sys.exit(main())
