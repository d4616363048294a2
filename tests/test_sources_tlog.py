"""MAVLink telemetry logs (.tlog): tlogs written here from a known truth (ArduPilot's calibration applied as
``correct_field`` does, the field sent as RAW_IMU / SCALED_IMU2 in whole milligauss), read back, the
calibration undone with the PARAM_VALUE parameters and the truth recovered through the command line; link
damage skipped and said; a tlog without a compass and damaged files refused in one line.

The frames are written by a small encoder below (MAVLink's checksum written from its definition, the
payloads packed with struct in wire order), checked against two frames pymavlink 2.4 wrote."""

from __future__ import annotations

import json
import struct
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from scipy.spatial.transform import Rotation

import magfit
from magfit.cli import cli
from magfit.errors import DataFileError
from magfit.export import export
from magfit.sources import log_kind, open_source
from magfit.sources.tlog import _CRC_EXTRA, _IDS, _LAYOUTS, _MAX_LENGTH, TelemetryLog
from test_sources_dataflash import COMPASSES, _assert_recovers, correct_field

#: CRC_EXTRA of the messages written here (MAVLink's generated definitions: pymavlink's crc_extra).
CRC_EXTRA = {0: 50, 22: 220, 24: 24, 27: 144, 30: 39, 105: 93, 116: 76, 129: 46}
#: Payloads in wire order (largest fields first, then the extensions).
PACK = {
    0: "<IBBBBB",  # HEARTBEAT: custom_mode, type, autopilot, base_mode, system_status, mavlink_version
    22: "<fHH16sB",  # PARAM_VALUE: value, count, index, id, type
    24: "<QiiiHHHHBB",  # GPS_RAW_INT (no extensions): time_usec, lat, lon, alt, eph, epv, vel, cog, fix, sats
    27: "<Q9hBh",  # RAW_IMU: time_usec, acc, gyro, mag, id, temperature
    30: "<I6f",  # ATTITUDE: time_boot_ms, roll, pitch, yaw, rates
    105: "<Q13fHB",  # HIGHRES_IMU: time_usec, acc, gyro, mag, pressures, temperature, fields_updated, id
    116: "<I9hh",  # SCALED_IMU2: time_boot_ms, acc, gyro, mag, temperature
}
#: Frames pymavlink 2.4 packed (ardupilotmega dialect): RAW_IMU in MAVLink 2 (seq 7, its 3 trailing zero bytes
#: dropped), PARAM_VALUE COMPASS_OFS_X = -12.5 in MAVLink 1 (seq 8).
PYMAVLINK_RAW_IMU = bytes.fromhex("fd1a00000701011b000015cd5b07000000000a00ecff18fc010002000300d700dbff9201fc7f")
PYMAVLINK_PARAM = bytes.fromhex("fe1908010116000048c184030100434f4d504153535f4f46535f5800000006f9f7")
#: 2026-05-01 12:00:00 UTC, microseconds.
T0_US = 1_777_636_800_000_000
#: The vehicle's attitude (ATTITUDE: roll, pitch, yaw in rad; body -> NED = Rz(yaw) Ry(pitch) Rx(roll)), and the
#: accelerometer at rest in it (milli-g, as ArduPilot sends it): gravity turned into the body frame.
ROLL_PITCH_YAW = (0.1, -0.2, 1.5)
BODY_TO_NED = Rotation.from_euler("ZYX", ROLL_PITCH_YAW[::-1]).as_matrix()
ACCEL_MG = [int(v) for v in np.round(BODY_TO_NED.T @ [0.0, 0.0, -1000.0])]


def x25(data: bytes) -> int:
    """MAVLink's checksum (crc_accumulate in checksum.h), one byte at a time."""
    crc = 0xFFFF
    for byte in data:
        tmp = (byte ^ (crc & 0xFF)) & 0xFF
        tmp = (tmp ^ (tmp << 4)) & 0xFF
        crc = ((crc >> 8) ^ (tmp << 8) ^ (tmp << 3) ^ (tmp >> 4)) & 0xFFFF
    return crc


def frame(msgid: int, payload: bytes, *, seq: int, sysid: int = 1, compid: int = 1, v1: bool = False) -> bytes:
    """One MAVLink frame; MAVLink 2 drops the payload's trailing zeros (keeping one byte)."""
    if v1:
        header = struct.pack("<BBBBBB", 0xFE, len(payload), seq, sysid, compid, msgid)
    else:
        payload = payload.rstrip(b"\x00") or payload[:1]
        header = struct.pack("<BBBBBBBHB", 0xFD, len(payload), 0, 0, seq, sysid, compid, msgid & 0xFFFF, msgid >> 16)
    body = header + payload
    return body + struct.pack("<H", x25(body[1:] + bytes([CRC_EXTRA[msgid]])))


class TlogWriter:
    """Records of a tlog: the receive time (µs since 1970, big-endian), then the frame."""

    def __init__(self) -> None:
        self.records: list[tuple[int, bytes]] = []
        self.seq: dict[int, int] = {}

    def add(self, time_us: int, msgid: int, *values: object, v1: bool = False, sysid: int = 1) -> None:
        seq = self.seq.get(sysid, 0)
        self.seq[sysid] = (seq + 1) % 256
        payload = struct.pack(PACK[msgid], *values)
        self.records.append((int(time_us), frame(msgid, payload, seq=seq, sysid=sysid, v1=v1)))

    def bytes(self) -> bytes:
        return b"".join(struct.pack(">Q", t) + f for t, f in self.records)


def write_vehicle(
    path: Path,
    n: int = 1200,
    *,
    parameters: bool = True,
    motct: int = 0,
    armed_from: int | None = None,
    compasses: bool = True,
    reboot_at: int | None = None,
    soft_iron_parameters: bool = True,
    second_imu: bool = True,
    trim_deg: tuple[float, float] = (0.0, 0.0),
    trim_change: tuple[int, float] | None = None,
    offsets_change: tuple[int, np.ndarray] | None = None,
) -> list[magfit.Simulation]:
    """An ArduPilot vehicle turned in every direction, streamed at 10 Hz with a jittery link (20-300 ms): RAW_IMU
    (compass k = 0) and SCALED_IMU2 (k = 1), ATTITUDE, a HEARTBEAT and a 3-D GPS fix each second, and the
    COMPASS_* parameters first; ``armed_from``: the HEARTBEATs say armed from that sample on; ``reboot_at``:
    the vehicle's clock restarts there (as after a reboot); ``soft_iron_parameters`` False: a firmware without
    COMPASS_DIA/ODI/SCALE, which applies the offsets alone; ``second_imu`` False: SCALED_IMU2 carries zeros for
    its accelerometer and gyroscope, as ArduPilot sends for an IMU the board lacks; ``trim_deg``: AHRS_TRIM_X/Y,
    subtracted from ATTITUDE's roll and pitch as the EKF does; ``trim_change`` (sample, degrees): AHRS_TRIM_Y
    set to that at that sample (a "Calibrate Level" while connected); ``offsets_change`` (sample, offsets):
    COMPASS_OFS_X/Y/Z set to those at that sample (sent as PARAM_VALUE), compass 0 corrected with them from then
    on. Returns the raw truths."""
    simulations = [
        magfit.simulate(
            n, soft_iron=c["soft_iron"], hard_iron=c["hard_iron"], field_strength=480.0, noise=1.5, seed=11 + k
        )
        for k, c in enumerate(COMPASSES)
    ]
    applied = [
        c if soft_iron_parameters else {**c, "dia": np.zeros(3), "odi": np.zeros(3), "scale": 0.0} for c in COMPASSES
    ]
    logged = [
        np.trunc(correct_field(s.samples, c["ofs"], c["dia"], c["odi"], c["scale"]))  # int16(float): truncated
        for s, c in zip(simulations, applied, strict=True)
    ]
    if offsets_change is not None:
        start, new = offsets_change
        c = applied[0]
        logged[0][start:] = np.trunc(correct_field(simulations[0].samples[start:], new, c["dia"], c["odi"], c["scale"]))
    writer = TlogWriter()
    rng = np.random.default_rng(5)
    if parameters:
        names = []
        for k, c in enumerate(COMPASSES):
            s = "" if k == 0 else str(k + 1)
            for i, axis in enumerate("XYZ"):
                names += [(f"COMPASS_OFS{s}_{axis}", c["ofs"][i])]
                if soft_iron_parameters:
                    names += [(f"COMPASS_DIA{s}_{axis}", c["dia"][i]), (f"COMPASS_ODI{s}_{axis}", c["odi"][i])]
            names += [(f"COMPASS_SCALE{s}", c["scale"])] if soft_iron_parameters else []
            names += [(f"COMPASS_DEV_ID{s}", c["dev_id"])]
            names += [(f"COMPASS_EXTERN{s}", 1.0), (f"COMPASS_ORIENT{s}", 0.0)]
        names += [("COMPASS_MOTCT", float(motct)), ("AHRS_ORIENTATION", 0.0)]
        names += [(f"AHRS_TRIM_{axis}", float(np.radians(d))) for axis, d in zip("XY", trim_deg, strict=True) if d]
        for index, (name, value) in enumerate(names):
            writer.add(T0_US + 5_000 * index, 22, float(value), len(names), index, name.encode(), 9, v1=index % 2 == 0)
    boot_start_ms, clock_shift_ms = 20_000, 0
    for i in range(n):
        if reboot_at is not None and i == reboot_at:
            clock_shift_ms = -(boot_start_ms + i * 100) + 3_000  # the boot clock restarts at 3 s, 0 s of gap
        boot_ms = boot_start_ms + i * 100 + clock_shift_ms
        wall_us = T0_US + 1_000_000 + i * 100_000
        latency = int(rng.uniform(20_000, 300_000))
        if compasses:
            mag0 = [int(v) for v in logged[0][i]]
            mag1 = [int(v) for v in logged[1][i]]
            writer.add(wall_us + latency, 27, boot_ms * 1000, *ACCEL_MG, 10, -20, 30, *mag0, 0, 0, v1=i % 3 == 0)
            imu2 = (*ACCEL_MG, 11, -21, 31) if second_imu else (0,) * 6
            writer.add(wall_us + latency + 200, 116, boot_ms, *imu2, *mag1, 0)
        if offsets_change is not None and i == offsets_change[0]:
            for axis, value in zip("XYZ", offsets_change[1], strict=True):
                writer.add(wall_us + latency + 250, 22, float(value), 1, 65535, f"COMPASS_OFS_{axis}".encode(), 9)
        if trim_change is not None and i == trim_change[0]:
            trim_deg = (trim_deg[0], trim_change[1])
            writer.add(wall_us + latency + 250, 22, float(np.radians(trim_change[1])), 1, 0, b"AHRS_TRIM_Y", 9)
        roll, pitch, yaw = ROLL_PITCH_YAW
        trimmed = (roll - np.radians(trim_deg[0]), pitch - np.radians(trim_deg[1]), yaw)
        writer.add(wall_us + latency + 300, 30, boot_ms, *trimmed, 0.0, 0.0, 0.0)
        if i % 10 == 0:
            armed = armed_from is not None and i >= armed_from
            writer.add(wall_us + latency + 400, 0, 0, 2, 3, 128 if armed else 0, 4, 3)
            writer.add(wall_us + latency + 500, 24, boot_ms * 1000, 473_977_000, 85_403_000, 488_500, 1, 1, 0, 0, 3, 12)
    path.write_bytes(writer.bytes())
    return simulations


# ------------------------------------------------------------------------------------------------ the format


def test_the_encoder_and_the_reader_agree_with_frames_pymavlink_wrote(tmp_path: Path) -> None:
    raw_imu = struct.pack(PACK[27], 123456789, 10, -20, -1000, 1, 2, 3, 215, -37, 402, 0, 0)
    assert frame(27, raw_imu, seq=7) == PYMAVLINK_RAW_IMU  # the checksum, the header, the dropped zeros
    param = struct.pack(PACK[22], -12.5, 900, 1, b"COMPASS_OFS_X", 6)
    assert frame(22, param, seq=8, v1=True) == PYMAVLINK_PARAM
    path = tmp_path / "two.tlog"
    path.write_bytes(struct.pack(">Q", T0_US) + PYMAVLINK_RAW_IMU + struct.pack(">Q", T0_US + 1) + PYMAVLINK_PARAM)
    log = TelemetryLog(path, path.read_bytes())
    assert log.skipped_bytes == 0 and len(log.msgid) == 2
    records = log.messages("RAW_IMU", log.frames("RAW_IMU", (1, 1)))  # 26 bytes on the wire, 29 read
    assert records[["xmag", "ymag", "zmag"]].tolist() == [(215, -37, 402)]
    assert records["time_usec"].tolist() == [123456789] and records["zacc"].tolist() == [-1000]
    param_records = log.messages("PARAM_VALUE", log.frames("PARAM_VALUE", (1, 1)))
    assert param_records["param_id"].tolist() == [b"COMPASS_OFS_X"] and param_records["param_value"][0] == -12.5
    assert log_kind(path) == "tlog"


def test_the_layouts_have_the_lengths_and_checksums_of_the_definitions() -> None:
    for msgid, (_name, dtype) in _LAYOUTS.items():
        where = int(np.searchsorted(_IDS, msgid))
        assert _IDS[where] == msgid and _MAX_LENGTH[where] == dtype.itemsize
        if msgid in CRC_EXTRA:
            assert _CRC_EXTRA[where] == CRC_EXTRA[msgid]


def test_a_dataflash_log_or_text_is_not_a_tlog(tmp_path: Path) -> None:
    text = tmp_path / "mag.csv"
    text.write_text("mx,my,mz\n1,2,3\n")
    noise = tmp_path / "noise.bin"
    noise.write_bytes(np.random.default_rng(0).integers(0, 256, 5000, dtype=np.uint8).tobytes())
    assert log_kind(text) is None and log_kind(noise) is None


# --------------------------------------------------------------------------------------------- the compasses


def test_calibrate_recovers_each_compass_through_the_command_line(tmp_path: Path) -> None:
    path = tmp_path / "flight.tlog"
    simulations = write_vehicle(path)
    source = open_source(path)
    assert source.kind == "tlog" and [m.id for m in source.magnetometers] == ["RAW_IMU", "SCALED_IMU2"]
    first, second = source.magnetometers
    assert (first.slot, second.slot) == (0, 1) and (first.device_id, second.device_id) == (97539, 658953)
    assert first.unit == "mG" and first.n_samples == 1200 and not first.raw and first.problem is None
    assert first.rate_hz == pytest.approx(10.0, rel=1e-6)  # the vehicle's clock: the link's jitter is gone
    assert any("undone with COMPASS_OFS, DIA, ODI and SCALE" in note for note in first.notes)
    read = source.read("RAW_IMU")  # the raw field, to the whole-mG truncation ArduPilot's int16 makes
    assert np.max(np.abs(read.samples - simulations[0].samples)) < 1.5
    output = tmp_path / "cal.json"
    result = CliRunner().invoke(
        cli, ["calibrate", str(path), "--sensor", "RAW_IMU", "-m", "ellipsoid", "-o", str(output)]
    )
    assert result.exit_code == 0, result.output
    _assert_recovers(magfit.Calibration.from_json(output.read_text()), simulations[0].truth)
    assert "2026-05-01 12:00:01" in result.output  # the time line is the station's UTC
    second_fit = magfit.calibrate_file(path, "ellipsoid", sensor="SCALED_IMU2")
    _assert_recovers(second_fit.calibration, simulations[1].truth)


def test_corrupt_bytes_are_skipped_and_said(tmp_path: Path) -> None:
    path = tmp_path / "clean.tlog"
    simulations = write_vehicle(path)
    data = bytearray(path.read_bytes())
    rng = np.random.default_rng(2)
    hit = rng.choice(np.arange(2000, len(data) - 100), size=40, replace=False)
    for where in hit:
        data[where] ^= 0x5A  # a garbled byte: its frame's checksum fails
    data[5000:5000] = b"\xfe\x1d\x00garbage from a radio\xfd\xfd\x00"  # inserted bytes, false magic included
    damaged = tmp_path / "damaged.tlog"
    damaged.write_bytes(bytes(data))
    source = open_source(damaged)
    said = " ".join(source.notes)
    assert "bytes skipped as damaged" in said
    compass = source.magnetometer("RAW_IMU")
    assert 1200 - 40 <= compass.n_samples < 1200  # the frames hit are lost, the others kept
    calibration = magfit.calibrate_file(damaged, "ellipsoid", sensor="RAW_IMU").calibration
    _assert_recovers(calibration, simulations[0].truth)
    truncated = tmp_path / "cut.tlog"
    truncated.write_bytes(path.read_bytes()[:-7])
    assert any("cut short" in note for note in open_source(truncated).notes)


def test_without_parameters_the_samples_stay_calibrated_and_the_fit_is_a_residual(tmp_path: Path) -> None:
    path = tmp_path / "noparams.tlog"
    simulations = write_vehicle(path, 300, parameters=False)
    source = open_source(path)
    compass = source.magnetometer("RAW_IMU")
    assert compass.problem is None and compass.slot == 0 and compass.device_id is None
    assert any("residual correction" in note and "COMPASS_OFS" in note for note in compass.notes)
    expected = np.trunc(
        correct_field(simulations[0].samples, **{k: COMPASSES[0][k] for k in ("ofs", "dia", "odi", "scale")})
    )
    np.testing.assert_array_equal(source.read("RAW_IMU").samples, expected)
    # The residual must never be written as the firmware's calibration: it would replace the one in use.
    assert compass.calibration_in_use is not None
    output = tmp_path / "mag.param"
    result = CliRunner().invoke(
        cli, ["calibrate", str(path), "--sensor", "RAW_IMU", "--export", "ardupilot", "-o", str(output)]
    )
    assert result.exit_code != 0 and not output.exists(), result.output
    assert "residual correction on top of that one" in result.output and "Traceback" not in result.output
    fitted = magfit.calibrate_file(path, "ellipsoid", sensor="RAW_IMU").calibration
    with pytest.raises(magfit.ExportError, match="written as px4 it would replace it"):
        export(fitted, "px4")
    kept = magfit.Calibration.from_json(export(fitted, "json"))  # json keeps it, and what it is
    with pytest.raises(magfit.ExportError, match="already carry the firmware's calibration"):
        export(kept, "c")


def test_a_tlog_without_a_compass_says_what_to_stream(tmp_path: Path) -> None:
    path = tmp_path / "nocompass.tlog"
    write_vehicle(path, 50, compasses=False)
    result = CliRunner().invoke(cli, ["calibrate", str(path)])
    assert result.exit_code == 2
    lines = result.output.strip().splitlines()
    assert len(lines) == 1 and "SR0_RAW_SENS" in lines[0] and "Traceback" not in result.output


def test_motor_compensation_keeps_the_disarmed_samples_or_refuses(tmp_path: Path) -> None:
    path = tmp_path / "motct1.tlog"
    simulations = write_vehicle(path, motct=1, armed_from=1000)
    compass = open_source(path).magnetometer("RAW_IMU")
    # Armed from the HEARTBEAT of sample 1000: samples 991..999 lie between a disarmed and an armed one, dropped.
    assert compass.problem is None and compass.n_samples == 991
    assert any("while armed are dropped" in note for note in compass.notes)
    read = open_source(path).read("RAW_IMU")
    assert np.max(np.abs(read.samples - simulations[0].samples[:991])) < 1.5
    current = tmp_path / "motct2.tlog"
    write_vehicle(current, 100, motct=2)
    problem = open_source(current).magnetometer("RAW_IMU").problem
    assert problem is not None and "COMPASS_MOTCT 2" in problem


def test_motion_position_and_time_from_the_tlog(tmp_path: Path) -> None:
    path = tmp_path / "motion.tlog"
    write_vehicle(path, 400, reboot_at=200)
    source = open_source(path)
    assert source.position is not None
    assert (source.position.lat_deg, source.position.lon_deg) == pytest.approx((47.3977, 8.5403))
    assert source.position.alt_km == pytest.approx(0.4885)
    assert source.position.time_s == pytest.approx(T0_US / 1e6 + 1.0, abs=0.5)  # the tlog's own stamp: its date
    assert any("restarted 1 time" in note for note in source.notes)
    motion = source.read_motion("RAW_IMU")
    assert motion.magnetometer_frame == "body" and motion.n_dropped == 0
    steps = np.diff(motion.time_s)
    assert np.sum(np.abs(steps - 0.1) > 1e-6) <= 1  # each stretch keeps the vehicle's 10 Hz; one jump at the reboot
    assert abs(motion.time_s[0] - (T0_US / 1e6 + 1.0)) < 0.35  # placed by the station's stamps (20-300 ms late)
    np.testing.assert_allclose(motion.accel, np.tile(ACCEL_MG, (400, 1)) * 9.80665 / 1000)  # milli-g
    np.testing.assert_allclose(motion.gyro, np.tile([0.010, -0.020, 0.030], (400, 1)))  # mrad/s
    np.testing.assert_allclose(motion.attitude[0], BODY_TO_NED, atol=1e-6)
    assert any(note.startswith("check: attitude · accel") for note in motion.notes)  # gravity where it belongs
    assert motion.mounting is not None and np.allclose(motion.mounting, np.eye(3))
    assert motion.date is not None and str(motion.date) == "2026-05-01"


def test_an_ardupilot_trim_is_taken_off_attitude(tmp_path: Path) -> None:
    # ATTITUDE carries AP_AHRS's angles, the vehicle body's (the EKF's minus AHRS_TRIM); the IMU and the compass
    # are sent in the autopilot's body: with the trim left on, the reference would turn against them by it.
    path = tmp_path / "trim.tlog"
    write_vehicle(path, 100, trim_deg=(0.7, -2.0))
    motion = open_source(path).read_motion("RAW_IMU")
    np.testing.assert_allclose(motion.attitude[0], BODY_TO_NED, atol=1e-6)
    # A "Calibrate Level" halfway: each attitude with the trim then in effect.
    path = tmp_path / "relevelled.tlog"
    write_vehicle(path, 100, trim_deg=(0.7, -2.0), trim_change=(50, 1.5))
    motion = open_source(path).read_motion("RAW_IMU")
    away = np.abs(np.arange(len(motion.time_s)) - 50) > 3  # the change's own instant: the link's latency
    np.testing.assert_allclose(motion.attitude[away], np.broadcast_to(BODY_TO_NED, (int(away.sum()), 3, 3)), atol=1e-6)
    assert any("changed during the log" in note for note in motion.notes)


def test_offsets_set_while_connected_undo_each_sample_with_those_in_effect(tmp_path: Path) -> None:
    # COMPASS_OFS_X/Y/Z set half-way (a recalibration while the station recorded): before, refused ("fit a log
    # recorded after the change"); now each sample is undone with the offsets in effect when it was measured.
    path = tmp_path / "recalibrated.tlog"
    new = np.array([60.0, -15.0, 140.0])
    simulations = write_vehicle(path, offsets_change=(600, new))
    source = open_source(path)
    assert source.magnetometer("RAW_IMU").problem is None
    assert any(
        "the calibration changed during the log (COMPASS_OFS_X at" in n for n in source.magnetometer("RAW_IMU").notes
    )
    read = source.read("RAW_IMU")
    # The change's own instant is known to the link's latency (20-300 ms): a few samples either side may be
    # undone with the other offsets; the rest to the int16 truncation.
    away = np.abs(np.arange(len(read.samples)) - 600) > 4
    assert np.max(np.abs(read.samples[away] - simulations[0].samples[away])) < 1.5
    _assert_recovers(magfit.calibrate_file(path, "ellipsoid", sensor="RAW_IMU").calibration, simulations[0].truth)


def test_damaged_files_are_one_line_errors(tmp_path: Path) -> None:
    path = tmp_path / "clean.tlog"
    write_vehicle(path, 30)
    data = path.read_bytes()
    garbled = bytearray(data)
    pos = 0
    while pos < len(data):  # each record: its 8-byte stamp, then a frame (v1: 8 bytes beside the payload)
        end = pos + 8 + (data[pos + 9] + (8 if data[pos + 8] == 0xFE else 12 + 13 * (data[pos + 10] & 1)))
        garbled[end - 1] ^= 0xFF  # every frame's checksum wrong, the records' layout kept
        pos = end
    cases = {"short.tlog": data[:40], "garbled.tlog": bytes(garbled), "cut.tlog": data[:20]}
    runner = CliRunner()
    for name, content in cases.items():
        damaged = tmp_path / name
        damaged.write_bytes(content)
        result = runner.invoke(cli, ["calibrate", str(damaged)])
        assert result.exit_code == 2, (name, result.output)
        assert len(result.output.strip().splitlines()) == 1 and "Traceback" not in result.output
    with pytest.raises(DataFileError, match="no MAVLink frame whose checksum is right"):
        open_source(tmp_path / "garbled.tlog")


def test_inspect_lists_the_compasses_and_the_other_messages(tmp_path: Path) -> None:
    path = tmp_path / "flight.tlog"
    write_vehicle(path, 100)
    result = CliRunner().invoke(cli, ["inspect", str(path), "--format", "json"])
    if result.exit_code != 0 and "--format" in result.output:  # an inspect without JSON: its text
        result = CliRunner().invoke(cli, ["inspect", str(path)])
        assert result.exit_code == 0 and "RAW_IMU" in result.output and "ATTITUDE" in result.output
        return
    assert result.exit_code == 0, result.output
    text = json.dumps(json.loads(result.output))
    assert "RAW_IMU" in text and "ATTITUDE" in text


def test_a_firmware_without_soft_iron_parameters_applied_the_offsets_alone(tmp_path: Path) -> None:
    # A complete parameter list (every index of param_count came) without COMPASS_DIA/ODI: ArduPilot before the
    # soft-iron parameters. Only the offsets are undone; a partial list without them is refused instead.
    path = tmp_path / "old.tlog"
    simulations = write_vehicle(path, 300, soft_iron_parameters=False, second_imu=False)
    source = open_source(path)
    compass = source.magnetometer("RAW_IMU")
    assert compass.problem is None and any("applied no soft-iron matrix" in note for note in compass.notes)
    np.testing.assert_allclose(source.read("RAW_IMU").samples, simulations[0].samples, atol=1.0)
    motion = source.read_motion("SCALED_IMU2")  # its IMU sends zeros: no stream rather than a still vehicle
    assert motion.gyro is None and motion.accel is None and motion.attitude is not None
    assert any("no such IMU on the board" in note for note in motion.notes)


def test_frames_whose_checksum_never_matches_are_another_definition_not_damage(tmp_path: Path) -> None:
    path = tmp_path / "flight.tlog"
    write_vehicle(path, 100)
    data = path.read_bytes()
    # DISTANCE_SENSOR (132) from a companion (component 194), checksummed with another CRC_EXTRA: a sender whose
    # definition of the message differs. Every one fails; nothing else is touched.
    payload = struct.pack("<IHHHBBBB", 1000, 20, 700, 150, 0, 1, 25, 255)
    body = struct.pack("<BBBBBBBHB", 0xFD, len(payload), 0, 0, 0, 1, 194, 132, 0) + payload
    odd = body + struct.pack("<H", x25(body[1:] + bytes([0])))
    records = [struct.pack(">Q", T0_US + 2_000_000 + k) + odd for k in range(5)]
    path.write_bytes(data + b"".join(records))
    source = open_source(path)
    said = " ".join(source.notes)
    assert "5 of message 132 from system 1 component 194" in said and "bytes skipped" not in said
    assert source.magnetometer("RAW_IMU").n_samples == 100


def test_px4_highres_imu_is_read_as_calibrated_gauss_and_systems_are_told_apart(tmp_path: Path) -> None:
    # Two vehicles on one link: system 1 a PX4 (HEARTBEAT autopilot 12) streaming HIGHRES_IMU in gauss, system 2
    # an ArduPilot streaming RAW_IMU (and HIGHRES_IMU, which ArduPilot fills in microgauss: not read).
    rng = np.random.default_rng(9)
    field = rng.normal(size=(200, 3))
    field = 0.48 * field / np.linalg.norm(field, axis=1, keepdims=True) + [0.05, -0.02, 0.1]
    writer = TlogWriter()
    for i in range(200):
        t = T0_US + i * 50_000
        if i % 20 == 0:
            writer.add(t, 0, 0, 2, 12, 0, 3, 3, sysid=1)
            writer.add(t, 0, 0, 2, 3, 0, 3, 3, sysid=2)
        mag = [float(v) for v in field[i]]
        writer.add(
            t + 10, 105, 1_000_000 + i * 50_000, 0.0, 0.0, -9.8, 0.0, 0.0, 0.0, *mag, 0, 0, 0, 0, 0x1FF, 0, sysid=1
        )
        milli = [int(v) for v in np.trunc(field[i] * 1000)]
        writer.add(t + 20, 27, 2_000_000 + i * 50_000, 0, 0, -1000, 0, 0, 0, *milli, 0, 0, sysid=2)
        writer.add(
            t + 30,
            105,
            2_000_000 + i * 50_000,
            0.0,
            0.0,
            -9.8,
            0.0,
            0.0,
            0.0,
            *(v * 1e6 for v in mag),
            0,
            0,
            0,
            0,
            0x1FF,
            0,
            sysid=2,
        )
    path = tmp_path / "two.tlog"
    path.write_bytes(writer.bytes())
    source = open_source(path)
    assert [m.id for m in source.magnetometers] == ["HIGHRES_IMU@1.1", "RAW_IMU@2.1"]
    px4 = source.magnetometer("HIGHRES_IMU@1.1")
    assert px4.unit == "G" and px4.slot is None and any("residual correction" in note for note in px4.notes)
    np.testing.assert_allclose(source.read("HIGHRES_IMU@1.1").samples, field, atol=1e-6)
    ardupilot = source.read("RAW_IMU@2.1")
    assert ardupilot.magnetometer.unit == "mG" and np.max(np.abs(ardupilot.samples - field * 1000)) < 1.0


def test_parameter_names_end_where_their_letters_end(tmp_path: Path) -> None:
    # Old ArduPilot firmwares sent stack bytes after the name's NUL, or in place of it after a 15-letter name
    # (dronekit's test.tlog): the names must still be found.
    from magfit.sources.tlog import _parameters

    writer = TlogWriter()
    for index, (raw, value) in enumerate([(b"COMPASS_OFS_X\x00\x00\x90", 12.5), (b"COMPASS_AUTODEC\xdf", 1.0)]):
        writer.add(T0_US + index, 22, value, 2, index, raw, 9)
    path = tmp_path / "names.tlog"
    path.write_bytes(writer.bytes())
    table, _ = _parameters(TelemetryLog(path, path.read_bytes()), (1, 1))
    assert table["COMPASS_OFS_X"][0][1] == 12.5 and table["COMPASS_AUTODEC"][0][1] == 1.0
