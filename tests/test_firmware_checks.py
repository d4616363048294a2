"""The firmwares' acceptance tests replayed (ArduPilot's CompassCalibrator, PX4's check_calibration_result), each
against a simulated sensor whose truth says which test must fail and by how much; and the firmware's own reports
and messages read back from a tlog and a DataFlash log."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

import magfit
from magfit.cli import cli
from magfit.firmware_checks import explain_log, replay_ardupilot, replay_px4
from magfit.rotations import euler_matrix
from magfit.sources.calibration_messages import read_calibration_messages
from magfit.vehicle import simulate_vehicle
from test_consistency import write_two_compass_log
from test_sources_dataflash import DataFlashWriter
from test_sources_tlog import CRC_EXTRA, PACK, T0_US, TlogWriter

SOFT = np.array([[1.10, 0.05, 0.0], [0.05, 0.95, 0.02], [0.0, 0.02, 1.0]])


def _sensor(*, field: float = 480.0, hard=(120.0, -60.0, 200.0), noise: float = 1.5, mounting=None, seed: int = 1):
    """A tumble: the raw field (mG) of a compass mounted at ``mounting`` (declared identity), and the attitude."""
    sim = simulate_vehicle(2000, "tumble", rate_hz=20.0, field_strength=field, inclination_deg=60.0, seed=seed)
    body = np.einsum("nji,j->ni", sim.attitude, sim.field_world)
    mounting = np.eye(3) if mounting is None else mounting
    rng = np.random.default_rng(seed)
    raw = (body @ mounting) @ SOFT.T + np.asarray(hard) + rng.normal(0, noise, body.shape)
    return raw, sim.attitude


def _test(replay, name):
    (test,) = [t for t in replay.tests if t.name == name]
    return test


def test_a_good_calibration_passes_every_ardupilot_test_and_its_fitness_is_the_noise() -> None:
    raw, attitude = _sensor()
    calibration = magfit.fit(raw, method="ellipsoid")
    replay = replay_ardupilot(raw, calibration, unit="mG", expected_field=480.0, attitude=attitude)
    assert replay.passed and replay.status == "SUCCESS" and replay.reasons == ()
    assert all(t.passed for t in replay.tests)
    fitness = float(_test(replay, "fitness").value.split()[0])
    assert 1.0 < fitness < 4.0  # 1.5 mG per axis of noise: about that along the radius
    assert "ROTATION_NONE (0)" in _test(replay, "orientation").value


@pytest.mark.parametrize(("model", "passes"), [(480.0 * 1.45, True), (480.0 * 1.6, False), (480.0 / 1.6, False)])
def test_the_radius_against_the_model_is_ardupilots_scale_factor_window(model: float, passes: bool) -> None:
    raw, _ = _sensor()
    replay = replay_ardupilot(raw, magfit.fit(raw, method="ellipsoid"), unit="mG", expected_field=model)
    assert _test(replay, "field against the model").passed is passes
    assert replay.status == ("SUCCESS" if passes else "BAD_RADIUS")
    assert [r.code for r in replay.reasons] == ([] if passes else ["firmware_check"])


def test_offsets_beyond_compass_offs_max_and_a_noisy_field_fail_with_their_margin() -> None:
    raw, _ = _sensor(hard=(2100.0, 0.0, 0.0), noise=25.0)
    replay = replay_ardupilot(raw, magfit.fit(raw, method="ellipsoid"), unit="mG", tolerance=16.0, offsets_max=1800.0)
    assert replay.status == "FAILED"
    offsets = _test(replay, "offsets")
    assert offsets.passed is False and abs(float(offsets.value.split()[-2]) - 2100.0) < 21.0
    fitness = _test(replay, "fitness")
    assert fitness.passed is False and float(fitness.value.split()[0]) > 16.0
    assert len(replay.reasons) == 2 and {r.code for r in replay.reasons} == {"firmware_check"}


def test_without_a_physical_unit_nothing_is_replayed_and_nothing_passes() -> None:
    raw, _ = _sensor()
    replay = replay_ardupilot(raw, magfit.fit(raw, method="ellipsoid"))
    assert replay.status == "unknown" and not replay.passed and _test(replay, "fitness").passed is None


def test_a_field_outside_150_to_950_mg_fails_the_radius_test() -> None:
    raw, _ = _sensor(field=1200.0, hard=(0.0, 0.0, 0.0))
    replay = replay_ardupilot(raw, magfit.fit(raw, method="ellipsoid"), unit="mG")
    assert _test(replay, "radius").passed is False and replay.status == "FAILED"


def test_the_orientation_test_finds_a_compass_turned_90_degrees() -> None:
    raw, attitude = _sensor(mounting=euler_matrix(0.0, 0.0, 90.0))
    calibration = magfit.fit(raw, method="ellipsoid")
    internal = replay_ardupilot(raw, calibration, unit="mG", attitude=attitude, external=False, parameter_suffix="2")
    test = _test(internal, "orientation")
    assert test.passed is False and "ROTATION_YAW_90 (2)" in test.value
    assert internal.status == "BAD_ORIENTATION"
    assert internal.reasons[-1].remedy == (("COMPASS_ORIENT2", "2"),)
    fixed = replay_ardupilot(raw, calibration, unit="mG", attitude=attitude, external=True, auto_rot=2)
    assert _test(fixed, "orientation").passed is True  # the firmware turns an external compass itself
    # Declared right: the firmware logs the sensor's field turned by ROTATION_YAW_90 (body = matrix @ sensor).
    logged = raw @ euler_matrix(0.0, 0.0, 90.0).T
    right = replay_ardupilot(
        logged, magfit.fit(logged, method="ellipsoid"), unit="mG", attitude=attitude, orientation=2, external=False
    )
    assert _test(right, "orientation").passed is True and right.status == "SUCCESS"


def test_px4_radius_scale_and_offset_warning() -> None:
    raw, _ = _sensor()  # 480 mG = 0.48 G
    calibration = magfit.fit(raw / 1000.0, method="ellipsoid")
    good = replay_px4(raw / 1000.0, magfit.Calibration(**{**_fields(calibration), "unit": "G"}))
    assert good.passed and good.status == "OK"
    strong = magfit.Calibration(**{**_fields(calibration), "unit": "G", "field_strength": 0.8})
    bad = replay_px4(raw / 1000.0, strong)
    assert _test(bad, "radius").passed is False and [r.code for r in bad.reasons] == ["firmware_check"]
    offset = magfit.Calibration(**{**_fields(calibration), "unit": "G", "offset": np.array([1.5, 0.0, 0.0])})
    warned = replay_px4(raw / 1000.0, offset)
    assert _test(warned, "offsets").passed is False and warned.passed  # a warning, not a failure


def _fields(calibration: magfit.Calibration) -> dict:
    return {
        "method": calibration.method,
        "offset": calibration.offset,
        "matrix": calibration.matrix,
        "field_strength": calibration.field_strength,
    }


def test_a_tlog_s_calibration_report_and_messages_are_read(tmp_path: Path) -> None:
    CRC_EXTRA.update({191: 92, 192: 36, 253: 83})
    PACK.update({191: "<3f5B10B", 192: "<10f4BfBBf", 253: "<B50sHB"})
    writer = TlogWriter()
    writer.add(T0_US, 22, 30.0, 2, 0, b"COMPASS_CAL_FIT", 9)
    writer.add(T0_US + 1000, 22, 1500.0, 2, 1, b"COMPASS_OFFS_MAX", 4)
    for pct in (10, 55, 97):
        writer.add(T0_US + 2000 + pct, 191, 0.0, 0.0, 1.0, 1, 3, 3, 1, pct, *([0] * 10))
    writer.add(T0_US + 5000, 253, 3, b"Mag(1) bad radius 912 expected 480", 0, 0)
    writer.add(T0_US + 6000, 253, 6, b"Throttle armed", 0, 0)
    report = (41.5, -120.0, 60.0, -200.0, 1.1, 0.9, 1.0, 0.02, -0.01, 0.0, 1, 3, 7, 0, 3.5, 0, 0, 0.0)
    writer.add(T0_US + 7000, 192, *report)
    log = tmp_path / "cal.tlog"
    log.write_bytes(writer.bytes())
    said = read_calibration_messages(log)
    assert [m.text for m in said.messages] == ["Mag(1) bad radius 912 expected 480"]
    (r,) = said.reports
    assert r.compass_id == 1 and r.status == "BAD_RADIUS" and r.fitness == pytest.approx(41.5)
    assert r.offsets == pytest.approx((-120.0, 60.0, -200.0)) and r.orientation_confidence == pytest.approx(3.5)
    assert said.progress == {1: 97}
    assert said.settings == {"COMPASS_CAL_FIT": 30.0, "COMPASS_OFFS_MAX": 1500.0}


def test_a_dataflash_log_s_msg_lines_and_settings_are_read(tmp_path: Path) -> None:
    writer = DataFlashWriter()
    writer.define(129, "PARM", "QNf", "TimeUS,Name,Value")
    writer.define(133, "MSG", "QZ", "TimeUS,Message")
    writer.write("PARM", 1000, "COMPASS_CAL_FIT", 16.0)
    writer.write("MSG", 2_000_000, "PreArm: Compasses inconsistent")
    writer.write("MSG", 3_000_000, "EKF3 IMU0 is using GPS")
    log = tmp_path / "msg.bin"
    log.write_bytes(writer.bytes())
    said = read_calibration_messages(log)
    assert [(m.time_s, m.text) for m in said.messages] == [(2.0, "PreArm: Compasses inconsistent")]
    assert said.settings == {"COMPASS_CAL_FIT": 16.0}


def test_explain_log_replays_each_compass_of_a_log(tmp_path: Path) -> None:
    log = tmp_path / "two.bin"
    write_two_compass_log(log, euler_matrix(0.0, 0.0, 90.0))
    explanation = explain_log(magfit.calibrate_file(log))
    assert [r.sensor for r in explanation.replays] == ["MAG/0", "MAG/1"]
    assert all(r.firmware == "ardupilot" for r in explanation.replays)
    first, second = explanation.replays
    assert first.passed
    orientation = _test(second, "orientation")
    assert "ROTATION_YAW_90 (2)" in orientation.value  # external, COMPASS_AUTO_ROT default 2: fixed, passes
    assert orientation.passed is True


@pytest.mark.slow
def test_calibrate_prints_the_firmware_replay(tmp_path: Path) -> None:
    log = tmp_path / "two.bin"
    write_two_compass_log(log, euler_matrix(0.0, 0.0, 0.0))
    run = CliRunner().invoke(cli, ["calibrate", str(log)])
    assert run.exit_code == 0, run.output
    assert "ArduPilot tests  MAG/0: SUCCESS" in run.output and "ArduPilot tests  MAG/1: SUCCESS" in run.output


def test_inspect_repeats_what_the_firmware_said(tmp_path: Path) -> None:
    writer = DataFlashWriter()
    writer.define(129, "PARM", "QNf", "TimeUS,Name,Value")
    writer.define(130, "MAG", "QBfff", "TimeUS,I,MagX,MagY,MagZ")
    writer.define(133, "MSG", "QZ", "TimeUS,Message")
    for axis in "XYZ":
        for name, value in (("OFS", 0.0), ("DIA", 1.0), ("ODI", 0.0)):
            writer.write("PARM", 1000, f"COMPASS_{name}_{axis}", value)
    writer.write("PARM", 1000, "COMPASS_SCALE", 0.0)
    writer.write("PARM", 1000, "COMPASS_DEV_ID", 97539.0)
    writer.write("PARM", 1000, "COMPASS_MOTCT", 0.0)
    for j in range(50):
        writer.write("MAG", 1_000_000 + 100_000 * j, 0, 200.0, 10.0, 400.0)
    writer.write("MSG", 2_000_000, "Mag(0) bad orientation: 6/0 0.9")
    log = tmp_path / "said.bin"
    log.write_bytes(writer.bytes())
    run = CliRunner().invoke(cli, ["inspect", str(log)])
    assert run.exit_code == 0, run.output
    said = [line for line in run.output.splitlines() if line.startswith("firmware said")]
    assert said == ["firmware said    Mag(0) bad orientation: 6/0 0.9"]
