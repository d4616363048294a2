"""``magfit inspect`` and ``open_source`` on samples files: the same sniffing as the readers, one Source."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from click.testing import CliRunner

from magfit.cli import cli
from magfit.sources import log_kind, open_source


def test_a_csv_is_one_magnetometer_with_its_columns(tmp_path: Path) -> None:
    path = tmp_path / "mag.csv"
    samples = np.random.default_rng(0).normal(size=(50, 3))
    np.savetxt(path, np.column_stack([np.arange(50), samples]), delimiter=",", header="t,mx,my,mz", comments="")
    assert log_kind(path) is None
    source = open_source(path)
    assert source.kind == "samples"
    (magnetometer,) = source.magnetometers
    assert magnetometer.description == "mx, my, mz" and magnetometer.n_samples == 50 and magnetometer.problem is None
    result = CliRunner().invoke(cli, ["inspect", str(path)])
    assert result.exit_code == 0, result.output
    assert "columns  mx, my, mz: 50 samples" in result.stdout


def test_columns_that_cannot_be_found_are_listed_with_the_reason(tmp_path: Path) -> None:
    path = tmp_path / "abc.csv"
    path.write_text("a,b,c\n1,2,3\n4,5,6\n")
    result = CliRunner().invoke(cli, ["inspect", str(path)])
    assert result.exit_code == 0, result.output
    assert "cannot be fitted" in result.stdout and "--columns X,Y,Z" in result.stdout


def test_sensor_on_a_samples_file_is_a_usage_error(tmp_path: Path) -> None:
    path = tmp_path / "mag.csv"
    np.savetxt(path, np.random.default_rng(1).normal(size=(50, 3)), delimiter=",", header="mx,my,mz", comments="")
    result = CliRunner().invoke(cli, ["calibrate", str(path), "--sensor", "MAG/0"])
    assert result.exit_code == 2 and "--sensor ID chooses a compass of a flight log" in result.stderr


def test_a_binary_file_that_is_no_log_is_refused_in_one_line(tmp_path: Path) -> None:
    path = tmp_path / "encrypted.BIN"
    path.write_bytes(b"\xa5\x01\x02\x00" + bytes(range(256)) * 8)  # a signed log container, not DataFlash
    result = CliRunner().invoke(cli, ["inspect", str(path)])
    assert result.exit_code == 2 and len(result.stderr.strip().splitlines()) == 1
