"""The columns of the usual converters (blackbox_decode, ulog2csv, mavlogdump, ROS CSV exports), their units,
and files that interleave several compasses: each compass read alone, never one cloud.

The fixtures are in tests/data/converters: PX4's are ulog2csv's own output on tests/data/px4_pyulog's log
(checked here against pyulog's read of the same log); the others carry the header their converter writes
and samples of a known calibration (make_fixtures.py, truth.json).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

import magfit
from magfit import DataFileError
from magfit.cli import cli
from magfit.io import ChunkReader, find_magnetometer_columns, read_samples
from magfit.io.columns import name_unit, recognise_converter
from magfit.io.instances import head_sensors, sensor_listing
from magfit.sources import open_source

DATA = Path(__file__).parent / "data" / "converters"
TRUTH = json.loads((DATA / "truth.json").read_text())


def assert_truth(calibration: magfit.Calibration, truth: dict, *, offset_tol: float, shape_tol: float) -> None:
    """The fit against the fixture's truth: raw = strength * D u + offset, so A = (D Dᵀ)⁻¹ / strength²."""
    distortion = np.asarray(truth["distortion"])
    strength = truth["field_strength"]
    expected = np.linalg.inv(distortion @ distortion.T) / strength**2
    np.testing.assert_allclose(calibration.offset, truth["offset"], atol=offset_tol)
    np.testing.assert_allclose(calibration.ellipsoid_matrix, expected, atol=shape_tol * np.abs(expected).max())
    geometric_mean = strength * abs(np.linalg.det(distortion)) ** (1 / 3)
    assert calibration.field_strength == pytest.approx(geometric_mean, rel=shape_tol)


# ---------------------------------------------------------------------------------------------- names


@pytest.mark.parametrize(
    ("names", "chosen"),
    [
        (["loopIteration", "time (us)", "gyroADC[0]", "gyroADC[1]", "gyroADC[2]", "accSmooth[0]", "accSmooth[1]",
          "accSmooth[2]", "magADC[0]", "magADC[1]", "magADC[2]", "axisP[0]", "axisP[1]", "axisP[2]", "debug[0]",
          "debug[1]", "debug[2]", "heading[0]", "heading[1]", "heading[2]"], ("magADC[0]", "magADC[1]", "magADC[2]")),
        (["timestamp", "magnetometer_ga[0]", "magnetometer_ga[1]", "magnetometer_ga[2]"],
         ("magnetometer_ga[0]", "magnetometer_ga[1]", "magnetometer_ga[2]")),
        (["TimeUS", "I", "MagX", "MagY", "MagZ", "OfsX", "OfsY", "OfsZ", "MOX", "MOY", "MOZ"],
         ("MagX", "MagY", "MagZ")),
        (["t", "hx", "hy", "hz"], ("hx", "hy", "hz")),
        (["mag_x", "mag_y", "mag_z", "acc_x", "acc_y", "acc_z"], ("mag_x", "mag_y", "mag_z")),
        (["Bx", "By", "Bz"], ("Bx", "By", "Bz")),
        (["time", "mag_x_uT", "mag_y_uT", "mag_z_uT"], ("mag_x_uT", "mag_y_uT", "mag_z_uT")),
        (["%time", "field.header.frame_id", "field.magnetic_field.x", "field.magnetic_field.y",
          "field.magnetic_field.z"], ("field.magnetic_field.x", "field.magnetic_field.y", "field.magnetic_field.z")),
        ([".header.stamp.secs", ".magnetic_field.x", ".magnetic_field.y", ".magnetic_field.z"],
         (".magnetic_field.x", ".magnetic_field.y", ".magnetic_field.z")),
    ],
)  # fmt: skip
def test_the_converters_magnetometer_columns_are_found_by_name(names: list[str], chosen: tuple[str, ...]) -> None:
    candidates = find_magnetometer_columns(names)
    assert candidates and candidates[0].names == chosen
    assert all(triple.score < candidates[0].score for triple in candidates[1:])


@pytest.mark.parametrize(
    "names",
    [
        ["accSmooth[0]", "accSmooth[1]", "accSmooth[2]", "gyroADC[0]", "gyroADC[1]", "gyroADC[2]"],
        ["TimeUS", "I", "GyrX", "GyrY", "GyrZ", "AccX", "AccY", "AccZ"],
        ["gyro_rad[0]", "gyro_rad[1]", "gyro_rad[2]", "accelerometer_m_s2[0]", "accelerometer_m_s2[1]",
         "accelerometer_m_s2[2]"],
        ["G_x", "G_y", "G_z"],  # a unit word is never the first: this is a gyro, not gauss
        ["axisP[0]", "axisP[1]", "axisP[2]", "navVel[0]", "navVel[1]", "navVel[2]"],
    ],
)  # fmt: skip
def test_accelerometer_and_gyro_columns_are_never_a_magnetometer(names: list[str]) -> None:
    assert find_magnetometer_columns(names) == []


@pytest.mark.parametrize(
    ("name", "unit"),
    [
        ("mag_x_uT", "uT"),
        ("MagX (mG)", "mG"),
        ("mag_x [nT]", "nT"),
        ("Bx_nT", "nT"),
        ("magnetometer_ga[0]", "G"),
        ("mag_x_gauss", "G"),
        ("B_x_T", "T"),
        ("mx", None),
        ("mx_raw", None),  # raw is no unit
        ("mag_x_t", None),  # a lone lower-case t is rather a time
        ("time (us)", None),
    ],
)
def test_the_unit_a_name_states(name: str, unit: str | None) -> None:
    assert name_unit(name) == unit


def test_a_converter_is_recognised_by_the_header_around_the_names() -> None:
    sensor_mag = ["timestamp", "timestamp_sample", "device_id", "x", "y", "z", "temperature", "error_count"]
    assert recognise_converter(("x", "y", "z"), sensor_mag).unit == "G"
    assert recognise_converter(("x", "y", "z"), ["t", "x", "y", "z"]) is None  # plain x, y, z: no unit guessed
    assert recognise_converter(("MagX", "MagY", "MagZ"), ["TimeUS", "MagX", "MagY", "MagZ"]).unit == "mG"
    assert recognise_converter(("MagX", "MagY", "MagZ"), ["t", "MagX", "MagY", "MagZ"]) is None  # not mavlogdump's


# ---------------------------------------------------------------------------------------------- fixtures


@pytest.mark.parametrize(
    ("name", "unit", "converter", "method", "offset_tol", "shape_tol"),
    [
        ("blackbox_magadc.csv", "counts", "blackbox_decode", "ellipsoid", 1.5, 0.01),
        ("ros_magnetic_field.csv", "T", "sensor_msgs/MagneticField", "ellipsoid", 1.5e-7, 0.01),
    ],
)
def test_a_converter_file_reads_with_its_unit_and_recovers_its_truth(
    name: str, unit: str, converter: str, method: str, offset_tol: float, shape_tol: float
) -> None:
    table = read_samples(DATA / name)
    assert table.unit == unit and table.column_note is not None and converter in table.column_note
    assert_truth(magfit.fit(table.samples, method=method), TRUTH[name], offset_tol=offset_tol, shape_tol=shape_tol)


def test_blackbox_csv_on_the_command_line_names_its_converter_and_unit(tmp_path: Path) -> None:
    output = tmp_path / "cal.json"
    result = CliRunner().invoke(cli, ["calibrate", str(DATA / "blackbox_magadc.csv"), "-o", str(output)])
    assert result.exit_code == 0, result.output
    assert "magADC[0], magADC[1], magADC[2] (Betaflight/INAV blackbox_decode magADC, counts;" in result.stdout
    assert "minus the offset the firmware stores" in result.stdout  # the trap, told
    calibration = magfit.Calibration.from_json(output.read_text())
    assert calibration.unit == "counts"  # the converter's unit labels the calibration
    assert_truth(calibration, TRUTH["blackbox_magadc.csv"], offset_tol=1.5, shape_tol=0.01)
    labelled = tmp_path / "ros.json"
    result = CliRunner().invoke(cli, ["calibrate", str(DATA / "ros_magnetic_field.csv"), "-o", str(labelled)])
    assert result.exit_code == 0 and magfit.Calibration.from_json(labelled.read_text()).unit == "T"
    (strength,) = [line for line in result.stdout.splitlines() if line.startswith("field strength")]
    assert strength.endswith("e-05 T")  # about 49 µT, printed in the file's tesla


def test_ulog2csv_output_is_pyulogs_data_in_gauss() -> None:
    pyulog = pytest.importorskip("pyulog")
    log = pyulog.ULog(str(DATA.parent / "px4_pyulog" / "sample_log_small.ulg"), ["vehicle_magnetometer", "sensor_mag"])
    topics = {(data.name, data.multi_id): data.data for data in log.data_list}
    vehicle = read_samples(DATA / "px4_vehicle_magnetometer_0.csv")
    expected = np.column_stack([topics["vehicle_magnetometer", 0][f"magnetometer_ga[{i}]"] for i in range(3)])
    np.testing.assert_allclose(vehicle.samples, expected, rtol=1e-6)
    assert vehicle.unit == "G" and "PX4's calibrated field" in (vehicle.column_note or "")
    raw = read_samples(DATA / "px4_sensor_mag_1.csv")
    expected = np.column_stack([topics["sensor_mag", 1][axis] for axis in "xyz"])
    np.testing.assert_allclose(raw.samples, expected, rtol=1e-6)
    assert raw.unit == "G" and raw.sensor is None  # one device_id: read whole
    magnetometer = open_source(DATA / "px4_sensor_mag_1.csv").magnetometers[0]
    assert magnetometer.device_id == int(topics["sensor_mag", 1]["device_id"][0]) == 592905
    assert magnetometer.unit == "G"
    assert read_samples(DATA / "px4_sensor_mag_1.csv", sensor="592905").sensor == "device_id=592905"


# ---------------------------------------------------------------------------------------------- instances


def test_an_interleaved_file_is_refused_as_one_cloud_naming_the_column_and_the_ids() -> None:
    path = DATA / "mavlogdump_mag.csv"
    with pytest.raises(DataFileError, match=r"interleaves 2 magnetometers in column 'I' \(I=0, I=1\).*sensor='I=0'"):
        read_samples(path)
    with pytest.raises(DataFileError, match="interleaves 2 magnetometers"):
        ChunkReader(path)  # at once, before any row is read
    assert head_sensors(path) == ("I=0", "I=1")
    listing = sensor_listing(path)
    assert listing is not None and listing.counts == {"I=0": 500, "I=1": 500} and listing.unit == "mG"


@pytest.mark.parametrize("sensor", ["I=1", "i=1", "1"])
def test_each_compass_of_an_interleaved_file_is_its_own_truth(sensor: str) -> None:
    table = read_samples(DATA / "mavlogdump_mag.csv", sensor=sensor)
    assert table.sensor == "I=1" and table.n_rows == 500 and table.unit == "mG"
    truth = TRUTH["mavlogdump_mag.csv I=1"]
    assert_truth(magfit.fit(table.samples, method="ellipsoid"), truth, offset_tol=1.0, shape_tol=0.01)
    other = read_samples(DATA / "mavlogdump_mag.csv", sensor="I=0")
    truth = TRUTH["mavlogdump_mag.csv I=0"]
    assert_truth(magfit.fit(other.samples, method="ellipsoid"), truth, offset_tol=1.0, shape_tol=0.01)


def test_real_mavlogdump_csv_of_three_compasses_reads_each_as_the_bin_holds_it() -> None:
    path = DATA / "sitl_three_compasses_mag.csv"  # mavlogdump --format csv --types MAG on the SITL .bin
    log = open_source(DATA.parent / "ardupilot_sitl" / "sitl_three_compasses.bin")
    listing = sensor_listing(path)
    assert listing is not None and listing.unit == "mG"
    assert (
        listing.counts
        == {f"I={m.slot}": m.n_samples for m in log.magnetometers}
        == {"I=0": 249, "I=1": 249, "I=2": 249}
    )
    for sensor in listing.counts:
        table = read_samples(path, sensor=sensor)
        assert table.samples.shape == (249, 3) and table.samples[0].tolist() == [195.0, 119.0, 427.0]
    result = CliRunner().invoke(cli, ["calibrate", str(path)])  # a vehicle standing still: each refused, exit 1
    assert result.exit_code == 1 and "3 of 3 magnetometers could not be fitted (I=0, I=1, I=2)" in result.stderr
    assert "all 249 samples are identical" in result.stderr


@pytest.mark.parametrize(
    ("sensor", "message"),
    [
        ("J=1", r"holds no column 'J'; its magnetometers are told apart by 'I': I=0, I=1"),
        ("I=7", r"has no rows with I=7; it holds I=0, I=1"),
        ("x", r"sensor='x' is not a value of column 'I'"),
    ],
)
def test_a_sensor_the_file_does_not_hold_is_one_line(sensor: str, message: str) -> None:
    with pytest.raises(DataFileError, match=message):
        read_samples(DATA / "mavlogdump_mag.csv", sensor=sensor)


def test_a_sensor_on_a_file_without_an_instance_column_is_refused() -> None:
    with pytest.raises(DataFileError, match="has no column that tells magnetometers apart"):
        read_samples(DATA / "blackbox_magadc.csv", sensor="I=1")


def interleaved_text(tmp_path: Path, n_first: int, n_second: int) -> tuple[Path, np.ndarray, np.ndarray, int]:
    """A device_id column: one compass's rows only for the first ``n_first`` rows (beyond the 256 KiB head),
    then the two interleaved; a NaN in one row of the second compass."""
    rng = np.random.default_rng(7)
    first = rng.normal(0, 300, (n_first + n_second, 3)).round(2)
    second = rng.normal(1000, 300, (n_second, 3)).round(2)
    second[10, 1] = np.nan
    lines = ["t,device_id,mx,my,mz"]
    for k in range(n_first):
        lines.append(f"{k},589858,{first[k, 0]},{first[k, 1]},{first[k, 2]}")
    nan_line = 0
    for k in range(n_second):
        a = first[n_first + k]
        lines.append(f"{n_first + k},589858,{a[0]},{a[1]},{a[2]}")
        lines.append(f"{n_first + k},592905,{second[k, 0]},{second[k, 1]},{second[k, 2]}".replace("nan", ""))
        if k == 10:
            nan_line = len(lines)
    path = tmp_path / "two.csv"
    path.write_text("\n".join(lines) + "\n")
    return path, first, second, nan_line


def test_a_second_compass_beyond_the_head_is_an_error_with_its_line(tmp_path: Path) -> None:
    path, first, second, nan_line = interleaved_text(tmp_path, 12_000, 300)
    assert head_sensors(path) == ("device_id=589858",)  # the head holds one
    with pytest.raises(DataFileError, match=r"line 12003: column 'device_id' changes from 589858 to 592905"):
        read_samples(path)
    chosen = read_samples(path, sensor="device_id=592905")
    np.testing.assert_array_equal(chosen.samples, np.delete(second, 10, axis=0))
    assert (chosen.n_rows, chosen.n_skipped, chosen.skipped_lines) == (300, 1, (nan_line,))
    fields = path.read_text().splitlines()[nan_line - 1].split(",")  # the file's own line, header counted
    assert fields[1] == "592905" and fields[3] == ""
    one = read_samples(path, sensor="589858")
    np.testing.assert_array_equal(one.samples, first)


def test_a_compass_is_read_alike_in_parallel_pieces(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import magfit.io.chunks as chunks

    path, _, _, nan_line = interleaved_text(tmp_path, 2_000, 3_000)
    whole = read_samples(path, sensor="592905")
    monkeypatch.setattr(chunks, "PARALLEL_BYTES", 1000)
    monkeypatch.setattr(chunks.os, "cpu_count", lambda: 3)
    assert len(ChunkReader(path, sensor="592905").parallel_pieces()) == 3
    split = read_samples(path, sensor="592905")
    np.testing.assert_array_equal(split.samples, whole.samples)
    assert (split.n_rows, split.skipped_lines) == (whole.n_rows, whole.skipped_lines) == (3_000, (nan_line,))


def test_a_cell_of_the_instance_column_that_is_not_a_number_is_named(tmp_path: Path) -> None:
    path = tmp_path / "bad.csv"
    rows = [f"{k % 2},{k},{2 * k},{3 * k}" for k in range(50)]
    rows[20] = "one,1,2,3"
    path.write_text("I,mx,my,mz\n" + "\n".join(rows) + "\n")
    with pytest.raises(DataFileError, match=r"line 22, column 'I' \(column 1\): 'one' is not a number"):
        read_samples(path, sensor="I=1")


def test_a_column_named_i_that_holds_no_instance_is_just_another_column(tmp_path: Path) -> None:
    path = tmp_path / "current.csv"  # I is a current in amperes here: many values, not whole numbers
    rows = [f"{k},{12 + 0.01 * k:.2f},{1.5 + 0.37 * (k % 7):.2f},{k},{2 * k},{3 * k}" for k in range(60)]
    path.write_text("t,V,I,mx,my,mz\n" + "\n".join(rows) + "\n")
    table = read_samples(path)
    assert table.columns == ("mx", "my", "mz") and table.n_rows == 60 and table.sensor is None
    assert head_sensors(path) == () and sensor_listing(path) is None


@pytest.mark.parametrize("name", ["mavlogdump_mag.csv", "blackbox_magadc.csv", "px4_sensor_mag_1.csv"])
def test_truncated_or_corrupted_converter_files_give_samples_or_one_clean_error(tmp_path: Path, name: str) -> None:
    original = (DATA / name).read_bytes()
    rng = np.random.default_rng(5)
    for trial in range(12):
        data = bytearray(original[: int(rng.integers(1, len(original)))])
        for position in rng.integers(0, len(data), size=int(rng.integers(0, 4))):
            data[position] = int(rng.choice(list(b",\n0xI=-\x00 ")))
        path = tmp_path / f"{trial}-{name}"
        path.write_bytes(bytes(data))
        for sensor in (None, "I=1") if name.startswith("mavlogdump") else (None,):
            try:
                table = read_samples(path, sensor=sensor)
            except magfit.MagfitError as error:  # a DataFileError, on one line naming the file
                assert str(path) in str(error) and "\n" not in str(error)
            else:
                assert table.samples.ndim == 2 and np.isfinite(table.samples).all()


# ---------------------------------------------------------------------------------------------- command line


def test_inspect_lists_each_compass_of_an_interleaved_file() -> None:
    result = CliRunner().invoke(cli, ["inspect", str(DATA / "mavlogdump_mag.csv")])
    assert result.exit_code == 0, result.output
    assert "I=0  MagX, MagY, MagZ where I = 0" in result.stdout and "500 samples in mG" in result.stdout
    assert "I=1  MagX, MagY, MagZ where I = 1" in result.stdout
    assert "logged after ArduPilot's current calibration" in result.stdout
    source = open_source(DATA / "mavlogdump_mag.csv")
    assert [(m.id, m.slot, m.n_samples) for m in source.magnetometers] == [("I=0", 0, 500), ("I=1", 1, 500)]
    assert source.read("I=1").samples.shape == (500, 3)


def test_calibrate_fits_each_compass_or_the_one_chosen(tmp_path: Path) -> None:
    path = DATA / "mavlogdump_mag.csv"
    chosen = tmp_path / "one.json"
    result = CliRunner().invoke(cli, ["calibrate", str(path), "--sensor", "I=1", "-m", "ellipsoid", "-o", str(chosen)])
    assert result.exit_code == 0, result.output
    calibration = magfit.Calibration.from_json(chosen.read_text())
    assert calibration.unit == "mG"
    assert_truth(calibration, TRUTH["mavlogdump_mag.csv I=1"], offset_tol=1.0, shape_tol=0.01)
    each = CliRunner().invoke(cli, ["calibrate", str(path), "-m", "ellipsoid", "-o", str(tmp_path / "cal.json")])
    assert each.exit_code == 0, each.output
    for sensor in ("I=0", "I=1"):
        written = magfit.Calibration.from_json((tmp_path / f"cal-{sensor.replace('=', '_')}.json").read_text())
        assert_truth(written, TRUTH[f"mavlogdump_mag.csv {sensor}"], offset_tol=1.0, shape_tol=0.01)


def test_compare_refuses_an_interleaved_file_without_sensor_in_one_line() -> None:
    result = CliRunner().invoke(cli, ["compare", str(DATA / "mavlogdump_mag.csv")])
    assert result.exit_code == 2
    assert "interleaves 2 magnetometers in column 'I' (I=0, I=1)" in result.stderr
    assert "--sensor I=0" in result.stderr and "Traceback" not in result.output
    one = CliRunner().invoke(cli, ["compare", str(DATA / "mavlogdump_mag.csv"), "--sensor", "I=0", "--format", "json"])
    assert one.exit_code == 0, one.output
    (compared,) = json.loads(one.stdout)
    assert compared["unit"] == "mG" and compared["n_rows"] == 500
