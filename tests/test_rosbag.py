"""magfit.sources.rosbag: synthetic ROS 1 and ROS 2 bags with a simulated magnetometer of known truth, read back;
damaged bags give one clean line."""

from __future__ import annotations

import shutil
import sys
from pathlib import Path

import numpy as np
import pytest

import magfit
from magfit.errors import DataFileError
from magfit.sources import rosbag
from magfit.sources.rosbag import bag_kind, read_bag, read_bag_contents

pytest.importorskip("rosbags", reason="the ros extra is not installed")

from rosbags.rosbag1 import Writer as Writer1
from rosbags.rosbag2 import StoragePlugin
from rosbags.rosbag2 import Writer as Writer2
from rosbags.typesys import Stores, get_typestore

N = 600
#: 100 Hz from this instant (ns since the epoch).
START_NS = 1_767_225_600_000_000_000  # 2026-01-01T00:00:00Z
STEP_NS = 10_000_000


@pytest.fixture(scope="module")
def simulation() -> magfit.Simulation:
    """The paper's Ellipse 2A with steel, in µT-sized gauss units: converted to tesla for the bag."""
    return magfit.scenario("ellipse2a", "steel").simulate(N, seed=7)


def _tesla(simulation: magfit.Simulation) -> np.ndarray:
    # The simulated sensor reads about 0.5 (gauss-like units); 1e-4 makes it tesla of a 50 µT field.
    return simulation.samples * 1e-4


def _messages(typestore, samples_t: np.ndarray, *, zero_stamps: bool = False, frame: str = "imu_link"):
    """MagneticField and Imu messages at 100 Hz: header stamps START_NS + i * STEP_NS (or zero)."""
    header_cls = typestore.types["std_msgs/msg/Header"]
    time_cls = typestore.types["builtin_interfaces/msg/Time"]
    vector_cls = typestore.types["geometry_msgs/msg/Vector3"]
    quaternion_cls = typestore.types["geometry_msgs/msg/Quaternion"]
    mag_cls = typestore.types["sensor_msgs/msg/MagneticField"]
    imu_cls = typestore.types["sensor_msgs/msg/Imu"]
    for i, (x, y, z) in enumerate(samples_t):
        ns = 0 if zero_stamps else START_NS + i * STEP_NS
        stamp = time_cls(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)
        # A ROS 1 header counts its messages too (seq); a ROS 2 one does not.
        seq = {"seq": i} if "seq" in header_cls.__dataclass_fields__ else {}
        header = header_cls(stamp=stamp, frame_id=frame, **seq)
        mag = mag_cls(header=header, magnetic_field=vector_cls(x=x, y=y, z=z), magnetic_field_covariance=np.zeros(9))
        angle = 0.001 * i
        imu = imu_cls(
            header=header,
            orientation=quaternion_cls(x=0.0, y=0.0, z=np.sin(angle / 2), w=np.cos(angle / 2)),
            orientation_covariance=np.zeros(9),
            angular_velocity=vector_cls(x=0.0, y=0.0, z=0.1),
            angular_velocity_covariance=np.zeros(9),
            linear_acceleration=vector_cls(x=0.0, y=0.1 * i, z=9.81),
            linear_acceleration_covariance=np.zeros(9),
        )
        yield START_NS + i * STEP_NS + 5_000_000, mag, imu  # received 5 ms after the measurement


def write_ros1(path: Path, samples_t: np.ndarray, **options) -> Path:
    typestore = get_typestore(Stores.ROS1_NOETIC)
    with Writer1(path) as writer:
        mag_conn = writer.add_connection("/imu/mag", "sensor_msgs/msg/MagneticField", typestore=typestore)
        imu_conn = writer.add_connection("/imu/data", "sensor_msgs/msg/Imu", typestore=typestore)
        other = writer.add_connection("/chatter", "std_msgs/msg/String", typestore=typestore)
        string_cls = typestore.types["std_msgs/msg/String"]
        for bag_time, mag, imu in _messages(typestore, samples_t, **options):
            writer.write(mag_conn, bag_time, typestore.serialize_ros1(mag, "sensor_msgs/msg/MagneticField"))
            writer.write(imu_conn, bag_time, typestore.serialize_ros1(imu, "sensor_msgs/msg/Imu"))
        writer.write(other, START_NS, typestore.serialize_ros1(string_cls(data="hello"), "std_msgs/msg/String"))
    return path


def write_ros2(path: Path, samples_t: np.ndarray, storage: StoragePlugin, **options) -> Path:
    typestore = get_typestore(Stores.ROS2_HUMBLE)
    with Writer2(path, version=9, storage_plugin=storage) as writer:
        mag_conn = writer.add_connection("/imu/mag", "sensor_msgs/msg/MagneticField", typestore=typestore)
        imu_conn = writer.add_connection("/imu/data", "sensor_msgs/msg/Imu", typestore=typestore)
        second = writer.add_connection("/compass2/mag", "sensor_msgs/msg/MagneticField", typestore=typestore)
        for i, (bag_time, mag, imu) in enumerate(_messages(typestore, samples_t, **options)):
            writer.write(mag_conn, bag_time, typestore.serialize_cdr(mag, "sensor_msgs/msg/MagneticField"))
            writer.write(imu_conn, bag_time, typestore.serialize_cdr(imu, "sensor_msgs/msg/Imu"))
            if i % 10 == 0:  # a second, slower compass: 10 Hz
                writer.write(second, bag_time, typestore.serialize_cdr(mag, "sensor_msgs/msg/MagneticField"))
    return path


@pytest.fixture(scope="module")
def bags(tmp_path_factory: pytest.TempPathFactory, simulation: magfit.Simulation) -> dict[str, Path]:
    folder = tmp_path_factory.mktemp("bags")
    samples_t = _tesla(simulation)
    return {
        "ros1": write_ros1(folder / "run.bag", samples_t),
        "sqlite3": write_ros2(folder / "run_sqlite", samples_t, StoragePlugin.SQLITE3),
        "mcap": write_ros2(folder / "run_mcap", samples_t, StoragePlugin.MCAP),
    }


def _expected_times() -> np.ndarray:
    return (START_NS + np.arange(N, dtype=np.int64) * STEP_NS) / 1e9


@pytest.mark.parametrize("kind", ["ros1", "sqlite3", "mcap"])
def test_the_magnetometer_comes_back_exactly(kind: str, bags: dict[str, Path], simulation: magfit.Simulation) -> None:
    topics = read_bag(bags[kind])
    by_name = {t.topic: t for t in topics}
    mag = by_name["/imu/mag"]
    topic, frame_id, samples, timestamps = mag.topic, mag.frame_id, mag.samples, mag.timestamps
    assert (topic, frame_id, mag.unit, mag.time_base) == ("/imu/mag", "imu_link", "T", "header")
    np.testing.assert_array_equal(samples, _tesla(simulation))  # float64 in the message: bit for bit
    np.testing.assert_allclose(timestamps, _expected_times(), rtol=0, atol=1e-6)
    assert mag.rate_hz == pytest.approx(100.0, rel=1e-6)
    if kind != "ros1":
        assert by_name["/compass2/mag"].samples.shape == (N // 10, 3)
        assert by_name["/compass2/mag"].rate_hz == pytest.approx(10.0, rel=1e-6)


@pytest.mark.parametrize("kind", ["ros1", "mcap"])
def test_the_calibration_from_a_bag_recovers_the_truth(
    kind: str, bags: dict[str, Path], simulation: magfit.Simulation
) -> None:
    mag = {t.topic: t for t in read_bag(bags[kind])}["/imu/mag"]
    calibration = magfit.fit(mag.samples * 1e6, method="ellipsoid")  # in µT
    truth = simulation.truth
    # 1e-4 T per simulated unit = 100 µT per unit.
    np.testing.assert_allclose(calibration.offset, truth.offset * 100, atol=0.01 * truth.field_strength * 100)
    scale = float(np.max(np.abs(truth.ellipsoid_matrix)))
    np.testing.assert_allclose(calibration.ellipsoid_matrix * 1e4, truth.ellipsoid_matrix, atol=0.02 * scale)


def test_the_imu_is_read_beside(bags: dict[str, Path]) -> None:
    contents = read_bag_contents(bags["mcap"])
    assert contents.kind == "folder"
    assert [t.topic for t in contents.magnetometers] == ["/compass2/mag", "/imu/mag"]
    (imu,) = contents.imus
    assert imu.topic == "/imu/data" and imu.frame_id == "imu_link"
    angle = 0.001 * np.arange(N)
    np.testing.assert_allclose(imu.orientation[:, 2], np.sin(angle / 2), rtol=0, atol=1e-15)
    np.testing.assert_allclose(imu.orientation[:, 3], np.cos(angle / 2), rtol=0, atol=1e-15)
    np.testing.assert_allclose(imu.linear_acceleration[:, 1], 0.1 * np.arange(N), rtol=0, atol=1e-12)
    np.testing.assert_allclose(imu.timestamps, _expected_times(), rtol=0, atol=1e-6)
    assert contents.topics["/imu/data"] == "sensor_msgs/msg/Imu"


def test_zero_stamps_fall_back_to_the_bag_time(tmp_path: Path, simulation: magfit.Simulation) -> None:
    path = write_ros1(tmp_path / "zero.bag", _tesla(simulation), zero_stamps=True)
    mag = {t.topic: t for t in read_bag(path)}["/imu/mag"]
    assert mag.time_base == "bag"
    np.testing.assert_allclose(mag.timestamps, _expected_times() + 0.005, rtol=0, atol=1e-6)


def test_a_bag_is_known_by_its_content(tmp_path: Path, bags: dict[str, Path], simulation: magfit.Simulation) -> None:
    assert bag_kind(bags["ros1"]) == "ros1"
    assert bag_kind(bags["mcap"]) == "folder"
    (mcap_file,) = bags["mcap"].glob("*.mcap")
    (db3_file,) = bags["sqlite3"].glob("*.db3")
    assert bag_kind(mcap_file) == "mcap" and bag_kind(db3_file) == "sqlite3"
    # Renamed files are still read: the reader is picked by the first bytes.
    for source, name in ((bags["ros1"], "renamed.log"), (mcap_file, "renamed.bin"), (db3_file, "renamed")):
        copy = tmp_path / name
        shutil.copyfile(source, copy)
        mag = {t.topic: t for t in read_bag(copy)}["/imu/mag"]
        np.testing.assert_array_equal(mag.samples, _tesla(simulation))
    text = tmp_path / "mag.csv"
    text.write_text("mx,my,mz\n1,2,3\n")
    assert bag_kind(text) is None
    with pytest.raises(DataFileError, match=r"mag\.csv: not a ROS bag"):
        read_bag(text)


def test_a_bag_without_a_magnetometer_lists_its_topics(tmp_path: Path) -> None:
    typestore = get_typestore(Stores.ROS1_NOETIC)
    path = tmp_path / "chatter.bag"
    with Writer1(path) as writer:
        conn = writer.add_connection("/chatter", "std_msgs/msg/String", typestore=typestore)
        message = typestore.types["std_msgs/msg/String"](data="hi")
        writer.write(conn, START_NS, typestore.serialize_ros1(message, "std_msgs/msg/String"))
    with pytest.raises(DataFileError, match=r"no sensor_msgs/MagneticField .*/chatter \(std_msgs/msg/String\)"):
        read_bag(path)


def _assert_one_clean_line(path: Path) -> None:
    try:
        topics = read_bag(path)
    except DataFileError as error:
        message = str(error)
        assert "\n" not in message and str(path) in message, message
        return
    # A cut that spares every magnetometer message (only the index or metadata lost) may still read:
    # then what comes back must be the true prefix, never invented data.
    for topic in topics:
        assert np.all(np.isfinite(topic.samples))


@pytest.mark.parametrize("kind", ["ros1", "mcap_file", "db3_file"])
@pytest.mark.slow
def test_truncated_and_corrupted_bags_give_one_clean_line(
    kind: str, bags: dict[str, Path], tmp_path: Path, simulation: magfit.Simulation
) -> None:
    if kind == "ros1":
        source = bags["ros1"]
    else:
        (source,) = bags["mcap" if kind == "mcap_file" else "sqlite3"].glob(
            "*.mcap" if kind == "mcap_file" else "*.db3"
        )
    data = source.read_bytes()
    rng = np.random.default_rng(3)
    cuts = sorted({16, 64, 200, len(data) // 3, len(data) // 2, len(data) - 100, len(data) - 1})
    for cut in cuts:
        damaged = tmp_path / f"cut{cut}{source.suffix}"
        damaged.write_bytes(data[:cut])
        _assert_one_clean_line(damaged)
    for trial in range(12):
        corrupted = bytearray(data)
        where = rng.integers(16, len(data), size=8)
        start = int(where[0])
        corrupted[start : start + 64] = rng.bytes(len(corrupted[start : start + 64]))
        for position in where[1:]:
            corrupted[position] ^= 0xFF
        path = tmp_path / f"noise{trial}{source.suffix}"
        path.write_bytes(bytes(corrupted))
        _assert_one_clean_line(path)


def test_a_ros2_folder_with_a_broken_metadata_is_one_line(bags: dict[str, Path], tmp_path: Path) -> None:
    folder = tmp_path / "broken"
    shutil.copytree(bags["mcap"], folder)
    (folder / "metadata.yaml").write_text("rosbag2_bagfile_information: {version: 9\n")
    with pytest.raises(DataFileError, match=r"broken: this ROS 2 bag folder cannot be read .*ros2 bag reindex"):
        read_bag(folder)
    missing = tmp_path / "missing"
    shutil.copytree(bags["mcap"], missing)
    for file in missing.glob("*.mcap"):
        file.unlink()
    with pytest.raises(DataFileError, match="missing"):
        read_bag(missing)


def test_a_missing_extra_is_the_install_command(bags: dict[str, Path], monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "rosbags.highlevel", None)
    with pytest.raises(ImportError, match=r"pip install 'magfit\[ros\]'"):
        read_bag(bags["ros1"])


def test_missing_path(tmp_path: Path) -> None:
    with pytest.raises(DataFileError, match="no such file or folder"):
        rosbag.read_bag(tmp_path / "nothing.bag")


def test_a_bag_as_a_source(bags: dict[str, Path], simulation: magfit.Simulation) -> None:
    source = rosbag.open_rosbag(bags["mcap"])
    assert (source.kind, source.format) == ("rosbag", "ROS 2 bag folder")
    assert [m.id for m in source.magnetometers] == ["/compass2/mag", "/imu/mag"]
    main = source.magnetometer("/imu/mag")
    assert main.unit == "uT" and main.n_samples == N and main.rate_hz == pytest.approx(100.0, rel=1e-6)
    assert main.start_s == pytest.approx(START_NS / 1e9) and "frame imu_link" in main.description
    read = source.read("/imu/mag")
    np.testing.assert_allclose(read.samples, _tesla(simulation) * 1e6, rtol=1e-15)  # 100 µT per simulated unit
    np.testing.assert_allclose(read.time_s, _expected_times(), rtol=0, atol=1e-6)
    assert any("/imu/data (sensor_msgs/Imu, 600)" in line for line in source.other)
    with pytest.raises(DataFileError, match="choose one with sensor='ID'"):
        source.read()  # two compasses: the user chooses


def test_a_slow_compass_is_named(tmp_path: Path, simulation: magfit.Simulation) -> None:
    typestore = get_typestore(Stores.ROS1_NOETIC)
    path = tmp_path / "slow.bag"
    with Writer1(path) as writer:
        conn = writer.add_connection("/mag", "sensor_msgs/msg/MagneticField", typestore=typestore)
        for bag_time, mag, _ in list(_messages(typestore, _tesla(simulation)))[:50]:
            slow = typestore.types["sensor_msgs/msg/MagneticField"](
                header=typestore.types["std_msgs/msg/Header"](
                    seq=mag.header.seq,
                    stamp=typestore.types["builtin_interfaces/msg/Time"](
                        sec=mag.header.stamp.sec + (mag.header.seq), nanosec=mag.header.stamp.nanosec
                    ),
                    frame_id="mag",
                ),
                magnetic_field=mag.magnetic_field,
                magnetic_field_covariance=np.zeros(9),
            )
            writer.write(conn, bag_time, typestore.serialize_ros1(slow, "sensor_msgs/msg/MagneticField"))
    (magnetometer,) = rosbag.open_rosbag(path).magnetometers
    assert magnetometer.rate_hz < 1.0
    assert any("published at only" in note for note in magnetometer.notes)


def test_a_bag_written_by_ros_itself() -> None:
    # tests/data/ros/README.md: written by ROS's rosbag, MIT; hard-coded field, stamps left at zero, 0.5 Hz.
    path = Path(__file__).parent / "data" / "ros" / "fake_sensors_sample.bag"
    contents = read_bag_contents(path)
    assert contents.topics == {
        "/my_magnetic_field": "sensor_msgs/msg/MagneticField",
        "/my_temperature": "sensor_msgs/msg/Temperature",
    }
    (mag,) = contents.magnetometers
    np.testing.assert_array_equal(mag.samples, np.tile([1.4, 0.2, 0.6], (10, 1)))
    assert mag.time_base == "bag" and mag.frame_id == ""
    assert np.all(np.diff(mag.timestamps) > 0) and mag.timestamps[0] == pytest.approx(1626720936.25, abs=0.01)
    assert mag.rate_hz == pytest.approx(0.5, rel=0.01)
    (magnetometer,) = rosbag.open_rosbag(path).magnetometers
    assert any("header stamps are zero" in note for note in magnetometer.notes)
    assert any("only 0.5 Hz" in note for note in magnetometer.notes)


@pytest.mark.parametrize("kind", ["ros1", "mcap_file", "folder"])
def test_magfit_calibrate_on_a_bag_recovers_the_truth(
    kind: str, bags: dict[str, Path], tmp_path: Path, simulation: magfit.Simulation
) -> None:
    from click.testing import CliRunner

    from magfit.cli import cli

    path = {"ros1": bags["ros1"], "mcap_file": next(bags["mcap"].glob("*.mcap")), "folder": bags["sqlite3"]}[kind]
    output = tmp_path / "cal.json"
    args = ["calibrate", str(path), "--sensor", "/imu/mag", "-m", "ellipsoid", "-o", str(output)]
    result = CliRunner().invoke(cli, args)
    assert result.exit_code == 0, result.output
    calibration = magfit.Calibration.from_json(output.read_text())
    truth = simulation.truth
    assert calibration.unit == "uT"  # tesla read as µT: 100 µT per simulated unit
    np.testing.assert_allclose(calibration.offset, truth.offset * 100, atol=0.01 * truth.field_strength * 100)
    scale = float(np.max(np.abs(truth.ellipsoid_matrix)))
    np.testing.assert_allclose(calibration.ellipsoid_matrix * 1e4, truth.ellipsoid_matrix, atol=0.02 * scale)
    assert "/imu/mag" in result.stdout and "warning" not in result.stderr


def test_a_bag_with_gnss_fixes_pins_the_field_to_the_model_there(tmp_path: Path, simulation: magfit.Simulation) -> None:
    from click.testing import CliRunner

    from magfit.cli import cli
    from magfit.geomag import field_at

    typestore = get_typestore(Stores.ROS1_NOETIC)
    types = typestore.types
    # The simulated sensor scaled to a 48 µT field (what an ellipsoid fit finds), in tesla.
    samples_t = simulation.samples * (48e-6 / magfit.fit(simulation.samples, method="ellipsoid").field_strength)
    path = tmp_path / "gnss.bag"
    fixes = [(-1, 0.0, 0.0, 0.0), (0, 47.40, 8.50, 500.0), (0, 47.41, 8.51, 510.0), (1, 47.39, 8.49, 490.0)]
    with Writer1(path) as writer:
        mag_conn = writer.add_connection("/imu/mag", "sensor_msgs/msg/MagneticField", typestore=typestore)
        fix_conn = writer.add_connection("/gps/fix", "sensor_msgs/msg/NavSatFix", typestore=typestore)
        for bag_time, mag, _ in _messages(typestore, samples_t):
            writer.write(mag_conn, bag_time, typestore.serialize_ros1(mag, "sensor_msgs/msg/MagneticField"))
        for i, (status, lat, lon, alt) in enumerate(fixes):
            ns = START_NS + i * 1_000_000_000
            header = types["std_msgs/msg/Header"](
                seq=i, stamp=types["builtin_interfaces/msg/Time"](sec=ns // 10**9, nanosec=0), frame_id="gps"
            )
            message = types["sensor_msgs/msg/NavSatFix"](
                header=header,
                status=types["sensor_msgs/msg/NavSatStatus"](status=status, service=1),
                latitude=lat,
                longitude=lon,
                altitude=alt,
                position_covariance=np.zeros(9),
                position_covariance_type=0,
            )
            writer.write(fix_conn, ns, typestore.serialize_ros1(message, "sensor_msgs/msg/NavSatFix"))
    contents = read_bag_contents(path)
    assert contents.fixes.shape == (3, 4)  # the status -1 message (no fix) is left out
    lat, lon, alt_km, when = contents.position()
    assert (lat, lon, alt_km) == pytest.approx((47.40, 8.50, 0.5)) and when == pytest.approx(START_NS / 1e9 + 1)
    output = tmp_path / "cal.json"
    args = ["calibrate", str(path), "-m", "ellipsoid", "--field-strength", "wmm", "-o", str(output)]
    result = CliRunner().invoke(cli, args)
    assert result.exit_code == 0, result.output
    expected = field_at(47.40, 8.50, alt_km=0.5, date="2026-01-01").total_in("uT")  # the date of the first fix
    assert magfit.Calibration.from_json(output.read_text()).field_strength == pytest.approx(expected, rel=1e-12)
    assert "WMM-2025 at 47.4°, 8.5°, 0.5 km on 2026.00" in result.stdout


def test_a_truncated_bag_on_the_command_line_is_exit_2_and_one_line(bags: dict[str, Path], tmp_path: Path) -> None:
    from click.testing import CliRunner

    from magfit.cli import cli

    for source in (bags["ros1"], next(bags["mcap"].glob("*.mcap")), next(bags["sqlite3"].glob("*.db3"))):
        damaged = tmp_path / f"cut{source.suffix}"
        damaged.write_bytes(source.read_bytes()[: len(source.read_bytes()) // 2])
        output = tmp_path / "cal.json"
        output.write_text("kept")
        result = CliRunner().invoke(cli, ["calibrate", str(damaged), "--sensor", "/imu/mag", "-o", str(output)])
        assert result.exit_code == 2, result.output
        lines = result.stderr.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith(f"magfit: error: {damaged}: this "), lines
        assert output.read_text() == "kept"


def test_an_mcap_record_announcing_more_than_the_file_is_damage_not_memory(
    bags: dict[str, Path], tmp_path: Path
) -> None:
    import struct

    from click.testing import CliRunner

    from magfit.cli import cli

    data = next(bags["mcap"].glob("*.mcap")).read_bytes()
    records, position = [], 8  # after the magic: opcode (1 byte), length (uint64), body
    while position < len(data) - 8 and len(records) < 12:
        length = struct.unpack_from("<Q", data, position + 1)[0]
        records.append(position)
        position += 9 + length
    refused = 0
    for index, start in enumerate(records):
        damaged = bytearray(data)
        struct.pack_into("<Q", damaged, start + 1, 1 << 62)  # a length no machine can allocate
        path = tmp_path / f"length{index}.mcap"
        path.write_bytes(bytes(damaged))
        result = CliRunner().invoke(cli, ["calibrate", str(path), "--sensor", "/imu/mag", "-m", "ellipsoid"])
        if result.exit_code == 0:  # a record the reader skips (a chunk whose messages the index also holds)
            continue
        refused += 1
        assert result.exit_code == 2, result.output
        lines = result.stderr.strip().splitlines()
        assert len(lines) == 1 and f"{path}: this MCAP file cannot be read" in lines[0], lines
        assert "memory" not in lines[0].replace("MemoryError", "") and "--max-samples" not in lines[0], lines[0]
    assert refused >= 3
