"""`magfit calibrate --force`: a calibration the samples do not support is returned, marked, never silently."""

from __future__ import annotations

import inspect
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

import magfit
from magfit.cli import cli

pytestmark = pytest.mark.skipif(
    "allow_undetermined" not in inspect.signature(magfit.fit).parameters,
    reason="this magfit.fit reaches no support verdict (allow_undetermined)",
)


def _yaw_only(tmp_path: Path) -> Path:
    """A sensor that only turned about z (a slight wobble): z's offset and scale are not determined."""
    angle = np.linspace(0, 6 * np.pi, 600)
    ring = np.column_stack([30 * np.cos(angle), 30 * np.sin(angle), 20 + 0.5 * np.sin(7 * angle)])
    path = tmp_path / "ring.csv"
    np.savetxt(path, ring, delimiter=",", header="mx,my,mz", comments="")
    return path


def test_refused_without_force_returned_and_marked_with_it(tmp_path: Path) -> None:
    path = _yaw_only(tmp_path)
    runner = CliRunner()
    refused = runner.invoke(cli, ["calibrate", str(path), "-m", "sphere", "-o", str(tmp_path / "cal.json")])
    assert refused.exit_code == 1, refused.output
    assert "do not support the sphere calibration" in refused.stderr and not (tmp_path / "cal.json").exists()
    forced = runner.invoke(cli, ["calibrate", str(path), "-m", "sphere", "--force", "-o", str(tmp_path / "cal.json")])
    assert forced.exit_code == 0, forced.output
    assert "magfit: warning: NOT SUPPORTED (forced): " in forced.stderr
    assert "verdict          NOT SUPPORTED by the samples, returned because of --force" in forced.stdout
    saved = magfit.Calibration.from_json((tmp_path / "cal.json").read_text())
    assert saved.support.verdict == "refused" and saved.support.forced is True


def test_a_supported_fit_says_so(tmp_path: Path) -> None:
    samples = magfit.scenario("mpu9250", "steel").simulate(3000, seed=4).samples
    path = tmp_path / "steel.csv"
    np.savetxt(path, samples, delimiter=",", header="mx,my,mz", comments="")
    result = CliRunner().invoke(cli, ["calibrate", str(path), "-m", "ellipsoid"])
    assert result.exit_code == 0, result.output
    (line,) = [line for line in result.stdout.splitlines() if line.startswith("verdict")]
    assert line.split()[1] in ("supported", "weak:")


def test_auto_is_refused_without_force_and_returned_with_it(tmp_path: Path) -> None:
    # auto refuses when no model is determined; forced, it returns the model its unforced choice ranks best
    # (exit 0, as README and docs/cli.md say), the refusal the first warning; it exited 1 before.
    path = _yaw_only(tmp_path)
    runner = CliRunner()
    refused = runner.invoke(cli, ["calibrate", str(path), "-o", str(tmp_path / "cal.json")])
    assert refused.exit_code == 1 and not (tmp_path / "cal.json").exists()
    forced = runner.invoke(cli, ["calibrate", str(path), "--force", "-o", str(tmp_path / "cal.json")])
    assert forced.exit_code == 0, forced.output
    assert forced.stderr.startswith("magfit: warning: NOT SUPPORTED (forced): the samples determine no calibration")
    assert "verdict          NOT SUPPORTED by the samples, returned because of --force" in forced.stdout
    saved = magfit.Calibration.from_json((tmp_path / "cal.json").read_text())
    assert saved.method == "auto" and saved.support.forced is True
    # The ring is a circle of radius 30 about (0, 0, 20): the sphere through it has that centre in x and y.
    np.testing.assert_allclose(saved.offset[:2], [0.0, 0.0], atol=0.5)
