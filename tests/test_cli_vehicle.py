"""A vehicle's samples file on the command line: the attitude, reference field and time columns found by name
or named, through the logs' path to ``vector``; the same numbers as ``magfit.fit`` from Python; a missing
stream named with the exact command line and Python call; the methods that work for a vehicle advised; the
unit check's warning printed."""

from __future__ import annotations

import ast
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from scipy.spatial.transform import Rotation

import magfit
from magfit.cli import cli
from magfit.errors import DataFileError
from magfit.findings import Reason
from magfit.pipeline import StreamsMissing
from magfit.vehicle import simulate_vehicle

HEADER = "time,flux_x,flux_y,flux_z,pitch,roll,yaw,ref_n,ref_e,ref_d"


@pytest.fixture(scope="module")
def flight() -> object:
    return simulate_vehicle(
        3000, "flight", rate_hz=10.0, field_strength=50000.0, inclination_deg=64.0, declination_deg=3.0, noise=5.0,
        hard_iron=[800.0, -500.0, 300.0], soft_iron=np.array([[1.05, 0.02, 0.0], [0.02, 0.97, 0.01], [0.0, 0.01, 1.0]]),
        attitude_noise_deg=0.1, seed=3,
    )  # fmt: skip


def table(sim: object, *, radians: bool = False) -> np.ndarray:
    yaw, pitch, roll = Rotation.from_matrix(sim.attitude_measured).as_euler("ZYX", degrees=not radians).T  # type: ignore[attr-defined]
    yaw = np.mod(yaw, 2 * np.pi if radians else 360.0)
    ned = np.tile(sim.field_world, (len(yaw), 1))  # type: ignore[attr-defined]
    return np.column_stack([sim.time_s, sim.samples, pitch, roll, yaw, ned])  # type: ignore[attr-defined]


def python_fit(values: np.ndarray, *, radians: bool = False) -> magfit.Calibration:
    """What a Python user writes: the reference turned into the body frame by the attitude, then fit."""
    attitude = Rotation.from_euler("ZYX", values[:, [6, 4, 5]], degrees=not radians).as_matrix()
    reference = np.einsum("kji,kj->ki", attitude, values[:, 7:10])
    return magfit.fit(values[:, 1:4], method="vector", reference=reference, time_s=values[:, 0])


def write(path: Path, values: np.ndarray, header: bool = True) -> Path:
    np.savetxt(path, values, delimiter=",", header=HEADER if header else "", comments="", fmt="%.10g")
    return path


def test_vector_from_a_named_flight_csv_matches_python_and_the_truth(tmp_path: Path, flight: object) -> None:
    values = table(flight)
    path = write(tmp_path / "flight.csv", values)
    out = tmp_path / "cal.json"
    result = CliRunner().invoke(cli, ["calibrate", str(path), "--unit", "nT", "--method", "vector", "-o", str(out)])
    assert result.exit_code == 0, result.output
    fitted = magfit.Calibration.from_json(out.read_text())
    expected = python_fit(np.loadtxt(path, delimiter=",", skiprows=1))
    np.testing.assert_allclose(fitted.offset, expected.offset, rtol=1e-9, atol=1e-6)
    np.testing.assert_allclose(fitted.matrix, expected.matrix, rtol=1e-9, atol=1e-12)
    # Against the truth: the corrected field in the body frame, within a fraction of a degree.
    corrected, truth = fitted.apply(flight.clean), flight.truth.apply(flight.clean)  # type: ignore[attr-defined]
    cosine = np.sum(corrected * truth, axis=1) / np.linalg.norm(corrected, axis=1) / np.linalg.norm(truth, axis=1)
    assert np.degrees(np.arccos(np.clip(cosine, -1, 1))).mean() < 0.3


def test_a_headerless_file_with_the_columns_named_and_radians(tmp_path: Path, flight: object) -> None:
    values = table(flight, radians=True)
    path = write(tmp_path / "flight.txt", values, header=False)
    result = magfit.calibrate_file(path, method="vector", unit="nT", attitude=[5, 4, 6], reference=[7, 8, 9], time=[0])
    expected = python_fit(np.loadtxt(path, delimiter=","), radians=True)
    np.testing.assert_allclose(result.calibration.offset, expected.offset, rtol=1e-9, atol=1e-6)
    assert any("in radians" in note for note in result.compasses[0].notes)
    cli_run = CliRunner().invoke(
        cli, ["calibrate", str(path), "--unit", "nT", "-m", "vector", "--attitude", "5,4,6", "--reference", "7,8,9",
              "--time", "column 1"],
    )  # fmt: skip
    assert cli_run.exit_code == 0, cli_run.output
    assert f"offset           ({expected.offset[0]:.6g}" in cli_run.stdout


def test_angles_that_could_be_either_unit_are_refused(tmp_path: Path, flight: object) -> None:
    values = table(flight, radians=True)
    values[:, 4:7] = np.clip(values[:, 4:7], -0.9, 0.9)
    path = write(tmp_path / "small.csv", values)
    with pytest.raises(DataFileError, match="angle_unit='deg' or angle_unit='rad'"):
        magfit.calibrate_file(path, method="vector", unit="nT")


def test_a_missing_attitude_names_the_command_line_and_a_python_call_that_parses(
    tmp_path: Path, flight: object
) -> None:
    values = table(flight)[:, :4]
    path = tmp_path / "mag.csv"
    np.savetxt(path, values, delimiter=",", header="time,flux_x,flux_y,flux_z", comments="", fmt="%.10g")
    with pytest.raises(StreamsMissing) as caught:
        magfit.calibrate_file(path, method="vector", unit="nT")
    call = str(caught.value).split("from Python: ", 1)[1]
    ast.parse(call)  # valid Python, not "magfit.fit(samples, --method vector, ...)"
    assert call.startswith(f"magfit.calibrate_file({str(path)!r}, method='vector', unit='nT', attitude=[")
    assert ("method", "vector") in caught.value.remedy
    result = CliRunner().invoke(cli, ["calibrate", str(path), "--unit", "nT", "--method", "vector"])
    assert result.exit_code == 2
    assert f"on the command line: magfit calibrate {path} --method vector --unit nT --attitude ROLL,PITCH,YAW" in (
        result.stderr
    )
    assert "--method vector," not in result.stderr and "Traceback" not in result.output


def test_a_vehicle_s_weak_or_refused_fit_names_what_works(tmp_path: Path, flight: object) -> None:
    path = write(tmp_path / "flight.csv", table(flight))
    try:
        result = magfit.calibrate_file(path, method="auto", unit="nT")
    except magfit.CalibrationError as error:  # refused: the advice rides on the error
        advice = error.advice  # type: ignore[attr-defined]
    else:
        advice = result.compasses[0].advice
    methods = {dict(reason.remedy)["method"] for reason in advice}
    assert {"vector", "gyro", "sphere"} <= methods
    assert all(isinstance(reason, Reason) and reason.code == "vehicle_methods" for reason in advice)
    run = CliRunner().invoke(cli, ["calibrate", str(path), "--unit", "nT"])
    assert f"magfit calibrate {path} --method vector" in run.stderr
    assert "--field-strength wmm --location" in run.stderr


def test_counts_declared_as_microtesla_are_named_in_a_warning(tmp_path: Path) -> None:
    """A field of 1078 "uT" is no place on Earth's: raw counts, said as a warning (unit_mismatch) and exit 0."""
    sim = magfit.simulate(1500, field_strength=1078.0, hard_iron=[10.0, -20.0, 30.0], noise=0.5, seed=4)
    path = tmp_path / "counts.csv"
    np.savetxt(path, sim.samples, delimiter=",", header="mx,my,mz", comments="")
    result = magfit.calibrate_file(path, method="sphere", unit="uT")
    assert [reason.code for reason in result.compasses[0].warnings] == ["unit_mismatch"]
    run = CliRunner().invoke(cli, ["calibrate", str(path), "--unit", "uT", "-m", "sphere"])
    assert run.exit_code == 0
    assert "magfit: warning:" in run.stderr and "counts" in run.stderr
    # The exports that carry a physical unit refuse it unless forced.
    refused = CliRunner().invoke(cli, ["calibrate", str(path), "--unit", "uT", "-m", "sphere", "-f", "adafruit",
                                       "-o", str(tmp_path / "cal.h")])  # fmt: skip
    assert refused.exit_code == 2 and not (tmp_path / "cal.h").exists()


def test_align_from_the_attitude_and_reference_columns(tmp_path: Path) -> None:
    """No accelerometer: the rotation is the vector fit's polar factor, the same as from Python, and near the
    true mounting (upside down, turned 25°)."""
    mounting = Rotation.from_euler("ZYX", [25.0, 0.0, 180.0], degrees=True).as_matrix()
    sim = simulate_vehicle(
        3000, "flight", rate_hz=10.0, field_strength=50000.0, inclination_deg=64.0, declination_deg=3.0, noise=5.0,
        hard_iron=[800.0, -500.0, 300.0], mounting=mounting, attitude_noise_deg=0.1, seed=5,
    )  # fmt: skip
    path = write(tmp_path / "flight.csv", table(sim))
    result = CliRunner().invoke(cli, ["align", str(path), "--unit", "nT"])
    assert result.exit_code == 0, result.output
    lines = [line for line in result.stdout.splitlines() if line.startswith(("rotation", " " * 17 + "("))][:3]
    printed = np.array([[float(v) for v in line.split("(")[1].split(")")[0].split(",")] for line in lines])
    expected = magfit.rotations.polar_decomposition(python_fit(np.loadtxt(path, delimiter=",", skiprows=1)).matrix)[0]
    np.testing.assert_allclose(printed, expected, atol=6e-6)  # printed to 5 decimals
    angle = np.degrees(np.arccos(np.clip((np.trace(expected.T @ mounting) - 1) / 2, -1, 1)))
    assert angle < 0.5
    assert "COMPASS_ORIENT 8 " in result.stdout or "ROTATION_ROLL_180" in result.stdout


@pytest.mark.slow
def test_a_flight_log_s_refusal_or_weak_fit_names_the_log_s_methods(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A DataFlash log of level turns (roll and pitch within ±6°): every remedy is a command that runs on the log,
    with no column to name; never only "tumble it"."""
    import test_sources_motion as motion_log

    def level_turns(t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        a = np.column_stack([0.1 * np.sin(0.31 * t), 0.05 * np.sin(0.23 * t + 1.0), 0.7 * t])
        da = np.column_stack(
            [0.1 * 0.31 * np.cos(0.31 * t), 0.05 * 0.23 * np.cos(0.23 * t + 1.0), np.full_like(t, 0.7)]
        )
        return a, da

    monkeypatch.setattr(motion_log, "euler", level_turns)
    formats, rows = motion_log.dataflash_messages(n_mag=1600)
    path = motion_log.write_bin(tmp_path / "level.bin", formats, rows)
    try:
        advice = magfit.calibrate_file(path, method="ellipsoid").compasses[0].advice
    except magfit.CalibrationError as error:
        advice = error.advice  # type: ignore[attr-defined]
    remedies = [dict(reason.remedy) for reason in advice]
    assert [remedy["method"] for remedy in remedies] == ["vector", "tilt", "gyro", "sphere"]
    assert all(set(remedy) <= {"method", "field_strength", "unit", "sensor"} for remedy in remedies)
    run = CliRunner().invoke(cli, ["calibrate", str(path), "--method", "ellipsoid"])
    assert f"(magfit calibrate {path} --method vector)" in run.stderr
    assert f"(magfit calibrate {path} --method sphere --field-strength wmm" in run.stderr


@pytest.mark.slow
def test_gyro_from_a_samples_file_matches_python_and_the_truth(tmp_path: Path) -> None:
    sim = simulate_vehicle(
        6000, "car", rate_hz=20.0, field_strength=50.0, noise=0.05, hard_iron=[8.0, -5.0, 3.0],
        soft_iron=np.array([[1.05, 0.02, 0.0], [0.02, 0.97, 0.01], [0.0, 0.01, 1.0]]), gyro_noise=0.001, seed=2,
    )  # fmt: skip
    path = tmp_path / "car.csv"
    values = np.column_stack([sim.time_s, sim.samples, sim.gyro, sim.accel])
    np.savetxt(path, values, delimiter=",", header="time,mx,my,mz,gx,gy,gz,ax,ay,az", comments="", fmt="%.12g")
    read = np.loadtxt(path, delimiter=",", skiprows=1)
    expected = magfit.fit(read[:, 1:4], method="gyro", gyro=read[:, 4:7], time_s=read[:, 0], accel=read[:, 7:10])
    run = CliRunner().invoke(
        cli, ["calibrate", str(path), "-m", "gyro", "--unit", "uT", "-o", str(tmp_path / "c.json")]
    )
    assert run.exit_code == 0, run.output
    fitted = magfit.Calibration.from_json((tmp_path / "c.json").read_text())
    np.testing.assert_allclose(fitted.offset, expected.offset, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(fitted.offset, sim.hard_iron, atol=0.2)  # the truth
    # PX4's ulog2csv `timestamp` counts microseconds since boot: read as such, said in a note.
    values[:, 0] = 1.7e9 + np.round(values[:, 0] * 1e6)
    stamped = tmp_path / "car_us.csv"
    np.savetxt(stamped, values, delimiter=",", header="timestamp,mx,my,mz,gx,gy,gz,ax,ay,az", comments="", fmt="%.12g")
    compass = magfit.calibrate_file(stamped, method="gyro", unit="uT").compasses[0]
    np.testing.assert_allclose(compass.calibration.offset, expected.offset, atol=1e-4)
    assert any("microseconds" in note for note in compass.notes)


def test_a_quaternion_and_the_ros_convention_give_the_same_fit(tmp_path: Path, flight: object) -> None:
    values = table(flight)
    expected = python_fit(values)
    rotation = Rotation.from_matrix(flight.attitude_measured)  # type: ignore[attr-defined]
    wxyz = rotation.as_quat()[:, [3, 0, 1, 2]]
    quaternion = tmp_path / "quaternion.csv"
    body = np.column_stack([values[:, :4], wxyz, values[:, 7:10]])
    np.savetxt(quaternion, body, delimiter=",", header="time,mx,my,mz,qw,qx,qy,qz,ref_n,ref_e,ref_d", comments="")
    fitted = magfit.calibrate_file(quaternion, method="vector", unit="nT").calibration
    np.testing.assert_allclose(fitted.offset, expected.offset, rtol=1e-6, atol=1e-3)
    # ROS: FLU body -> ENU, yaw counter-clockwise from east; the reference as E, N, U.
    swap, flip = np.array([[0.0, 1, 0], [1, 0, 0], [0, 0, -1]]), np.diag([1.0, -1, -1])
    enu = Rotation.from_matrix(np.einsum("ij,njk,kl->nil", swap, rotation.as_matrix(), flip))
    yaw, pitch, roll = enu.as_euler("ZYX", degrees=True).T
    ros = tmp_path / "ros.csv"
    columns = [values[:, :4], roll, pitch, yaw, values[:, 7:10] @ swap.T]
    np.savetxt(
        ros, np.column_stack(columns), delimiter=",", header="t,mx,my,mz,roll,pitch,yaw,ref_e,ref_n,ref_u", comments=""
    )
    run = magfit.calibrate_file(
        ros, method="vector", unit="nT", reference=["ref_e", "ref_n", "ref_u"], attitude_convention="enu"
    )
    np.testing.assert_allclose(run.calibration.offset, expected.offset, rtol=1e-6, atol=1e-3)


def test_the_world_magnetic_model_at_the_file_s_own_place(tmp_path: Path, flight: object) -> None:
    pytest.importorskip("pygeomag")
    from magfit.geomag import field_at

    values = table(flight)[:, :7]
    place = np.tile([47.4, 8.5, 500.0], (len(values), 1))
    path = tmp_path / "survey.csv"
    header = "time,mx,my,mz,pitch,roll,yaw,lat,lon,alt"
    np.savetxt(path, np.column_stack([values, place]), delimiter=",", header=header, comments="", fmt="%.10g")
    result = magfit.calibrate_file(path, method="vector", unit="nT", date="2026-04-14")
    read = np.loadtxt(path, delimiter=",", skiprows=1)
    attitude = Rotation.from_euler("ZYX", read[:, [6, 4, 5]], degrees=True).as_matrix()
    ned = field_at(47.4, 8.5, 0.5, date="2026-04-14").vector_in("nT")
    expected = magfit.fit(
        read[:, 1:4], method="vector", reference=np.einsum("kji,j->ki", attitude, ned), time_s=read[:, 0]
    )
    np.testing.assert_allclose(result.calibration.offset, expected.offset, rtol=1e-9, atol=1e-6)
    without_unit = CliRunner().invoke(cli, ["calibrate", str(path), "-m", "vector"])
    assert without_unit.exit_code == 2 and "physical unit" in without_unit.stderr


def test_inspect_names_the_streams_and_missing_rows_are_counted_or_refused(tmp_path: Path, flight: object) -> None:
    values = table(flight)
    values[10, 5] = np.nan  # one roll missing
    path = write(tmp_path / "flight.csv", values)
    shown = CliRunner().invoke(cli, ["inspect", str(path)])
    assert "streams          attitude: roll, pitch, yaw" in shown.stdout
    assert "reference: ref_n, ref_e, ref_d" in shown.stdout
    compass = magfit.calibrate_file(path, method="vector", unit="nT").compasses[0]
    assert (compass.n_rows, compass.n_skipped) == (len(values), 1)
    assert compass.calibration.source is not None and compass.calibration.source.column_indices == (1, 2, 3)
    with pytest.raises(DataFileError, match="data row 11 holds a missing value"):
        magfit.calibrate_file(path, method="vector", unit="nT", nonfinite="error")


def test_a_headerless_file_s_missing_attitude_points_at_the_columns_that_look_like_it(tmp_path: Path) -> None:
    from test_columns_wide import flight_table

    path = tmp_path / "wide.csv"
    np.savetxt(path, flight_table(2500, seed=1), delimiter=",", fmt="%.3f")
    run = CliRunner().invoke(cli, ["calibrate", str(path), "--unit", "nT", "-m", "vector"])
    assert run.exit_code == 2
    assert "columns 4,5,6 (0-based) look like angles" in run.stderr
    assert "columns 7,8,9 (0-based) like a reference field" in run.stderr


def test_compare_runs_vector_on_a_samples_file_s_own_columns(tmp_path: Path, flight: object) -> None:
    path = write(tmp_path / "flight.csv", table(flight))
    run = CliRunner().invoke(
        cli, ["compare", str(path), "--methods", "sphere,vector,gyro", "--unit", "nT", "--format", "csv"]
    )
    assert run.exit_code == 0, run.output
    rows = {line.split(",")[1]: line.split(",") for line in run.stdout.splitlines()[1:]}
    expected = python_fit(np.loadtxt(path, delimiter=",", skiprows=1))
    header = run.stdout.splitlines()[0].split(",")
    offset = [float(rows["vector"][header.index(f"offset_{axis}")]) for axis in "xyz"]
    np.testing.assert_allclose(offset, expected.offset, rtol=1e-5)
    assert rows["gyro"][2] == "failed"
    assert "the file holds no gyroscope columns" in run.stderr and "--gyro X,Y,Z" in run.stderr


def test_what_looks_like_a_vehicle() -> None:
    """Level turns (a ring tilted by ±10°) look like a vehicle's; a tumble, a hemisphere and a still sensor do
    not (a still sensor is helped by no method: only by recording again)."""
    from magfit.pipeline.advice import looks_like_vehicle

    rng = np.random.default_rng(0)
    heading = rng.uniform(0, 2 * np.pi, 3000)
    tilt = np.radians(rng.uniform(-10, 10, 3000))
    ring = 50 * np.column_stack([np.cos(heading) * 0.45, np.sin(heading) * 0.45, 0.9 + 0.45 * np.sin(tilt)])
    tumble = rng.normal(size=(3000, 3))
    tumble = 50 * tumble / np.linalg.norm(tumble, axis=1, keepdims=True)
    hemisphere = tumble * np.where(tumble[:, 2:] < 0, -1, 1)
    still = np.tile([20.0, -5.0, 44.0], (3000, 1)) + rng.normal(scale=0.1, size=(3000, 3))

    def shape(samples: np.ndarray) -> bool:
        return looks_like_vehicle(np.cov(samples.T), float(np.mean(np.sum(samples**2, axis=1))))

    assert shape(ring)
    assert not shape(tumble) and not shape(hemisphere) and not shape(still)


def test_stream_columns_for_a_method_that_does_not_read_them_are_refused(tmp_path: Path, flight: object) -> None:
    path = write(tmp_path / "flight.csv", table(flight))
    with pytest.raises(magfit.OptionError, match="sphere takes the samples alone"):
        magfit.calibrate_file(path, method="sphere", attitude=["roll", "pitch", "yaw"])
    run = CliRunner().invoke(cli, ["calibrate", str(path), "-m", "sphere", "--gyro", "1,2,3"])
    assert run.exit_code == 2 and "--gyro" in run.stderr


@pytest.mark.slow
def test_a_real_imu_npz_through_gyro_with_its_rates_in_degrees(real_data_dir: Path) -> None:
    """ensta_tlefloch_imu/raw_data.npz (time, accel, gyro in °/s, mag keys; ../shared/data/real): the gyro
    method reads its keys by name; rates in °/s are refused as rad/s with the option that says so, and with it
    the offsets agree with auto's supported fit within 2 % of the field."""
    path = real_data_dir / "ensta_tlefloch_imu" / "raw_data.npz"
    refused = CliRunner().invoke(cli, ["calibrate", str(path), "-m", "gyro"])
    assert refused.exit_code == 2 and "say so with --gyro-unit deg/s" in refused.stderr
    gyro = magfit.calibrate_file(path, method="gyro", gyro_unit="deg/s").calibration
    auto = magfit.calibrate_file(path, method="auto").calibration
    assert np.linalg.norm(gyro.offset - auto.offset) < 0.02 * auto.field_strength
