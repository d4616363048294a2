"""``magfit simulate``: the written samples are the library's simulation; overrides; refusals."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

import magfit
from magfit.cli import cli


def test_simulate_writes_the_scenario_as_csv(tmp_path: Path) -> None:
    output = tmp_path / "steel.csv"
    args = ["simulate", "--sensor", "mpu9250", "--disturbance", "steel", "-n", "500", "-o", str(output), "--seed", "4"]
    result = CliRunner().invoke(cli, args)
    assert result.exit_code == 0, result.output
    lines = output.read_text().splitlines()
    assert lines[0] == "mx,my,mz" and len(lines) == 501
    expected = magfit.scenario("mpu9250", "steel").simulate(500, seed=4)
    np.testing.assert_array_equal(np.loadtxt(output, delimiter=",", skiprows=1), expected.samples)  # whole counts
    assert f"wrote 500 samples to {output}" in result.stdout
    assert "true semi-axes  (193, 714, 1362)" in result.stdout


def test_simulate_npy_and_overrides_with_the_truth_file(tmp_path: Path) -> None:
    output, truth = tmp_path / "custom.npy", tmp_path / "truth.json"
    w = [1.1, 0.05, 0.0, 0.05, 0.9, 0.0, 0.0, 0.0, 1.0]
    args = [
        "simulate",
        "-n",
        "400",
        "-o",
        str(output),
        "--seed",
        "2",
        "--offset=-30,12,45",
        "--matrix",
        ",".join(map(str, w)),
    ]
    args += ["--noise", "0", "--field-strength", "50", "--truth", str(truth)]
    result = CliRunner().invoke(cli, args)
    assert result.exit_code == 0, result.output
    samples = np.load(output)
    expected = magfit.simulate(400, soft_iron=np.reshape(w, (3, 3)), hard_iron=[-30, 12, 45], field_strength=50, seed=2)
    np.testing.assert_array_equal(samples, expected.samples)
    calibration = magfit.Calibration.from_json(truth.read_text())
    np.testing.assert_array_equal(calibration.offset, [-30, 12, 45])
    np.testing.assert_allclose(calibration.matrix, np.linalg.inv(np.reshape(w, (3, 3))), rtol=1e-12)
    # Noise-free samples: the paper's ellipsoid fit gives the truth back to round-off.
    fitted = magfit.fit(samples, method="ellipsoid")
    np.testing.assert_allclose(fitted.ellipsoid_matrix, calibration.ellipsoid_matrix, rtol=1e-8, atol=1e-12)
    np.testing.assert_allclose(fitted.offset, calibration.offset, atol=1e-8)


def test_simulate_orientations_restricted(tmp_path: Path) -> None:
    output = tmp_path / "ring.csv"
    args = ["simulate", "--sensor", "ellipse2a", "-n", "300", "-o", str(output), "--orientations", "restricted"]
    result = CliRunner().invoke(cli, [*args, "--max-tilt", "5", "--seed", "1"])
    assert result.exit_code == 0, result.output
    expected = magfit.scenario("ellipse2a", "none").simulate(300, seed=1, orientations="restricted", max_tilt_deg=5)
    np.testing.assert_allclose(np.loadtxt(output, delimiter=",", skiprows=1), expected.samples, rtol=1e-9)


def test_simulate_refuses_to_overwrite_without_force(tmp_path: Path) -> None:
    output = tmp_path / "data.csv"
    output.write_text("precious\n")
    runner = CliRunner()
    result = runner.invoke(cli, ["simulate", "-n", "10", "-o", str(output)])
    assert result.exit_code == 2
    assert result.stderr == f"magfit: error: {output} already exists; pass --force to overwrite\n"
    assert output.read_text() == "precious\n"
    forced = runner.invoke(cli, ["simulate", "-n", "10", "-o", str(output), "--force"])
    assert forced.exit_code == 0 and output.read_text().startswith("mx,my,mz\n")


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["-o", "x.dat"], "cannot tell the format of x.dat: use a .csv, .txt or .npy extension"),
        (["-o", "x.csv", "--offset", "1,2"], "Invalid value for '--offset': expected 3 comma-separated numbers, got 2"),
        (["-o", "x.csv", "--matrix", "1,0,0,0,1,0,0,0,0"], "is singular: the soft iron W must be invertible"),
        (["-o", "x.csv", "--sensor", "bmm150"], "Invalid value for '--sensor'"),
        (["-o", "x.csv", "--noise", "-1"], "Invalid value for '--noise'"),
    ],
)
def test_simulate_bad_options(tmp_path: Path, extra: list[str], message: str, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)
    result = CliRunner().invoke(cli, ["simulate", "-n", "10", *extra])
    assert result.exit_code == 2
    assert result.stderr.startswith("magfit: error: ") and message in result.stderr
    assert len(result.stderr.strip().splitlines()) == 1
    assert list(tmp_path.iterdir()) == []
