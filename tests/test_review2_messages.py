"""Messages of the command line that a second review found missing or wrong: each test failed before its fix."""

from __future__ import annotations

from pathlib import Path

import numpy as np
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
