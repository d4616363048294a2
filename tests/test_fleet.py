"""magfit.fleet and `magfit fleet`: many recordings in one run, each vehicle's flights combined, changes named."""

from __future__ import annotations

import importlib
import json
import shutil
import sys
from pathlib import Path

import numpy as np
import pytest

import magfit
from magfit.cli import main
from magfit.export._heading import heading_error_deg
from magfit.fleet import FleetRow, fleet, recordings, residual_rms

BENCHMARKS = Path(__file__).resolve().parents[1] / "benchmarks"
sys.path.insert(0, str(BENCHMARKS))
bench = importlib.import_module("fleet")
DATA = Path(__file__).parent / "data"


@pytest.fixture(scope="module")
def vehicles(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """partial/: 5 flights of 15-30 % of directions; magnetised/: offset moved before flight 2; steady/: none."""
    root = tmp_path_factory.mktemp("fleet")
    bench.partial_vehicle(root / "partial", seed=1)
    bench.magnetised_vehicle(root / "magnetised", seed=2, move=np.array([2.0, -1.5, 1.0]))
    bench.magnetised_vehicle(root / "steady", seed=3, move=np.zeros(3))
    return root


def _matrix(row: FleetRow) -> np.ndarray:
    return np.array([[row.matrix_xx, row.matrix_xy, row.matrix_xz], [row.matrix_yx, row.matrix_yy, row.matrix_yz],
                     [row.matrix_zx, row.matrix_zy, row.matrix_zz]])  # fmt: skip


def test_residual_rms_from_statistics_matches_the_samples() -> None:
    sim = magfit.scenario("mpu9250", "steel").simulate(3000, seed=4)
    statistics = magfit.Statistics.from_samples(sim.samples)
    # The algebraic residual |M (x − V)|² / B² − 1, halved, over the samples themselves.
    corrected = sim.truth.apply(sim.samples, normalized=True)
    expected = 0.5 * np.sqrt(np.mean((np.sum(corrected**2, axis=1) - 1.0) ** 2))
    assert residual_rms(statistics, sim.truth) == pytest.approx(expected, rel=1e-6)


def test_statistics_round_trip_through_numbers() -> None:
    sim = magfit.scenario("mpu9250", "steel").simulate(2000, seed=5)
    statistics = magfit.Statistics.from_samples(sim.samples)
    again = magfit.Statistics.from_dict(json.loads(json.dumps(statistics.to_dict())))
    assert again.n == statistics.n
    np.testing.assert_allclose(again.scatter, statistics.scatter, rtol=1e-12, atol=1e-9)
    with pytest.raises(magfit.SampleError, match="Statistics"):
        magfit.Statistics.from_dict({"n": 3})


@pytest.mark.slow
def test_partial_flights_merge_into_a_determined_calibration(vehicles: Path) -> None:
    result = fleet([vehicles / "partial"], workers=1, unit="uT")
    assert len(result.flights()) == 5
    (combined,) = result.combined()
    assert combined.flights == 5 and combined.verdict in ("supported", "weak"), combined.reason
    truth = bench.truth()
    error = heading_error_deg(truth, _matrix(combined), combined.offset)
    reference = magfit.fit(bench.tumble(10_000, 2.5, 7), method="als")  # one tumble with as many samples
    assert error <= 1.5 * heading_error_deg(truth, reference.matrix, reference.offset) + 0.2
    assert not result.events


@pytest.mark.slow
def test_a_magnetisation_is_named_with_its_date_and_size(vehicles: Path) -> None:
    result = fleet([vehicles / "magnetised", vehicles / "steady"], workers=1, unit="uT")
    (event,) = result.events  # the steady vehicle has none
    assert event.startswith("magnetised") and "flight2.csv" in event and "2023-11-16" in event
    assert "offset moved by (+2" in event
    combined = [row for row in result.combined() if row.vehicle == "magnetised"]
    assert [row.flights for row in combined] == [2, 2]
    np.testing.assert_allclose(combined[1].offset - combined[0].offset, [2.0, -1.5, 1.0], atol=0.1)
    assert len([row for row in result.combined() if row.vehicle == "steady"]) == 1


def test_a_failing_recording_is_one_row_and_the_run_goes_on(tmp_path: Path, vehicles: Path) -> None:
    shutil.copytree(vehicles / "steady", tmp_path / "v")
    (tmp_path / "v" / "broken.csv").write_text("mx,my,mz\n1,2\nnot,a,number\n", encoding="utf-8")
    (tmp_path / "v" / "still.csv").write_text("mx,my,mz\n" + "1,2,3\n" * 50, encoding="utf-8")
    result = fleet([tmp_path / "v"], workers=1)
    rows = {Path(row.path).name: row for row in result.flights()}
    assert rows["broken.csv"].kind == "error" and "broken.csv" in rows["broken.csv"].reason
    assert rows["still.csv"].verdict in ("refused", "error") and rows["still.csv"].reason
    assert sum(row.verdict == "supported" for row in rows.values()) == 4


@pytest.mark.slow
@pytest.mark.parametrize("suffix", [".csv", ".jsonl", ".parquet"])
def test_the_table_and_the_resumed_run(tmp_path: Path, vehicles: Path, suffix: str) -> None:
    table = tmp_path / f"fleet{suffix}"
    first = fleet([vehicles / "steady"], table, workers=1)
    assert first.skipped == 0 and table.exists()
    second = fleet([vehicles / "steady", vehicles / "magnetised"], table, workers=1)
    assert second.skipped == 4 and len(second.flights()) == 8 and second.events
    if suffix == ".jsonl":
        records = [json.loads(line) for line in table.read_text(encoding="utf-8").splitlines()]
    else:
        import pandas as pd

        frame = pd.read_csv(table) if suffix == ".csv" else pd.read_parquet(table)
        records = frame.to_dict("records")
    assert len(records) == len(second.rows)
    assert set(records[0]) == set(FleetRow.columns())
    # A journal line cut by an interrupted run: that recording runs again, the others are kept.
    journal = table.with_name(table.name + ".journal.jsonl")
    text = journal.read_text(encoding="utf-8")
    journal.write_text(text[: len(text) - 40], encoding="utf-8")
    third = fleet([vehicles / "steady", vehicles / "magnetised"], table, workers=1)
    assert third.skipped == 7 and len(third.flights()) == 8


@pytest.mark.slow
def test_local_processes_give_the_rows_of_one_process(vehicles: Path) -> None:
    one = fleet([vehicles / "steady"], workers=1)
    two = fleet([vehicles / "steady"], workers=2)
    assert [(r.path, r.verdict) for r in one.rows] == [(r.path, r.verdict) for r in two.rows]
    np.testing.assert_allclose([r.offset for r in one.rows], [r.offset for r in two.rows], rtol=1e-12)


@pytest.mark.slow
def test_a_dask_cluster_gives_the_rows_of_one_process(vehicles: Path) -> None:
    distributed = pytest.importorskip("distributed")
    one = fleet([vehicles / "steady"], workers=1)
    cluster = distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=False, dashboard_address=None)
    with cluster:
        other = fleet([vehicles / "steady"], scheduler=cluster.scheduler_address)
    assert [(r.path, r.verdict) for r in one.rows] == [(r.path, r.verdict) for r in other.rows]
    np.testing.assert_allclose([r.offset for r in one.rows], [r.offset for r in other.rows], rtol=1e-12)


def test_a_log_with_several_compasses(tmp_path: Path) -> None:
    log = DATA / "ardupilot_sitl" / "sitl_three_compasses.bin"
    shutil.copy(log, tmp_path / "flight.bin")
    result = fleet([tmp_path], workers=1)
    sensors = [row.sensor for row in result.flights()]
    assert len(sensors) >= 2 and all(sensor.startswith("MAG") for sensor in sensors)
    assert all(row.device_id is not None for row in result.flights() if row.kind == "flight")


def test_recordings_from_folders_globs_and_lists(tmp_path: Path, vehicles: Path) -> None:
    listing = tmp_path / "list.txt"
    listing.write_text(f"# two flights\n{vehicles / 'steady' / 'flight0.csv'}\n{vehicles / 'steady' / 'flight1.csv'}\n")
    assert [p.name for p in recordings([f"@{listing}"])] == ["flight0.csv", "flight1.csv"]
    assert len(recordings([str(vehicles / "*" / "flight3.csv")])) == 3
    assert len(recordings([vehicles])) == 13
    for bad, words in ((tmp_path / "none", "no such file"), (str(tmp_path / "*.bin"), "matches no file")):
        with pytest.raises(magfit.OptionError, match=words):
            recordings([bad])
    with pytest.raises(magfit.OptionError, match="no recording"):
        recordings([tmp_path / "empty"] if (tmp_path / "empty").mkdir() is None else [])


@pytest.mark.slow
def test_the_command(tmp_path: Path, vehicles: Path, capsys: pytest.CaptureFixture[str]) -> None:
    table, report = tmp_path / "fleet.csv", tmp_path / "fleet.html"
    argv = ["fleet", str(vehicles / "magnetised"), "-o", str(table), "--workers", "1", "--unit", "uT"]
    assert main([*argv, "--report", str(report)]) == 0
    out = capsys.readouterr().out
    assert "2 flights combined" in out and "change: magnetised" in out and f"wrote {table}" in out
    page = report.read_text(encoding="utf-8")
    assert "Content-Security-Policy" in page and "data:image/png;base64," in page
    assert "offset moved by" in page and page.count("<tr>") >= 4 + 2
    assert main(["fleet", str(vehicles / "magnetised"), "-o", str(tmp_path / "t.xls")]) == 2
    assert ".csv, .parquet or .jsonl" in capsys.readouterr().err
    # Nothing calibrated at all: exit 1, the table still written with each row's reason.
    (tmp_path / "bad").mkdir()
    (tmp_path / "bad" / "still.csv").write_text("mx,my,mz\n" + "1,2,3\n" * 50, encoding="utf-8")
    assert main(["fleet", str(tmp_path / "bad"), "-o", str(tmp_path / "bad.csv"), "--workers", "1"]) == 1
    assert (tmp_path / "bad.csv").exists() and "none of the 1 compass fits" in capsys.readouterr().err
    # The table is never written over a recording.
    flight = tmp_path / "bad" / "still.csv"
    assert main(["fleet", str(flight), "-o", str(flight)]) == 2
    assert flight.read_text(encoding="utf-8").startswith("mx,my,mz")


@pytest.mark.slow
def test_vehicles_are_folders_below_the_common_root(tmp_path: Path) -> None:
    """droneA/logs and droneB/logs are two vehicles (a folder's own name would merge them)."""
    for vehicle, move in (("droneA", 0.0), ("droneB", 30.0)):
        bench.magnetised_vehicle(tmp_path / vehicle / "logs", seed=7, move=np.zeros(3))
        for flight in (tmp_path / vehicle / "logs").glob("*.csv"):
            if move:
                shifted = np.loadtxt(flight, delimiter=",", skiprows=1) + np.array([move, 0.0, 0.0])
                bench.write_flight(flight, shifted, int(flight.stem[-1]))
    result = fleet([tmp_path], workers=1, unit="uT")
    assert {row.vehicle for row in result.rows} == {"droneA/logs", "droneB/logs"}
    assert not result.events and len(result.combined()) == 2


@pytest.mark.slow
def test_a_changed_recording_is_fitted_again_on_resume(tmp_path: Path, vehicles: Path) -> None:
    shutil.copytree(vehicles / "steady", tmp_path / "v")
    table = tmp_path / "fleet.csv"
    first = fleet([tmp_path / "v"], table, workers=1)
    flight = tmp_path / "v" / "flight0.csv"
    moved = np.loadtxt(flight, delimiter=",", skiprows=1) + np.array([20.0, 0.0, 0.0])
    bench.write_flight(flight, moved, 9)  # rewritten: another size and modification time
    second = fleet([tmp_path / "v"], table, workers=1)
    assert second.skipped == 3
    before = {Path(r.path).name: r for r in first.flights()}["flight0.csv"]
    after = {Path(r.path).name: r for r in second.flights()}["flight0.csv"]
    assert after.offset_x == pytest.approx(before.offset_x + 20.0, abs=0.5)
    # Fitted another way (the method), every recording runs again.
    assert fleet([tmp_path / "v"], table, workers=1, method="ellipsoid").skipped == 0


@pytest.mark.slow
def test_a_log_names_its_vehicle_wherever_its_file_lies(tmp_path: Path) -> None:
    """The board and unique id ArduPilot logs at boot group a vehicle's logs kept in different folders."""
    log = DATA / "ardupilot_real" / "copter33_log171_trimmed.bin"
    for folder in ("monday", "tuesday"):
        (tmp_path / folder).mkdir()
        shutil.copy(log, tmp_path / folder / "flight.bin")
    result = fleet([tmp_path], workers=1, method="sphere", combine=False)
    assert {row.vehicle for row in result.rows} == {"PX4v2 004A002F 33345119 32383433"}
    # Every row dated by the log's GNSS time, refused compasses too (not by the copy's modification time).
    assert {row.date for row in result.rows} == {"2015-11-21 23:44 UTC"}


def test_the_fleet_reads_a_recording_once(tmp_path: Path, vehicles: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """calibrate_file gives each compass's statistics, the log's date and its identity with its fits: the fleet
    reads no file more often than calibrate_file alone does (the combined fit aside)."""
    import magfit.io
    import magfit.sources.dataflash as dataflash

    reads: list[str] = []
    read_samples = magfit.io.read_samples
    monkeypatch.setattr(magfit.io, "read_samples", lambda path, *a, **k: reads.append(str(path)) or read_samples(
        path, *a, **k))  # fmt: skip
    walk = dataflash.DataFlashLog.__init__

    def walked(self: object, path: Path, *args: object, **kwargs: object) -> None:
        reads.append(str(path))
        walk(self, path, *args, **kwargs)  # type: ignore[arg-type]

    monkeypatch.setattr(dataflash.DataFlashLog, "__init__", walked)
    result = fleet([vehicles / "steady"], workers=1, combine=False)
    assert len(result.rows) == 4 and sorted(reads) == sorted(row.path for row in result.rows)  # one read each
    log = tmp_path / "flight.bin"
    # Four MAG records a compass: the sphere's 4 numbers leave nothing to measure the noise, both are refused.
    shutil.copy(DATA / "ardupilot_real" / "copter462_head_80k.bin", log)
    reads.clear()
    try:
        magfit.calibrate_file(log, "sphere")
    except magfit.MagfitError:
        pass  # both refused: the reads are what is counted
    alone = len(reads)
    reads.clear()
    rows = fleet([tmp_path], workers=1, method="sphere", combine=False).rows
    assert [row.verdict for row in rows] == ["refused", "refused"] and len(reads) <= alone  # power streams: cached


def test_calibrate_file_carries_the_statistics_of_the_samples_fitted(tmp_path: Path) -> None:
    """CompassCalibration.statistics is that of the samples read (a log's compass, a samples file's)."""
    from magfit.sources import open_source

    path = tmp_path / "flight.csv"
    samples = bench.tumble(3000, 0.3, 11)
    bench.write_flight(path, samples, 0)
    compass = magfit.calibrate_file(path, "ellipsoid").compasses[0]
    assert compass.statistics is not None and compass.statistics.n == 3000
    expected = magfit.Statistics.from_samples(np.loadtxt(path, delimiter=",", skiprows=1))
    np.testing.assert_allclose(compass.statistics.scatter, expected.scatter, rtol=1e-9, atol=1e-9)
    log = DATA / "ardupilot_real" / "copter462_head_80k.bin"
    result = magfit.calibrate_file(log, "sphere")
    source = open_source(log)
    assert result.identity == source.identity and result.position == source.position
    for fitted in result.compasses:
        read = source.read(fitted.sensor).samples
        assert fitted.statistics is not None and fitted.statistics.n == len(read)
        np.testing.assert_allclose(fitted.statistics.scatter, magfit.Statistics.from_samples(read).scatter)


def _pid_of(index: int) -> tuple[int, int]:
    import os
    import time

    time.sleep(0.05)
    return index, os.getpid()


@pytest.mark.slow
def test_the_local_engine_runs_every_task_once_here_and_in_a_worker() -> None:
    """workers=2: two worker processes (forked from the preloading server) take the tasks from one queue, this
    process hands them out; every task's result comes back once, and the pool serves a second batch (the
    combined fits)."""
    import os

    from magfit.fleet import _LocalEngine

    engine = _LocalEngine(2)
    try:
        first = list(engine.run(_pid_of, [(i,) for i in range(40)]))
        second = list(engine.run(_pid_of, [(i,) for i in range(40, 60)]))
    finally:
        engine.close()
    assert sorted(i for i, _ in first) == list(range(40)) and sorted(i for i, _ in second) == list(range(40, 60))
    pids = {pid for _, pid in first + second}
    assert os.getpid() not in pids and len(pids) == 2
