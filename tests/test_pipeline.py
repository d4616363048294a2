"""``magfit.calibrate_file`` and every command on logs: each compass's truth recovered from a synthetic
DataFlash and ULog log, one output per compass (never over an existing file), the World Magnetic Model at the
log's own GNSS fixes, and plot / apply / compare / report / inspect taking a log as calibrate does."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

import magfit
from magfit.cli import cli
from magfit.errors import DataFileError, MagfitError, OptionError
from magfit.facts import LogCompass
from test_sources_dataflash import COMPASSES, DataFlashWriter, write_new_style
from test_sources_ulog import DEVICE, write_log

ROS_BAG = Path(__file__).parent / "data" / "ros" / "fake_sensors_sample.bag"


def _assert_recovers(calibration: magfit.Calibration, truth: magfit.Calibration, tolerance: float = 0.01) -> None:
    # 0.3 % noise and int16 truncation (DataFlash) on 1500 samples: the identifiable ellipsoid within 1 % of its
    # largest entry, the offset within 1 % of the field; an axis, sign or compass mix-up is far outside.
    scale = float(np.max(np.abs(truth.ellipsoid_matrix)))
    np.testing.assert_allclose(calibration.ellipsoid_matrix, truth.ellipsoid_matrix, atol=tolerance * scale)
    np.testing.assert_allclose(calibration.offset, truth.offset, atol=tolerance * truth.field_strength)


#: GPS fixes near Zurich in GPS week 2300 (2024-02-04): three 3-D fixes at 488.5 m.
def _with_gps(path: Path) -> None:
    writer = DataFlashWriter()
    writer.define(132, "GPS", "QBBIHLLe", "TimeUS,I,Status,GMS,GWk,Lat,Lng,Alt")
    for j, lat in enumerate((472000000, 472000010, 472000020)):
        writer.write("GPS", 2_000_000 + j, 0, 3, 100_000 + j * 200, 2300, lat, 85000000, 48850)
    path.write_bytes(path.read_bytes() + writer.bytes())


@pytest.fixture(scope="module")
def two_compasses(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list[magfit.Simulation]]:
    path = tmp_path_factory.mktemp("logs") / "flight.bin"
    return path, write_new_style(path)


def test_calibrate_file_fits_each_compass_of_a_dataflash_log(two_compasses) -> None:
    path, simulations = two_compasses
    result = magfit.calibrate_file(path, "ellipsoid")
    assert result.sensors == ("MAG/0", "MAG/1") and not result.failures
    for k, compass in enumerate(result.compasses):
        _assert_recovers(compass.calibration, simulations[k].truth)
        assert compass.calibration.unit == "mG"
        assert compass.calibration.sensor == LogCompass(f"MAG/{k}", k, COMPASSES[k]["dev_id"])
        # 1500 samples at 20 Hz from 2 s after boot; the tumble reaches every direction.
        assert (compass.start_s, compass.end_s) == pytest.approx((2.0, 2.0 + 1499 * 0.05))
        assert compass.rate_hz == pytest.approx(20.0) and compass.coverage == 1.0
        assert any("logged after ArduPilot's calibration" in note for note in compass.notes)
        assert compass.model_field is None
    with pytest.raises(MagfitError, match="2 compasses were fitted"):
        result.calibration  # noqa: B018
    one = magfit.calibrate_file(path, "ellipsoid", sensor=str(COMPASSES[1]["dev_id"]))  # by device id
    assert one.calibration == result.compasses[1].calibration


def test_calibrate_file_on_a_samples_file_is_what_the_command_prints(tmp_path: Path) -> None:
    sim = magfit.simulate(2000, field_strength=50.0, hard_iron=[10.0, -20.0, 30.0], noise=0.5, seed=4)
    path = tmp_path / "mag.csv"
    np.savetxt(path, sim.samples, delimiter=",", header="mx,my,mz", comments="")
    result = magfit.calibrate_file(path, "sphere", unit="uT")
    np.testing.assert_allclose(result.calibration.offset, sim.truth.offset, atol=0.1)
    compass = result.compasses[0]
    assert compass.sensor is None and np.isnan(compass.span_s) and compass.columns == ("mx", "my", "mz")
    output = tmp_path / "cal.json"
    printed = CliRunner().invoke(cli, ["calibrate", str(path), "-m", "sphere", "--unit", "uT", "-o", str(output)])
    assert printed.exit_code == 0, printed.output
    assert magfit.Calibration.from_json(output.read_text()) == result.calibration
    assert "time  " not in printed.stdout and "directions  " not in printed.stdout  # samples files: as before
    with pytest.raises(DataFileError, match="sensor='ID' chooses a compass of a flight log"):
        magfit.calibrate_file(path, "sphere", sensor="MAG/0")
    with pytest.raises(OptionError, match="field_strength='wmm' needs location="):
        magfit.calibrate_file(path, "sphere", unit="uT", field_strength="wmm")


def test_a_log_refused_compass_is_a_failure_beside_the_others(tmp_path: Path) -> None:
    # sensor_mag/1 holds one repeated value: refused; the raw and the undone calibrated stream recover the truth.
    path = tmp_path / "flight.ulg"
    simulation = write_log(path)
    result = magfit.calibrate_file(path, "ellipsoid")
    assert result.sensors == ("sensor_mag/0", "sensor_mag/1", "vehicle_magnetometer/0")
    assert [failure.sensor for failure in result.failures] == ["sensor_mag/1"]
    assert "identical" in result.failures[0].reason
    for compass in result.compasses:
        _assert_recovers(compass.calibration, simulation.truth)
        assert compass.calibration.sensor.device_id == DEVICE and compass.calibration.unit == "G"
    with pytest.raises(magfit.CalibrationError, match="identical"):  # chosen alone, the refusal raises
        magfit.calibrate_file(path, "ellipsoid", sensor="sensor_mag/1")


def test_several_compasses_go_to_one_file_each_never_over_an_existing_one(two_compasses, tmp_path: Path) -> None:
    path, simulations = two_compasses
    runner = CliRunner()
    output = tmp_path / "cal.json"
    result = runner.invoke(cli, ["calibrate", str(path), "-m", "ellipsoid", "-o", str(output)])
    assert result.exit_code == 0, result.output
    written = {k: tmp_path / f"cal-MAG_{k}.json" for k in range(2)}
    for k, file in written.items():
        calibration = magfit.Calibration.from_json(file.read_text())
        _assert_recovers(calibration, simulations[k].truth)
        assert calibration.sensor is not None and calibration.sensor.id == f"MAG/{k}"
        assert f"wrote the calibration of MAG/{k} to {file}" in result.stdout
    assert not output.exists()
    before = {k: file.read_bytes() for k, file in written.items()}
    again = runner.invoke(cli, ["calibrate", str(path), "-m", "ml", "-o", str(output)])
    assert again.exit_code == 2 and "cal-MAG_0.json exists" in again.stderr and "never written over" in again.stderr
    assert {k: file.read_bytes() for k, file in written.items()} == before
    # A one-compass format without -o has nowhere to put the second compass.
    to_stdout = runner.invoke(cli, ["calibrate", str(path), "-m", "ellipsoid", "--export", "c"])
    assert to_stdout.exit_code == 2 and "give -o NAME" in to_stdout.stderr and to_stdout.stdout == ""
    headers = runner.invoke(
        cli, ["calibrate", str(path), "-m", "ellipsoid", "--export", "c", "-o", str(tmp_path / "m.h")]
    )
    assert headers.exit_code == 0, headers.output
    assert sorted(p.name for p in tmp_path.glob("m-*.h")) == ["m-MAG_0.h", "m-MAG_1.h"]


@pytest.mark.parametrize("export_format", ["ardupilot", "px4"])
def test_several_compasses_in_one_parameter_file(two_compasses, tmp_path: Path, export_format: str) -> None:
    from magfit.export import export

    path, _ = two_compasses
    output = tmp_path / f"vehicle.{'param' if export_format == 'ardupilot' else 'params'}"
    args = ["calibrate", str(path), "-m", "ellipsoid", "--export", export_format, "-o", str(output)]
    result = CliRunner().invoke(cli, args)
    assert result.exit_code == 0, result.output
    assert f"wrote the {export_format} export of MAG/0, MAG/1 to {output}" in result.stdout
    text = output.read_text()
    fitted = magfit.calibrate_file(path, "ellipsoid").compasses
    # Each compass's lines are those of its own export for its slot (ArduPilot: OFS, OFS2; PX4: CAL_MAG0, 1).
    for compass in fitted:
        alone = export(compass.calibration, export_format)
        lines = [line for line in alone.splitlines() if line and not line.startswith("#")]
        assert lines and all(line in text.splitlines() for line in lines)
    names = ("COMPASS_OFS_X", "COMPASS_OFS2_X") if export_format == "ardupilot" else ("CAL_MAG0_XOFF", "CAL_MAG1_XOFF")
    assert all(name in text for name in names)


def test_the_model_field_comes_from_the_logs_own_fixes(two_compasses, tmp_path: Path) -> None:
    pytest.importorskip("pygeomag")
    from magfit.geomag import field_at

    path = tmp_path / "gps.bin"
    path.write_bytes(two_compasses[0].read_bytes())
    _with_gps(path)
    # GPS week 2300, 100 s in, less 18 leap seconds: 2024-02-04; the median of the three fixes.
    expected = field_at(47.200001, 8.5, 0.4885, date="2024-02-04")
    result = magfit.calibrate_file(path, "ellipsoid", field_strength="wmm")
    assert result.model_field is not None and "median of 3 3-D fixes" in result.model_field.origin
    for compass in result.compasses:
        assert compass.calibration.field_strength == pytest.approx(expected.total_in("mG"), rel=1e-6)
    output = tmp_path / "vehicle.param"
    args = ["calibrate", str(path), "-m", "ellipsoid", "--location", "log", "--export", "ardupilot", "-o", str(output)]
    printed = CliRunner().invoke(cli, args)
    assert printed.exit_code == 0, printed.output
    assert printed.stdout.count(f"inclination {expected.inclination_deg:.1f}°") == 2
    assert "at the log's GNSS fixes (median of 3 3-D fixes, first at 2024-02-04 00:01 UTC)" in printed.stdout
    # Not pinned: COMPASS_SCALE carries expected / fitted field, as ArduPilot's calibrator sets it.
    scales = dict(re.findall(r"^(COMPASS_SCALE2?),([^\n]+)$", output.read_text(), re.MULTILINE))
    for k, name in enumerate(("COMPASS_SCALE", "COMPASS_SCALE2")):
        fitted = magfit.calibrate_file(path, "ellipsoid").compasses[k].calibration.field_strength
        assert float(scales[name]) == pytest.approx(expected.total_in("mG") / fitted, rel=1e-6)
    no_fix = CliRunner().invoke(cli, ["calibrate", str(two_compasses[0]), "--field-strength", "wmm"])
    assert no_fix.exit_code == 2 and "this log holds no 3-D GNSS fix" in no_fix.stderr
    assert "--location LAT,LON[,ALT]" in no_fix.stderr


def test_apply_writes_a_logs_corrected_samples_with_their_time_stamps(two_compasses, tmp_path: Path) -> None:
    path, simulations = two_compasses
    runner = CliRunner()
    assert (
        runner.invoke(cli, ["calibrate", str(path), "-m", "ellipsoid", "-o", str(tmp_path / "c.json")]).exit_code == 0
    )
    output = tmp_path / "mag1.csv"
    # The calibration remembers its compass: MAG/1 is corrected without --sensor.
    result = runner.invoke(cli, ["apply", str(tmp_path / "c-MAG_1.json"), str(path), "-o", str(output)])
    assert result.exit_code == 0, result.output
    table = np.loadtxt(output, delimiter=",", skiprows=1)
    assert output.read_text().splitlines()[0] == "time_s,MagX,MagY,MagZ"
    np.testing.assert_allclose(table[:, 0], 2.0 + 0.05 * np.arange(1500))
    truth = simulations[1].truth  # the true calibration puts the raw field on the sphere of its strength
    np.testing.assert_allclose(
        np.linalg.norm(table[:, 1:], axis=1), np.linalg.norm(truth.apply(simulations[1].samples), axis=1), rtol=0.02
    )
    array = tmp_path / "mag0.npy"
    other = runner.invoke(
        cli, ["apply", str(tmp_path / "c-MAG_1.json"), str(path), "--sensor", "MAG/0", "-o", str(array)]
    )
    assert other.exit_code == 0 and "was fitted on MAG/1, and is applied to MAG/0" in other.stderr
    assert np.load(array).shape == (1500, 4)


@pytest.mark.slow
def test_plot_compare_and_report_take_a_log(two_compasses, tmp_path: Path) -> None:
    path, simulations = two_compasses
    runner = CliRunner()
    compared = runner.invoke(cli, ["compare", str(path), "--methods", "ellipsoid", "--format", "json"])
    assert compared.exit_code == 0, compared.output
    document = json.loads(compared.stdout)
    assert [entry["file"] for entry in document] == [f"{path} (MAG/0)", f"{path} (MAG/1)"]
    assert [entry["unit"] for entry in document] == ["mG", "mG"]
    for k, entry in enumerate(document):
        offset = entry["results"][0]["calibration"]["offset"]
        np.testing.assert_allclose(offset, simulations[k].truth.offset, atol=0.01 * simulations[k].field_strength)
    pytest.importorskip("matplotlib")
    figure = tmp_path / "mag1.png"
    several = runner.invoke(cli, ["plot", str(path), "-o", str(figure)])
    assert several.exit_code == 2 and "--sensor" in several.stderr and not figure.exists()
    plotted = runner.invoke(cli, ["plot", str(path), "--sensor", "MAG/1", "-m", "ellipsoid", "-o", str(figure)])
    assert plotted.exit_code == 0, plotted.output
    assert figure.read_bytes().startswith(b"\x89PNG") and f"{path} (MAG/1): columns MagX" in plotted.stdout
    pytest.importorskip("plotly")
    report = tmp_path / "report.html"
    written = runner.invoke(cli, ["report", str(path), "--methods", "ellipsoid", "-o", str(report)])
    assert written.exit_code == 0, written.output
    html = report.read_text()
    assert "flight.bin (MAG/0)" in html and "flight.bin (MAG/1)" in html


def test_inspect_shows_a_bags_time_as_a_utc_date() -> None:
    pytest.importorskip("rosbags")
    result = CliRunner().invoke(cli, ["inspect", str(ROS_BAG)])
    assert result.exit_code == 0, result.output
    assert "2021-07-19 18:55:36 to 18:55:54 UTC (18.0 s)" in result.stdout
    assert "1626720936" not in result.stdout  # not epoch seconds


def test_with_a_compass_refused_nothing_is_written(tmp_path: Path) -> None:
    # sensor_mag/1 of this ULog is refused: the other two are fitted and printed, no file is written, exit 1.
    path = tmp_path / "flight.ulg"
    write_log(path)
    output = tmp_path / "cal.json"
    result = CliRunner().invoke(cli, ["calibrate", str(path), "-m", "ellipsoid", "-o", str(output)])
    assert result.exit_code == 1
    assert "1 of 3 magnetometers could not be fitted (sensor_mag/1); nothing is written" in result.stderr
    assert "sensor_mag/1: not fitted" in result.stdout and result.stdout.count("verdict          supported") == 2
    assert list(tmp_path.glob("cal*")) == []


def test_the_module_example_runs() -> None:
    import doctest

    import magfit.pipeline

    assert doctest.testmod(magfit.pipeline).failed == 0


def test_the_model_field_at_a_real_logs_own_fixes() -> None:
    # PX4's sample log (pyulog's repository) flew near Trondheim on 2021-04-21; its raw sensor_mag is logged at
    # 1 Hz, too few samples: no compass is fitted, but the model's field is that of the log's place and date.
    pytest.importorskip("pyulog")
    pytest.importorskip("pygeomag")
    from magfit.geomag import field_at

    sample = Path(__file__).parent / "data" / "px4_pyulog" / "sample_log_small.ulg"
    result = magfit.calibrate_file(sample, "ellipsoid", location="log")
    assert not result.compasses and {f.sensor for f in result.failures} == {"sensor_mag/0", "sensor_mag/1"}
    assert all("SDLOG_PROFILE" in failure.reason for failure in result.failures)  # how to log more
    assert result.model_field is not None
    expected = field_at(63.41705, 10.40822, 0.064, date="2021-04-21")
    assert result.model_field.field.total == pytest.approx(expected.total, rel=1e-4)
    assert result.model_field.field.year == pytest.approx(expected.year)
    printed = CliRunner().invoke(cli, ["calibrate", str(sample), "--location", "log"])
    assert printed.exit_code == 1 and "2 of 2 magnetometers could not be fitted" in printed.stderr
    assert f"model field      {expected.total / 1000:.6g} uT" in printed.stdout
    assert "first at 2021-04-21 06:30 UTC" in printed.stdout


def test_time_spans_in_words() -> None:
    from magfit.cli._common import time_span

    assert time_span(100.25, 125.0, "seconds since boot (TimeUS)") == "100.2 to 125.0 s after boot (24.8 s)"
    # 2021-07-19 18:55:36 UTC is 1626720936 s after 1970-01-01.
    assert time_span(1626720936.0, 1626720954.0, "seconds since the epoch (header.stamp)") == (
        "2021-07-19 18:55:36 to 18:55:54 UTC (18.0 s)"
    )
    # PX4 SITL stamps a "boot" clock with the host's time: shown as the date it is.
    assert time_span(1626720936.0, 1626807400.0, "seconds since boot (timestamp)") == (
        "2021-07-19 18:55:36 to 2021-07-20 18:56:40 UTC (86464.0 s)"
    )
    assert time_span(float("nan"), float("nan"), "none (rows)") == "no time stamps"
