"""Source.read_motion: the attitude, gyroscope and accelerometer of a log on its magnetometer's stamps.

Synthetic logs of every format are written from one known motion — a tumble given by analytic Euler angles,
its body rates and specific force derived by hand — with a magnetometer that reads the Earth's field turned
into the body (and the sensor) frame, then distorted (soft and hard iron). Each test checks that
``read_motion`` gives back the attitude and the rates at the magnetometer's stamps (within the interpolation
error) and that ``attitude · calibrated sample`` is the world field. The real fixtures are checked against
what physics says of them (gravity in NED, the field's direction).
"""

from __future__ import annotations

import datetime
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import magfit
from magfit.errors import DataFileError
from magfit.rotations import standard_rotations
from magfit.sources import open_source
from magfit.sources.motion import Stream, align
from test_sources_dataflash import COMPASSES, DataFlashWriter, correct_field

DATA = Path(__file__).parent / "data"
SITL = DATA / "ardupilot_sitl" / "sitl_three_compasses.bin"
#: The same log as pymavlink's mavlogdump.py prints it (tests/data/ardupilot_sitl/README.md), gzip-compressed.
SITL_DUMP = DATA / "ardupilot_sitl" / "sitl_three_compasses_mavlogdump.txt.gz"
PX4_SAMPLE = DATA / "px4_pyulog" / "sample_log_small.ulg"

#: The Earth's field in NED, mG (about Zurich's): north, east, down.
FIELD_NED = np.array([215.0, 12.0, 430.0])
G = 9.80665
#: Soft iron (symmetric: the symmetric root the fit returns undoes it exactly) and hard iron, mG.
SOFT = np.array([[1.15, 0.06, -0.03], [0.06, 0.9, 0.04], [-0.03, 0.04, 1.02]])
HARD = np.array([60.0, -110.0, 35.0])


def euler(t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Roll, pitch, yaw (rad) of a tumble, and their time derivatives (rad/s), shape (N, 3) each."""
    a = np.column_stack([2.6 * np.sin(0.31 * t), 1.2 * np.sin(0.23 * t + 1.0), 0.7 * t])
    da = np.column_stack([2.6 * 0.31 * np.cos(0.31 * t), 1.2 * 0.23 * np.cos(0.23 * t + 1.0), np.full_like(t, 0.7)])
    return a, da


def attitude(t: np.ndarray) -> np.ndarray:
    """Body (FRD) -> NED matrices, ``Rz(yaw) Ry(pitch) Rx(roll)``, shape (N, 3, 3)."""
    a, _ = euler(t)
    return Rotation.from_euler("ZYX", a[:, ::-1]).as_matrix()


def body_rates(t: np.ndarray) -> np.ndarray:
    """The body rates (p, q, r) of the 3-2-1 Euler angles' derivatives (the kinematic equations), rad/s."""
    (phi, theta, _), (dphi, dtheta, dpsi) = (x.T for x in euler(t))
    return np.column_stack(
        [
            dphi - dpsi * np.sin(theta),
            dtheta * np.cos(phi) + dpsi * np.sin(phi) * np.cos(theta),
            -dtheta * np.sin(phi) + dpsi * np.cos(phi) * np.cos(theta),
        ]
    )


def specific_force(t: np.ndarray) -> np.ndarray:
    """What an accelerometer at rest (turning in place) reads in the body frame: Rᵀ (0, 0, -g), m/s²."""
    return np.einsum("nji,j->ni", attitude(t), np.array([0.0, 0.0, -G]))


def raw_field(t: np.ndarray, mounting: np.ndarray | None = None, noise: float = 0.5, seed: int = 0) -> np.ndarray:
    """The magnetometer's raw reading: the field in its frame (body, or sensor = mountingᵀ body), distorted."""
    body = np.einsum("nji,j->ni", attitude(t), FIELD_NED)
    sensor = body if mounting is None else body @ mounting  # rows: (Mᵀ b)ᵀ = bᵀ M
    rng = np.random.default_rng(seed)
    return sensor @ SOFT.T + HARD + rng.normal(0, noise, size=sensor.shape)


def angle_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angle of the rotation between matrices a[i] and b[i], degrees."""
    return np.degrees(Rotation.from_matrix(np.einsum("nji,njk->nik", a, b)).magnitude())


def assert_motion_matches_truth(motion, *, rate_tol: float = 2e-3, accel_tol: float = 0.02) -> None:
    t = motion.time_s
    assert motion.attitude is not None and motion.gyro is not None and motion.accel is not None
    # Slerp between attitudes 40 ms apart on a motion turning ≤ 1.3 rad/s: well under 0.1°.
    assert np.max(angle_deg(motion.attitude, attitude(t))) < 0.1
    np.testing.assert_allclose(motion.gyro, body_rates(t), atol=rate_tol)
    np.testing.assert_allclose(motion.accel, specific_force(t), atol=accel_tol)


def assert_world_field(motion, mounting: np.ndarray | None = None) -> None:
    """attitude · (mounting ·) calibrated sample is FIELD_NED, sample by sample, within 1 % of its strength."""
    calibration = magfit.fit(motion.samples, method="ellipsoid")
    corrected = calibration.apply(motion.samples, normalized=False)
    if mounting is not None:
        corrected = corrected @ mounting.T
    # The fit's scale is the geometric mean of the semi-axes (det(SOFT) ≠ 1): compare directions and strength.
    world = np.einsum("nij,nj->ni", motion.attitude, corrected)
    world *= np.linalg.norm(FIELD_NED) / calibration.field_strength
    error = np.linalg.norm(world - FIELD_NED, axis=1) / np.linalg.norm(FIELD_NED)
    assert np.percentile(error, 99) < 0.01, np.percentile(error, 99)


# --- ArduPilot DataFlash and its mavlogdump text ------------------------------------------------------------

#: COMPASS_ORIENT 6 (ROTATION_YAW_270) on an external compass: the logged MAG is already in the body frame.
ORIENT = 6


def dataflash_messages(
    n_mag: int = 2400, *, att_start_s: float = 2.0, gap: tuple[float, float] | None = None, calibrated: bool = False
):
    """(name, letters, labels, rows) of a tumble: MAG 20 Hz from 1 s, ATT 25 Hz from ``att_start_s``, IMU 50 Hz.

    ``calibrated``: MAG logged after the firmware's calibration (COMPASSES[0]'s parameters), as ArduPilot does.
    """
    t_mag = 1.0 + np.arange(n_mag) / 20.0
    end = t_mag[-1] + 0.5
    t_att = np.arange(att_start_s, end, 0.04) + 0.013  # another clock than the magnetometer's
    if gap is not None:
        t_att = t_att[(t_att < gap[0]) | (t_att > gap[1])]
    t_imu = np.arange(0.5, end, 0.02) + 0.007
    rows: dict[str, list[tuple]] = {"PARM": [], "MAG": [], "ATT": [], "IMU": []}
    params = {
        "COMPASS_OFS_X": 0.0, "COMPASS_OFS_Y": 0.0, "COMPASS_OFS_Z": 0.0,
        "COMPASS_DIA_X": 1.0, "COMPASS_DIA_Y": 1.0, "COMPASS_DIA_Z": 1.0,
        "COMPASS_ODI_X": 0.0, "COMPASS_ODI_Y": 0.0, "COMPASS_ODI_Z": 0.0,
        "COMPASS_SCALE": 0.0, "COMPASS_DEV_ID": 97539.0, "COMPASS_MOTCT": 0.0,
        "COMPASS_EXTERNAL": 1.0, "COMPASS_ORIENT": float(ORIENT), "AHRS_ORIENTATION": 0.0,
    }  # fmt: skip
    mag = raw_field(t_mag)  # ArduPilot logs the body frame: COMPASS_ORIENT is applied before the log
    if calibrated:
        c = COMPASSES[0]
        for axis, i in zip("XYZ", range(3), strict=True):
            params.update({f"COMPASS_OFS_{axis}": c["ofs"][i], f"COMPASS_DIA_{axis}": c["dia"][i]})
            params[f"COMPASS_ODI_{axis}"] = c["odi"][i]
        params["COMPASS_SCALE"] = c["scale"]
        mag = correct_field(mag, c["ofs"], c["dia"], c["odi"], c["scale"])
    for name, value in params.items():
        rows["PARM"].append((500_000, name, float(value)))
    for time, field in zip(t_mag, mag, strict=True):
        rows["MAG"].append((round(time * 1e6), 0, *field))
    a, _ = euler(t_att)
    for time, (roll, pitch, yaw) in zip(t_att, np.degrees(a), strict=True):
        rows["ATT"].append((round(time * 1e6), roll, pitch, yaw % 360.0))
    for time, gyro, accel in zip(t_imu, body_rates(t_imu), specific_force(t_imu), strict=True):
        rows["IMU"].append((round(time * 1e6), 0, *gyro, *accel))
    formats = {
        "PARM": (129, "QNf", "TimeUS,Name,Value"),
        "MAG": (130, "QBfff", "TimeUS,I,MagX,MagY,MagZ"),
        "ATT": (131, "Qfff", "TimeUS,Roll,Pitch,Yaw"),
        "IMU": (132, "QBffffff", "TimeUS,I,GyrX,GyrY,GyrZ,AccX,AccY,AccZ"),
    }
    return formats, rows


def write_bin(path: Path, formats, rows) -> Path:
    writer = DataFlashWriter()
    for name, (type_id, letters, labels) in formats.items():
        writer.define(type_id, name, letters, labels)
    for name, table in rows.items():
        for row in table:
            writer.write(name, *row)
    path.write_bytes(writer.bytes())
    return path


#: The wall-clock time mavlogdump would print for TimeUS 0 (any: the reader uses TimeUS).
BOOT = datetime.datetime(2026, 4, 14, 17, 8, 31)


def write_mavlogdump(path: Path, formats, rows) -> Path:
    """The same messages as ``mavlogdump.py`` prints them (``str()`` of DFMessage), in time order."""
    lines = []
    for name, table in rows.items():
        labels = formats[name][2].split(",")
        for row in table:
            fields = ", ".join(f"{label} : {value}" for label, value in zip(labels, row, strict=True))
            when = BOOT + datetime.timedelta(microseconds=row[0])
            lines.append((row[0], f"{when:%Y-%m-%d %H:%M:%S}.{when.microsecond // 10_000:02d}: {name} {{{fields}}}"))
    lines.sort(key=lambda pair: pair[0])
    path.write_text("\n".join(line for _, line in lines) + "\n")
    return path


@pytest.fixture(scope="module")
def dataflash(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    folder = tmp_path_factory.mktemp("df")
    formats, rows = dataflash_messages()
    return {
        "bin": write_bin(folder / "tumble.bin", formats, rows),
        "text": write_mavlogdump(folder / "tumble.txt", formats, rows),
    }


@pytest.mark.parametrize("kind", ["bin", "text"])
def test_dataflash_motion_gives_back_the_truth(dataflash: dict[str, Path], kind: str) -> None:
    source = open_source(dataflash[kind])
    assert source.kind == "dataflash"
    assert [(m.id, m.slot, m.device_id) for m in source.magnetometers] == [("MAG/0", 0, 97539)]
    motion = source.read_motion()
    assert motion.magnetometer_frame == "body" and motion.world_frame == "NED" and motion.unit == "mG"
    # The attitude starts at 2.013 s, the magnetometer at 1 s: the 21 samples before are dropped and said.
    assert motion.n_dropped == 21 and motion.time_s[0] == pytest.approx(2.05)
    assert any("21 outside ATT Roll/Pitch/Yaw's span" in note for note in motion.notes)
    assert motion.sources is not None and motion.sources["attitude"].startswith("ATT Roll/Pitch/Yaw")
    np.testing.assert_allclose(motion.mounting, standard_rotations("ardupilot")[ORIENT].matrix)
    assert "COMPASS_ORIENT 6" in motion.mounting_note and "already applied" in motion.mounting_note
    assert_motion_matches_truth(motion)
    assert_world_field(motion)
    assert any("gravity where it belongs" in note for note in motion.notes)
    # The gyro at its own stamps too, one message beyond each end of the samples kept: the truth there.
    raw = motion.gyro_stream
    assert raw is not None and raw.time_s[0] <= motion.time_s[0] and raw.time_s[-1] >= motion.time_s[-1]
    assert raw.time_s[1] > motion.time_s[0] and raw.time_s[-2] < motion.time_s[-1]
    np.testing.assert_allclose(raw.values, body_rates(raw.time_s), atol=2e-3)


def test_mavlogdump_text_reads_as_its_bin(dataflash: dict[str, Path]) -> None:
    from_bin, from_text = open_source(dataflash["bin"]).read_motion(), open_source(dataflash["text"]).read_motion()
    # float32 in the .bin, printed by Python's repr of the same float64 in the text: equal to float32 rounding.
    np.testing.assert_allclose(from_text.samples, from_bin.samples, rtol=1e-6, atol=1e-4)
    np.testing.assert_allclose(from_text.attitude, from_bin.attitude, atol=1e-6)
    np.testing.assert_array_equal(from_text.time_s, from_bin.time_s)


@pytest.mark.parametrize("writer", [write_bin, write_mavlogdump])
def test_the_calibration_logged_is_undone_in_both_forms(tmp_path: Path, writer) -> None:
    formats, rows = dataflash_messages(200, att_start_s=0.5, calibrated=True)
    source = open_source(writer(tmp_path / "calibrated.log", formats, rows))
    read = source.read()
    assert "undone with COMPASS_OFS, DIA, ODI and SCALE" in " ".join(read.notes)
    np.testing.assert_allclose(read.samples, raw_field(read.time_s), atol=1e-3)  # float32 of ~500 mG


def test_a_damaged_mavlogdump_line_is_skipped_and_said(tmp_path: Path) -> None:
    formats, rows = dataflash_messages(200, att_start_s=0.5)
    path = write_mavlogdump(tmp_path / "dump.txt", formats, rows)
    lines = path.read_text().splitlines()
    lines[300] = lines[300][:25]  # a line cut short
    lines.insert(10, "garbage that is no message")
    path.write_text("\n".join(lines) + "\n")
    source = open_source(path)
    assert source.notes == ("2 lines skipped: not a mavlogdump message line",)
    assert len(source.read_motion().samples) >= 198


def test_a_dump_without_parm_lines_says_how_to_dump_again(tmp_path: Path) -> None:
    formats, rows = dataflash_messages(100, att_start_s=0.5)
    del rows["PARM"]
    source = open_source(write_mavlogdump(tmp_path / "mag_only.txt", formats, rows))
    with pytest.raises(DataFileError, match=r"no PARM lines.*mavlogdump.py --types MAG,PARM,ATT,IMU,GPS"):
        source.read_motion()


def test_inspect_lists_a_mavlogdump_file(dataflash: dict[str, Path]) -> None:
    from click.testing import CliRunner

    from magfit.cli import cli

    result = CliRunner().invoke(cli, ["inspect", str(dataflash["text"])])
    assert result.exit_code == 0, result.output
    assert "ArduPilot log as mavlogdump.py text" in result.stdout
    assert "MAG/0" in result.stdout and "ATT (" in result.stdout and "IMU (" in result.stdout


def test_a_gap_in_the_attitude_drops_the_samples_inside_it(tmp_path: Path) -> None:
    formats, rows = dataflash_messages(600, att_start_s=0.5, gap=(10.0, 13.0))
    motion = open_source(write_bin(tmp_path / "gap.bin", formats, rows)).read_motion()
    inside = (motion.time_s > 10.0) & (motion.time_s < 13.0)
    assert not np.any(inside)
    # The attitudes around the gap are at 9.973 and 13.013 s: the samples from 10.00 to 13.00 s lie between.
    assert motion.n_dropped == 61
    assert any("in its 1 gap(s)" in note for note in motion.notes)
    assert np.max(angle_deg(motion.attitude, attitude(motion.time_s))) < 0.1


def test_the_attitude_from_ekf_quaternions_when_there_is_no_att(tmp_path: Path) -> None:
    formats, rows = dataflash_messages(400, att_start_s=0.5)
    quaternions = Rotation.from_matrix(attitude(np.array([r[0] / 1e6 for r in rows["ATT"]]))).as_quat()
    formats["XKQ"] = (133, "QBffff", "TimeUS,C,Q1,Q2,Q3,Q4")
    rows["XKQ"] = [(r[0], 0, q[3], q[0], q[1], q[2]) for r, q in zip(rows.pop("ATT"), quaternions, strict=True)]
    del formats["ATT"]
    motion = open_source(write_bin(tmp_path / "xkq.bin", formats, rows)).read_motion()
    assert motion.sources is not None and motion.sources["attitude"].startswith("XKQ Q1..Q4")
    assert np.max(angle_deg(motion.attitude, attitude(motion.time_s))) < 0.1


# --- PX4 ULog --------------------------------------------------------------------------------------------


def write_ulog(path: Path, mounting_rot: int, n: int = 2400) -> None:
    from test_sources_ulog import ULogWriter

    writer = ULogWriter()
    writer.format("sensor_mag", [("uint64_t", "timestamp"), ("uint32_t", "device_id"), *(("float", a) for a in "xyz")])
    writer.format("vehicle_attitude", [("uint64_t", "timestamp"), ("float[4]", "q")])
    writer.format(
        "sensor_combined",
        [("uint64_t", "timestamp"), ("float[3]", "gyro_rad"), ("float[3]", "accelerometer_m_s2")],
    )
    writer.parameter("CAL_MAG0_ID", 592905)
    writer.parameter("CAL_MAG0_ROT", mounting_rot)
    writer.parameter("CAL_MAG1_ID", 0)
    writer.subscribe("sensor_mag", 0)
    writer.subscribe("sensor_mag", 1)
    writer.subscribe("vehicle_attitude", 0)
    writer.subscribe("sensor_combined", 0)
    mounting = standard_rotations("px4")[mounting_rot].matrix
    t_mag = 1.0 + np.arange(n) / 20.0
    raw = raw_field(t_mag, mounting) / 1000.0  # gauss
    t_fast = np.arange(0.9, t_mag[-1] + 0.2, 0.01) + 0.003
    q = Rotation.from_matrix(attitude(t_fast)).as_quat()  # x, y, z, w
    gyro, accel = body_rates(t_fast), specific_force(t_fast)
    events = [(t, 0, j) for j, t in enumerate(t_mag)] + [(t, 1, j) for j, t in enumerate(t_fast)]
    for time, kind, j in sorted(events):
        stamp = round(time * 1e6)
        if kind == 0:
            writer.data("sensor_mag", 0, stamp, 592905, *raw[j])
            writer.data("sensor_mag", 1, stamp, 12345, 0.2, 0.1, 0.4)
        else:
            writer.data("vehicle_attitude", 0, stamp, q[j, 3], q[j, 0], q[j, 1], q[j, 2])  # PX4: w, x, y, z
            writer.data("sensor_combined", 0, stamp, *gyro[j], *accel[j])
    path.write_bytes(writer.bytes())


@pytest.mark.parametrize("mounting_rot", [0, 6, 10])
@pytest.mark.slow
def test_ulog_motion_gives_back_the_truth_in_the_sensor_frame(tmp_path: Path, mounting_rot: int) -> None:
    pytest.importorskip("pyulog")
    path = tmp_path / "tumble.ulg"
    write_ulog(path, mounting_rot)
    for everything in (True, False):  # opened for the magnetometers only, the motion topics are read when asked
        source = open_source(path, everything=everything)
        # sensor_mag/1's device has no CAL_MAGn_ID: the first free index, 1, is where its calibration goes.
        assert [(m.id, m.slot) for m in source.magnetometers] == [("sensor_mag/0", 0), ("sensor_mag/1", 1)]
        motion = source.read_motion("sensor_mag/0")
        assert motion.magnetometer_frame == "sensor" and motion.unit == "G"
        mounting = standard_rotations("px4")[mounting_rot].matrix
        np.testing.assert_allclose(motion.mounting, mounting)
        assert f"CAL_MAG0_ROT {mounting_rot}" in motion.mounting_note
        assert_motion_matches_truth(motion, rate_tol=1e-5, accel_tol=1e-4)  # float32, 100 Hz
    assert_world_field(motion, mounting)
    if mounting_rot:  # without the mounting rotation the world field is wrong: the test can fail
        calibration = magfit.fit(motion.samples, method="ellipsoid")
        world = np.einsum("nij,nj->ni", motion.attitude, calibration.apply(motion.samples, normalized=True))
        assert np.max(np.abs(world - FIELD_NED / np.linalg.norm(FIELD_NED))) > 0.3


# --- ROS bags --------------------------------------------------------------------------------------------


def write_bag(path: Path, kind: str, n: int = 1200, mag_mounting: np.ndarray | None = None) -> Path:
    """A ROS 1 bag (``kind`` "ros1") or a ROS 2 bag folder with MCAP storage ("mcap") of the tumble.

    ``mag_mounting``: the magnetometer in its own frame ``mag_link``, turned by this rotation within
    ``imu_link`` (``v_imu = mag_mounting · v_mag``), which a /tf_static message states.
    """
    pytest.importorskip("rosbags")
    from rosbags.rosbag1 import Writer as Writer1
    from rosbags.rosbag2 import StoragePlugin
    from rosbags.rosbag2 import Writer as Writer2
    from rosbags.typesys import Stores, get_typestore

    ros1 = kind == "ros1"
    typestore = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    serialize = typestore.serialize_ros1 if ros1 else typestore.serialize_cdr
    types = typestore.types
    start = 1_767_225_600_000_000_000
    # REP-103: the body frame is x forward, y left, z up (FLU) and the world ENU: v_flu = F · v_frd with
    # F = diag(1, -1, -1), v_enu = C · v_ned with C swapping x and y and negating z, so R_enu_flu = C · R_ned_frd · F.
    flip = np.diag([1.0, -1.0, -1.0])
    swap = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
    t_mag = np.arange(n) / 20.0
    t_imu = np.arange(0.0, t_mag[-1] + 0.1, 0.01) + 0.004
    mag_flu = raw_field(t_mag) @ flip * 1e-7  # mG -> tesla; the FRD reading turned into FLU axes
    if mag_mounting is not None:
        mag_flu = mag_flu @ mag_mounting  # rows: (Mᵀ v)ᵀ = vᵀ M, the reading in mag_link's axes
    r_enu = swap @ attitude(t_imu) @ flip
    q = Rotation.from_matrix(r_enu).as_quat()
    gyro, accel = body_rates(t_imu) @ flip, specific_force(t_imu) @ flip
    writer_cls = Writer1(path) if ros1 else Writer2(path, version=9, storage_plugin=StoragePlugin.MCAP)
    with writer_cls as writer:
        mag_conn = writer.add_connection("/imu/mag", "sensor_msgs/msg/MagneticField", typestore=typestore)
        imu_conn = writer.add_connection("/imu/data", "sensor_msgs/msg/Imu", typestore=typestore)

        def header(time: float, seq: int, frame: str = "imu_link"):
            ns = start + round(time * 1e9)
            stamp = types["builtin_interfaces/msg/Time"](sec=ns // 10**9, nanosec=ns % 10**9)
            counter = {"seq": seq} if ros1 else {}  # a ROS 1 header counts its messages; a ROS 2 one does not
            return types["std_msgs/msg/Header"](stamp=stamp, frame_id=frame, **counter), ns

        mag_frame = "imu_link" if mag_mounting is None else "mag_link"
        if mag_mounting is not None:
            if "tf2_msgs/msg/TFMessage" not in types:  # rosbags' ROS 1 store lacks it (a bag carries its own)
                from rosbags.typesys import get_types_from_msg

                definition = "geometry_msgs/TransformStamped[] transforms"
                typestore.register(get_types_from_msg(definition, "tf2_msgs/msg/TFMessage"))
                types = typestore.types
            tf_conn = writer.add_connection("/tf_static", "tf2_msgs/msg/TFMessage", typestore=typestore)
            qx, qy, qz, qw = Rotation.from_matrix(mag_mounting).as_quat()
            head, ns = header(0.0, 0)
            transform = types["geometry_msgs/msg/TransformStamped"](
                header=head,
                child_frame_id="mag_link",
                transform=types["geometry_msgs/msg/Transform"](
                    translation=types["geometry_msgs/msg/Vector3"](x=0.1, y=0.0, z=0.05),
                    rotation=types["geometry_msgs/msg/Quaternion"](x=qx, y=qy, z=qz, w=qw),
                ),
            )
            message = types["tf2_msgs/msg/TFMessage"](transforms=[transform])
            writer.write(tf_conn, ns, serialize(message, "tf2_msgs/msg/TFMessage"))

        vector, quaternion = types["geometry_msgs/msg/Vector3"], types["geometry_msgs/msg/Quaternion"]
        for j, time in enumerate(t_mag):
            head, ns = header(time, j, mag_frame)
            x, y, z = mag_flu[j]
            message = types["sensor_msgs/msg/MagneticField"](
                header=head, magnetic_field=vector(x=x, y=y, z=z), magnetic_field_covariance=np.zeros(9)
            )
            writer.write(mag_conn, ns, serialize(message, "sensor_msgs/msg/MagneticField"))
        for j, time in enumerate(t_imu):
            head, ns = header(time, j)
            message = types["sensor_msgs/msg/Imu"](
                header=head,
                orientation=quaternion(x=q[j, 0], y=q[j, 1], z=q[j, 2], w=q[j, 3]),
                orientation_covariance=np.zeros(9),
                angular_velocity=vector(x=gyro[j, 0], y=gyro[j, 1], z=gyro[j, 2]),
                angular_velocity_covariance=np.zeros(9),
                linear_acceleration=vector(x=accel[j, 0], y=accel[j, 1], z=accel[j, 2]),
                linear_acceleration_covariance=np.zeros(9),
            )
            writer.write(imu_conn, ns, serialize(message, "sensor_msgs/msg/Imu"))
    return path


@pytest.mark.parametrize("kind", ["ros1", "mcap"])
@pytest.mark.slow
def test_bag_motion_turns_rep_103_into_ned(tmp_path: Path, kind: str) -> None:
    path = write_bag(tmp_path / ("tumble.bag" if kind == "ros1" else "tumble"), kind)
    motion = open_source(path).read_motion("/imu/mag")
    assert motion.magnetometer_frame == "body" and motion.unit == "uT"
    assert any("same frame_id" in note for note in motion.notes)
    flip = np.diag([1.0, -1.0, -1.0])
    t = motion.time_s - 1_767_225_600.0  # the stamps are epoch seconds; the truth's clock starts at 0
    # The attitude maps the FLU body into NED: R_ned_flu = R_ned_frd · F.
    assert np.max(angle_deg(motion.attitude, attitude(t) @ flip)) < 0.1
    np.testing.assert_allclose(motion.gyro, body_rates(t) @ flip, atol=2e-3)
    np.testing.assert_allclose(motion.accel, specific_force(t) @ flip, atol=0.02)
    assert any("gravity where it belongs" in note for note in motion.notes)
    assert motion.date == datetime.date(2026, 1, 1)  # the header stamps' own date
    # attitude · calibrated (FLU) field = the NED field: the frames line up end to end.
    calibration = magfit.fit(motion.samples, method="ellipsoid")
    world = np.einsum("nij,nj->ni", motion.attitude, calibration.apply(motion.samples, normalized=True))
    np.testing.assert_allclose(np.median(world, axis=0), FIELD_NED / np.linalg.norm(FIELD_NED), atol=0.01)


def test_the_imu_with_an_orientation_goes_with_the_magnetometer() -> None:
    from magfit.sources.rosbag import ImuTopic, MagneticTopic, _companion

    time = np.arange(3.0)
    raw = ImuTopic("/imu/a_raw", "imu_link", np.full((3, 4), np.nan), np.zeros((3, 3)), time)
    fused = ImuTopic("/imu/data", "imu_link", np.tile([0.0, 0.0, 0.0, 1.0], (3, 1)), np.zeros((3, 3)), time)
    other = ImuTopic("/other/imu", "base_link", np.tile([0.0, 0.0, 0.0, 1.0], (3, 1)), np.zeros((3, 3)), time)
    mag = MagneticTopic("/imu/mag", "imu_link", np.zeros((3, 3)), time)
    chosen, why = _companion(mag, [other, raw, fused])
    assert chosen is fused and "same frame_id" in why


@pytest.mark.slow
def test_bag_motion_takes_the_mounting_from_tf_static(tmp_path: Path) -> None:
    # The magnetometer in its own frame, turned 30° about z and 180° about x within imu_link: /tf_static says so,
    # read_motion gives it as the mounting, and attitude · mounting · calibrated is the NED field again.
    mounting = Rotation.from_euler("ZX", [30, 180], degrees=True).as_matrix()
    path = write_bag(tmp_path / "mounted.bag", "ros1", mag_mounting=mounting)
    motion = open_source(path).read_motion("/imu/mag")
    assert motion.magnetometer_frame == "sensor" and "/tf_static: mag_link -> imu_link" in motion.mounting_note
    np.testing.assert_allclose(motion.mounting, mounting, atol=1e-9)
    calibration = magfit.fit(motion.samples, method="ellipsoid")
    body = calibration.apply(motion.samples, normalized=True) @ motion.mounting.T
    world = np.einsum("nij,nj->ni", motion.attitude, body)
    np.testing.assert_allclose(np.median(world, axis=0), FIELD_NED / np.linalg.norm(FIELD_NED), atol=0.01)


# --- what align does on its own, and what a samples file says ---------------------------------------------


def test_align_leaves_out_a_stream_with_one_message_and_says_so() -> None:
    time = np.linspace(0, 1, 11)
    gyro = Stream("lonely", np.array([0.5]), np.zeros((1, 3)))
    motion = align("m", "uT", time, np.ones((11, 3)), magnetometer_frame="body", gyro=gyro)
    assert motion.gyro is None and motion.n_dropped == 0 and len(motion.samples) == 11
    assert any("fewer than two usable messages; left out" in note for note in motion.notes)


def test_align_leaves_out_an_attitude_of_zero_quaternions() -> None:
    # Found by fuzzing a mavlogdump file: every quaternion unusable left an empty stream that could not be cleaned.
    time = np.linspace(0, 1, 11)
    attitude_stream = Stream("damaged", time, np.zeros((11, 4)))
    motion = align("m", "uT", time, np.ones((11, 3)), magnetometer_frame="body", attitude=attitude_stream)
    assert motion.attitude is None and len(motion.samples) == 11
    assert any(note.startswith("attitude: damaged has fewer than two usable messages") for note in motion.notes)


def test_an_accelerometer_in_another_frame_than_stated_fails_the_gravity_check() -> None:
    # A z-up IMU (ROS's FLU) taken for a z-down one: gravity turned into NED points up; said, in words.
    time = np.linspace(0, 1, 11)
    level = Stream("level", time, np.tile([0.0, 0.0, 0.0, 1.0], (11, 1)))
    up = Stream("z-up accel", time, np.tile([0.0, 0.0, 9.81], (11, 1)))
    motion = align("m", "uT", time, np.ones((11, 3)), magnetometer_frame="body", attitude=level, accel=up)
    assert any(note.startswith("check FAILED: attitude · accel = (0.00, 0.00, 9.81)") for note in motion.notes)


def test_a_samples_file_has_no_motion(tmp_path: Path) -> None:
    path = tmp_path / "samples.csv"
    path.write_text("mx,my,mz\n" + "\n".join(f"{i},{2 * i},{3 * i + 1}" for i in range(20)) + "\n")
    with pytest.raises(DataFileError, match="holds no attitude, gyroscope or accelerometer"):
        open_source(path).read_motion()


# --- the real fixtures ----------------------------------------------------------------------------------


def test_ardupilot_sitl_log_gravity_and_field_in_ned() -> None:
    # ArduPilot's SITL sits level on the ground: the IMU's specific force turned by the attitude is (0, 0, -g),
    # and the three compasses' field turned into NED points 64° down and 10.6° east of north (the SITL's own
    # field table; the World Magnetic Model says 62.0° and 11.4° at the log's place and date).
    source = open_source(SITL)
    for magnetometer in source.magnetometers:
        motion = source.read_motion(magnetometer.id)
        assert len(motion.samples) == magnetometer.n_samples and motion.n_dropped == 0
        gravity = np.einsum("nij,nj->ni", motion.attitude, motion.accel).mean(axis=0)
        np.testing.assert_allclose(gravity, [0, 0, -G], atol=0.05)
        world = np.einsum("nij,nj->ni", motion.attitude, motion.samples).mean(axis=0)
        inclination = np.degrees(np.arctan2(world[2], np.hypot(world[0], world[1])))
        declination = np.degrees(np.arctan2(world[1], world[0]))
        assert inclination == pytest.approx(63.9, abs=0.3) and declination == pytest.approx(10.6, abs=0.3)
        assert motion.position is not None and motion.position.lat_deg == pytest.approx(37.24, abs=0.01)
        assert motion.date == datetime.date(2026, 4, 14)  # the first GPS fix's week and milliseconds


def test_the_real_mavlogdump_output_reads_as_its_bin() -> None:
    # The text pymavlink's own mavlogdump.py printed for the SITL log (compressed: read as it is): the same
    # compasses, device ids, slots, raw samples, time stamps, motion and position as the .bin.
    binary, text = open_source(SITL), open_source(SITL_DUMP)
    assert text.kind == "dataflash" and text.format == "ArduPilot log as mavlogdump.py text" and not text.notes
    assert text.other == binary.other and text.position == binary.position
    assert [(m.id, m.device_id, m.slot, m.n_samples) for m in text.magnetometers] == [
        (m.id, m.device_id, m.slot, m.n_samples) for m in binary.magnetometers
    ]
    for magnetometer in binary.magnetometers:
        a, b = binary.read_motion(magnetometer.id), text.read_motion(magnetometer.id)
        np.testing.assert_array_equal(b.samples, a.samples)
        np.testing.assert_array_equal(b.time_s, a.time_s)
        np.testing.assert_allclose(b.attitude, a.attitude, atol=1e-12)  # ATT in centidegrees, printed as degrees
        np.testing.assert_array_equal(b.gyro, a.gyro)
        np.testing.assert_array_equal(b.accel, a.accel)


def test_px4_sample_log_gravity_in_ned() -> None:
    pytest.importorskip("pyulog")
    source = open_source(PX4_SAMPLE)
    motion = source.read_motion("sensor_mag/1")
    assert motion.magnetometer_frame == "sensor" and "CAL_MAG1_ROT 0" in motion.mounting_note
    assert motion.sources is not None and motion.sources["gyro"].startswith("vehicle_angular_velocity")
    gravity = np.einsum("nij,nj->ni", motion.attitude, motion.accel)
    np.testing.assert_allclose(gravity, np.tile([0, 0, -9.62], (len(gravity), 1)), atol=0.1)
    # The internal compass sits on a board fine-tuned by SENS_BOARD_X/Y_OFF: its mounting is not guessed.
    internal = source.read_motion("sensor_mag/0")
    assert internal.mounting is None and "SENS_BOARD_X/Y/Z_OFF" in internal.mounting_note
