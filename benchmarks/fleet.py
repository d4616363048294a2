"""The fleet benchmark: partial flights merged, a magnetisation found, and the fleet run's cost against its fits.

Three measurements, each against a reference measured in the same run (the machines are shared and noisy):

1. **Partial flights merged.** A vehicle flies 5 times, each flight covering 15-30 % of the sphere of
   directions (a cap around another axis each time), with noise that leaves no single flight determined.
   ``magfit.fleet`` combines them; the combined calibration's heading error (worst over level headings and
   inclinations up to 70°, against the simulated truth) is compared with one full tumble's calibration
   (the same sensor, noise and number of samples). Target: determined where each alone is not, and within 1.2× the
   tumble's heading error (RMS over trials: one tumble per trial is itself a noisy reference).
2. **A magnetisation event.** A vehicle's offset moves by a few per cent of the field between its second
   and third flight: named, with the date and the offset's move. Target: found in every trial, and no event
   on the vehicles without one.
3. **Cost.** 200 small recordings (2 000 samples, 10 vehicles), and 50 flight logs (the real logs in
   tests/data, copied into 10 vehicles' folders): ``fleet(workers=2)`` against the sum of the fits alone
   (``calibrate_file`` on each, one process, after a warm-up). Target: at most 1.3×. Also on ``workers=1``
   and, with ``--dask``, on local Dask clusters of 1, 2 and 4 worker processes (the speed-up from 1 to 4).
   The least of ``--repeat`` runs of each, taking turns.

Run: ``python benchmarks/fleet.py [--trials 5] [--recordings 200] [--logs 50] [--repeat 3] [--dask] [--write]``
(``--trials 0`` runs the cost alone); ``--write`` puts the
results in ``benchmarks/results/fleet.md``.
"""

from __future__ import annotations

import argparse
import math
import os
import statistics
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

import magfit
from magfit.export._heading import heading_error_deg
from magfit.fleet import fleet

SOFT_IRON = np.array([[1.10, 0.05, 0.02], [0.05, 0.95, -0.03], [0.02, -0.03, 1.00]])
HARD_IRON = np.array([12.0, -8.0, 20.0])
FIELD = 50.0
CAP_AXES = ([1, 0, 0], [0, 1, 0], [0, 0, 1], [-1, -1, 0], [0, -1, -1])
ROOT = Path(__file__).resolve().parents[1]
START = 1_700_000_000  # the first flight's time stamp (2023-11-14), a day between flights


def truth(soft_iron: NDArray[np.float64] = SOFT_IRON, hard_iron: NDArray[np.float64] = HARD_IRON) -> magfit.Calibration:
    return magfit.Calibration("truth", hard_iron, np.linalg.inv(soft_iron), FIELD * np.linalg.det(soft_iron) ** (1 / 3))


def partial_flight(
    n: int, axis: NDArray[np.float64], share: float, noise: float, seed: int, hard_iron: NDArray[np.float64] = HARD_IRON
) -> NDArray[np.float64]:
    """``n`` samples whose true field directions lie in a cap around ``axis`` covering ``share`` of the sphere."""
    rng = np.random.default_rng(seed)
    axis = np.asarray(axis, dtype=np.float64) / np.linalg.norm(axis)
    kept: list[NDArray[np.float64]] = []
    while sum(len(k) for k in kept) < n:
        directions = rng.normal(size=(4 * n, 3))
        directions /= np.linalg.norm(directions, axis=1, keepdims=True)
        kept.append(directions[directions @ axis > 1.0 - 2.0 * share])  # a cap's area share is (1 − cos)/2
    field = FIELD * np.concatenate(kept)[:n]
    return field @ SOFT_IRON.T + hard_iron + rng.normal(scale=noise, size=(n, 3))


def tumble(n: int, noise: float, seed: int) -> NDArray[np.float64]:
    return partial_flight(n, np.array([0.0, 0.0, 1.0]), 1.0, noise, seed)


def write_flight(path: Path, samples: NDArray[np.float64], day: int) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savetxt(path, samples, delimiter=",", header="mx,my,mz", comments="", fmt="%.5f")
    os.utime(path, (START + 86400 * day, START + 86400 * day))


def partial_vehicle(folder: Path, seed: int, n: int = 2000, noise: float = 2.5) -> None:
    """Vehicle ``folder``: 5 flights covering 15-30 % of directions each."""
    for index, axis in enumerate(CAP_AXES):
        share = 0.15 + 0.15 * index / (len(CAP_AXES) - 1)
        samples = partial_flight(n, np.array(axis), share, noise, seed * 10 + index)
        write_flight(folder / f"flight{index}.csv", samples, index)


def magnetised_vehicle(folder: Path, seed: int, move: NDArray[np.float64], n: int = 2000, noise: float = 0.3) -> None:
    """Vehicle ``folder``: 4 full flights, the offset moved by ``move`` from the third on."""
    for index in range(4):
        offset = HARD_IRON + (move if index >= 2 else 0.0)
        write_flight(folder / f"flight{index}.csv", partial_flight(n, np.array([0, 0, 1.0]), 1.0, noise,
                                                                   seed * 10 + index, offset), index)  # fmt: skip


def merged_trial(seed: int, root: Path) -> dict[str, float]:
    partial_vehicle(root / "partial", seed)
    result = fleet([root / "partial"], workers=1, unit="uT")
    flights = result.flights()
    combined = result.combined()
    alone_determined = sum(row.verdict in ("supported", "weak") and "undetermined" not in row.codes for row in flights)
    reference = magfit.fit(tumble(10_000, 2.5, seed + 999), method="als")  # as many samples as the 5 flights
    true = truth()
    tumble_error = heading_error_deg(true, reference.matrix, reference.offset)
    if len(combined) != 1 or combined[0].verdict == "refused":
        return {"alone_determined": alone_determined, "combined_error": float("inf"), "tumble_error": tumble_error}
    row = combined[0]
    matrix = np.array([[row.matrix_xx, row.matrix_xy, row.matrix_xz], [row.matrix_yx, row.matrix_yy, row.matrix_yz],
                       [row.matrix_zx, row.matrix_zy, row.matrix_zz]])  # fmt: skip
    return {
        "alone_determined": alone_determined,
        "combined_error": heading_error_deg(true, matrix, row.offset),
        "tumble_error": tumble_error,
        "verdict": row.verdict,  # type: ignore[dict-item]
    }


def magnetisation_trial(seed: int, root: Path) -> tuple[bool, bool, str]:
    magnetised_vehicle(root / "magnetised", seed, np.array([2.0, -1.5, 1.0]))
    magnetised_vehicle(root / "steady", seed + 50, np.zeros(3))
    result = fleet([root / "magnetised", root / "steady"], workers=1, unit="uT")
    found = [e for e in result.events if e.startswith("magnetised") and "flight2.csv" in e]
    false = [e for e in result.events if e.startswith("steady")]
    return bool(found), not false, (found[0] if found else "")


#: Real logs in tests/data (their READMEs give the origin and licence), copied over and over for the logs' case.
LOGS = (
    ROOT / "tests" / "data" / "ardupilot_real" / "copter462_head_80k.bin",
    ROOT / "tests" / "data" / "ardupilot_real" / "copter33_log171_trimmed.bin",
    ROOT / "tests" / "data" / "ardupilot_sitl" / "sitl_three_compasses.bin",
    ROOT / "tests" / "data" / "px4_pyulog" / "sample_log_small.ulg",
)


def recordings_case(root: Path, count: int) -> list[Path]:
    """``count`` small recordings (2 000 samples of a tumble each), 10 vehicles, a day between flights."""
    for index in range(count):
        vehicle = root / f"vehicle{index % 10}"
        write_flight(vehicle / f"r{index}.csv", tumble(2000, 0.3, 5000 + index), index // 10)
    return sorted(root.rglob("*.csv"))


def logs_case(root: Path, count: int) -> list[Path]:
    """``count`` flight logs: the real logs of :data:`LOGS` in turn, copied into 10 vehicles' folders."""
    import shutil

    for index in range(count):
        source = LOGS[index % len(LOGS)]
        target = root / f"vehicle{index % 10}" / f"log{index}{source.suffix}"
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(source, target)
    return sorted(p for p in root.rglob("*") if p.is_file())


def _fits_alone(files: list[Path]) -> None:
    for path in files:
        try:
            magfit.calibrate_file(path)
        except magfit.MagfitError:
            pass  # a refused recording costs its fit too


def cost(files: list[Path], root: Path, dask: bool, repeat: int) -> dict[str, float]:
    """Seconds of the fits alone (``calibrate_file`` on each file, one process, after a warm-up) and of the fleet
    run on 1 and 2 local processes and (``dask``) on local Dask clusters of 1, 2 and 4 workers; the least of
    ``repeat`` runs each, taking turns (a shared machine disturbs some runs, never speeds one up)."""
    _fits_alone(files[:1])  # warm-up: imports, caches
    runs: dict[str, list[float]] = {}

    def timed(name: str, run: Callable[[], object]) -> None:
        busy = _cpu_times()
        start = time.perf_counter()
        run()
        runs.setdefault(name, []).append(time.perf_counter() - start)
        idle = _idle_share(busy, _cpu_times())
        runs.setdefault(name.replace("_s", "_idle"), []).append(idle)
        print(f"  {name}: {runs[name][-1]:.1f} s, machine idle {100 * idle:.0f} %", file=sys.stderr, flush=True)

    for _ in range(repeat):
        timed("fits_alone_s", lambda: _fits_alone(files))
        for workers in (1, 2):
            timed(f"fleet_{workers}_s", lambda workers=workers: fleet([root], workers=workers))
    if dask:
        from distributed import Client, LocalCluster

        for workers in (1, 2, 4):
            with LocalCluster(n_workers=workers, threads_per_worker=1, processes=True) as cluster, Client(
                cluster
            ) as client:
                for _ in range(repeat):
                    timed(f"fleet_dask{workers}_s", lambda: fleet([root], scheduler=client))
    # Each configuration's least time, and how idle the machine was during that run.
    best = {name: min(seconds) for name, seconds in runs.items() if name.endswith("_s")}
    idle = {f"{name}_idle": runs[name.replace("_s", "_idle")][runs[name].index(best[name])] for name in best}
    return {**best, **idle}


def _cpu_times() -> tuple[float, float]:
    """The machine's (idle, total) CPU time so far, from /proc/stat (NaN where there is none)."""
    try:
        fields = [float(v) for v in Path("/proc/stat").read_text().splitlines()[0].split()[1:]]
    except (OSError, ValueError, IndexError):
        return math.nan, math.nan
    return fields[3] + fields[4], sum(fields[:8])  # idle + iowait; user ... steal


def _idle_share(before: tuple[float, float], after: tuple[float, float]) -> float:
    """The share of the machine's CPU time left idle between two readings: near 0, the cores were saturated
    (by this run and others' work), and more processes can only share them, not add to them."""
    total = after[1] - before[1]
    return (after[0] - before[0]) / total if total > 0 else math.nan


def _cost_lines(title: str, timings: dict[str, float]) -> list[str]:
    alone = timings["fits_alone_s"]
    ratio2 = timings["fleet_2_s"] / alone
    lines = [title, "", "| run | seconds | / fits alone | speed-up over 1 worker | machine idle during it |",
             "|---|---|---|---|---|"]  # fmt: skip
    for name, seconds in timings.items():
        if not name.endswith("_s"):
            continue
        base = timings.get("fleet_dask1_s" if "dask" in name else "fleet_1_s", math.nan)
        speed = f"{base / seconds:.2f}" if name != "fits_alone_s" else ""
        idle = timings.get(f"{name}_idle", math.nan)
        lines.append(f"| {name} | {seconds:.1f} | {seconds / alone:.2f} | {speed} | {100 * idle:.0f} % |")
    lines += ["", f"fleet on 2 processes / the fits alone in one: {ratio2:.2f} (target ≤ 1.3): "
              f"{'PASS' if ratio2 <= 1.3 else 'FAIL'}.", ""]  # fmt: skip
    return lines


def trial_lines(trials: int) -> list[str]:
    """Sections 1 and 2: the partial flights merged and the magnetisation found, over ``trials`` trials."""
    lines: list[str] = []
    ratios, alone, combined_errors, tumble_errors = [], [], [], []
    lines += ["## 1. Five partial flights (15-30 % of directions each) merged", "",
              "| trial | flights determined alone | combined verdict | combined heading error | one tumble's | ratio |",
              "|---|---|---|---|---|---|"]  # fmt: skip
    for trial in range(trials):
        with tempfile.TemporaryDirectory() as folder:
            r = merged_trial(trial, Path(folder))
        ratio = r["combined_error"] / r["tumble_error"]
        ratios.append(ratio)
        combined_errors.append(r["combined_error"])
        tumble_errors.append(r["tumble_error"])
        alone.append(r["alone_determined"])
        lines.append(f"| {trial} | {int(r['alone_determined'])} of 5 | {r.get('verdict', 'refused')} | "
                     f"{r['combined_error']:.2f}° | {r['tumble_error']:.2f}° | {ratio:.2f} |")  # fmt: skip
    # One tumble per trial is itself a noisy reference (0.2-0.8° here): the target compares the RMS over trials,
    # as the accuracy benchmarks do, and the per-trial ratios are shown beside it.
    combined_rms = math.sqrt(statistics.fmean(e**2 for e in combined_errors))
    tumble_rms = math.sqrt(statistics.fmean(e**2 for e in tumble_errors))
    ratio_rms = combined_rms / tumble_rms
    verdict = "PASS" if ratio_rms <= 1.2 else "FAIL"
    lines += ["", f"RMS over trials: combined {combined_rms:.2f}°, one tumble {tumble_rms:.2f}°, ratio {ratio_rms:.2f} "
              f"(target ≤ 1.2): {verdict}; median of the per-trial ratios {statistics.median(ratios):.2f}; flights "
              f"determined alone: {max(alone):.0f} of 5 at most.", ""]  # fmt: skip
    lines += ["## 2. A magnetisation between the second and third flight", ""]
    found_all, clean_all = True, True
    example = ""
    for trial in range(trials):
        with tempfile.TemporaryDirectory() as folder:
            found, clean, words = magnetisation_trial(trial, Path(folder))
        found_all &= found
        clean_all &= clean
        example = example or words
    lines += [f"Found in every trial: {'PASS' if found_all else 'FAIL'}; no event on the steady vehicle: "
              f"{'PASS' if clean_all else 'FAIL'}.", "", f"> {example}", ""]  # fmt: skip
    return lines


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=5)
    parser.add_argument("--recordings", type=int, default=200)
    parser.add_argument("--logs", type=int, default=50, help="flight logs for the logs' cost case (0: none)")
    parser.add_argument("--repeat", type=int, default=3, help="runs of each cost configuration (the least kept)")
    parser.add_argument("--dask", action="store_true")
    parser.add_argument("--write", action="store_true")
    parser.add_argument("--output", type=Path, default=None, help="with --write: the file (default results/fleet.md)")
    args = parser.parse_args(argv)
    lines = ["# Fleet benchmark", "", f"`python benchmarks/fleet.py --trials {args.trials} --recordings "
             f"{args.recordings} --logs {args.logs} --repeat {args.repeat}{' --dask' if args.dask else ''}`, "
             f"{os.cpu_count()} cores.", ""]  # fmt: skip
    if args.trials:
        lines += trial_lines(args.trials)
    if args.recordings:
        with tempfile.TemporaryDirectory() as folder:
            files = recordings_case(Path(folder), args.recordings)
            timings = cost(files, Path(folder), args.dask, args.repeat)
        lines += _cost_lines(f"## 3. Cost: {args.recordings} recordings of 2 000 samples, 10 vehicles", timings)
    if args.logs:
        with tempfile.TemporaryDirectory() as folder:
            files = logs_case(Path(folder), args.logs)
            timings = cost(files, Path(folder), args.dask, args.repeat)
        names = ", ".join(path.name for path in LOGS)
        lines += _cost_lines(f"## 4. Cost: {args.logs} flight logs ({names} in turn), 10 vehicles", timings)
    load = ", ".join(f"{v:.1f}" for v in os.getloadavg())
    lines += [f"Load average at the end: {load} (2 cores shared with other work: the least of the repeats is "
              "shown, each configuration's runs taking turns).", ""]  # fmt: skip
    text = "\n".join(lines)
    print(text)
    if args.write:
        output = args.output or Path(__file__).with_name("results").joinpath("fleet.md")
        output.write_text(text, encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())
