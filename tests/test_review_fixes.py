"""Defects of the command line found by an adversarial review, each with a test that failed before its fix.

Where a calibration is involved the recording is simulated and the fit compared with the known truth.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
from click.testing import CliRunner

from magfit.cli import cli
from test_review_defects import _vehicle_csv


def _vehicle_hard_iron(seed: int) -> np.ndarray:
    """The hard-iron offset :func:`_vehicle_csv` simulates for ``seed`` (its draws, in its order)."""
    rng = np.random.default_rng(seed)
    rng.normal(0, 0.05, (3, 3))  # the soft iron
    return np.asarray(rng.normal(0, 0.3, 3) * 50)


@pytest.mark.slow
def test_report_gyro_reads_the_gyro_columns_calibrate_finds(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import magfit.report

    path = tmp_path / "car.csv"
    _vehicle_csv(path, "car", 1)
    drawn: list[Any] = []
    section = magfit.report.section_from_comparison
    monkeypatch.setattr(
        magfit.report, "section_from_comparison", lambda *a, **k: drawn.append(a[2]) or section(*a, **k)
    )
    result = CliRunner().invoke(cli, ["report", str(path), "--methods", "gyro", "-o", str(tmp_path / "r.html")])
    assert result.exit_code == 0, result.output
    (gyro,) = [r for comparison in drawn for r in comparison if r.method == "gyro"]
    assert gyro.ok, gyro.error
    # Ground truth: the simulated hard iron (about 4.4, 0.4, 8.2 in the samples' unit; field 50).
    np.testing.assert_allclose(gyro.calibration.offset, _vehicle_hard_iron(1), atol=1.5)


DATA = Path(__file__).parent / "data"


@pytest.mark.parametrize("command", ["calibrate", "compare"])
def test_a_cut_log_says_it_is_cut_short_once(command: str, tmp_path: Path) -> None:
    whole = (DATA / "ardupilot_real" / "copter33_log171_trimmed.bin").read_bytes()  # three compasses
    cut = tmp_path / "cut.bin"
    cut.write_bytes(whole[:-7])  # the last message cut short: a log that was not closed
    result = CliRunner().invoke(cli, [command, str(cut)])
    assert result.exit_code in (0, 1), result.output
    assert result.stderr.count("cut short") == 1, result.stderr


@pytest.mark.parametrize("size", [100, 20_000])
@pytest.mark.parametrize("command", ["calibrate", "inspect"])
def test_a_ulog_cut_inside_its_header_is_said_cut_short(command: str, size: int, tmp_path: Path) -> None:
    cut = tmp_path / "cut.ulg"
    cut.write_bytes((DATA / "px4_pyulog" / "sample_log_small.ulg").read_bytes()[:size])  # before any logged data
    result = CliRunner().invoke(cli, [command, str(cut)])
    assert result.exit_code == 2, result.output
    assert "cut short" in result.stderr and "no magnetometer" not in result.stderr, result.stderr


@pytest.mark.parametrize("place", [[], ["--location", "47,8"]])
def test_field_strength_wmm_on_an_empty_file_says_the_file_is_empty(place: list[str], tmp_path: Path) -> None:
    empty = tmp_path / "mag.csv"
    empty.write_bytes(b"")
    result = CliRunner().invoke(cli, ["calibrate", str(empty), "--field-strength", "wmm", *place])
    assert result.exit_code == 2, result.output
    assert "is empty" in result.stderr and "unit" not in result.stderr and "--location" not in result.stderr
