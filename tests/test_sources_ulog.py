"""PX4 ULog files: logs written here from a known truth (raw sensor_mag, and vehicle_magnetometer corrected
as PX4 corrects it), read back with pyulog, the calibration undone and the truth recovered; PX4's sample
log (1 Hz sensor_mag) told in words; damaged logs refused in one line."""

from __future__ import annotations

import shutil
import struct
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

import magfit
from magfit.cli import cli
from magfit.errors import DataFileError
from magfit.sources import open_source
from magfit.sources.ulog import undo_px4_calibration

pytest.importorskip("pyulog")

#: PX4's sample log from pyulog's repository (BSD 3-clause, tests/data/px4_pyulog/LICENSE).
SAMPLE = Path(__file__).parent / "data" / "px4_pyulog" / "sample_log_small.ulg"


#: ULog field types and their struct letters.
ULOG_TYPES = {"uint64_t": "Q", "uint32_t": "I", "int32_t": "i", "float": "f", "uint8_t": "B", "int16_t": "h"}


class ULogWriter:
    """A minimal ULog writer (file format version 1): header, formats, parameters, subscriptions, data."""

    def __init__(self) -> None:
        self.out = [b"ULog\x01\x12\x35\x01" + struct.pack("<Q", 0)]
        self._message(b"B", bytes(40))  # flag bits: nothing incompatible
        self.layouts: dict[int, str] = {}
        self.ids: dict[tuple[str, int], int] = {}
        self.layouts_by_name: dict[str, str] = {}

    def _message(self, kind: bytes, payload: bytes) -> None:
        self.out.append(struct.pack("<HB", len(payload), kind[0]) + payload)

    def format(self, name: str, fields: list[tuple[str, str]]) -> None:
        text = name + ":" + "".join(f"{t} {f};" for t, f in fields)
        self._message(b"F", text.encode())
        layout = ""
        for t, _ in fields:
            base, _, count = t.partition("[")
            layout += ULOG_TYPES[base] * (int(count[:-1]) if count else 1)
        self.layouts_by_name[name] = layout

    def info(self, key: str, value: str) -> None:
        encoded = value.encode()
        full = f"char[{len(encoded)}] {key}".encode()
        self._message(b"I", bytes([len(full)]) + full + encoded)

    def parameter(self, name: str, value: float | int) -> None:
        kind, packed = (
            ("int32_t", struct.pack("<i", value)) if isinstance(value, int) else ("float", struct.pack("<f", value))
        )
        full = f"{kind} {name}".encode()
        self._message(b"P", bytes([len(full)]) + full + packed)

    def subscribe(self, name: str, multi_id: int = 0) -> None:
        msg_id = len(self.ids)
        self.ids[(name, multi_id)] = msg_id
        self.layouts[msg_id] = self.layouts_by_name[name]
        self._message(b"A", struct.pack("<BH", multi_id, msg_id) + name.encode())

    def data(self, name: str, multi_id: int, *values: float | int) -> None:
        msg_id = self.ids[(name, multi_id)]
        self._message(b"D", struct.pack("<H", msg_id) + struct.pack("<" + self.layouts[msg_id], *values))

    def bytes(self) -> bytes:
        return b"".join(self.out)


def px4_correct(raw: np.ndarray, off: np.ndarray, scale: np.ndarray, odiag: np.ndarray) -> np.ndarray:
    """PX4's Correct() with no rotation and no power compensation: S · (raw - OFF)."""
    matrix = np.array([[scale[0], odiag[0], odiag[1]], [odiag[0], scale[1], odiag[2]], [odiag[1], odiag[2], scale[2]]])
    return (raw - off) @ matrix.T


CAL = {
    "off": np.array([0.12, -0.3, 0.05]),
    "scale": np.array([1.04, 0.97, 1.01]),
    "odiag": np.array([0.02, -0.01, 0.03]),
}
DEVICE = 592905


def write_log(
    path: Path,
    n: int = 1500,
    *,
    board_rot: int = 0,
    second: bool = True,
    cal_rot: int = -1,
    board_tilt: float = 0.0,
    rotation: np.ndarray | None = None,
    recalibrated: tuple[int, dict[str, np.ndarray]] | None = None,
) -> magfit.Simulation:
    """sensor_mag at 50 Hz (two instances) and vehicle_magnetometer (corrected) beside it, in gauss.

    ``rotation``: the R of PX4's Correct that CAL_MAG0_ROT ``cal_rot`` or SENS_BOARD_ROT ``board_rot`` stands
    for, written here from PX4's rotate_3f cases (not from magfit's table), applied to vehicle_magnetometer.
    ``recalibrated``: (j, calibration): from sample j on, CAL_MAG0_* change to ``calibration`` (parameter
    messages in the data section, as PX4's logger writes a change) and vehicle_magnetometer is corrected with it.
    """
    simulation = magfit.simulate(
        n,
        soft_iron=[[1.1, 0.05, 0.0], [0.05, 0.92, 0.02], [0.0, 0.02, 1.0]],
        hard_iron=[0.15, -0.22, 0.4],
        field_strength=0.5,
        noise=0.002,
        seed=11,
    )
    writer = ULogWriter()
    writer.format(
        "sensor_mag",
        [("uint64_t", "timestamp"), ("uint32_t", "device_id"), ("float", "x"), ("float", "y"), ("float", "z")],
    )
    writer.format(
        "vehicle_magnetometer", [("uint64_t", "timestamp"), ("uint32_t", "device_id"), ("float[3]", "magnetometer_ga")]
    )
    writer.format("vehicle_attitude", [("uint64_t", "timestamp"), ("float[4]", "q")])
    writer.info("ver_sw", "v1.14.0-test")
    writer.parameter("CAL_MAG0_ID", DEVICE)
    writer.parameter("CAL_MAG0_ROT", cal_rot)
    writer.parameter("SENS_BOARD_ROT", board_rot)
    writer.parameter("SENS_BOARD_X_OFF", board_tilt)
    writer.parameter("CAL_MAG_COMP_TYP", 0)
    for axis, i in zip("XYZ", range(3), strict=True):
        writer.parameter(f"CAL_MAG0_{axis}OFF", float(CAL["off"][i]))
        writer.parameter(f"CAL_MAG0_{axis}SCALE", float(CAL["scale"][i]))
        writer.parameter(f"CAL_MAG0_{axis}ODIAG", float(CAL["odiag"][i]))
    writer.subscribe("sensor_mag", 0)
    if second:
        writer.subscribe("sensor_mag", 1)
    writer.subscribe("vehicle_magnetometer", 0)
    writer.subscribe("vehicle_attitude", 0)
    corrected = px4_correct(simulation.samples, CAL["off"], CAL["scale"], CAL["odiag"])
    if recalibrated is not None:
        start, new = recalibrated
        corrected[start:] = px4_correct(simulation.samples[start:], new["off"], new["scale"], new["odiag"])
    if rotation is not None:
        corrected = corrected @ rotation.T
    for j in range(n):
        time = 1_000_000 + j * 20_000
        if recalibrated is not None and j == recalibrated[0]:
            for axis, i in zip("XYZ", range(3), strict=True):  # pyulog stamps them with the last data's time
                writer.parameter(f"CAL_MAG0_{axis}OFF", float(recalibrated[1]["off"][i]))
                writer.parameter(f"CAL_MAG0_{axis}SCALE", float(recalibrated[1]["scale"][i]))
                writer.parameter(f"CAL_MAG0_{axis}ODIAG", float(recalibrated[1]["odiag"][i]))
        writer.data("sensor_mag", 0, time, DEVICE, *simulation.samples[j])
        if second:
            writer.data("sensor_mag", 1, time, 12345, 0.2, 0.1, 0.4)
        writer.data("vehicle_magnetometer", 0, time + 100, DEVICE, *corrected[j])
        writer.data("vehicle_attitude", 0, time, 1.0, 0.0, 0.0, 0.0)
    path.write_bytes(writer.bytes())
    return simulation


def _assert_recovers(calibration: magfit.Calibration, truth: magfit.Calibration) -> None:
    # Noise 0.4 % of the field over 1500 samples: the ellipsoid within 1 % of its largest entry, the offset
    # within 1 % of the field.
    scale = float(np.max(np.abs(truth.ellipsoid_matrix)))
    np.testing.assert_allclose(calibration.ellipsoid_matrix, truth.ellipsoid_matrix, atol=0.01 * scale)
    np.testing.assert_allclose(calibration.offset, truth.offset, atol=0.01 * truth.field_strength)


def test_undo_is_the_inverse_of_px4_correct() -> None:
    raw = np.random.default_rng(2).normal(0, 0.5, size=(40, 3))
    corrected = px4_correct(raw, CAL["off"], CAL["scale"], CAL["odiag"])
    back = undo_px4_calibration(corrected, offsets=CAL["off"], scales=CAL["scale"], offdiagonals=CAL["odiag"])
    np.testing.assert_allclose(back, raw, atol=1e-12)


def test_raw_and_calibrated_streams_both_recover_the_truth(tmp_path: Path) -> None:
    path = tmp_path / "flight.ulg"
    simulation = write_log(path)
    source = open_source(path)
    assert source.kind == "ulog" and "v1.14.0-test" in source.format
    assert [m.id for m in source.magnetometers] == ["sensor_mag/0", "sensor_mag/1", "vehicle_magnetometer/0"]
    raw = source.read("sensor_mag/0")
    assert raw.magnetometer.rate_hz == pytest.approx(50.0) and raw.magnetometer.unit == "G"
    np.testing.assert_allclose(raw.samples, simulation.samples, atol=1e-6)  # float32 in the log
    undone = source.read("vehicle_magnetometer/0")
    np.testing.assert_allclose(undone.samples, simulation.samples, atol=1e-6)
    for read in (raw, undone):
        _assert_recovers(magfit.fit(read.samples, method="ellipsoid"), simulation.truth)


def test_a_calibration_changed_half_way_undoes_each_sample_with_the_one_in_effect(tmp_path: Path) -> None:
    # A recalibration in flight: CAL_MAG0_* change at sample 700 (a changed_parameters entry with its time).
    # Every sample is undone with the calibration it was corrected with, and the whole log is fitted.
    path = tmp_path / "recalibrated.ulg"
    new = {"off": np.array([-0.2, 0.1, 0.33]), "scale": np.array([0.95, 1.08, 0.99]), "odiag": np.array([0.0, 0.04, 0])}
    simulation = write_log(path, second=False, recalibrated=(700, new))
    source = open_source(path)
    stream = source.magnetometer("vehicle_magnetometer/0")
    assert stream.problem is None
    assert any("calibration changed during the log" in note for note in stream.notes)
    undone = source.read("vehicle_magnetometer/0")
    # The changes are stamped with the last data message's time: sample 699's vehicle_attitude, before 699's
    # vehicle_magnetometer (100 µs later). So that one sample reads as the new calibration: the reader follows
    # the log's own stamps, which put the change before it.
    np.testing.assert_allclose(undone.samples[:699], simulation.samples[:699], atol=1e-6)
    np.testing.assert_allclose(undone.samples[700:], simulation.samples[700:], atol=1e-6)
    _assert_recovers(
        magfit.calibrate_file(path, "ellipsoid", sensor="vehicle_magnetometer/0").calibration, simulation.truth
    )
    # The same log with the samples after the change undone with the first calibration is visibly wrong: the
    # test can fail.
    assert np.max(np.abs(undone.samples[700:] - simulation.samples[700:])) < 1e-5
    assert (
        np.max(
            np.abs(
                px4_correct(simulation.samples[700:], CAL["off"], CAL["scale"], CAL["odiag"])
                - px4_correct(simulation.samples[700:], new["off"], new["scale"], new["odiag"])
            )
        )
        > 0.1
    )


def test_calibrate_by_device_id_and_inspect(tmp_path: Path) -> None:
    path = tmp_path / "flight.ulg"
    simulation = write_log(path)
    runner = CliRunner()
    # Without --sensor every stream is fitted: sensor_mag/1 holds one repeated value and is refused (exit 1),
    # the other two recover the truth, each summary naming its stream.
    result = runner.invoke(cli, ["calibrate", str(path), "-m", "ellipsoid"])
    assert result.exit_code == 1
    assert "1 of 3 magnetometers could not be fitted (sensor_mag/1)" in result.stderr.splitlines()[-1]
    assert "sensor_mag/0: raw sensor_mag, device_id 592905" in result.stdout
    assert "vehicle_magnetometer/0: calibrated vehicle_magnetometer, device_id 592905" in result.stdout
    assert "sensor_mag/1: not fitted" in result.stdout
    output = tmp_path / "cal.json"
    result = runner.invoke(
        cli, ["calibrate", str(path), "--sensor", "sensor_mag/0", "-m", "ellipsoid", "-o", str(output)]
    )
    assert result.exit_code == 0, result.output
    calibration = magfit.Calibration.from_json(output.read_text())
    assert calibration.unit == "G" and calibration.sensor.device_id == DEVICE
    _assert_recovers(calibration, simulation.truth)
    result = runner.invoke(cli, ["inspect", str(path)])
    assert result.exit_code == 0, result.output
    assert "sensor_mag/0  raw sensor_mag, device_id 592905: 1500 samples in G" in result.stdout
    assert "50.0 Hz" in result.stdout and "vehicle_attitude (1500)" in result.stdout


#: R of PX4's Correct, from rotate_3f's cases in src/lib/conversion/rotation.cpp: YAW_180 (4) is
#: x, y = -x, -y; ROLL_180_YAW_90 (10) is x, y, z = y, x, -z; PITCH_270 (25) is x, z = -z, x.
ROTATE_3F = {
    4: np.array([[-1.0, 0, 0], [0, -1, 0], [0, 0, 1]]),
    10: np.array([[0.0, 1, 0], [1, 0, 0], [0, 0, -1]]),
    25: np.array([[0.0, 0, -1], [0, 1, 0], [1, 0, 0]]),
}


@pytest.mark.parametrize(("cal_rot", "board_rot", "applied"), [(-1, 4, 4), (10, 4, 10), (25, 0, 25)])
def test_a_rotated_calibrated_stream_is_undone_to_the_sensor_frame(
    tmp_path: Path, cal_rot: int, board_rot: int, applied: int
) -> None:
    # An internal compass (CAL_MAG0_ROT -1) turns with the board (SENS_BOARD_ROT); an external one by its own
    # CAL_MAG0_ROT, whatever the board's.
    path = tmp_path / "rotated.ulg"
    simulation = write_log(path, n=300, board_rot=board_rot, cal_rot=cal_rot, second=False, rotation=ROTATE_3F[applied])
    source = open_source(path)
    undone = source.read("vehicle_magnetometer/0")
    np.testing.assert_allclose(undone.samples, simulation.samples, atol=1e-6)
    assert source.magnetometers[1].slot == 0 and source.magnetometers[0].slot == 0
    motion = source.read_motion("vehicle_magnetometer/0")
    assert motion.magnetometer_frame == "sensor"
    np.testing.assert_allclose(motion.mounting, ROTATE_3F[applied], atol=1e-12)


def test_an_old_px4_sensor_mag_calibrated_by_its_driver_is_undone(tmp_path: Path) -> None:
    # Before v1.11 PX4Magnetometer::update published x = SCALE · (raw - OFF) (diagonal SCALE) beside x_raw.
    simulation = magfit.simulate(
        400, soft_iron=np.diag([1.1, 0.9, 1.0]), hard_iron=[0.1, -0.2, 0.3], field_strength=0.5, seed=4
    )
    off, scale = np.array([0.05, -0.1, 0.2]), np.array([1.03, 0.98, 1.01])
    writer = ULogWriter()
    fields = [("uint64_t", "timestamp"), ("uint32_t", "device_id"), *(("float", a) for a in "xyz")]
    writer.format("sensor_mag", [*fields, *(("int16_t", f"{a}_raw") for a in "xyz")])
    writer.parameter("CAL_MAG0_ID", DEVICE)
    for axis, i in zip("XYZ", range(3), strict=True):
        writer.parameter(f"CAL_MAG0_{axis}OFF", float(off[i]))
        writer.parameter(f"CAL_MAG0_{axis}SCALE", float(scale[i]))
    writer.subscribe("sensor_mag", 0)
    for j, raw in enumerate(simulation.samples):
        writer.data("sensor_mag", 0, 1_000_000 + j * 20_000, DEVICE, *(scale * (raw - off)), 0, 0, 0)
    path = tmp_path / "old.ulg"
    path.write_bytes(writer.bytes())
    source = open_source(path)
    magnetometer = source.magnetometers[0]
    assert not magnetometer.raw and "calibrated by the driver" in magnetometer.description
    assert "undone with CAL_MAG0_*OFF and *SCALE" in magnetometer.notes[0]
    np.testing.assert_allclose(source.read().samples, simulation.samples, atol=1e-6)


def test_an_older_px4_compass_only_in_sensor_combined_is_listed_with_the_reason(tmp_path: Path) -> None:
    # PX4's oldest ULogs (pyulog's sample.ulg) have no sensor_mag: only the primary compass, calibrated and
    # rotated, in sensor_combined.magnetometer_ga. Listed, refused with the reason, even when only the
    # magnetometer topics were asked for.
    writer = ULogWriter()
    writer.format("sensor_combined", [("uint64_t", "timestamp"), ("float[3]", "magnetometer_ga")])
    writer.subscribe("sensor_combined", 0)
    for j in range(50):
        writer.data("sensor_combined", 0, 1_000_000 + j * 4_000, 0.2, 0.01, 0.43)
    path = tmp_path / "old.ulg"
    path.write_bytes(writer.bytes())
    for everything in (True, False):
        source = open_source(path, everything=everything)
        assert [(m.id, m.n_samples, m.raw) for m in source.magnetometers] == [("sensor_combined/0", 50, False)]
        with pytest.raises(DataFileError, match="older PX4 logs only its primary compass's field"):
            source.read()


def test_a_fine_tuned_board_rotation_is_refused_with_the_reason(tmp_path: Path) -> None:
    path = tmp_path / "tilted.ulg"
    write_log(path, n=100, board_rot=4, board_tilt=2.5, second=False)
    source = open_source(path)
    assert source.magnetometers[1].problem is not None and "SENS_BOARD_X/Y/Z_OFF" in source.magnetometers[1].problem
    with pytest.raises(DataFileError, match="rotation into the body frame cannot be undone"):
        source.read("vehicle_magnetometer/0")
    # Only the raw stream can be fitted, so it is chosen without --sensor.
    assert source.magnetometer(None).id == "sensor_mag/0"


def test_px4_sample_log_tells_that_sensor_mag_is_logged_at_1_hz(tmp_path: Path) -> None:
    runner = CliRunner()
    result = runner.invoke(cli, ["inspect", str(SAMPLE)])
    assert result.exit_code == 0, result.output
    assert "sensor_mag/0  raw sensor_mag, device_id 589858: 6 samples in G" in result.stdout
    assert "1.0 Hz" in result.stdout and "SDLOG_PROFILE" in result.stdout
    assert "no device_id" in result.stdout  # this PX4 version's vehicle_magnetometer cannot be undone
    result = runner.invoke(cli, ["calibrate", str(SAMPLE), "--sensor", "sensor_mag/1"])
    assert result.exit_code == 1
    assert "needs at least" in result.stderr and "SDLOG_PROFILE" in result.stderr.splitlines()[-1]


@pytest.mark.slow
def test_damaged_and_truncated_logs_fail_in_one_line(tmp_path: Path) -> None:
    path = tmp_path / "good.ulg"
    write_log(path, n=300, second=False)
    data = path.read_bytes()
    rng = np.random.default_rng(9)
    cases = [data[:cut] for cut in (7, 16, 30, 200, len(data) // 2, len(data) - 3)]
    for _ in range(12):
        damaged = bytearray(data)
        for where in rng.integers(0, len(data), size=int(rng.integers(1, 30))):
            damaged[where] = int(rng.integers(0, 256))
        cases.append(bytes(damaged))
    sample = SAMPLE.read_bytes()
    cases += [sample[: len(sample) // 3], sample[:5000]]
    runner = CliRunner()
    for i, case in enumerate(cases):
        broken = tmp_path / f"broken{i}.ulg"
        broken.write_bytes(case)
        for command in (
            ["inspect", str(broken)],
            ["calibrate", str(broken), "--sensor", "sensor_mag/0", "-m", "ellipsoid"],
        ):
            result = runner.invoke(cli, command)
            assert result.exit_code in (0, 1, 2), (i, command, result.output)
            if result.exit_code:
                assert result.stderr.strip().splitlines()[-1].startswith("magfit: error: "), (i, result.output)
                assert "Traceback" not in result.output


def test_without_pyulog_the_error_is_the_install_hint(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import sys

    monkeypatch.setitem(sys.modules, "pyulog", None)  # import fails as when it is not installed
    copy = tmp_path / "flight.ulg"
    shutil.copy(SAMPLE, copy)
    result = CliRunner().invoke(cli, ["inspect", str(copy)])
    assert result.exit_code == 2
    assert "pip install 'magfit[ulog]'" in result.stderr and len(result.stderr.strip().splitlines()) == 1


@pytest.mark.slow
def test_a_log_that_sends_pyulog_round_in_circles_is_one_line() -> None:
    # Found by the long fuzz run: a synthetic log (written by ULogWriter) with a few bytes overwritten in its
    # definitions section makes pyulog seek back as far as it read, for ever. Run in a subprocess with a time
    # limit, so that a regression fails instead of hanging the suite.
    import subprocess
    import sys

    damaged = Path(__file__).parent / "data" / "synthetic" / "ulog_pyulog_loops.ulg"
    done = subprocess.run(
        [sys.executable, "-c", "import sys; from magfit.cli import main; sys.exit(main())", "inspect", str(damaged)],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert done.returncode == 2, done.stderr
    assert "went round in circles on damaged data" in done.stderr and len(done.stderr.strip().splitlines()) == 1


def test_the_position_comes_from_the_3d_fixes() -> None:
    # PX4's sample log was flown in Trondheim (vehicle_gps_position in 1e-7 degrees and millimetres).
    position = open_source(SAMPLE).position
    assert position is not None and position.n_fixes == 32
    assert position.lat_deg == pytest.approx(63.41705, abs=1e-4) and position.lon_deg == pytest.approx(
        10.40822, abs=1e-4
    )
    assert 0.0 < position.alt_km < 0.2
    assert position.time_s == pytest.approx(1618986658.6, abs=1.0)  # 2021-04-21 06:30 UTC
