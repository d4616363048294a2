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


def _log_with_gps(
    path: Path, monkeypatch: pytest.MonkeyPatch, drop: tuple[str, ...] = (), trim_deg: tuple[float, float] = (0, 0)
) -> tuple[Path, np.ndarray]:
    """A DataFlash tumble (tests/test_sources_motion.py) whose field is the model's at its GPS fixes, without the
    messages ``drop`` names; ``trim_deg``: AHRS_TRIM_X/Y, subtracted from ATT's roll and pitch as the EKF does."""
    from magfit.geomag import field_at

    field = field_at(LAT, LON, ALT_KM, date=DATE).vector_in("mG")
    monkeypatch.setattr(motion_log, "FIELD_NED", field)
    formats, rows = motion_log.dataflash_messages(n_mag=1600)
    formats["GPS"] = (133, "QBIHLLf", "TimeUS,Status,GMS,GWk,Lat,Lng,Alt")
    rows["GPS"] = [
        (round(t * 1e6), 3, 200_000_000 + int(t * 1000), 2414, round(LAT * 1e7), round(LON * 1e7), ALT_KM * 1000)
        for t in np.arange(1.0, 80.0, 0.2)
    ]
    for name in drop:
        del formats[name], rows[name]
    if any(trim_deg):
        rows["ATT"] = [(t, roll - trim_deg[0], pitch - trim_deg[1], yaw) for t, roll, pitch, yaw in rows["ATT"]]
        trims = zip("XY", trim_deg, strict=True)
        rows["PARM"] += [(500_000, f"AHRS_TRIM_{axis}", float(np.radians(d))) for axis, d in trims]
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
    assert calibration.sensor is not None and calibration.sensor.applied_rotation is not None
    # the log's stamps are given: the attitude's lag is fitted (the synthetic ATT is on time)
    assert calibration.vector.lag_s is not None and abs(calibration.vector.lag_s) < 0.02
    # and the accelerometer and gyro reached the fit (a tumble that never holds still: no gravity rows used)
    gravity = calibration.vector.gravity
    assert gravity["of"] > 1000 and not gravity["used"] and "turning faster" in gravity["note"]


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
    assert result.exit_code == 2 and "no attitude columns were found" in result.output
    assert f"on the command line: magfit calibrate {csv} --method vector --attitude ROLL,PITCH,YAW" in result.output


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


@pytest.mark.slow
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


# ---------------------------------------------------------------------- the accelerometer (issue 14)


def _probe(monkeypatch: pytest.MonkeyPatch, needs: tuple[str, ...]) -> list[dict]:
    """A method registered for the test that takes ``accel=`` and fits ``vector`` (or a sphere): what it was
    given is appended to the list returned. vector and gyro take the accelerometer the same way."""
    from magfit.methods.registry import METHODS, MethodSpec
    from magfit.methods.vector import fit_vector

    seen: list[dict] = []

    def probe(data, *, reference=None, time_s=None, gyro=None, accel=None):
        seen.append({"reference": reference, "gyro": gyro, "time_s": time_s, "accel": accel})
        if reference is not None:
            return fit_vector(data, reference=reference, time_s=time_s)
        return METHODS["sphere"].function(data)

    monkeypatch.setitem(METHODS, "probe", MethodSpec("probe", probe, 50, "samples", "test", (), needs))
    return seen


def test_the_accelerometer_is_asked_of_the_methods_that_take_it_only(monkeypatch) -> None:
    from magfit.pipeline.streams import stream_names

    _probe(monkeypatch, ("reference",))
    # the stamps too (vector fits the lag), the gyro (vector's still gate) and the accelerometer: only taken
    assert stream_names(["probe"]) == (("reference",), ("time_s", "gyro", "accel"))
    assert stream_names(["sphere", "auto"]) == ((), ())  # the samples alone: no stream, the accelerometer neither
    assert stream_names(["probe", "gyro"]).needed == ("reference", "gyro", "time_s")  # needed by one: needed
    for method in ("vector", "gyro"):  # whatever their signature says today
        spec = magfit.METHODS[method]
        names = stream_names([method])
        assert ("accel" in names.optional) == ("accel" in spec.options)
        assert names.needed == spec.needs and not set(names.needed) & set(names.optional)


def test_the_logs_accelerometer_is_given_in_the_body_frame_on_the_compass_stamps(tmp_path, monkeypatch) -> None:
    path, _ = _log_with_gps(tmp_path / "gps.bin", monkeypatch)
    streams = method_streams(
        open_source(path), "MAG/0", ("reference",), optional=("gyro", "time_s", "accel"), unit=None
    )
    accel, t = streams.options["accel"], streams.options["time_s"]
    assert accel.shape == streams.samples.shape
    # The IMU is logged at 50 Hz in the body frame (FRD): the specific force of the tumble, interpolated.
    np.testing.assert_allclose(accel, motion_log.specific_force(t), atol=0.05)
    # ... so the attitude turns it into gravity in NED, sample by sample
    gravity = np.einsum("nij,nj->ni", motion_log.attitude(t), accel)
    np.testing.assert_allclose(gravity, np.tile([0.0, 0.0, -motion_log.G], (len(t), 1)), atol=0.05)
    assert any("accelerometer: IMU[0] AccX/Y/Z" in note and "body (FRD)" in note for note in streams.notes)


def test_a_log_without_an_accelerometer_is_fitted_without_one(tmp_path, monkeypatch) -> None:
    path, _ = _log_with_gps(tmp_path / "noimu.bin", monkeypatch, drop=("IMU",))
    seen = _probe(monkeypatch, ("reference",))
    for available in (False, True):
        streams = method_streams(open_source(path), "MAG/0", ("reference",), optional=("time_s", "gyro", "accel"),
                                 unit=None, available=available)  # fmt: skip
        assert "accel" not in streams.options and "gyro" not in streams.options and "reference" in streams.options
        assert any("no accelerometer beside this compass: the methods run without it" in n for n in streams.notes)
    calibration = magfit.calibrate_file(path, "probe", sensor="MAG/0").calibration
    assert seen[-1]["accel"] is None and seen[-1]["reference"] is not None
    np.testing.assert_allclose(calibration.offset, motion_log.HARD, atol=3.0)


def test_calibrate_file_gives_the_accelerometer_to_a_method_that_takes_it(tmp_path, monkeypatch) -> None:
    path, _ = _log_with_gps(tmp_path / "gps.bin", monkeypatch)
    seen = _probe(monkeypatch, ("reference",))
    result = magfit.calibrate_file(path, "probe", sensor="MAG/0")
    given = seen[-1]
    assert given["accel"] is not None and given["accel"].shape == given["reference"].shape
    np.testing.assert_allclose(given["gyro"], motion_log.body_rates(given["time_s"]), atol=0.02)
    np.testing.assert_allclose(given["accel"], motion_log.specific_force(given["time_s"]), atol=0.05)
    assert any("accelerometer: IMU[0] AccX/Y/Z" in note for note in result.compasses[0].notes)


def _ulog_with_raw_accel(path: Path) -> Path:
    """The tumble as a PX4 log whose gyro is vehicle_angular_velocity (body frame) and whose accelerometer
    is only the raw sensor_accel (the board's frame, before SENS_BOARD_ROT)."""
    from test_sources_ulog import ULogWriter

    writer = ULogWriter()
    writer.format("sensor_mag", [("uint64_t", "timestamp"), ("uint32_t", "device_id"), *(("float", a) for a in "xyz")])
    writer.format("vehicle_attitude", [("uint64_t", "timestamp"), ("float[4]", "q")])
    writer.format("vehicle_angular_velocity", [("uint64_t", "timestamp"), ("float[3]", "xyz")])
    writer.format("sensor_accel", [("uint64_t", "timestamp"), *(("float", a) for a in "xyz")])
    writer.parameter("CAL_MAG0_ID", 592905)
    writer.parameter("CAL_MAG0_ROT", 0)
    for topic in ("sensor_mag", "vehicle_attitude", "vehicle_angular_velocity", "sensor_accel"):
        writer.subscribe(topic, 0)
    t_mag = 1.0 + np.arange(600) / 20.0
    raw = motion_log.raw_field(t_mag) / 1000.0  # gauss
    t_fast = np.arange(0.9, t_mag[-1] + 0.2, 0.01) + 0.003
    q = motion_log.Rotation.from_matrix(motion_log.attitude(t_fast)).as_quat()  # x, y, z, w
    gyro, accel = motion_log.body_rates(t_fast), motion_log.specific_force(t_fast)
    events = [(t, 0, j) for j, t in enumerate(t_mag)] + [(t, 1, j) for j, t in enumerate(t_fast)]
    for time, kind, j in sorted(events):
        stamp = round(time * 1e6)
        if kind == 0:
            writer.data("sensor_mag", 0, stamp, 592905, *raw[j])
        else:
            writer.data("vehicle_attitude", 0, stamp, q[j, 3], q[j, 0], q[j, 1], q[j, 2])  # PX4: w, x, y, z
            writer.data("vehicle_angular_velocity", 0, stamp, *gyro[j])
            writer.data("sensor_accel", 0, stamp, *accel[j])
    path.write_bytes(writer.bytes())
    return path


def test_an_accelerometer_in_another_frame_than_the_gyro_or_the_attitude_is_left_out(tmp_path) -> None:
    pytest.importorskip("pyulog")
    path = _ulog_with_raw_accel(tmp_path / "raw_accel.ulg")
    # The frames are what the reader says of the topics (the values here happen to be the body's: only the
    # frames stated decide), and the accelerometer is left out for either method, with the reason.
    for needs, other in ((("gyro", "time_s"), "gyro"), (("reference",), "attitude")):
        streams = method_streams(open_source(path), "sensor_mag/0", needs, optional=("time_s", "gyro", "accel"),
                                 unit=None, available=True)  # fmt: skip
        assert "accel" not in streams.options
        # vector takes the gyro only to find gravity alone: without the accelerometer it is not given
        assert ("gyro" in streams.options) == ("gyro" in needs)
        assert any(
            "left out: it is in the sensor (before SENS_BOARD_ROT" in note and f"the {other} in the body (FRD)" in note
            for note in streams.notes
        ), streams.notes
    # sensor_combined (the rotated IMU, body frame) is given to the gyro method: the gyro's own frame
    combined = tmp_path / "combined.ulg"
    motion_log.write_ulog(combined, 0, n=600)
    streams = method_streams(open_source(combined), "sensor_mag/0", ("gyro", "time_s"), optional=("accel",), unit=None)
    np.testing.assert_allclose(streams.options["accel"], motion_log.specific_force(streams.options["time_s"]),
                               atol=1e-3)  # fmt: skip


def test_an_ardupilot_trim_is_taken_off_the_attitude_so_it_shares_the_imus_frame(tmp_path, monkeypatch) -> None:
    # ATT logs the EKF's angles minus AHRS_TRIM (NavEKF3_core::getEulerAngles); the IMU and MAG are logged in the
    # autopilot's own body. A 2° pitch trim left on the attitude would turn the reference and gravity by 2°.
    path, field = _log_with_gps(tmp_path / "trim.bin", monkeypatch, trim_deg=(0.7, -2.0))
    streams = method_streams(open_source(path), "MAG/0", ("reference", "time_s"), optional=("accel",), unit=None)
    truth = np.einsum("nji,j->ni", motion_log.attitude(streams.options["time_s"]), field)
    cosines = np.sum(streams.options["reference"] * truth, axis=1) / np.linalg.norm(truth, axis=1) ** 2
    assert np.degrees(np.max(np.arccos(np.clip(cosines, -1.0, 1.0)))) < 0.1  # the untrimmed attitude's field
    motion = open_source(path).read_motion("MAG/0")
    gravity = np.einsum("nij,nj->ni", motion.attitude, motion.accel)
    np.testing.assert_allclose(gravity, np.tile([0.0, 0.0, -motion_log.G], (len(gravity), 1)), atol=0.03)
    assert any("AHRS_TRIM_X/Y 0.70°, -2.00° taken off" in note for note in motion.notes)


def test_the_gyro_method_gets_the_gyroscope_at_its_own_rate_and_the_models_inclination(tmp_path, monkeypatch) -> None:
    # The IMU is logged at 50 Hz beside a 20 Hz compass: the gyro method integrates it at its own rate.
    from magfit.geomag import field_at

    path, _ = _log_with_gps(tmp_path / "gps.bin", monkeypatch)
    streams = method_streams(open_source(path), "MAG/0", ("gyro", "time_s"), optional=("accel", "inclination_deg"),
                             unit=None, gyro_own_rate=True)  # fmt: skip
    own, stamps = streams.options["gyro"], streams.options["gyro_time_s"]
    assert len(own) == len(stamps) > 2 * len(streams.options["time_s"])
    assert stamps[0] <= streams.options["time_s"][0] and stamps[-1] >= streams.options["time_s"][-1]
    np.testing.assert_allclose(own, motion_log.body_rates(stamps), atol=2e-3)
    model = field_at(LAT, LON, ALT_KM, date=DATE)
    assert streams.options["inclination_deg"] == pytest.approx(model.inclination_deg, abs=0.05)
    assert any("at its own rate" in note for note in streams.notes)
    # A comparison shares one gyro on the compass's stamps (vector takes it too): not at its own rate there.
    shared = method_streams(open_source(path), "MAG/0", ("gyro", "time_s"), unit=None)
    assert "gyro_time_s" not in shared.options and len(shared.options["gyro"]) == len(shared.options["time_s"])
    fitted = magfit.calibrate_file(path, "gyro", sensor="MAG/0").calibration
    np.testing.assert_allclose(fitted.offset, motion_log.HARD, atol=3.0)
