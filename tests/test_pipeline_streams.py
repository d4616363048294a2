"""The streams a log gives the methods that need more than the samples (vector: the reference field)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import magfit
import test_sources_motion as motion_log
from magfit.errors import DataFileError, OptionError
from magfit.pipeline.streams import method_streams
from magfit.sources import open_source

pytest.importorskip("pygeomag")

#: Zurich, 0.5 km, 2026-04-14 (GPS week 2414 is April 2026): where and when the synthetic log was recorded.
LAT, LON, ALT_KM, DATE = 47.4, 8.5, 0.5, "2026-04-14"


def _log_with_gps(path: Path, monkeypatch: pytest.MonkeyPatch) -> tuple[Path, np.ndarray]:
    """A DataFlash tumble (tests/test_sources_motion.py) whose field is the model's at its GPS fixes."""
    from magfit.geomag import field_at

    field = field_at(LAT, LON, ALT_KM, date=DATE).vector_in("mG")
    monkeypatch.setattr(motion_log, "FIELD_NED", field)
    formats, rows = motion_log.dataflash_messages(n_mag=1600)
    formats["GPS"] = (133, "QBIHLLf", "TimeUS,Status,GMS,GWk,Lat,Lng,Alt")
    rows["GPS"] = [
        (round(t * 1e6), 3, 200_000_000 + int(t * 1000), 2414, round(LAT * 1e7), round(LON * 1e7), ALT_KM * 1000)
        for t in np.arange(1.0, 80.0, 0.2)
    ]
    return motion_log.write_bin(path, formats, rows), field


def test_the_reference_is_the_models_field_turned_by_the_logged_attitude(tmp_path, monkeypatch) -> None:
    path, field = _log_with_gps(tmp_path / "gps.bin", monkeypatch)
    streams = method_streams(open_source(path), "MAG/0", ("reference", "time_s"), unit=None)
    reference = streams.options["reference"]
    t = streams.options["time_s"]
    truth = np.einsum("nji,j->ni", motion_log.attitude(t), field)
    assert reference.shape == streams.samples.shape == (len(t), 3)
    assert np.percentile(np.linalg.norm(reference - truth, axis=1) / np.linalg.norm(field), 99) < 0.01
    assert any("reference field WMM" in note for note in streams.notes)
    # ArduPilot logs MAG after COMPASS_ORIENT: the exports must know the rotation already applied
    assert np.allclose(
        streams.sensor_details["applied_rotation"], motion_log.standard_rotations("ardupilot")[motion_log.ORIENT].matrix
    )


def test_calibrate_file_fits_the_vector_method_on_a_log(tmp_path, monkeypatch) -> None:
    path, _ = _log_with_gps(tmp_path / "gps.bin", monkeypatch)
    result = magfit.calibrate_file(path, "vector", sensor="MAG/0")
    calibration = result.calibration
    assert calibration.frame == "vehicle"
    # the field logged is the body frame's (after COMPASS_ORIENT): the fit undoes the soft and hard iron only
    np.testing.assert_allclose(calibration.offset, motion_log.HARD, atol=3.0)
    np.testing.assert_allclose(np.linalg.inv(calibration.matrix), motion_log.SOFT, atol=0.01)
    assert calibration.details["sensor"]["applied_rotation"] is not None


def test_what_is_missing_is_said(tmp_path, monkeypatch) -> None:
    formats, rows = motion_log.dataflash_messages(n_mag=400)
    no_gps = motion_log.write_bin(tmp_path / "nogps.bin", formats, rows)
    with pytest.raises(DataFileError, match="no 3-D GNSS fix"):
        method_streams(open_source(no_gps), "MAG/0", ("reference",), unit=None)
    del rows["ATT"], formats["ATT"]
    no_attitude = motion_log.write_bin(tmp_path / "noatt.bin", formats, rows)
    with pytest.raises(DataFileError, match="no attitude"):
        method_streams(open_source(no_attitude), "MAG/0", ("reference",), unit=None)
    path, _ = _log_with_gps(tmp_path / "gps.bin", monkeypatch)
    with pytest.raises(OptionError, match="physical unit"):
        method_streams(open_source(path), "MAG/0", ("reference",), unit="counts")


def test_the_command_fits_the_vector_method_on_a_log_and_refuses_it_on_a_samples_file(tmp_path, monkeypatch) -> None:
    from click.testing import CliRunner

    from magfit.cli import cli

    path, _ = _log_with_gps(tmp_path / "gps.bin", monkeypatch)
    result = CliRunner().invoke(cli, ["calibrate", str(path), "--method", "vector", "--sensor", "MAG/0"])
    assert result.exit_code == 0, result.output
    assert "reference field WMM" in result.output
    csv = tmp_path / "samples.csv"
    np.savetxt(csv, np.random.default_rng(0).normal(size=(100, 3)), delimiter=",")
    result = CliRunner().invoke(cli, ["calibrate", str(csv), "--method", "vector"])
    assert result.exit_code == 2 and "a samples file does not hold" in result.output


def test_compare_on_a_log_runs_vector_with_the_logs_streams_and_says_why_gyro_or_vector_cannot(
    tmp_path, monkeypatch
) -> None:
    from click.testing import CliRunner

    from magfit.cli import cli

    path, _ = _log_with_gps(tmp_path / "gps.bin", monkeypatch)
    result = CliRunner().invoke(
        cli, ["compare", str(path), "--sensor", "MAG/0", "--methods", "auto,vector", "--format", "json"]
    )
    assert result.exit_code == 0, result.output
    assert '"method": "vector"' in result.output and "not run" not in result.output
    formats, rows = motion_log.dataflash_messages(n_mag=600)
    no_gps = motion_log.write_bin(tmp_path / "nogps.bin", formats, rows)
    result = CliRunner().invoke(cli, ["compare", str(no_gps), "--sensor", "MAG/0", "--methods", "auto,vector"])
    assert result.exit_code == 0, result.output
    assert "no 3-D GNSS fix" in result.output and "not run: the vector method needs" in result.output


def test_report_on_a_log_includes_the_vector_method(tmp_path, monkeypatch) -> None:
    pytest.importorskip("plotly")
    from click.testing import CliRunner

    from magfit.cli import cli

    path, _ = _log_with_gps(tmp_path / "gps.bin", monkeypatch)
    out = tmp_path / "report.html"
    result = CliRunner().invoke(
        cli, ["report", str(path), "--sensor", "MAG/0", "--methods", "auto,vector", "-o", str(out)]
    )
    assert result.exit_code == 0, result.output
    assert "2 of 2 methods fitted" in result.output and "vector" in out.read_text()
