"""The motors' field from flight logs: the current and throttle read (sources.power), fitted by calibrate_file."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import magfit
from magfit.errors import OptionError
from magfit.motorsim import MotorFlight, heading_error_deg, simulate_motor_flight
from magfit.sources.power import read_power
from test_sources_dataflash import DataFlashWriter


def write_flight(path: Path, flight: MotorFlight, *, bat: bool = True, ctun: bool = True, att: bool = False) -> Path:
    """An ArduPilot DataFlash log of the flight: MAG (the raw field: no calibration, COMPASS_MOTCT 0), BAT, CTUN,
    and with ``att`` the true attitude as ATT (degrees) and AHRS_EKF_TYPE 0 (what pymavlink's magfit_WMM reads)."""
    writer = DataFlashWriter()
    writer.define(129, "PARM", "QNf", "TimeUS,Name,Value")
    writer.define(130, "MAG", "QBhhhhhhhhhBI", "TimeUS,I,MagX,MagY,MagZ,OfsX,OfsY,OfsZ,MOX,MOY,MOZ,Health,S")
    writer.define(131, "BAT", "QBff", "TimeUS,Inst,Volt,Curr")
    writer.define(132, "CTUN", "Qff", "TimeUS,ThI,ThO")
    writer.define(133, "ATT", "Qfff", "TimeUS,Roll,Pitch,Yaw")
    for name in ("AHRS_EKF_TYPE", "AHRS_TRIM_X", "AHRS_TRIM_Y", "AHRS_TRIM_Z"):
        writer.write("PARM", 1000, name, 0.0)
    for axis in "XYZ":
        writer.write("PARM", 1000, f"COMPASS_OFS_{axis}", 0.0)
        writer.write("PARM", 1000, f"COMPASS_DIA_{axis}", 1.0)
        writer.write("PARM", 1000, f"COMPASS_ODI_{axis}", 0.0)
    writer.write("PARM", 1000, "COMPASS_SCALE", 1.0)
    writer.write("PARM", 1000, "COMPASS_MOTCT", 0.0)
    logged = np.trunc(flight.samples)
    for j, t in enumerate(flight.time_s):
        time = int(1_000_000 + t * 1e6)
        writer.write("MAG", time, 0, *logged[j].astype(int), 0, 0, 0, 0, 0, 0, 1, time)
        if att:
            roll, pitch, yaw = np.degrees(flight.euler[j])
            writer.write("ATT", time, float(roll), float(pitch), float(yaw % 360.0))
        if j % 5 == 0:  # 10 Hz, as ArduPilot logs BAT and CTUN
            if bat:
                writer.write("BAT", time + 3000, 0, 15.8, float(flight.current[j]))
            if ctun:
                writer.write("CTUN", time + 1000, float(flight.throttle[j]), float(flight.throttle[j]))
    path.write_bytes(writer.bytes())
    return path


@pytest.fixture(scope="module")
def current_flight() -> MotorFlight:
    return simulate_motor_flight(240, driver="current", per_unit=3.5, seed=11)


def test_power_is_read_from_dataflash(tmp_path: Path, current_flight: MotorFlight) -> None:
    path = write_flight(tmp_path / "quad.bin", current_flight)
    power = read_power(path)
    assert power.current is not None and power.throttle is not None
    assert power.current.name == "BAT.Curr" and power.throttle.name == "CTUN.ThO"
    np.testing.assert_allclose(power.current.values, current_flight.current[::5], rtol=1e-6)
    np.testing.assert_allclose(power.current.time_s, 1.0 + current_flight.time_s[::5] + 0.003, atol=1e-6)


@pytest.mark.slow
def test_calibrate_file_fits_the_current_and_beats_the_plain_fit(tmp_path: Path, current_flight: MotorFlight) -> None:
    path = write_flight(tmp_path / "quad.bin", current_flight)
    result = magfit.calibrate_file(path)
    calibration = result.calibration
    assert calibration.motor is not None and calibration.motor.regressor == "current"
    truth = current_flight.truth.motor
    assert truth is not None
    assert np.linalg.norm(calibration.motor.coefficients - truth.coefficients) < 0.1 * np.linalg.norm(
        truth.coefficients
    )
    flight = current_flight
    lagged = np.interp(flight.time_s - calibration.motor.lag_s, flight.time_s, flight.current)
    fitted = heading_error_deg(
        calibration.apply(np.trunc(flight.samples), regressor=lagged), flight.attitude, flight.field_ned
    )
    true_lagged = np.interp(flight.time_s - flight.lag_s, flight.time_s, flight.current)
    best = heading_error_deg(
        flight.truth.apply(flight.samples, regressor=true_lagged), flight.attitude, flight.field_ned
    )
    plain = magfit.calibrate_file(path, motor="none").calibration
    assert plain.motor is None
    before = heading_error_deg(plain.apply(np.trunc(flight.samples)), flight.attitude, flight.field_ned)
    assert fitted <= 1.5 * best < before
    assert any("the motors' field (current)" in note and "fitted" in note for note in result.compasses[0].notes)
    again = magfit.Calibration.from_json(calibration.to_json())
    assert again == calibration


@pytest.mark.slow
def test_a_clean_vehicle_log_gets_no_term(tmp_path: Path) -> None:
    flight = simulate_motor_flight(180, driver="none", seed=12)
    result = magfit.calibrate_file(write_flight(tmp_path / "clean.bin", flight))
    assert result.calibration.motor is None
    facts = result.calibration.details["motor"]
    assert facts["chosen"] is None and "motor_negligible" in facts["codes"]
    assert all(tried["percent"] < 2.0 for tried in facts["tried"])


def test_asking_for_a_regressor_the_log_lacks_is_an_option_error(tmp_path: Path) -> None:
    flight = simulate_motor_flight(30, driver="none", seed=13)
    path = write_flight(tmp_path / "nobat.bin", flight, bat=False)
    with pytest.raises(OptionError) as error:
        magfit.calibrate_file(path, method="sphere", motor="current")
    assert error.value.codes == ("motor_no_regressor",)
    with pytest.raises(OptionError):
        magfit.calibrate_file(path, motor="rpm")


@pytest.mark.slow
def test_cli_says_the_motors_field_and_exports_it(tmp_path: Path, current_flight: MotorFlight) -> None:
    from click.testing import CliRunner

    from magfit.cli import cli

    path = write_flight(tmp_path / "quad.bin", current_flight)
    result = CliRunner().invoke(cli, ["calibrate", str(path), "--export", "ardupilot", "-o", str(tmp_path / "m.param")])
    assert result.exit_code == 0, result.output
    assert "motors           the motors' field (current)" in result.output and ", fitted" in result.output
    written = (tmp_path / "m.param").read_text()
    assert "COMPASS_MOTCT,2" in written and "COMPASS_MOT_Y," in written
    refused = CliRunner().invoke(cli, ["calibrate", str(path), "--export", "fusion"])
    assert refused.exit_code != 0 and "no place for the motors' field" in refused.output
    plain = CliRunner().invoke(cli, ["calibrate", str(path), "--motor", "none", "--export", "fusion"])
    assert plain.exit_code == 0, plain.output
    assert "motors " not in plain.output


def write_px4_flight(path: Path, flight: MotorFlight) -> Path:
    """A PX4 ULog of the flight: raw sensor_mag (gauss, 50 Hz), battery_status and vehicle_thrust_setpoint (10 Hz)."""
    from test_sources_ulog import ULogWriter

    writer = ULogWriter()
    writer.format(
        "sensor_mag",
        [("uint64_t", "timestamp"), ("uint32_t", "device_id"), ("float", "x"), ("float", "y"), ("float", "z")],
    )
    writer.format("battery_status", [("uint64_t", "timestamp"), ("float", "current_a"), ("uint8_t", "connected")])
    writer.format("vehicle_thrust_setpoint", [("uint64_t", "timestamp"), ("float[3]", "xyz")])
    writer.info("ver_sw", "v1.14.0-test")
    writer.parameter("CAL_MAG0_ID", 396809)
    writer.parameter("CAL_MAG0_ROT", -1)
    writer.parameter("CAL_MAG_COMP_TYP", 0)
    for axis in "XYZ":
        writer.parameter(f"CAL_MAG0_{axis}OFF", 0.0)
        writer.parameter(f"CAL_MAG0_{axis}SCALE", 1.0)
        writer.parameter(f"CAL_MAG0_{axis}ODIAG", 0.0)
    for name in ("sensor_mag", "battery_status", "vehicle_thrust_setpoint"):
        writer.subscribe(name, 0)
    for j, t in enumerate(flight.time_s):
        time = int(1_000_000 + t * 1e6)
        writer.data("sensor_mag", 0, time, 396809, *(flight.samples[j] * 1e-3))
        if j % 5 == 0:
            writer.data("battery_status", 0, time + 2000, float(flight.current[j]), 1)
            writer.data("vehicle_thrust_setpoint", 0, time + 1000, 0.0, 0.0, -float(flight.throttle[j]))
    path.write_bytes(writer.bytes())
    return path


@pytest.mark.slow
def test_a_px4_log_fits_the_current_and_exports_comp(tmp_path: Path, current_flight: MotorFlight) -> None:
    pytest.importorskip("pyulog")
    path = write_px4_flight(tmp_path / "quad.ulg", current_flight)
    power = read_power(path)
    assert power.current is not None and power.current.name == "battery_status.current_a"
    assert power.throttle is not None and power.throttle.name == "|vehicle_thrust_setpoint.xyz|"
    np.testing.assert_allclose(power.throttle.values, current_flight.throttle[::5], rtol=1e-6)
    calibration = magfit.calibrate_file(path).calibration
    assert calibration.motor is not None and calibration.motor.regressor == "current"
    truth = current_flight.truth.motor
    assert truth is not None
    expected = truth.coefficients * 1e-3  # mG -> G per A
    assert np.linalg.norm(calibration.motor.coefficients - expected) < 0.1 * np.linalg.norm(expected)


def test_a_tlog_current_and_throttle_are_read(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import struct

    import test_sources_tlog as tlogs

    monkeypatch.setitem(tlogs.CRC_EXTRA, 1, 124)  # SYS_STATUS (pymavlink's definitions)
    monkeypatch.setitem(tlogs.CRC_EXTRA, 74, 20)  # VFR_HUD
    monkeypatch.setitem(tlogs.PACK, 1, "<IIIHHhHHHHHHb")
    monkeypatch.setitem(tlogs.PACK, 74, "<ffffhH")
    path = tmp_path / "vehicle.tlog"
    tlogs.write_vehicle(path, 300)
    writer = tlogs.TlogWriter()
    start = struct.unpack(">Q", path.read_bytes()[:8])[0]
    for j in range(30):
        time = start + j * 1_000_000
        writer.add(time, 1, 0, 0, 0, 0, 15800, 1000 + 100 * j, 0, 0, 0, 0, 0, 0, 80)  # current_battery in cA
        writer.add(time + 500, 74, 0.0, 0.0, 10.0, 0.0, 90, 30 + j)  # throttle in %
    path.write_bytes(path.read_bytes() + writer.bytes())
    power = read_power(path)
    assert power.current is not None and power.throttle is not None
    assert power.current.name == "SYS_STATUS.current_battery"
    np.testing.assert_allclose(np.sort(power.current.values), 10.0 + np.arange(30), rtol=1e-9)
    # BATTERY_STATUS of battery 0 is preferred when the vehicle sends it (battery 1's is not the one the firmware uses)
    monkeypatch.setitem(tlogs.CRC_EXTRA, 147, 154)
    monkeypatch.setitem(tlogs.PACK, 147, "<iih10HhBBBb")
    writer = tlogs.TlogWriter()
    for j in range(30):
        time = start + j * 1_000_000 + 700
        writer.add(time, 147, -1, -1, 2500, *([3950] * 10), 2000 + 50 * j, 0, 0, 0, 80)
        writer.add(time + 1, 147, -1, -1, 2500, *([3950] * 10), 9999, 1, 0, 0, 80)
    path.write_bytes(path.read_bytes() + writer.bytes())
    power = read_power(path)
    assert power.current is not None and power.current.name == "BATTERY_STATUS.current_battery"
    np.testing.assert_allclose(np.sort(power.current.values), 20.0 + 0.5 * np.arange(30), rtol=1e-9)
    np.testing.assert_allclose(np.sort(power.throttle.values), (30 + np.arange(30)) / 100.0, rtol=1e-9)


@pytest.mark.slow
def test_two_compasses_each_get_their_own_term_and_one_motct(tmp_path: Path) -> None:
    """An external compass far from the power wires (0.3 mG/A: 3 % of the field) and an internal one beside
    them (4 mG/A): each is fitted on its own; the ArduPilot file carries one COMPASS_MOTCT and each compass's MOT."""
    from magfit.export import export_several

    external = simulate_motor_flight(240, driver="current", per_unit=0.3, seed=21)
    internal = simulate_motor_flight(240, driver="current", per_unit=4.0, seed=21)  # same flight, same current
    writer = DataFlashWriter()
    writer.define(129, "PARM", "QNf", "TimeUS,Name,Value")
    writer.define(130, "MAG", "QBhhhhhhhhhBI", "TimeUS,I,MagX,MagY,MagZ,OfsX,OfsY,OfsZ,MOX,MOY,MOZ,Health,S")
    writer.define(131, "BAT", "QBff", "TimeUS,Inst,Volt,Curr")
    for suffix in ("", "2"):
        for axis in "XYZ":
            writer.write("PARM", 1000, f"COMPASS_OFS{suffix}_{axis}", 0.0)
            writer.write("PARM", 1000, f"COMPASS_DIA{suffix}_{axis}", 1.0)
            writer.write("PARM", 1000, f"COMPASS_ODI{suffix}_{axis}", 0.0)
        writer.write("PARM", 1000, f"COMPASS_SCALE{suffix}", 1.0)
    writer.write("PARM", 1000, "COMPASS_MOTCT", 0.0)
    for j, t in enumerate(external.time_s):
        time = int(1_000_000 + t * 1e6)
        for instance, flight in enumerate((external, internal)):
            writer.write("MAG", time, instance, *np.trunc(flight.samples[j]).astype(int), 0, 0, 0, 0, 0, 0, 1, time)
        if j % 5 == 0:
            writer.write("BAT", time + 3000, 0, 15.8, float(external.current[j]))
    path = tmp_path / "two.bin"
    path.write_bytes(writer.bytes())
    result = magfit.calibrate_file(path)
    assert len(result.compasses) == 2
    for compass, flight in zip(result.compasses, (external, internal), strict=True):
        term, truth = compass.calibration.motor, flight.truth.motor
        assert term is not None and truth is not None
        assert np.linalg.norm(term.coefficients - truth.coefficients) < 0.15 * np.linalg.norm(truth.coefficients)
    params = {
        name: float(value)
        for name, value in (
            line.split(",")
            for line in export_several([c.calibration for c in result.compasses], "ardupilot").splitlines()
            if line and not line.startswith("#")
        )
    }
    assert params["COMPASS_MOTCT"] == 2
    assert abs(params["COMPASS_MOT2_Y"]) > 5 * abs(params["COMPASS_MOT_Y"]) > 0
