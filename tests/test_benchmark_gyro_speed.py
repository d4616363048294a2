"""benchmarks/gyro_speed.py on a small recording: a row per size with both times, their ratio and gyro's verdict
(the fit it times is a real one: the simulated tumble's calibration is supported)."""

from __future__ import annotations

import importlib
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
gyro_speed = importlib.import_module("gyro_speed")


@pytest.mark.slow
def test_the_benchmark_writes_its_table(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "gyro_speed.md"
    assert gyro_speed.main(["--sizes", "3000", "--repeat", "1", "--out", str(out)]) == 0
    row = next(line for line in out.read_text(encoding="utf-8").splitlines() if line.startswith("| 3,000 |"))
    cells = [cell.strip() for cell in row.strip("|").split("|")]
    gyro, ellipsoid, ratio = float(cells[1]), float(cells[2]), float(cells[3])
    assert gyro > 0 and ellipsoid > 0 and abs(ratio - gyro / ellipsoid) < 0.06 * ratio + 0.05
    assert cells[4] == "—" and cells[5] == "supported"
    assert "| 3,000 |" in capsys.readouterr().out
