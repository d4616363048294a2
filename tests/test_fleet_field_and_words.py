"""The fleet's World Magnetic Model option and what it says: a place asked for where no recording has one, the
rows' reasons in the run's words, a quiet stderr; and the gyro's notes naming a samples file's compass."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

import magfit
from magfit.cli import main
from magfit.cli.app import cli
from magfit.fleet import fleet
from magfit.geomag import field_at
from magfit.vehicle import simulate_vehicle

DATA = Path(__file__).resolve().parent / "data"
#: Zürich: the World Magnetic Model's field there is what the samples below are made on.
PLACE = (47.4, 8.5, 0.0)
DATE = "2026-06-01"


def _recording(path: Path, radius: float, offset: np.ndarray, seed: int) -> None:
    """A full tumble on a sphere of ``radius`` µT around ``offset``, 0.2 % noise: samples in µT, with a header."""
    rng = np.random.default_rng(seed)
    directions = rng.normal(size=(3000, 3))
    directions /= np.linalg.norm(directions, axis=1)[:, None]
    samples = offset + radius * directions + rng.normal(scale=0.002 * radius, size=directions.shape)
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savetxt(path, samples, delimiter=",", header="mx,my,mz", comments="", fmt="%.5f")


@pytest.fixture
def samples_only(tmp_path: Path) -> tuple[Path, float, np.ndarray]:
    radius = field_at(*PLACE, date=DATE).total_in("uT")
    offset = np.array([12.0, -7.0, 3.0])
    for vehicle in ("a", "b"):
        for flight in range(2):
            _recording(tmp_path / "fleet" / vehicle / f"f{flight}.csv", radius, offset, seed=10 * flight + ord(vehicle))
    return tmp_path / "fleet", radius, offset


def test_wmm_without_a_place_and_no_log_is_one_usage_error(samples_only: tuple[Path, float, np.ndarray]) -> None:
    folder = samples_only[0]
    with pytest.raises(magfit.OptionError) as refused:
        fleet([folder], field_strength="wmm", unit="uT", workers=1)
    assert refused.value.codes == ("no_location",)
    table = folder.parent / "fleet.csv"
    run = CliRunner().invoke(cli, ["fleet", str(folder), "-o", str(table), "--field-strength", "wmm", "--unit", "uT"])
    assert run.exit_code == 2
    lines = run.stderr.strip().splitlines()
    assert len(lines) == 1 and "--location LAT,LON[,ALT]" in lines[0] and "none of the 4 recordings" in lines[0]
    assert not table.exists()  # refused before any recording was fitted


def test_wmm_at_the_place_given_pins_every_recording_to_the_truth(samples_only: tuple[Path, float, np.ndarray]) -> None:
    folder, radius, offset = samples_only
    result = fleet([folder], field_strength="wmm", unit="uT", location=PLACE, date=DATE, workers=1)
    flights = result.flights()
    assert len(flights) == 4 and all(row.verdict == "supported" for row in flights), [r.reason for r in flights]
    for row in (*flights, *result.combined()):
        assert "no_location" not in row.codes
        np.testing.assert_allclose(row.offset, offset, atol=0.01 * radius)  # the truth
        assert row.field_strength == pytest.approx(radius, rel=1e-6)  # pinned to the model's field
        assert row.field_vs_model == pytest.approx(1.0, rel=1e-6)


def test_wmm_without_a_place_beside_a_log_is_a_row_with_its_code(
    samples_only: tuple[Path, float, np.ndarray], tmp_path: Path
) -> None:
    folder = samples_only[0]
    shutil.copy(DATA / "ardupilot_sitl" / "sitl_three_compasses.bin", folder / "a" / "flight.bin")
    table = tmp_path / "mixed.csv"
    status = main(["fleet", str(folder), "-o", str(table), "--field-strength", "wmm", "--unit", "uT", "--workers", "1"])
    assert status in (0, 1)  # (0 when a compass of the log is calibrated; the rows below say why not)
    text = table.read_text(encoding="utf-8").splitlines()
    samples_rows = [line for line in text if ".csv," in line]
    assert len(samples_rows) == 4
    for line in samples_rows:
        assert line.startswith("error,") and ",error,no_location," in line
        assert "--location LAT" in line and "location=" not in line  # said in the command line's words
    log_rows = [line for line in text if "flight.bin" in line and line.startswith("flight,")]
    assert log_rows and not any("no_location" in line for line in log_rows)  # the log's own fixes gave its place


def test_the_command_writes_nothing_on_stderr_when_all_goes_well(samples_only: tuple[Path, float, np.ndarray]) -> None:
    folder = samples_only[0]
    run = CliRunner().invoke(
        cli, ["fleet", str(folder), "-o", str(folder.parent / "t.csv"), "--unit", "uT", "--workers", "1"]
    )
    assert run.exit_code == 0, run.output
    assert run.stderr == ""  # no progress bar off a terminal, not even its blank line
    assert run.stdout.startswith("4 compass fits: 4 supported")


def test_the_gyro_notes_name_a_samples_file_compass_by_its_columns(tmp_path: Path) -> None:
    sim = simulate_vehicle(3000, "car", rate_hz=20.0, field_strength=50.0, noise=0.05, hard_iron=[8.0, -5.0, 3.0],
                           gyro_noise=0.001, seed=2)  # fmt: skip
    path = tmp_path / "car.csv"
    values = np.column_stack([sim.time_s, sim.samples, sim.gyro, sim.accel])
    np.savetxt(path, values, delimiter=",", header="time,mx,my,mz,gx,gy,gz,ax,ay,az", comments="", fmt="%.12g")
    argv = ["calibrate", str(path), "-m", "gyro", "--unit", "uT", "-o", str(tmp_path / "c.json")]
    run = CliRunner().invoke(cli, argv)
    assert run.exit_code == 0, run.output
    assert "(columns)" not in run.stderr
    assert "car.csv (columns mx, my, mz): accelerometer" in run.stderr
    fitted = magfit.Calibration.from_json((tmp_path / "c.json").read_text())
    np.testing.assert_allclose(fitted.offset, sim.hard_iron, atol=0.3)  # the truth


def _sleep_then_pid(seconds: float) -> tuple[float, int]:
    import os
    import time

    time.sleep(seconds)
    return seconds, os.getpid()


def test_a_long_task_holds_up_no_other_in_the_local_engine() -> None:
    # Two long tasks first, then short ones: each worker takes the next task when it is free, so the two long
    # ones run side by side, and the short ones go to whichever worker is free (none queued behind a long one).
    from magfit.fleet import _LocalEngine

    engine = _LocalEngine(2)
    try:
        done = list(engine.run(_sleep_then_pid, [(1.5,), (1.5,), *[(0.01,)] * 6]))
    finally:
        engine.close()
    long_pids = {pid for seconds, pid in done if seconds == 1.5}
    assert len(done) == 8 and len(long_pids) == 2  # the two long tasks on two workers, not queued on one
