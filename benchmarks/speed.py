"""How fast is magfit at any size? Ratios measured in one run, on one machine, against floors and peers.

    .venv/bin/python benchmarks/speed.py                      # the full run (about 15 min on 2 cores)
    .venv/bin/python benchmarks/speed.py --smoke --no-peers   # a minute: small sizes, same tables

Four parts, each a ratio to a baseline timed in the same run (absolute times depend on the machine):

1. ``magfit.fit(samples, "ellipsoid")`` on N in-memory samples (10 million) against the bare floor, one
   chunked NumPy pass that builds the 10-column design matrix of eq. (4) and sums ``XᵀX`` (target: at
   most 3x), and against ``numpy.linalg.lstsq`` on the full design matrix (target: at least 10x
   faster); the fit's peak extra memory (tracemalloc, and RSS in a fresh process; target < 64 MB).
2. ``magfit calibrate`` on a CSV of N rows, as a subprocess, with ``-m ellipsoid`` and with the default
   method, against the fastest reader alone (pandas' C engine, pandas' pyarrow engine, pyarrow.csv whole
   and streamed; each a subprocess reading the three columns; target at most 1.5x) and their peak RSS
   (target < 300 MB, the samples alone are 24 bytes a row). The readers and both commands take turns.
3. ``magfit.fit(samples, "ml")`` on 1 million samples (target under 2 s).
4. The peers (magyc's ellipsoid fit, magcal, circuitpython-mag-cal) on the same samples at growing
   sizes, each size in its own process with a one-minute limit (run from ``benchmarks/.peers-venv``,
   see ``setup_peers.sh``); a size a peer cannot finish, or crashes on, is reported with the reason.

5. The two headline ratios, both sides timed in the same run, taking turns (best of ``--rounds``):
   ``magfit.fit(samples, "auto")`` against ``magfit.fit(samples, "ellipsoid")`` on the same 10 000 samples,
   default diagnostics (target at most 3x: ``auto`` fast enough to refit live), and ``magfit calibrate``
   (default method) on a 300-row CSV against ``python -c "import magfit.cli"``, both as processes (target
   at most 2x: the command costs little beyond its imports), and ``import magfit.cli`` against
   ``import numpy`` (no target: what magfit's own start-up costs).
6. ``magfit calibrate`` (default method) on the CSV of part 2 (10 million rows): its peak RSS (target
   < 300 MB), alone, so that it can be measured without the readers of part 2.

``--parts ratios,memory`` runs only some parts (the ratios take about a minute on an idle machine);
``--parts auto`` runs only the ``auto`` rows of part 5 (10 000, 100 000 and 1 million samples).
Times are the best of ``--repeat`` runs (the least disturbed by other processes); the machine's load
average is recorded with the results, since other work on the machine slows every row alike. The
pyarrow readers of part 2 need ``pip install pyarrow`` (a row says so when it is missing); the peak RSS
and CPU time of a subprocess come from ``resource.getrusage`` in a small launcher process. Results:
``benchmarks/results/speed.md`` and every number in ``speed.json`` beside it; the data files go to
``--workdir`` (a temporary folder).
"""

from __future__ import annotations

import argparse
import datetime as _dt
import json
import os
import platform
import re
import shlex
import subprocess
import sys
import tempfile
import time
import tracemalloc
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

import magfit

ROOT = Path(__file__).resolve().parents[1]
PEERS_PYTHON = ROOT / "benchmarks" / ".peers-venv" / "bin" / "python"
#: The samples: the paper's MPU-9250 beside a steel plate (strong, rotated soft iron), raw counts.
SCENARIO = ("mpu9250", "steel")
#: µT per count of the MPU-9250 magnetometer: the CSV holds µT with up to 3 decimals, like a real log.
MICROTESLA_PER_COUNT = 0.15
PEER_TIME_LIMIT = 60.0
#: Peak RSS a peer may be expected to need before a size is skipped (the machine is shared).
PEER_MEMORY_LIMIT_MB = 6000.0
TARGETS = {
    "fit_vs_floor": 1.0,
    "lstsq_vs_fit": 10.0,
    "fit_memory_mb": 64.0,
    "cli_vs_reader": 1.5,
    "cli_rss_mb": 300.0,
    "ml_seconds": 2.0,
    "auto_vs_ellipsoid": 3.0,
    "calibrate_vs_import": 2.0,
    "default_rss_mb": 300.0,
    "default_vs_reader": 1.5,
}
#: The parts, in the order they run (``--parts``).
PARTS = ("fit", "ml", "cli", "peers", "ratios", "auto", "memory")
#: Sizes of the headline ratios: samples of the in-memory fits, rows of the small CSV; and the larger sizes at
#: which ``auto`` is also timed against ``ellipsoid``.
N_RATIO_FIT = 10_000
N_RATIO_CSV = 300
N_RATIO_LARGE = (100_000, 1_000_000)


# ---------------------------------------------------------------------- data


def make_samples(n: int, seed: int = 0) -> NDArray[np.float64]:
    """N samples of the scenario, simulated a million at a time (bounded temporaries), shape (n, 3)."""
    scenario = magfit.scenario(*SCENARIO)
    samples = np.empty((n, 3))
    block = 1_000_000
    for i, start in enumerate(range(0, n, block)):
        size = min(block, n - start)
        samples[start : start + size] = scenario.simulate(size, seed=seed + i).samples
    return samples


def write_csv(samples: NDArray[np.float64], path: Path) -> None:
    """``time_ms,mx,my,mz`` in µT (3 decimals), written in blocks."""
    with open(path, "w", encoding="ascii") as handle:
        handle.write("time_ms,mx,my,mz\n")
        block = 500_000
        for start in range(0, len(samples), block):
            part = np.round(samples[start : start + block] * MICROTESLA_PER_COUNT, 3)
            times = np.arange(start, start + len(part)) * 10
            rows = zip(times.tolist(), part.tolist(), strict=True)
            lines = [f"{t},{x:.3f},{y:.3f},{z:.3f}\n" for t, (x, y, z) in rows]
            handle.writelines(lines)


# ---------------------------------------------------------------------- timing helpers


def best_time(function: Callable[[], Any], repeat: int) -> tuple[float, Any]:
    """Best wall time of ``repeat`` calls (seconds) and the last result."""
    best, result = float("inf"), None
    for _ in range(repeat):
        start = time.perf_counter()
        result = function()
        best = min(best, time.perf_counter() - start)
    return best, result


@dataclass
class ProcessRun:
    """One subprocess: wall time (s), peak RSS (MB), exit status, the tail of its output, CPU time (s)."""

    seconds: float
    rss_mb: float
    status: int
    output: str
    cpu_seconds: float = float("nan")


#: Runs the command given in its arguments and prints its peak RSS (kB) and CPU time (s) from
#: ``resource.getrusage(RUSAGE_CHILDREN)``: the launcher's only child is the command, so the children's
#: peak is the command's. (``wait4`` from the benchmark itself would not do: a child's peak can count
#: the memory of the parent it was forked from, and the benchmark holds the samples.)
_LAUNCHER = """
import resource, subprocess, sys
status = subprocess.call(sys.argv[2:])
usage = resource.getrusage(resource.RUSAGE_CHILDREN)
with open(sys.argv[1], "w") as out:
    out.write(f"{usage.ru_maxrss} {usage.ru_utime + usage.ru_stime}")
sys.exit(status)
"""


def run_process(command: Sequence[str], timeout: float | None = None) -> ProcessRun:
    """Run ``command`` in its own session under a small launcher that reports its peak RSS and CPU time."""
    with tempfile.NamedTemporaryFile("r", suffix=".rss") as rss_file:
        wrapped = [sys.executable, "-c", _LAUNCHER, rss_file.name, *command]
        start = time.perf_counter()
        process = subprocess.Popen(wrapped, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, start_new_session=True)
        try:
            output_bytes, _ = process.communicate(timeout=timeout)
            status = process.returncode
        except subprocess.TimeoutExpired:
            os.killpg(process.pid, 9)  # the whole session: the launcher and the command under it
            output_bytes, _ = process.communicate()
            status = -9
        seconds = time.perf_counter() - start
        rss_text = rss_file.read().strip().splitlines()
    fields = rss_text[-1].split() if rss_text else []
    try:
        rss_mb, cpu = float(fields[0]) / 1024, float(fields[1])
    except (IndexError, ValueError):
        rss_mb, cpu = float("nan"), float("nan")
    return ProcessRun(seconds, rss_mb, status, output_bytes.decode(errors="replace")[-2000:], cpu)


def _best_of(runs: Sequence[ProcessRun], command: Sequence[str]) -> ProcessRun:
    """The fastest of several runs of one command, with the least CPU time and the largest peak RSS seen."""
    for run in runs:
        if run.status != 0:
            raise RuntimeError(f"{shlex.join(command)} failed ({run.status}):\n{run.output}")
    fastest = min(runs, key=lambda run: run.seconds)
    cpu = min(run.cpu_seconds for run in runs)
    return ProcessRun(fastest.seconds, max(run.rss_mb for run in runs), 0, fastest.output, cpu)


# ---------------------------------------------------------------------- part 1: in-memory ellipsoid fit


def floor_scatter(samples: NDArray[np.float64], chunk: int = 1 << 16) -> NDArray[np.float64]:
    """The bare floor: one chunked pass, the (n, 10) design matrix of eq. (4), ``XᵀX`` summed."""
    scatter = np.zeros((10, 10))
    for start in range(0, len(samples), chunk):
        x = samples[start : start + chunk]
        design = np.empty((len(x), 10))
        design[:, 0:3] = x * x
        design[:, 3] = x[:, 0] * x[:, 1]
        design[:, 4] = x[:, 0] * x[:, 2]
        design[:, 5] = x[:, 1] * x[:, 2]
        design[:, 6:9] = x
        design[:, 9] = 1.0
        scatter += design.T @ design
    return scatter


def lstsq_fit(samples: NDArray[np.float64]) -> NDArray[np.float64]:
    """The usual ellipsoid fit of the peers: ``lstsq`` of ``[x² y² z² 2xy 2xz 2yz 2x 2y 2z] θ = 1``."""
    x, y, z = samples.T
    design = np.column_stack([x * x, y * y, z * z, 2 * x * y, 2 * x * z, 2 * y * z, 2 * x, 2 * y, 2 * z])
    solution: NDArray[np.float64] = np.linalg.lstsq(design, np.ones(len(samples)), rcond=None)[0]
    return solution


def fit_memory(samples: NDArray[np.float64]) -> float:
    """Peak bytes NumPy allocates during ``magfit.fit(samples, "ellipsoid")`` (tracemalloc), in MB."""
    tracemalloc.start()
    try:
        magfit.fit(samples, "ellipsoid")
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    return peak / 1e6


_RSS_SCRIPT = """
import sys, numpy as np, magfit
def status(key):
    for line in open("/proc/self/status"):
        if line.startswith(key):
            return int(line.split()[1]) / 1024
samples = np.load(sys.argv[1])
magfit.fit(samples[:1000], "ellipsoid")  # import and warm up everything the fit touches
open("/proc/self/clear_refs", "w").write("5")  # reset the peak RSS (VmHWM) to the current RSS
before = status("VmRSS")
magfit.fit(samples, "ellipsoid")
print(status("VmHWM") - before)
"""


def part_fit(n: int, repeat: int, workdir: Path, samples: NDArray[np.float64]) -> dict[str, Any]:
    """The floor, Statistics, the fit with and without its diagnostics, taking turns (min of ``repeat`` each)."""
    print(f"[fit] {n:,} in-memory samples", flush=True)
    timed: dict[str, Callable[[], Any]] = {
        "floor": lambda: floor_scatter(samples),
        "statistics": lambda: magfit.Statistics.from_samples(samples),
        "fit": lambda: magfit.fit(samples, "ellipsoid"),
        "fit_quiet": lambda: magfit.fit(samples, "ellipsoid", diagnostics=False),
    }
    magfit.fit(samples[:5000], "ellipsoid")  # imports and caches outside the timing
    times: dict[str, list[float]] = {name: [] for name in timed}
    outputs: dict[str, Any] = {}
    for _ in range(repeat):  # a slow spell of the shared machine slows every row of a round alike
        for name, function in timed.items():
            start = time.perf_counter()
            outputs[name] = function()
            times[name].append(time.perf_counter() - start)
    best = {name: min(values) for name, values in times.items()}
    calibration = outputs["fit"]
    lstsq, _ = best_time(lambda: lstsq_fit(samples), 1)
    memory = fit_memory(samples)
    npy = workdir / f"samples_{n}.npy"
    if not npy.exists():
        np.save(npy, samples)
    rss = float(run_process([sys.executable, "-c", _RSS_SCRIPT, str(npy)]).output.strip().splitlines()[-1])
    truth = magfit.scenario(*SCENARIO).simulate(1).truth
    return {
        "n": n,
        "floor_s": best["floor"],
        "statistics_s": best["statistics"],
        "fit_s": best["fit"],
        "fit_no_diagnostics_s": best["fit_quiet"],
        "all_s": times,
        "lstsq_s": lstsq,
        "fit_vs_floor": best["fit"] / best["floor"],
        "fit_no_diagnostics_vs_floor": best["fit_quiet"] / best["floor"],
        "lstsq_vs_fit": lstsq / best["fit"],
        "fit_tracemalloc_mb": memory,
        "fit_rss_extra_mb": rss,
        "offset_error": float(np.linalg.norm(calibration.offset - truth.offset)),
        "verdict": _support(calibration),
        "verdict_no_diagnostics": _support(outputs["fit_quiet"]),
    }


# ---------------------------------------------------------------------- part 2: the command line on a CSV

#: ``magfit calibrate`` (default method) with its text parsed by pandas alone (``MAGFIT_CSV_READER=pandas``).
PANDAS_LABEL = "(default: auto), pandas parse"

_READERS = {
    "pandas (C engine)": "import pandas as pd, sys; "
    "a = pd.read_csv(sys.argv[1], usecols=['mx', 'my', 'mz'], engine='c', dtype='float64').to_numpy()",
    "pandas (pyarrow engine)": "import pandas as pd, sys; "
    "a = pd.read_csv(sys.argv[1], usecols=['mx', 'my', 'mz'], engine='pyarrow', dtype='float64').to_numpy()",
    "pyarrow.csv": "import pyarrow as pa, pyarrow.csv as c, numpy as np, sys; "
    "t = c.read_csv(sys.argv[1], convert_options=c.ConvertOptions(include_columns=['mx', 'my', 'mz'], "
    "column_types={k: pa.float64() for k in ('mx', 'my', 'mz')})); "
    "a = np.column_stack([t.column(k).to_numpy() for k in ('mx', 'my', 'mz')])",
    # polars, when installed (it is no dependency of magfit): the fastest whole-file reader of three float
    # columns measured here; a row that says it is not installed otherwise.
    "polars": "import polars as pl, sys; "
    "a = pl.read_csv(sys.argv[1], columns=['mx', 'my', 'mz'], "
    "schema_overrides={k: pl.Float64 for k in ('mx', 'my', 'mz')}).to_numpy()",
    # The bounded-memory form of the same reader: record batches of block_size bytes, parsed on threads.
    "pyarrow.csv, streamed (open_csv, 4 MB blocks)": "import pyarrow as pa, pyarrow.csv as c, numpy as np, sys; "
    "r = c.open_csv(sys.argv[1], read_options=c.ReadOptions(block_size=4 << 20), "
    "convert_options=c.ConvertOptions(include_columns=['mx', 'my', 'mz'], "
    "column_types={k: pa.float64() for k in ('mx', 'my', 'mz')})); "
    "n = sum(len(np.column_stack([b.column(i).to_numpy() for i in range(3)])) for b in r)",
}


def _interleaved(commands: dict[str, list[str]], repeat: int) -> dict[str, ProcessRun | RuntimeError]:
    """Best run of each command, the commands taking turns: a slow spell on the machine hits them all alike."""
    runs: dict[str, list[ProcessRun]] = {name: [] for name in commands}
    for _ in range(repeat):
        for name, command in commands.items():
            runs[name].append(run_process(command))
    best: dict[str, ProcessRun | RuntimeError] = {}
    for name, command in commands.items():
        try:
            best[name] = _best_of(runs[name], command)
        except RuntimeError as error:
            best[name] = error
    return best


def _calibrate_row(run: ProcessRun) -> dict[str, Any]:
    fitted = re.search(r"fitted on\s+(.*)", run.output)
    chose = re.search(r"chose\s+(\w+) model", run.output)
    return {
        "seconds": run.seconds,
        "rss_mb": run.rss_mb,
        "cpu_seconds": run.cpu_seconds,
        "streamed": "(streamed)" in run.output,
        "fitted_on": fitted.group(1).strip() if fitted else "every sample",
        **({"chose": chose.group(1)} if chose else {}),
    }


def part_cli(n: int, repeat: int, workdir: Path, samples: NDArray[np.float64]) -> dict[str, Any]:
    csv = workdir / f"samples_{n}.csv"
    if not csv.exists():
        print(f"[cli] writing {csv}", flush=True)
        write_csv(samples, csv)
    print(f"[cli] {n:,}-row CSV ({csv.stat().st_size / 1e6:.0f} MB)", flush=True)
    magfit_command = [str(Path(sys.executable).parent / "magfit"), "calibrate", str(csv), "--columns", "mx,my,mz"]
    target = [*magfit_command, "-m", "ellipsoid"]
    # The target's command and the readers take turns, so that both see the same machine.
    commands = {name: [sys.executable, "-c", code, str(csv)] for name, code in _READERS.items()}
    commands["-m ellipsoid"] = target
    commands["(default: auto)"] = magfit_command
    # The same command with the text parsed by pandas alone (the reader before pyarrow's blocks).
    commands[PANDAS_LABEL] = ["env", "MAGFIT_CSV_READER=pandas", *magfit_command]
    best = _interleaved(commands, repeat)
    readers: dict[str, dict[str, Any]] = {}
    for name in _READERS:
        run = best[name]
        if isinstance(run, RuntimeError):
            readers[name] = {"error": str(run).splitlines()[-1]}
        else:
            readers[name] = {"seconds": run.seconds, "rss_mb": run.rss_mb, "cpu_seconds": run.cpu_seconds}
    runs: dict[str, dict[str, Any]] = {}
    for label in ("(default: auto)", "-m ellipsoid", PANDAS_LABEL):
        run = best[label]
        runs[label] = {"error": str(run)[-300:]} if isinstance(run, RuntimeError) else _calibrate_row(run)
    # Once each: ml, whole and on an even subsample (no targets).
    subsample = str(max(n // 10, 1000))
    for options in (["-m", "ml"], ["-m", "ml", "--max-samples", subsample]):
        label = " ".join(options) or "(default: auto)"
        command = [*magfit_command, *options]
        try:
            runs[label] = _calibrate_row(_best_of([run_process(command)], command))
        except RuntimeError as error:
            runs[label] = {"error": str(error)[-300:]}
    timed = {name: value["seconds"] for name, value in readers.items() if "seconds" in value}
    fastest_name = min(timed, key=timed.__getitem__) if timed else ""
    fastest = timed[fastest_name] if timed else float("nan")
    ellipsoid = runs["-m ellipsoid"]
    default = runs["(default: auto)"]
    return {
        "n": n,
        "csv_mb": csv.stat().st_size / 1e6,
        "readers": readers,
        "fastest_reader_s": fastest,
        "fastest_reader": fastest_name,
        "pyarrow_reader_s": readers.get("pyarrow.csv", {}).get("seconds", float("nan")),
        "calibrate": runs,
        "command": shlex.join(target),
        "cli_vs_reader": ellipsoid.get("seconds", float("nan")) / fastest,
        "cli_cpu_vs_reader": ellipsoid.get("cpu_seconds", float("nan"))
        / min((value["cpu_seconds"] for value in readers.values() if "cpu_seconds" in value), default=float("nan")),
        "cli_rss_mb": ellipsoid.get("rss_mb", float("nan")),
        "default_command": shlex.join(magfit_command),
        "default_vs_reader": default.get("seconds", float("nan")) / fastest,
        "default_cpu_vs_reader": default.get("cpu_seconds", float("nan"))
        / min((value["cpu_seconds"] for value in readers.values() if "cpu_seconds" in value), default=float("nan")),
        "default_rss_mb": default.get("rss_mb", float("nan")),
    }


# ---------------------------------------------------------------------- part 3: ml


def part_ml(n: int, repeat: int, samples: NDArray[np.float64]) -> dict[str, Any]:
    print(f"[ml] {n:,} samples", flush=True)
    subset = samples[:n]
    if "ml" not in magfit.METHODS:
        return {"n": n, "error": "method 'ml' is not registered"}
    magfit.fit(subset[:2000], "ml")  # imports and caches outside the timing
    cpu = float("inf")
    for _ in range(repeat):  # CPU time of the process (every thread): what the fit costs without the load
        start = time.process_time()
        magfit.fit(subset, "ml")
        cpu = min(cpu, time.process_time() - start)
    seconds, calibration = best_time(lambda: magfit.fit(subset, "ml"), repeat)
    truth = magfit.scenario(*SCENARIO).simulate(1).truth
    return {
        "n": n,
        "ml_seconds": seconds,
        "ml_cpu_seconds": cpu,
        "offset_error": float(np.linalg.norm(calibration.offset - truth.offset)),
    }


# ---------------------------------------------------------------------- part 5: the headline ratios


def part_ratios(rounds: int, workdir: Path) -> dict[str, Any]:
    """``auto`` / ``ellipsoid`` in memory and ``magfit calibrate`` / ``import magfit.cli`` as processes.

    Each pair takes turns for ``rounds`` rounds and the best time of each side counts: a slow spell of
    the shared machine then slows both sides of a round alike, and the best is the least disturbed.
    """
    results = part_auto(rounds)
    results["n_csv"] = N_RATIO_CSV
    results.update(_calibrate_vs_import(rounds, workdir))
    return results


def part_auto(rounds: int) -> dict[str, Any]:
    """``auto`` / ``ellipsoid`` in memory on 10 000 samples (``rounds`` rounds) and on the larger sizes."""
    samples = make_samples(N_RATIO_FIT, seed=10)
    print(f"[ratios] auto vs ellipsoid on {N_RATIO_FIT:,} samples, {rounds} rounds", flush=True)
    results: dict[str, Any] = {"n_fit": N_RATIO_FIT, "rounds": rounds}
    fits: dict[str, list[float]] = {"ellipsoid": [], "auto": []}
    outcome: dict[str, Any] = {}
    for method in fits:  # imports and caches outside the timing
        try:
            magfit.fit(samples, method)
        except magfit.MagfitError as error:
            outcome[method] = f"{type(error).__name__}: {str(error).splitlines()[0]}"
    for _ in range(rounds):
        for method in fits:
            start = time.perf_counter()
            try:
                calibration = magfit.fit(samples, method)
            except magfit.MagfitError:
                calibration = None  # a refusal is timed too, and said below
            fits[method].append(time.perf_counter() - start)
            if calibration is not None:
                verdict = calibration.support.verdict if calibration.support is not None else None
                chosen = calibration.auto.chosen if calibration.auto is not None else None
                outcome[method] = f"verdict {verdict}" + (f", chose {chosen}" if chosen else "")
    results["fit_seconds"] = {method: min(times) for method, times in fits.items()}
    results["fit_all_seconds"] = fits
    results["fit_outcome"] = outcome
    results["auto_vs_ellipsoid"] = results["fit_seconds"]["auto"] / results["fit_seconds"]["ellipsoid"]
    results["large"] = {str(n): _auto_vs_ellipsoid(n, max(3, rounds // 3)) for n in N_RATIO_LARGE}
    return results


def startup_processes(rounds: int, csv: Path) -> dict[str, ProcessRun | RuntimeError]:
    """The start-up processes, one definition for part 5 here and for benchmarks/startup.py.

    ``python -c "import numpy"``, ``"import magfit"``, ``"import magfit.cli"`` and ``magfit calibrate CSV``
    (keys ``numpy``, ``package``, ``import``, ``calibrate``) take turns for ``rounds`` rounds, the best of each
    counts, after one run of the command that compiles its modules' bytecode. The bytecode is kept as an
    installed package keeps it: ``PYTHONDONTWRITEBYTECODE`` is dropped from the environment, else every run of
    the command compiled the modules beyond the CLI's import again (0.1 s of CPU: the command measured 3.00x
    the import here against 1.91x in startup.py, which already dropped it).
    """
    os.environ.pop("PYTHONDONTWRITEBYTECODE", None)
    commands = {
        "numpy": [sys.executable, "-c", "import numpy"],
        "package": [sys.executable, "-c", "import magfit"],
        "import": [sys.executable, "-c", "import magfit.cli"],
        "calibrate": [str(Path(sys.executable).parent / "magfit"), "calibrate", str(csv)],
    }
    run_process(commands["calibrate"])  # the first run compiles the bytecode (kept) and warms the file cache
    return _interleaved(commands, rounds)


def startup_commands(csv: Path) -> dict[str, str]:
    """The commands of :func:`startup_processes`, as shell lines (for the results)."""
    return {
        "numpy": shlex.join([sys.executable, "-c", "import numpy"]),
        "package": shlex.join([sys.executable, "-c", "import magfit"]),
        "import": shlex.join([sys.executable, "-c", "import magfit.cli"]),
        "calibrate": shlex.join([str(Path(sys.executable).parent / "magfit"), "calibrate", str(csv)]),
    }


def _calibrate_vs_import(rounds: int, workdir: Path) -> dict[str, Any]:
    """``magfit calibrate`` on a 300-row CSV against ``import magfit.cli`` (and ``import numpy``), as processes."""
    results: dict[str, Any] = {}
    csv = workdir / f"samples_{N_RATIO_CSV}.csv"
    write_csv(make_samples(N_RATIO_CSV, seed=11), csv)
    print(f"[ratios] magfit calibrate on {N_RATIO_CSV} rows vs import magfit.cli, {rounds} rounds", flush=True)
    best = startup_processes(rounds, csv)
    processes: dict[str, Any] = {}
    for name, run in best.items():
        if isinstance(run, RuntimeError):
            processes[name] = {"error": str(run)[-300:]}
        else:
            processes[name] = {"seconds": run.seconds, "cpu_seconds": run.cpu_seconds, "rss_mb": run.rss_mb}
            if name == "calibrate":
                processes[name].update(_calibrate_row(run))
    results["processes"] = processes
    results["commands"] = startup_commands(csv)
    results["calibrate_vs_import"] = processes["calibrate"].get("seconds", float("nan")) / processes["import"].get(
        "seconds", float("nan")
    )
    results["import_vs_numpy"] = processes["import"].get("seconds", float("nan")) / processes["numpy"].get(
        "seconds", float("nan")
    )
    results["package_vs_numpy"] = processes["package"].get("seconds", float("nan")) / processes["numpy"].get(
        "seconds", float("nan")
    )
    return results


def _auto_vs_ellipsoid(n: int, rounds: int) -> dict[str, Any]:
    """``auto`` and ``ellipsoid`` (default diagnostics) on the same ``n`` samples, taking turns: best of each."""
    samples = make_samples(n, seed=20)
    print(f"[ratios] auto vs ellipsoid on {n:,} samples, {rounds} rounds", flush=True)
    times: dict[str, list[float]] = {"ellipsoid": [], "auto": []}
    outcome: dict[str, str] = {}
    for _ in range(rounds):
        for method in times:
            start = time.perf_counter()
            calibration = magfit.fit(samples, method)
            times[method].append(time.perf_counter() - start)
            chosen = calibration.auto.chosen if calibration.auto is not None else None
            outcome[method] = f"verdict {_support(calibration)}" + (f", chose {chosen}" if chosen else "")
    best = {method: min(values) for method, values in times.items()}
    return {
        "seconds": best,
        "all_seconds": times,
        "outcome": outcome,
        "ratio": best["auto"] / best["ellipsoid"],
        "load_average_after": os.getloadavg(),
    }


# ---------------------------------------------------------------------- part 6: the default method's memory


def part_memory(n: int, workdir: Path, samples: NDArray[np.float64]) -> dict[str, Any]:
    """Peak RSS of ``magfit calibrate`` with the default method on the ``n``-row CSV of part 2, one run."""
    csv = workdir / f"samples_{n}.csv"
    if not csv.exists():
        print(f"[memory] writing {csv}", flush=True)
        write_csv(samples[:n], csv)
    command = [str(Path(sys.executable).parent / "magfit"), "calibrate", str(csv), "--columns", "mx,my,mz"]
    print(f"[memory] {shlex.join(command)}", flush=True)
    run = run_process(command)
    row: dict[str, Any] = {"n": n, "csv_mb": csv.stat().st_size / 1e6, "command": shlex.join(command)}
    if run.status != 0:
        last = run.output.strip().splitlines()[-1] if run.output.strip() else ""
        return {**row, "error": f"exit {run.status}: {last[:300]}", "rss_mb": run.rss_mb, "seconds": run.seconds}
    return {**row, **_calibrate_row(run)}


# ---------------------------------------------------------------------- part 4: peers

_PEER_SCRIPT = """
import sys, time, json, numpy as np
sys.path.insert(0, sys.argv[1])
import peers
name, path, n = sys.argv[2], sys.argv[3], int(sys.argv[4])
samples = np.ascontiguousarray(np.load(path, mmap_mode="r")[:n])
best = float("inf")
try:
    for _ in range(3 if n <= 1_000_000 else 1):  # the best of 3 up to a million samples, as magfit's row
        start = time.perf_counter()
        cal = peers.PEERS[name].run(samples, None)
        best = min(best, time.perf_counter() - start)
    print(json.dumps({"seconds": best, "offset": cal.offset.tolist()}))
except Exception as error:
    print(json.dumps({"error": f"{type(error).__name__}: {error}"[:200]}))
"""


def part_peers(sizes: Sequence[int], workdir: Path, samples: NDArray[np.float64], python: Path) -> dict[str, Any]:
    npy = workdir / f"samples_{len(samples)}.npy"
    if not npy.exists():
        np.save(npy, samples)
    names = ["magyc.ellipsoid_fit", "magcal.ellipsoid", "mag_cal.ellipsoid"]
    table: dict[str, dict[str, Any]] = {"magfit.ellipsoid": {}}
    for n in sizes:
        part = samples[:n]
        seconds, cal = best_time(lambda: magfit.fit(part, "ellipsoid"), 3)  # noqa: B023 (called at once)
        table["magfit.ellipsoid"][str(n)] = {"seconds": seconds, "offset": cal.offset.tolist()}
    for name in names:
        table[name] = {}
        previous: tuple[int, dict[str, Any]] | None = None
        for n in sizes:
            skip = _predicted_failure(previous, n)
            if skip:  # the last size scaled linearly: over the time or memory limit, so not run
                table[name][str(n)] = {"error": skip}
                break
            print(f"[peers] {name} n={n:,}", flush=True)
            command = [str(python), "-c", _PEER_SCRIPT, str(ROOT / "benchmarks"), name, str(npy), str(n)]
            run = run_process(command, timeout=PEER_TIME_LIMIT)
            if run.status == -9:
                entry: dict[str, Any] = {"error": f"not done after {PEER_TIME_LIMIT:.0f} s (stopped)"}
            elif run.status != 0:
                last = run.output.strip().splitlines()[-1] if run.output.strip() else ""
                entry = {"error": f"crashed (exit {run.status}, peak RSS {run.rss_mb:.0f} MB): {last[:150]}"}
            else:
                entry = json.loads(run.output.strip().splitlines()[-1])
            entry["rss_mb"] = run.rss_mb
            table[name][str(n)] = entry
            if "error" in entry:
                break  # larger sizes will not do better
            previous = (n, entry)
    truth = magfit.scenario(*SCENARIO).simulate(1).truth
    return {"sizes": list(sizes), "table": table, "truth_offset": truth.offset.tolist()}


def _predicted_failure(previous: tuple[int, dict[str, Any]] | None, n: int) -> str | None:
    """Why size ``n`` is not run when the previous size, scaled linearly, would break a limit; else None."""
    if previous is None:
        return None
    done, entry = previous
    factor = n / done
    if entry["seconds"] * factor > PEER_TIME_LIMIT:
        return f"not run: N = {done:,} took {entry['seconds']:.0f} s, so about {entry['seconds'] * factor:.0f} s"
    if entry["rss_mb"] * factor > PEER_MEMORY_LIMIT_MB:
        return (
            f"not run: N = {done:,} needed {entry['rss_mb'] / 1e3:.1f} GB, so about "
            f"{entry['rss_mb'] * factor / 1e3:.0f} GB (limit {PEER_MEMORY_LIMIT_MB / 1e3:.0f} GB: a shared machine)"
        )
    return None


# ---------------------------------------------------------------------- report


def _fmt(seconds: float) -> str:
    return f"{seconds:.3g} s" if seconds >= 0.01 else f"{seconds * 1e3:.3g} ms"


def _verdict(ok: bool) -> str:
    return "PASS" if ok else "**FAIL**"


def machine() -> dict[str, Any]:
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return {
        "cpu": cpu,
        "cores": os.cpu_count(),
        "python": platform.python_version(),
        "numpy": np.__version__,
        "magfit": magfit.__version__,
        "load_average": os.getloadavg(),
    }


def report(results: dict[str, Any]) -> str:
    lines = [
        "# Speed benchmark",
        "",
        f"Command: `{results['command']}`  ",
        f"Date: {results['date']}, runtime {results['runtime_s'] / 60:.1f} min  ",
        f"Machine: {results['machine']['cpu']}, {results['machine']['cores']} cores; Python "
        f"{results['machine']['python']}, NumPy {results['machine']['numpy']}, magfit {results['machine']['magfit']}  ",
        "Load average (1, 5, 15 min) at the start: "
        + ", ".join(f"{v:.1f}" for v in results["machine"]["load_average"])
        + " and at the end: "
        + ", ".join(f"{v:.1f}" for v in results["load_average_end"])
        + " (other processes shared the cores: absolute times are pessimistic, the ratios less so)",
        "",
        f"Samples: `magfit.scenario{SCENARIO}` (raw counts, soft iron with semi-axes 193-1362 counts); "
        f"times are the best of {results['repeat']} runs.",
        "",
    ]
    fit = results.get("fit")
    if fit:
        lines += [
            f"## 1. Ellipsoid fit of {fit['n']:,} in-memory samples",
            "",
            f"The floor, Statistics and the two fits take turns, {results['repeat']} rounds, best (min) of each. "
            f"Verdict: {fit.get('verdict', '—')} (without diagnostics: {fit.get('verdict_no_diagnostics', '—')}).",
            "",
            "| what | time | ratio | target |",
            "|---|---|---|---|",
            f"| floor: chunked NumPy design matrix (10 columns) and XᵀX | {_fmt(fit['floor_s'])} | 1 | |",
            f"| `magfit.Statistics.from_samples` | {_fmt(fit['statistics_s'])} | "
            f"{fit['statistics_s'] / fit['floor_s']:.2f} x floor | |",
            f'| `magfit.fit(samples, "ellipsoid")` (with diagnostics) | {_fmt(fit["fit_s"])} | '
            f"{fit['fit_vs_floor']:.2f} x floor | <= {TARGETS['fit_vs_floor']:g} x: "
            f"{_verdict(fit['fit_vs_floor'] <= TARGETS['fit_vs_floor'])} |",
            f'| `magfit.fit(samples, "ellipsoid", diagnostics=False)` (the verdict only) | '
            f"{_fmt(fit['fit_no_diagnostics_s'])} | {fit['fit_no_diagnostics_vs_floor']:.2f} x floor | |",
            f"| `numpy.linalg.lstsq` on the full 9-column design matrix | {_fmt(fit['lstsq_s'])} | "
            f"fit is {fit['lstsq_vs_fit']:.2g} x faster | >= {TARGETS['lstsq_vs_fit']:g} x: "
            f"{_verdict(fit['lstsq_vs_fit'] >= TARGETS['lstsq_vs_fit'])} |",
            "",
            f"Peak extra memory of the fit: {fit['fit_tracemalloc_mb']:.1f} MB allocated (tracemalloc), "
            f"{fit['fit_rss_extra_mb']:.1f} MB of RSS growth in a fresh process (the samples themselves: "
            f"{fit['n'] * 24 / 1e6:.0f} MB); target < {TARGETS['fit_memory_mb']:g} MB: "
            f"{_verdict(max(fit['fit_tracemalloc_mb'], fit['fit_rss_extra_mb']) < TARGETS['fit_memory_mb'])}. "
            f"Offset error against the simulation truth: {fit['offset_error']:.3f} counts.",
            "",
        ]
    cli = results.get("cli")
    if cli:
        lines += [
            f"## 2. `magfit calibrate` on a {cli['n']:,}-row CSV ({cli['csv_mb']:.0f} MB)",
            "",
            "Each row is a separate process (interpreter start and imports included), as a user runs it. The "
            f"readers and the two commands with targets take turns, {results['repeat']} rounds, best (min) of "
            "each; the ml rows run once. Peak RSS and CPU time come from `resource.getrusage` in a launcher "
            "process whose only child is the row's command. CPU time (user + system) is less disturbed than "
            "wall time by other processes on the machine; pyarrow and magfit parse on several threads, so "
            "their CPU time exceeds their wall time.",
            "",
            "| what | time | CPU time | peak RSS |",
            "|---|---|---|---|",
        ]
        for name, value in cli["readers"].items():
            if "seconds" in value:
                lines.append(
                    f"| reader alone: {name}, three columns | {_fmt(value['seconds'])} | "
                    f"{_fmt(value['cpu_seconds'])} | {value['rss_mb']:.0f} MB |"
                )
            else:
                lines.append(f"| reader alone: {name} | failed: {value['error']} | | |")
        for label, value in cli["calibrate"].items():
            name = "`magfit calibrate`, the default method" if label.startswith("(") else f"`magfit calibrate {label}`"
            if label == PANDAS_LABEL:
                name = "`MAGFIT_CSV_READER=pandas magfit calibrate`, the default method, parsed by pandas alone"
            if "seconds" in value:
                how = "streamed in chunks" if value["streamed"] else "whole file in memory"
                chose = f"; chose the {value['chose']} model" if "chose" in value else ""
                lines.append(
                    f"| {name} ({how}; fitted on {value['fitted_on']}{chose}) | "
                    f"{_fmt(value['seconds'])} | {_fmt(value['cpu_seconds'])} | {value['rss_mb']:.0f} MB |"
                )
            else:
                lines.append(f"| {name} | failed: {value['error']} | | |")
        if "default_vs_reader" in cli:
            ratio, rss = cli["default_vs_reader"], cli["default_rss_mb"]
            lines += [
                "",
                f"`{cli['default_command']}` (the default method): {ratio:.2f} x the fastest reader (target <= "
                f"{TARGETS['default_vs_reader']:g} x: {_verdict(ratio <= TARGETS['default_vs_reader'])}); peak RSS "
                f"{rss:.0f} MB (target < {TARGETS['default_rss_mb']:g} MB: "
                f"{_verdict(rss < TARGETS['default_rss_mb'])}). In CPU time: {cli['default_cpu_vs_reader']:.2f} x "
                "the reader that used the least.",
            ]
        lines += [
            "",
            f"`{cli['command']}`: {cli['cli_vs_reader']:.2f} x the fastest reader (target <= "
            f"{TARGETS['cli_vs_reader']:g} x: {_verdict(cli['cli_vs_reader'] <= TARGETS['cli_vs_reader'])}); "
            f"peak RSS {cli['cli_rss_mb']:.0f} MB (target < {TARGETS['cli_rss_mb']:g} MB: "
            f"{_verdict(cli['cli_rss_mb'] < TARGETS['cli_rss_mb'])}). In CPU time: "
            f"{cli['cli_cpu_vs_reader']:.2f} x the reader that used the least.",
            "",
        ]
    ml = results.get("ml")
    if ml:
        lines += [f"## 3. `ml` on {ml['n']:,} samples", ""]
        if "error" in ml:
            lines.append(f"Not run: {ml['error']}.")
        else:
            lines.append(
                f'`magfit.fit(samples, "ml")`: {_fmt(ml["ml_seconds"])} wall time (target < '
                f"{TARGETS['ml_seconds']:g} s: {_verdict(ml['ml_seconds'] < TARGETS['ml_seconds'])}), "
                f"{_fmt(ml['ml_cpu_seconds'])} of CPU time (every thread of the process: about the wall time on "
                f"an idle machine); offset error {ml['offset_error']:.3f} counts."
            )
        lines.append("")
    peers = results.get("peers")
    if peers:
        sizes = peers["sizes"]
        lines += [
            "## 4. Peers on the same samples",
            "",
            f"Each cell is one process with a {PEER_TIME_LIMIT:.0f} s limit; after a failure the larger sizes "
            "are not tried, and a size that the previous one, scaled linearly, shows to be over the time limit "
            f"or over {PEER_MEMORY_LIMIT_MB / 1e3:.0f} GB is not run. Peers run from `benchmarks/.peers-venv` "
            "(their own pinned NumPy).",
            "",
            "| method | " + " | ".join(f"N = {n:,}" for n in sizes) + " |",
            "|---|" + "---|" * len(sizes),
        ]
        for name, row in peers["table"].items():
            cells = []
            for n in sizes:
                entry = row.get(str(n))
                if entry is None:
                    cells.append("not tried")
                elif "error" in entry:
                    cells.append(entry["error"] if entry["error"].startswith("not run") else f"fails: {entry['error']}")
                else:
                    rss = f", {entry['rss_mb']:.0f} MB" if "rss_mb" in entry else ""
                    error = ""
                    if "offset" in entry:
                        miss = np.linalg.norm(np.asarray(entry["offset"]) - np.asarray(peers["truth_offset"]))
                        error = f", offset off by {miss:.2g}"
                    cells.append(_fmt(entry["seconds"]) + rss + error)
            lines.append(f"| {name} | " + " | ".join(cells) + " |")
        lines += [
            "",
            "Peer times are the fit alone (the samples already loaded), the best of 3 runs up to a million "
            "samples (magfit's too); magfit's row is `magfit.fit` (with its diagnostics) in this "
            'process, peak RSS of a peer\'s process includes its interpreter and imports. "Offset off by": '
            "distance of the fitted hard-iron offset from the simulated one, in counts (noise: 6.4 counts per "
            "axis). magcal takes the sample mean as the centre (its quadric has no linear terms): right here, "
            "where the attitudes are uniform, biased when they are not.",
            "",
        ]
    elif results.get("peers_skipped"):
        lines += ["## 4. Peers", "", f"Not run: {results['peers_skipped']}.", ""]
    lines += _ratios_section(results.get("ratios"))
    lines += _memory_section(results.get("memory"))
    return "\n".join(lines)


def _ratios_section(ratios: dict[str, Any] | None) -> list[str]:
    """Part 5: the two headline ratios with their targets."""
    if not ratios:
        return []
    fit = ratios["fit_seconds"]
    auto_ok = ratios["auto_vs_ellipsoid"] <= TARGETS["auto_vs_ellipsoid"]
    lines = [
        "## 5. The headline ratios (fast enough to refit live)",
        "",
        f"Both sides of each ratio take turns, {ratios['rounds']} rounds, best (min) of each: the machine is "
        "shared, and the least disturbed run is the one that measures the program.",
        "",
        "| what | time | ratio | target |",
        "|---|---|---|---|",
        f'| `magfit.fit(samples, "ellipsoid")`, {ratios["n_fit"]:,} samples, default diagnostics '
        f"({ratios['fit_outcome'].get('ellipsoid', '—')}) | {_fmt(fit['ellipsoid'])} | 1 | |",
        f'| `magfit.fit(samples, "auto")`, the same samples ({ratios["fit_outcome"].get("auto", "—")}) | '
        f"{_fmt(fit['auto'])} | {ratios['auto_vs_ellipsoid']:.2f} x ellipsoid | <= "
        f"{TARGETS['auto_vs_ellipsoid']:g} x: {_verdict(auto_ok)} |",
    ]
    for n, large in ratios.get("large", {}).items():
        seconds, outcome = large["seconds"], large["outcome"]
        lines += [
            f'| `magfit.fit(samples, "ellipsoid")`, {int(n):,} samples ({outcome["ellipsoid"]}) | '
            f"{_fmt(seconds['ellipsoid'])} | 1 | |",
            f'| `magfit.fit(samples, "auto")`, the same samples ({outcome["auto"]}) | {_fmt(seconds["auto"])} | '
            f"{large['ratio']:.2f} x ellipsoid | <= {TARGETS['auto_vs_ellipsoid']:g} x: "
            f"{_verdict(large['ratio'] <= TARGETS['auto_vs_ellipsoid'])} |",
        ]
    processes = ratios.get("processes", {})  # absent when only the auto part ran
    base, calibrate = processes.get("import", {}), processes.get("calibrate", {})
    if "seconds" in base and "seconds" in calibrate:
        cli_ok = ratios["calibrate_vs_import"] <= TARGETS["calibrate_vs_import"]
        chose = f"; chose the {calibrate['chose']} model" if "chose" in calibrate else ""
        numpy_import = processes.get("numpy", {})
        if "seconds" in numpy_import:
            lines += [
                f"| `{ratios['commands']['numpy']}` (process) | {_fmt(numpy_import['seconds'])} | 1 | |",
                f"| `{ratios['commands']['import']}` (process) | {_fmt(base['seconds'])} | "
                f"{ratios['import_vs_numpy']:.2f} x numpy | |",
            ]
            package = processes.get("package", {})
            if "seconds" in package:
                lines.append(
                    f"| `{ratios['commands']['package']}` (process) | {_fmt(package['seconds'])} | "
                    f"{ratios['package_vs_numpy']:.2f} x numpy | |"
                )
        lines += [
            f"| `{ratios['commands']['import']}` (process) | {_fmt(base['seconds'])} | 1 | |",
            f"| `magfit calibrate` on a {ratios['n_csv']}-row CSV, default method (process{chose}) | "
            f"{_fmt(calibrate['seconds'])} | {ratios['calibrate_vs_import']:.2f} x import | <= "
            f"{TARGETS['calibrate_vs_import']:g} x: {_verdict(cli_ok)} |",
        ]
    elif processes:
        failed = calibrate.get("error") or base.get("error")
        lines.append(f"| `magfit calibrate` on {ratios['n_csv']} rows vs the import | failed: {failed} | | |")
    if not processes:  # --parts auto: the auto rows alone
        return [*lines, ""]
    lines += [
        "",
        "CPU time (user + system) of the processes: "
        + ", ".join(f"{name} {_fmt(v['cpu_seconds'])}" for name, v in processes.items() if "cpu_seconds" in v)
        + ".",
        "",
    ]
    return lines


def _memory_section(memory: dict[str, Any] | None) -> list[str]:
    """Part 6: the default method's peak RSS on the large CSV."""
    if not memory:
        return []
    title = f"## 6. `magfit calibrate` (default method) on a {memory['n']:,}-row CSV ({memory['csv_mb']:.0f} MB)"
    if "error" in memory:
        return [title, "", f"`{memory['command']}` failed: {memory['error']} (peak RSS {memory['rss_mb']:.0f} MB).", ""]
    ok = memory["rss_mb"] < TARGETS["default_rss_mb"]
    how = "streamed in chunks" if memory["streamed"] else "whole file in memory"
    chose = f", chose the {memory['chose']} model" if "chose" in memory else ""
    return [
        title,
        "",
        f"`{memory['command']}`: peak RSS {memory['rss_mb']:.0f} MB (target < {TARGETS['default_rss_mb']:g} MB: "
        f"{_verdict(ok)}), {_fmt(memory['seconds'])} ({how}; fitted on {memory['fitted_on']}{chose}). "
        f"The samples alone are {memory['n'] * 24 / 1e6:.0f} MB as float64.",
        "",
    ]


# ---------------------------------------------------------------------- main


@dataclass
class Options:
    n_fit: int
    n_cli: int
    n_ml: int
    peer_sizes: list[int] = field(default_factory=list)


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--smoke", action="store_true", help="small sizes (1e5-1e6): a minute")
    parser.add_argument("--no-peers", action="store_true", help="skip the peers (part 4)")
    parser.add_argument("--no-cli", action="store_true", help="skip the command line (part 2)")
    parser.add_argument("--repeat", type=int, default=3, help="runs per timing; the best counts (default 3)")
    parser.add_argument("--workdir", type=Path, default=Path(tempfile.gettempdir()) / "magfit-speed")
    parser.add_argument("--output", type=Path, default=ROOT / "benchmarks" / "results" / "speed.md")
    parser.add_argument("--peers-python", type=Path, default=PEERS_PYTHON)
    parser.add_argument(
        "--parts", default=",".join(PARTS), help=f"comma-separated parts to run, of {', '.join(PARTS)} (default all)"
    )
    parser.add_argument("--rounds", type=int, default=7, help="rounds of the interleaved ratios (part 5)")
    parser.add_argument("--peer-sizes", default=None, help="comma-separated sizes of part 4 (default 1e3 to 3e7)")
    args = parser.parse_args(argv)
    parts = {part.strip() for part in args.parts.split(",") if part.strip()}
    if not parts or parts - set(PARTS):
        parser.error(f"--parts takes names among {', '.join(PARTS)}, got {args.parts!r}")
    if args.no_peers:
        parts.discard("peers")
    if args.no_cli:
        parts.discard("cli")
    if args.smoke:
        options = Options(n_fit=1_000_000, n_cli=200_000, n_ml=100_000, peer_sizes=[1_000, 10_000])
    else:
        options = Options(
            n_fit=10_000_000,
            n_cli=10_000_000,
            n_ml=1_000_000,
            peer_sizes=[1_000, 10_000, 100_000, 1_000_000, 10_000_000, 30_000_000],
        )
    if args.peer_sizes:
        options.peer_sizes = [int(float(size)) for size in args.peer_sizes.split(",")]
    args.workdir.mkdir(parents=True, exist_ok=True)
    # The processes run as an installed package does, with their bytecode compiled once and kept.
    os.environ.pop("PYTHONDONTWRITEBYTECODE", None)
    start = time.perf_counter()
    results: dict[str, Any] = {
        "command": shlex.join(["python", "benchmarks/speed.py", *(argv if argv is not None else sys.argv[1:])]),
        "date": _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC"),
        "machine": machine(),
        "repeat": args.repeat,
    }
    results["parts"] = [part for part in PARTS if part in parts]
    # Only the samples the chosen parts use (the peers' largest size is 30 million: 720 MB).
    sizes = {"fit": options.n_fit, "ml": options.n_ml, "cli": options.n_cli, "memory": options.n_cli}
    needed = [sizes[part] for part in parts if part in sizes]
    if "peers" in parts:
        needed += options.peer_sizes
    samples = make_samples(max(needed)) if needed else np.empty((0, 3))
    if "fit" in parts:
        results["fit"] = part_fit(options.n_fit, args.repeat, args.workdir, samples[: options.n_fit])
    if "ml" in parts:
        results["ml"] = part_ml(options.n_ml, args.repeat, samples)
    if "cli" in parts:
        results["cli"] = part_cli(options.n_cli, args.repeat, args.workdir, samples[: options.n_cli])
    if args.no_peers:
        results["peers_skipped"] = "--no-peers"
    elif "peers" not in parts:
        pass
    elif not args.peers_python.exists():
        results["peers_skipped"] = f"no peers environment at {args.peers_python} (run benchmarks/setup_peers.sh)"
    else:
        results["peers"] = part_peers(options.peer_sizes, args.workdir, samples, args.peers_python)
    if "ratios" in parts:
        results["ratios"] = part_ratios(args.rounds, args.workdir)
    elif "auto" in parts:  # the auto rows of part 5 alone
        results["ratios"] = part_auto(args.rounds)
    if "memory" in parts:
        results["memory"] = part_memory(options.n_cli, args.workdir, samples)
    results["runtime_s"] = time.perf_counter() - start
    results["load_average_end"] = os.getloadavg()
    text = report(results)
    args.output.parent.mkdir(parents=True, exist_ok=True)
    args.output.write_text(text + "\n", encoding="utf-8")
    args.output.with_suffix(".json").write_text(json.dumps(results, indent=2, default=float) + "\n", encoding="utf-8")
    print(text)
    return 0


def _support(calibration: magfit.Calibration) -> str:
    """The calibration's verdict in a word (``_verdict`` is the PASS/FAIL of a target)."""
    return calibration.support.verdict if calibration.support is not None else "none"


if __name__ == "__main__":
    raise SystemExit(main())
