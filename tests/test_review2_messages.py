"""Messages of the command line that a second review found missing or wrong: each test failed before its fix."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

import magfit
from magfit.cli import cli

_REAL = Path(__file__).parent / "data" / "ardupilot_real"
_TLOG = _REAL / "fs_batt_2016.tlog"


def _write(path: Path, samples: np.ndarray) -> None:
    np.savetxt(path, samples, fmt="%.6f", delimiter=",", header="mx,my,mz", comments="")


def test_apply_to_a_log_names_the_ratio_to_the_calibrations_sphere(tmp_path: Path) -> None:
    sim = magfit.simulate(600, hard_iron=[10, -5, 3], field_strength=50.0, noise=0.3, seed=2)
    samples, cal, out = tmp_path / "bench.csv", tmp_path / "cal.json", tmp_path / "out.csv"
    _write(samples, sim.samples)
    assert CliRunner().invoke(cli, ["calibrate", str(samples), "-o", str(cal)]).exit_code == 0
    result = CliRunner().invoke(cli, ["apply", str(cal), str(_TLOG), "--sensor", "RAW_IMU", "-o", str(out)])
    assert result.exit_code == 0, result.output
    corrected = np.loadtxt(out, delimiter=",", skiprows=1)[:, 1:]
    # Ground truth: the corrected log's median norm against the 50-unit sphere (about 11: ~550 mG).
    ratio = np.median(np.linalg.norm(corrected, axis=1)) / magfit.Calibration.from_json(cal.read_text()).field_strength
    assert ratio > 5
    assert f"lies at {ratio:.3g} times its field strength" in result.stderr, result.stderr
    assert "RAW_IMU" in result.stderr


def test_fleet_leaves_out_the_tables_journals_and_reports_of_earlier_runs(tmp_path: Path) -> None:
    vehicle = tmp_path / "rover"
    vehicle.mkdir()
    sim = magfit.simulate(400, hard_iron=[10, -5, 3], field_strength=50.0, noise=0.3, seed=3)
    _write(vehicle / "bench.csv", sim.samples)
    first = CliRunner().invoke(cli, ["fleet", str(tmp_path), "-o", str(tmp_path / "fleet.csv"), "--workers", "1",
                                     "--report", str(tmp_path / "fleet.html")])  # fmt: skip
    assert first.exit_code == 0, first.output
    for run, paths in (("again.csv", [str(tmp_path)]), ("glob.csv", [f"{tmp_path}/**/*"])):
        result = magfit.fleet(paths, tmp_path / run, workers=1)
        # Ground truth: one recording, its offset the simulated one; no row for the earlier table, journal, report.
        assert {row.path for row in result.rows} == {str((vehicle / "bench.csv").resolve())}, result.rows
        (row,) = result.flights()
        assert np.allclose(row.offset, [10, -5, 3], atol=1.0), row
    named = CliRunner().invoke(cli, ["fleet", str(tmp_path / "fleet.csv"), str(vehicle), "-o", str(tmp_path / "x.csv")])
    assert named.exit_code == 2 and "written by 'magfit fleet'" in named.output, named.output


def test_a_dataflash_log_without_its_beginning_is_named_so(tmp_path: Path) -> None:
    from magfit.sources.detect import log_kind

    log = (_REAL / "copter462_head_80k.bin").read_bytes()
    tail = tmp_path / "part2.bin"
    tail.write_bytes(log[len(log) // 2 + 7 :])  # the second half, cut inside a message: no FMT at its start
    assert log_kind(tail) == "dataflash"
    for command in ("inspect", "calibrate"):
        result = CliRunner().invoke(cli, [command, str(tail)])
        assert result.exit_code == 2, result.output
        assert "DataFlash" in result.output and "FMT" in result.output and "binary file" not in result.output
    # Random bytes are not taken for a log.
    noise = tmp_path / "noise.bin"
    noise.write_bytes(np.random.default_rng(0).integers(0, 256, 40_000, dtype=np.uint8).tobytes())
    assert log_kind(noise) is None


def test_inspect_lists_each_of_two_magnetometer_column_groups(tmp_path: Path) -> None:
    from magfit.sources import open_source

    # Two sensors on one rig (as mxl_umich_mpu9250_rm3100/preflight_data_original.csv): imu_m* and mag_*.
    imu = magfit.simulate(500, hard_iron=[10, -5, 3], field_strength=50.0, noise=0.2, seed=4)
    pni = magfit.simulate(500, hard_iron=[-20, 7, 1], field_strength=50.0, noise=0.2, seed=5)
    path = tmp_path / "rig.csv"
    table = np.column_stack([np.arange(500) * 0.1, imu.samples, pni.samples])
    np.savetxt(path, table, fmt="%.5f", delimiter=",", header="t,imu_mx,imu_my,imu_mz,mag_x,mag_y,mag_z", comments="")
    source = open_source(path)
    assert [(m.id, m.n_samples, m.problem) for m in source.magnetometers] == [
        ("imu_mx,imu_my,imu_mz", 500, None),
        ("mag_x,mag_y,mag_z", 500, None),
    ]
    # Ground truth: each one read is its own sensor's samples.
    assert np.allclose(source.read("mag_x,mag_y,mag_z").samples, pni.samples, atol=1e-4)
    result = CliRunner().invoke(cli, ["inspect", str(path)])
    assert result.exit_code == 0 and "no magnetometer columns" not in result.output, result.output
    assert "--columns imu_mx,imu_my,imu_mz" in result.output and "--columns mag_x,mag_y,mag_z" in result.output
    refused = CliRunner().invoke(cli, ["calibrate", str(path)])
    assert refused.exit_code == 2 and "--columns imu_mx,imu_my,imu_mz" in refused.output, refused.output
    fitted = magfit.calibrate_file(path, columns=["mag_x", "mag_y", "mag_z"])
    assert np.allclose(fitted.calibration.offset, [-20, 7, 1], atol=1.0)


@pytest.mark.parametrize(
    ("name", "per_second"),
    [
        ("GPS_Time_s", 1.0),
        ("unix_time", 1.0),
        ("timestamp_s", 1.0),
        ("gps_time", 1.0),
        ("time_unix", 1.0),
        ("TimeUS", 1e6),
        ("unix_time_ms", 1e3),
        ("timestamp", 1e6),
    ],
)
def test_a_time_column_named_after_its_clock_is_the_time_base(tmp_path: Path, name: str, per_second: float) -> None:
    from magfit.pipeline.table import StreamSpec, samples_source
    from magfit.sources import open_source

    sim = magfit.simulate(200, hard_iron=[10, -5, 3], field_strength=50.0, noise=0.2, seed=6)
    # Ground truth: 20 Hz from a UNIX time (or boot time for the microsecond stamps), in the column's unit.
    start = 1.7e9 if per_second < 1e6 else 12.5
    seconds = start + np.arange(200) / 20.0
    path = tmp_path / "timed.csv"
    np.savetxt(path, np.column_stack([seconds * per_second, sim.samples]), fmt="%.6f", delimiter=",",
               header=f"{name},mx,my,mz", comments="")  # fmt: skip
    source = open_source(path)
    assert name in source.time_base, source.time_base
    (magnetometer,) = source.magnetometers
    assert magnetometer.rate_hz == pytest.approx(20.0, rel=1e-6) and magnetometer.start_s == pytest.approx(start)
    read = samples_source(path, None, StreamSpec(), ["time"])  # as vector's lag and gyro's integration read it
    stamps = read.source.read_motion("columns").time_s
    assert np.allclose(stamps, seconds, atol=1e-5), stamps[:3]


def test_a_log_joined_to_itself_is_read_once_and_said(tmp_path: Path) -> None:
    from magfit.sources import open_source

    log = (_REAL / "copter33_log171_trimmed.bin").read_bytes()
    twice = tmp_path / "twice.bin"
    twice.write_bytes(log + log)
    single, joined = open_source(_REAL / "copter33_log171_trimmed.bin"), open_source(twice)
    for alone, doubled in zip(single.magnetometers, joined.magnetometers, strict=True):
        # Ground truth: the same recording; its samples, count and rate as the log alone gives them.
        assert doubled.n_samples == alone.n_samples and doubled.rate_hz == pytest.approx(alone.rate_hz)
        assert np.array_equal(joined.read(doubled.id).samples, single.read(alone.id).samples)
        said = [note for note in doubled.notes if "go back" in note]
        assert len(said) == 1 and f"at {alone.end_s:.1f} s after boot (to {alone.start_s:.1f} s)" in said[0], said
        assert not any("go back" in note for note in alone.notes)
    result = CliRunner().invoke(cli, ["calibrate", str(twice), "--sensor", "MAG/0", "--method", "sphere"])
    warned = [line for line in result.stderr.splitlines() if "go back" in line]
    assert len(warned) == 1 and "MAG/0" in warned[0], result.stderr


def test_a_log_of_two_boots_says_its_stamps_go_back() -> None:
    from magfit.sources.dataflash import _time_jumps

    first, second = np.arange(100) * 0.1 + 5.0, np.arange(80) * 0.1 + 2.0  # a reboot: the clock starts again
    stamps = np.concatenate([first, second])
    jumps = _time_jumps(stamps, np.random.default_rng(1).normal(0, 300, (len(stamps), 3)))
    assert jumps is not None and jumps.backs == 1 and jumps.repeated == 0
    assert (jumps.at_s, jumps.to_s) == pytest.approx((14.9, 2.0))
    assert "more than one recording" in jumps.describe()
    assert _time_jumps(first, np.zeros((100, 3))) is None


def test_inspect_on_the_two_sensor_rig_recording(real_data_dir: Path) -> None:
    path = real_data_dir / "mxl_umich_mpu9250_rm3100" / "preflight_data_original.csv"
    rows = len(path.read_text(encoding="utf-8").splitlines()) - 1  # every row holds both sensors
    result = CliRunner().invoke(cli, ["inspect", str(path)])
    assert result.exit_code == 0, result.output
    assert result.output.count(f": {rows} samples") == 2, result.output
    assert "unix_time" in result.output and "does not increase" in result.output  # whole seconds at ~10 Hz
