"""``magfit apply``: corrected samples written beside the file's other columns; refusals."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

import magfit
from magfit.cli import cli


@pytest.fixture
def recording(tmp_path: Path) -> tuple[Path, Path, magfit.Simulation]:
    """A CSV (t, mx, my, mz, temp) of the paper's MPU-9250 with a smartphone, and its calibration file."""
    simulation = magfit.scenario("mpu9250", "smartphone").simulate(2000, seed=41)
    path = tmp_path / "flight.csv"
    table = np.column_stack([np.arange(2000) * 0.01, simulation.samples, np.full(2000, 21.5)])
    np.savetxt(path, table, fmt="%.10g", delimiter=",", header="t,mx,my,mz,temp", comments="")
    calibration = tmp_path / "cal.json"
    calibration.write_text(magfit.fit(simulation.samples, method="ellipsoid").to_json())
    return path, calibration, simulation


def test_apply_corrects_the_magnetometer_columns_and_keeps_the_others(
    recording: tuple[Path, Path, magfit.Simulation], tmp_path: Path
) -> None:
    path, cal_path, simulation = recording
    output = tmp_path / "flight_calibrated.csv"
    result = CliRunner().invoke(cli, ["apply", str(cal_path), str(path), "-o", str(output)])
    assert result.exit_code == 0, result.output
    assert f"wrote {output}" in result.stdout
    header = output.read_text().splitlines()[0]
    assert header == "t,mx,my,mz,temp"
    written = np.loadtxt(output, delimiter=",", skiprows=1)
    original = np.loadtxt(path, delimiter=",", skiprows=1)
    np.testing.assert_array_equal(written[:, [0, 4]], original[:, [0, 4]])
    calibration = magfit.Calibration.from_json(cal_path.read_text())
    np.testing.assert_allclose(written[:, 1:4], calibration.apply(original[:, 1:4]), rtol=1e-9, atol=1e-6)
    # Ground truth: the corrected samples lie on a sphere (spread = the simulated noise, 2.4 % of B) whose
    # radius is the calibration's field strength (det(matrix) = 1 makes it the semi-axes' geometric mean).
    norms = np.linalg.norm(written[:, 1:4], axis=1)
    assert np.mean(norms) == pytest.approx(calibration.field_strength, rel=0.002)
    assert np.std(norms) / calibration.field_strength == pytest.approx(0.0236, rel=0.15)
    true_radius = float(np.prod(magfit.scenario("mpu9250", "smartphone").semi_axes) ** (1 / 3))
    assert calibration.field_strength == pytest.approx(true_radius, rel=0.005)
    assert simulation.truth.offset == pytest.approx(calibration.offset, abs=2.0)


def test_apply_normalized_puts_the_samples_on_the_unit_sphere(
    recording: tuple[Path, Path, magfit.Simulation], tmp_path: Path
) -> None:
    path, cal_path, _ = recording
    output = tmp_path / "unit.csv"
    result = CliRunner().invoke(
        cli, ["apply", str(cal_path), str(path), "-o", str(output), "--normalized", "--columns", "mx,my,mz"]
    )
    assert result.exit_code == 0, result.output
    norms = np.linalg.norm(np.loadtxt(output, delimiter=",", skiprows=1)[:, 1:4], axis=1)
    # The paper's metric on the written file: mean ≈ 0, std ≈ the simulated noise of 2.4 % of B.
    assert abs(np.mean(norms) - 1) < 0.005
    assert np.std(norms) == pytest.approx(0.0236, rel=0.15)


def test_apply_refuses_to_overwrite_its_inputs(recording: tuple[Path, Path, magfit.Simulation]) -> None:
    path, cal_path, _ = recording
    before = path.read_bytes(), cal_path.read_bytes()
    runner = CliRunner()
    for target in (path, cal_path):
        result = runner.invoke(cli, ["apply", str(cal_path), str(path), "-o", str(target)])
        assert result.exit_code == 2
        assert result.stderr.startswith(f"magfit: error: the output {target} is the input file")
    assert (path.read_bytes(), cal_path.read_bytes()) == before


def test_apply_reports_a_bad_calibration_file(recording: tuple[Path, Path, magfit.Simulation], tmp_path: Path) -> None:
    path, _, _ = recording
    output = tmp_path / "out.csv"
    runner = CliRunner()
    missing = runner.invoke(cli, ["apply", str(tmp_path / "nope.json"), str(path), "-o", str(output)])
    assert missing.exit_code == 2
    assert missing.stderr == f"magfit: error: calibration file {tmp_path / 'nope.json'} does not exist\n"
    broken = tmp_path / "broken.json"
    broken.write_text('{"offset": [1, 2, 3]}')
    result = runner.invoke(cli, ["apply", str(broken), str(path), "-o", str(output)])
    assert result.exit_code == 2
    assert result.stderr.startswith(f"magfit: error: {broken}: not a magfit calibration")
    assert not output.exists()
