"""Start-up: ``magfit calibrate`` on a 300-row CSV against ``import magfit.cli``, and what it imports beyond it.

    .venv/bin/python benchmarks/startup.py [--rounds 9] [--importtime 5]

1. Four processes taking turns for ``--rounds`` rounds (the best of each counts; a slow spell of the shared
   machine slows a whole round): ``python -c "import numpy"``, ``python -c "import magfit"``,
   ``python -c "import magfit.cli"`` and ``magfit calibrate small.csv`` (the default method, 300 rows of
   benchmarks/speed.py's scenario), as part 5 of benchmarks/speed.py measures them (one definition:
   ``speed.startup_processes``, with the bytecode compiled once and kept, as installed). Targets: the
   command within 2x the CLI's import (issue 24); the import against ``import numpy`` is reported (no
   target). Wall time and CPU time (the launcher's
   ``RUSAGE_CHILDREN``), since CPU time moves less with the machine's load.
2. ``python -X importtime`` of both, ``--importtime`` runs each: the modules the command imports beyond the
   CLI's own, each its least self time over the runs, the largest first (what is left to make lazy).

Results: ``benchmarks/results/startup.md`` and ``startup.json`` beside it (``--output``).
"""

from __future__ import annotations

import argparse
import collections
import datetime as _dt
import json
import os
import re
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))

from speed import N_RATIO_CSV, machine, make_samples, startup_processes, write_csv

ROOT = Path(__file__).resolve().parents[1]
TARGET = 2.0
_IMPORT_LINE = re.compile(r"import time:\s+(\d+) \|\s+(\d+) \|( *)(\S+)")


def _importtime(command: list[str], runs: int) -> dict[str, int]:
    """Each module's least self time (µs) over ``runs`` runs of ``python -X importtime`` ``command``."""
    env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
    best: dict[str, int] = {}
    for _ in range(runs):
        run = subprocess.run([sys.executable, "-X", "importtime", *command], capture_output=True, text=True, env=env)
        seen: dict[str, int] = {}
        for line in run.stderr.splitlines():
            match = _IMPORT_LINE.match(line)
            if match:
                seen[match.group(4)] = int(match.group(1))
        best = seen if not best else {k: min(v, seen.get(k, v)) for k, v in best.items()}
    return best


def _group(module: str) -> str:
    """A module's package as a line of the table: magfit's to two levels below it, others their top level."""
    parts = module.split(".")
    return ".".join(parts[:3]) if parts[0] == "magfit" else parts[0]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=9)
    parser.add_argument("--importtime", type=int, default=5, help="runs of python -X importtime (0: none)")
    parser.add_argument("--output", type=Path, default=ROOT / "benchmarks" / "results" / "startup.md")
    args = parser.parse_args(argv)
    os.environ.pop("PYTHONDONTWRITEBYTECODE", None)  # (the children compile their bytecode once, as installed)
    info = machine()
    with tempfile.TemporaryDirectory() as folder:
        csv = Path(folder) / "small.csv"
        write_csv(make_samples(N_RATIO_CSV, seed=11), csv)
        labels = {
            "numpy": "import numpy",
            "package": "import magfit",
            "import": "import magfit.cli",
            "calibrate": "magfit calibrate (300 rows)",
        }
        best = {labels[key]: run for key, run in startup_processes(args.rounds, csv).items()}
        times: dict[str, dict[str, float]] = {}
        for name, run in best.items():
            if isinstance(run, RuntimeError):
                raise run
            times[name] = {"seconds": run.seconds, "cpu_seconds": run.cpu_seconds, "rss_mb": run.rss_mb}
        extra: dict[str, int] = {}
        if args.importtime:
            base = _importtime(["-c", "import magfit.cli"], args.importtime)
            command = _importtime(["-m", "magfit", "calibrate", str(csv)], args.importtime)
            extra = {k: v for k, v in command.items() if k not in base}
    cli, command_row = times["import magfit.cli"], times["magfit calibrate (300 rows)"]
    results: dict[str, Any] = {
        "date": _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC"),
        "machine": info,
        "rounds": args.rounds,
        "times": times,
        "calibrate_vs_import": command_row["seconds"] / cli["seconds"],
        "calibrate_vs_import_cpu": command_row["cpu_seconds"] / cli["cpu_seconds"],
        "import_vs_numpy": cli["seconds"] / times["import numpy"]["seconds"],
        "package_vs_numpy": times["import magfit"]["seconds"] / times["import numpy"]["seconds"],
        "extra_imports_us": dict(sorted(extra.items(), key=lambda kv: -kv[1])),
        "load_average_end": os.getloadavg(),
    }
    args.output.write_text(report(results) + "\n", encoding="utf-8")
    args.output.with_suffix(".json").write_text(json.dumps(results, indent=2) + "\n", encoding="utf-8")
    print(report(results))
    return 0


def report(results: dict[str, Any]) -> str:
    info, times = results["machine"], results["times"]
    verdict = "met" if results["calibrate_vs_import"] <= TARGET else "NOT met"
    lines = [
        "# Start-up: `magfit calibrate` on a small file against the CLI's import",
        "",
        f"{results['date']}; {info['cpu']}, {info['cores']} cores, Python {info['python']}, NumPy {info['numpy']}; "
        f"load average {info['load_average'][0]:.1f} at the start, {results['load_average_end'][0]:.1f} at the end. "
        f"`python benchmarks/startup.py --rounds {results['rounds']}`: the four processes take turns, the best of "
        "each counts.",
        "",
        "| process | wall (s) | CPU (s) | peak RSS (MB) |",
        "|---|---:|---:|---:|",
    ]
    for name, row in times.items():
        lines.append(f"| `{name}` | {row['seconds']:.3f} | {row['cpu_seconds']:.3f} | {row['rss_mb']:.0f} |")
    lines += [
        "",
        f"- `magfit calibrate` on {N_RATIO_CSV} rows: **{results['calibrate_vs_import']:.2f}x** `import magfit.cli` "
        f"(CPU {results['calibrate_vs_import_cpu']:.2f}x); target <= {TARGET:g}x: {verdict}.",
        f"- `import magfit.cli`: {results['import_vs_numpy']:.2f}x `import numpy`; `import magfit`: "
        f"{results['package_vs_numpy']:.2f}x.",
    ]
    extra = results["extra_imports_us"]
    if extra:
        groups: collections.Counter[str] = collections.Counter()
        for module, microseconds in extra.items():
            groups[_group(module)] += microseconds
        lines += [
            "",
            f"What the command imports beyond `import magfit.cli`: {len(extra)} modules, "
            f"{sum(extra.values()) / 1000:.0f} ms of self time (`-X importtime`, the least of each over the runs); "
            "the largest packages:",
            "",
            "| package | ms |",
            "|---|---:|",
        ]
        lines += [f"| `{name}` | {us / 1000:.1f} |" for name, us in groups.most_common(15)]
    return "\n".join(lines)


if __name__ == "__main__":
    raise SystemExit(main())
