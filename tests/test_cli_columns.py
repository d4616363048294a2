"""Files without a header: the magnetometer columns chosen by what they hold, named in every message, and
remembered by the calibration so that `magfit apply` corrects the same columns."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

import magfit
from magfit.cli import cli
from magfit.facts import SampleSource
from magfit.io import read_samples
from magfit.io.columns import choose_columns_by_content, ellipsoid_spread

FIELD = 48.0
OFFSET = np.array([12.0, -30.0, 7.5])


def directions(n: int, seed: int) -> np.ndarray:
    d = np.random.default_rng(seed).normal(size=(n, 3))
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def magnetometer(n: int = 1500, seed: int = 1, noise: float = 0.2) -> np.ndarray:
    """A full tumble in a field of 48 units, hard iron only: the true field strength is 48."""
    rng = np.random.default_rng(seed + 100)
    return FIELD * directions(n, seed) + OFFSET + rng.normal(scale=noise, size=(n, 3))


def write(path: Path, columns: list[np.ndarray], delimiter: str = " ") -> Path:
    np.savetxt(path, np.column_stack(columns), delimiter=delimiter, fmt="%.6f")
    return path


def test_a_time_column_first_is_passed_over_and_the_field_is_right(tmp_path: Path) -> None:
    samples = magnetometer()
    time = 1700000000.0 + 0.02 * np.arange(len(samples))
    path = write(tmp_path / "txyz.txt", [time, samples])
    result = CliRunner().invoke(cli, ["calibrate", str(path), "-m", "sphere", "-o", str(tmp_path / "cal.json")])
    assert result.exit_code == 0, result.output
    assert "columns          column 2, column 3, column 4 (column 1 is monotonic: time or a counter)" in result.stdout
    calibration = magfit.Calibration.from_json((tmp_path / "cal.json").read_text())
    assert calibration.field_strength == pytest.approx(FIELD, abs=0.1)  # 30.9 when time, x, y were read
    np.testing.assert_allclose(calibration.offset, OFFSET, atol=0.1)


def test_time_last_and_gyro_columns_beside_the_magnetometer(tmp_path: Path) -> None:
    samples = magnetometer(seed=2)
    gyro = np.random.default_rng(5).normal(scale=2.0, size=samples.shape)  # rates: no constant norm
    counter = np.arange(len(samples), dtype=float)
    path = write(tmp_path / "imu.csv", [gyro, samples, counter], delimiter=",")
    table = read_samples(path)
    assert table.columns == ("column 4", "column 5", "column 6")
    assert table.column_note is not None and "column 7 is monotonic" in table.column_note
    np.testing.assert_allclose(table.samples, samples, atol=1e-6)


def test_two_triples_with_a_constant_norm_are_an_ambiguity_not_a_guess(tmp_path: Path) -> None:
    """An accelerometer turned slowly reads gravity, whose norm is as constant as the earth field's."""
    samples = magnetometer(seed=3)
    gravity = 9.81 * directions(len(samples), 4) + np.random.default_rng(6).normal(scale=0.03, size=samples.shape)
    path = write(tmp_path / "acc_mag.txt", [gravity, samples])
    result = CliRunner().invoke(cli, ["calibrate", str(path)])
    assert result.exit_code == 2, result.output
    message = result.stderr.strip()
    assert "several column triples look like a magnetometer" in message
    assert "(column 4, column 5, column 6)" in message and "(column 1, column 2, column 3)" in message
    assert "--columns " in message and "columns=[" not in message  # the option, not the library's keyword
    chosen = CliRunner().invoke(cli, ["calibrate", str(path), "--columns", "3,4,5", "-m", "sphere"])
    assert chosen.exit_code == 0 and "field strength   48" in chosen.stdout


def test_a_refusal_names_the_columns_it_used(tmp_path: Path) -> None:
    """The exit-1 path: a sensor that only yawed (a flat ring) cannot be calibrated; the message says which
    columns were read, so a wrong column choice cannot pass for bad data."""
    angle = np.linspace(0, 4 * np.pi, 400)
    ring = np.column_stack([30 * np.cos(angle), 30 * np.sin(angle), np.full_like(angle, 20.0)])
    path = write(tmp_path / "yaw.txt", [np.arange(400.0), ring])
    result = CliRunner().invoke(cli, ["calibrate", str(path), "-o", str(tmp_path / "cal.json")])
    assert result.exit_code == 1, result.output
    line = result.stderr.strip()
    assert line.startswith(f"magfit: error: {path} (columns column 2, column 3, column 4; column 1 is monotonic")
    assert not (tmp_path / "cal.json").exists()


def test_apply_corrects_the_columns_the_fit_used_and_keeps_the_time_column(tmp_path: Path) -> None:
    """The issue's case: fitted with --columns 1,2,3 on a file whose column 0 is time, applied without it."""
    samples = magnetometer(seed=8)
    time = 1000.0 + 0.5 * np.arange(len(samples))
    path = write(tmp_path / "flight.csv", [time, samples], delimiter=",")
    runner = CliRunner()
    fitted = runner.invoke(cli, ["calibrate", str(path), "--columns", "1,2,3", "-o", str(tmp_path / "cal.json")])
    assert fitted.exit_code == 0, fitted.output
    document = json.loads((tmp_path / "cal.json").read_text())
    assert document["source"]["columns"] == ["column 2", "column 3", "column 4"]
    assert document["source"]["column_indices"] == [1, 2, 3]
    applied = runner.invoke(cli, ["apply", str(tmp_path / "cal.json"), str(path), "-o", str(tmp_path / "out.csv")])
    assert applied.exit_code == 0, applied.output
    assert "(columns column 2, column 3, column 4; as fitted" in applied.stdout
    before = [line.split(",") for line in path.read_text().splitlines()]
    after = [line.split(",") for line in (tmp_path / "out.csv").read_text().splitlines()]
    assert [row[0] for row in after] == [row[0] for row in before]  # the time column, byte for byte
    calibration = magfit.Calibration.from_json((tmp_path / "cal.json").read_text())
    corrected = np.array([[float(v) for v in row[1:]] for row in after])
    np.testing.assert_allclose(corrected, calibration.apply(samples), rtol=1e-8, atol=1e-6)
    np.testing.assert_allclose(np.linalg.norm(corrected, axis=1), FIELD, atol=1.5)


def test_explicit_columns_win_over_the_remembered_ones(tmp_path: Path) -> None:
    samples = magnetometer(seed=9)
    path = write(tmp_path / "two.csv", [samples, samples * 2], delimiter=",")
    runner = CliRunner()
    assert (
        runner.invoke(cli, ["calibrate", str(path), "--columns", "0,1,2", "-o", str(tmp_path / "c.json")]).exit_code
        == 0
    )
    applied = runner.invoke(
        cli, ["apply", str(tmp_path / "c.json"), str(path), "--columns", "3,4,5", "-o", str(tmp_path / "out.csv")]
    )
    assert applied.exit_code == 0, applied.output
    out = np.loadtxt(tmp_path / "out.csv", delimiter=",")
    np.testing.assert_allclose(out[:, :3], samples, atol=1e-5)  # untouched: --columns chose 3,4,5
    assert not np.allclose(out[:, 3:], samples * 2, atol=1e-3)


def test_remembered_positions_are_not_applied_to_a_file_of_another_layout(tmp_path: Path) -> None:
    """Positions fitted in a headerless t,x,y,z file mean nothing in a file with a header: names decide there."""
    samples = magnetometer(seed=10)
    headerless = write(tmp_path / "txyz.txt", [np.arange(len(samples), dtype=float), samples])
    runner = CliRunner()
    assert runner.invoke(cli, ["calibrate", str(headerless), "-o", str(tmp_path / "c.json")]).exit_code == 0
    named = tmp_path / "named.csv"
    np.savetxt(named, np.column_stack([samples, np.arange(len(samples))]), delimiter=",", header="x,y,z,t", comments="")
    applied = runner.invoke(cli, ["apply", str(tmp_path / "c.json"), str(named), "-o", str(tmp_path / "out.csv")])
    assert applied.exit_code == 0, applied.output
    assert "(columns x, y, z)" in applied.stdout
    out = np.loadtxt(tmp_path / "out.csv", delimiter=",", skiprows=1)
    np.testing.assert_array_equal(out[:, 3], np.arange(len(samples)))


def test_the_source_survives_the_json_round_trip(tmp_path: Path) -> None:
    path = write(tmp_path / "m.txt", [magnetometer(seed=11)])
    assert (
        CliRunner().invoke(cli, ["calibrate", str(path), "--unit", "uT", "-o", str(tmp_path / "c.json")]).exit_code == 0
    )
    text = (tmp_path / "c.json").read_text()
    calibration = magfit.Calibration.from_json(text)
    assert magfit.Calibration.from_json(calibration.to_json()) == calibration
    assert calibration.source == SampleSource(
        "m.txt", "uT", ("column 1", "column 2", "column 3"), (0, 1, 2), header=False, n_columns=3
    )


def test_content_rule_units() -> None:
    samples = magnetometer(300, seed=12)
    countdown = np.arange(300, 0, -1, dtype=float)
    constant = np.full(300, 3.3)
    head = np.column_stack([countdown, constant, samples])
    choice = choose_columns_by_content(head, [0, 1, 2, 3, 4])
    assert (choice.indices, choice.monotonic, choice.constant, choice.rivals) == ((2, 3, 4), (0,), (1,), ())
    assert choice.describe([f"c{i}" for i in range(5)]) == "c0 is monotonic: time or a counter; c1 constant"
    assert ellipsoid_spread(samples) == pytest.approx(0.2 / FIELD, rel=0.5)
    assert (
        ellipsoid_spread(np.random.default_rng(1).normal(size=(300, 3))) is None
        or ellipsoid_spread(np.random.default_rng(1).normal(size=(300, 3))) > 0.2
    )


@pytest.mark.parametrize(
    ("name", "columns"),
    [
        ("betaflight_apex5_qmc5883/20231014_apex5_mag_on_tpu_03.txt", ("column 1", "column 2", "column 3")),
        ("betaflight_apex5_qmc5883/20231008_apex5_mag_on_tpu_00.txt", ("column 1", "column 2", "column 3")),
        ("android_phone_kritiksoman/data_mag.txt", ("x", "y", "z")),
        ("fxos8700_magneto/mag-readings.txt", ("column 1", "column 2", "column 3")),
        ("ensta_tlefloch_imu/mag_data.txt", ("column 1", "column 2", "column 3")),
    ],
)
def test_real_recordings_keep_their_columns(real_data_dir: Path, name: str, columns: tuple[str, ...]) -> None:
    assert read_samples(real_data_dir / name).columns == columns


def test_a_real_imu_log_without_its_header_still_finds_the_magnetometer(real_data_dir: Path, tmp_path: Path) -> None:
    """gyrolib's log (sincIMU, Wx..Wz, Ax..Az, Mx..Mz, temperature), its header line removed: the gyro and
    accelerometer triples are passed over by content, the magnetometer is columns 8-10."""
    lines = (real_data_dir / "gyrolib_rahrs/calibrationGyroLib_converted.csv").read_text().splitlines()
    path = tmp_path / "no_header.csv"
    path.write_text("\n".join(lines[1:]) + "\n")
    table = read_samples(path)
    assert table.columns == ("column 8", "column 9", "column 10")
    named = read_samples(real_data_dir / "gyrolib_rahrs/calibrationGyroLib_converted.csv")
    np.testing.assert_array_equal(table.samples, named.samples)


def test_an_npy_array_with_a_time_column_first(tmp_path: Path) -> None:
    samples = magnetometer(seed=13)
    path = tmp_path / "log.npy"
    np.save(path, np.column_stack([100.0 + np.arange(len(samples)), samples]))
    table = read_samples(path)
    assert table.columns == ("column 2", "column 3", "column 4")
    assert table.column_note == "column 1 is monotonic: time or a counter"
    np.testing.assert_array_equal(table.samples, samples)


@pytest.mark.slow
def test_plot_names_its_columns_in_its_output_and_its_refusals(tmp_path: Path) -> None:
    samples = magnetometer(seed=14)
    good = write(tmp_path / "txyz.txt", [np.arange(len(samples), dtype=float), samples])
    result = CliRunner().invoke(cli, ["plot", str(good), "-o", str(tmp_path / "good.png"), "--methods", "sphere"])
    assert result.exit_code == 0, result.output
    assert f"{good}: columns column 2, column 3, column 4; column 1 is monotonic: time or a counter" in result.stdout
    angle = np.linspace(0, 4 * np.pi, 400)
    ring = np.column_stack([30 * np.cos(angle), 30 * np.sin(angle), np.full_like(angle, 20.0)])
    flat = write(tmp_path / "yaw.txt", [np.arange(400.0), ring])
    refused = CliRunner().invoke(cli, ["plot", str(flat), "-o", str(tmp_path / "flat.png")])
    assert refused.exit_code == 1, refused.output
    assert refused.stderr.startswith(f"magfit: error: {flat} (columns column 2, column 3, column 4;")
    assert not (tmp_path / "flat.png").exists()


def test_a_recording_that_starts_at_rest_is_judged_on_rows_further_in(tmp_path: Path) -> None:
    """6000 rows at rest (a warm-up: every column constant but for noise), then the tumble; gyro columns first.
    The head alone holds no direction: the rule also reads rows from further in."""
    rng = np.random.default_rng(15)
    rest = np.tile([20.0, -30.0, 25.0], (6000, 1)) + rng.normal(scale=0.3, size=(6000, 3))
    mag = np.vstack([rest, magnetometer(6000, seed=16, noise=0.3)])
    gyro = np.vstack([rng.normal(scale=0.01, size=(6000, 3)), rng.normal(scale=1.5, size=(6000, 3))])
    path = write(tmp_path / "rest_then_tumble.csv", [gyro, mag], delimiter=",")
    assert path.stat().st_size > 256 * 1024  # longer than the head the layout is sniffed from
    table = read_samples(path)
    assert table.columns == ("column 4", "column 5", "column 6")
    np.testing.assert_allclose(table.samples, mag, atol=1e-6)
