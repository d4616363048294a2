"""The command line on a big CSV: ``magfit calibrate`` on 10 million rows against the fastest reader alone.

    .venv/bin/python benchmarks/csv_cli.py [--rows 10000000] [--repeat 3] [--workdir /tmp/magfit-speed]

Parts 2 and 6 of benchmarks/speed.py, on their own (the same functions, the same CSV, the same readers):
the readers (pandas' C and pyarrow engines, pyarrow.csv whole and streamed in 4 MB blocks, polars when it
is installed) and ``magfit calibrate`` with ``-m ellipsoid``, with the default method (``auto``) and with the
default method parsing with pandas alone (``MAGFIT_CSV_READER=pandas``) take turns ``--repeat`` times, the
best of each counts; then the default command alone, for its peak RSS. Targets (issue 24): the default
command within 1.5x the fastest reader, in under 300 MB.

Results: ``benchmarks/results/csv_cli.md`` and ``csv_cli.json`` beside it (``--output``).
"""

from __future__ import annotations

import argparse
import datetime as _dt
import json
import os
import sys
import tempfile
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))

from speed import PANDAS_LABEL, machine, make_samples, part_cli, part_memory

ROOT = Path(__file__).resolve().parents[1]
TARGET_RATIO, TARGET_MB = 1.5, 300.0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rows", type=int, default=10_000_000)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--workdir", type=Path, default=Path(tempfile.gettempdir()) / "magfit-speed")
    parser.add_argument("--output", type=Path, default=ROOT / "benchmarks" / "results" / "csv_cli.md")
    args = parser.parse_args(argv)
    os.environ.pop("PYTHONDONTWRITEBYTECODE", None)
    args.workdir.mkdir(parents=True, exist_ok=True)
    info = machine()
    csv = args.workdir / f"samples_{args.rows}.csv"
    samples = make_samples(args.rows) if not csv.exists() else None  # (written once, then reused)
    cli = part_cli(args.rows, args.repeat, args.workdir, samples if samples is not None else _unused())
    memory = part_memory(args.rows, args.workdir, samples if samples is not None else _unused())
    results: dict[str, Any] = {
        "date": _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC"),
        "machine": info,
        "repeat": args.repeat,
        "cli": cli,
        "memory": memory,
        "load_average_end": os.getloadavg(),
    }
    args.output.write_text(report(results) + "\n", encoding="utf-8")
    args.output.with_suffix(".json").write_text(json.dumps(results, indent=2, default=float) + "\n", encoding="utf-8")
    print(report(results))
    return 0


def _unused() -> Any:
    import numpy as np

    return np.empty((0, 3))


def report(results: dict[str, Any]) -> str:
    info, cli, memory = results["machine"], results["cli"], results["memory"]
    lines = [
        f"# `magfit calibrate` on a {cli['n']:,}-row CSV ({cli['csv_mb']:.0f} MB) against the fastest reader",
        "",
        f"{results['date']}; {info['cpu']}, {info['cores']} cores, Python {info['python']}; load average "
        f"{info['load_average'][0]:.1f} at the start, {results['load_average_end'][0]:.1f} at the end. "
        f"`python benchmarks/csv_cli.py --repeat {results['repeat']}`: the readers and the two commands take turns, "
        "the best of each counts (CPU time: the least).",
        "",
        "| reader or command | wall (s) | CPU (s) | peak RSS (MB) | fitted on |",
        "|---|---:|---:|---:|---|",
    ]
    for name, row in cli["readers"].items():
        if "error" in row:
            lines.append(f"| {name} | {row['error']} | | | |")
        else:
            lines.append(f"| {name} | {row['seconds']:.2f} | {row['cpu_seconds']:.2f} | {row['rss_mb']:.0f} | |")
    for name, row in cli["calibrate"].items():
        if "error" in row:
            lines.append(f"| `magfit calibrate {name}` | {row['error'][:80]} | | | |")
        else:
            lines.append(
                f"| `magfit calibrate {name}` | {row['seconds']:.2f} | {row['cpu_seconds']:.2f} | {row['rss_mb']:.0f} "
                f"| {row['fitted_on']} |"
            )
    default_ok = cli["default_vs_reader"] <= TARGET_RATIO
    rss = memory.get("rss_mb", float("nan"))
    default_s = cli["calibrate"]["(default: auto)"].get("seconds", float("nan"))
    pandas_s = cli["calibrate"].get(PANDAS_LABEL, {}).get("seconds", float("nan"))
    default_cpu = cli["calibrate"]["(default: auto)"].get("cpu_seconds", float("nan"))
    fastest_row = cli["readers"].get(cli.get("fastest_reader", ""), {})
    pyarrow_cpu = cli["readers"].get("pyarrow.csv", {}).get("cpu_seconds", float("nan"))
    lines += [
        "",
        f"- The default command (`auto`): **{cli['default_vs_reader']:.2f}x** the fastest reader alone "
        f"({cli.get('fastest_reader', '')}, {cli['fastest_reader_s']:.2f} s), CPU {cli['default_cpu_vs_reader']:.2f}x "
        f"the least reader's; target <= {TARGET_RATIO:g}x: {'met' if default_ok else 'NOT met'}.",
        *(
            [
                f"- Caution: in its best run the fastest reader took {fastest_row['seconds']:.2f} s of wall time for "
                f"{fastest_row['cpu_seconds']:.2f} s of CPU, so it had no second core to itself (a loaded machine): "
                "the wall ratio then measures how the load fell on each run as much as the programs. "
                "The CPU ratios are the steadier figures."
            ]
            if fastest_row.get("seconds", 0.0) >= 0.9 * fastest_row.get("cpu_seconds", float("inf"))
            else []
        ),
        f"- Against pyarrow.csv alone ({cli.get('pyarrow_reader_s', float('nan')):.2f} s): "
        f"{default_s / cli.get('pyarrow_reader_s', float('nan')):.2f}x, CPU {default_cpu / pyarrow_cpu:.2f}x.",
        f"- The same command with the text parsed by pandas alone (`MAGFIT_CSV_READER=pandas`, the reader before "
        f"pyarrow's blocks): {pandas_s / cli['fastest_reader_s']:.2f}x the fastest reader.",
        f"- `-m ellipsoid`: {cli['cli_vs_reader']:.2f}x (CPU {cli['cli_cpu_vs_reader']:.2f}x).",
        f"- The default command alone: peak RSS **{rss:.0f} MB**, {memory.get('seconds', float('nan')):.2f} s; target "
        f"< {TARGET_MB:g} MB: {'met' if rss < TARGET_MB else 'NOT met'}.",
    ]
    return "\n".join(lines)


if __name__ == "__main__":
    raise SystemExit(main())
