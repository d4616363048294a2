"""Defects found by a second adversarial review of the command line, each reproduced and marked xfail (strict).

Each test states what the promise asks (README: a calibration only when the samples support it, its stated
one-sigma covering its real error against the simulated truth, the right reason code and exit code) and fails
today because of the defect named in its reason.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

import magfit
from magfit.cli import cli

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
from _common import heading_error_deg


def _write(path: Path, samples: np.ndarray) -> None:
    np.savetxt(path, samples, fmt="%.6f", delimiter=",", header="mx,my,mz", comments="")


def test_robust_on_a_short_flight_states_a_one_sigma_that_covers_its_error(tmp_path: Path) -> None:
    sim = magfit.scenario("mpu9250", "steel").simulate(30, seed=1, orientations="flight")
    path, cal = tmp_path / "flight.csv", tmp_path / "cal.json"
    _write(path, sim.samples)
    result = CliRunner().invoke(cli, ["calibrate", str(path), "--method", "robust", "-o", str(cal)])
    if result.exit_code == 1:  # refused, as every other method refuses these samples
        return
    assert result.exit_code == 0, result.output
    fitted = magfit.Calibration.from_json(cal.read_text())
    stated = fitted.diagnostics.uncertainty.heading_sigma_deg
    assert heading_error_deg(fitted, sim) <= 3 * stated, (heading_error_deg(fitted, sim), stated)


def test_the_true_field_strength_is_not_called_a_contradiction(tmp_path: Path) -> None:
    sim = magfit.simulate(
        1500, hard_iron=[10, -5, 20], field_strength=50.0, inclination_deg=60, noise=0.3, orientations="yaw", seed=3
    )
    path = tmp_path / "level.csv"
    _write(path, sim.samples)
    result = CliRunner().invoke(cli, ["calibrate", str(path), "--method", "sphere", "--field-strength", "50"])
    assert result.exit_code in (0, 1), result.output
    with pytest.raises(magfit.CalibrationError) as refused:
        magfit.fit(sim.samples, method="sphere", field_strength=50.0)
    # Ground truth: the field strength given is the simulated one (50); level turns leave the z offset open
    # (single_axis / undetermined), they cannot contradict the field strength.
    assert "field_mismatch" not in refused.value.codes, refused.value


@pytest.mark.slow
@pytest.mark.xfail(strict=True, reason="fleet: combined rows keyed by the flights' paths: three compasses, one row x3")
def test_fleet_combines_each_compass_of_a_vehicle_apart(tmp_path: Path) -> None:
    log = (Path(__file__).parent / "data" / "ardupilot_real" / "copter33_log171_trimmed.bin").read_bytes()
    vehicle = tmp_path / "copter"
    vehicle.mkdir()
    (vehicle / "a.bin").write_bytes(log)  # two flights of one vehicle with three compasses
    (vehicle / "b.bin").write_bytes(log)
    table = tmp_path / "fleet.csv"
    result = CliRunner().invoke(cli, ["fleet", str(vehicle), "-o", str(table), "--workers", "1", "--no-resume"])
    assert result.exit_code in (0, 1), result.output
    import csv

    rows = list(csv.DictReader(table.open()))
    flights = {(r["sensor"], r["device_id"]) for r in rows if r["kind"] == "flight"}
    combined = [(r["sensor"], r["device_id"]) for r in rows if r["kind"] == "combined"]
    assert len(flights) == 3, flights  # MAG/0 73225, MAG/1 131874, MAG/2 66826
    # Each compass's two flights combined once, under its own name and device id.
    assert sorted(combined) == sorted(flights), combined


def _car(seed: int = 1) -> tuple[object, dict[str, np.ndarray]]:
    """A car's recording (simulated, field 50 µT, inclination 60°): its truth and its columns (time s, mx..mz µT,
    roll/pitch/yaw degrees body to NED, reference N/E/D, gyro rad/s, accel m/s²)."""
    from scipy.spatial.transform import Rotation

    from magfit.vehicle import simulate_vehicle

    rng = np.random.default_rng(seed)
    w = np.eye(3) + rng.normal(0, 0.08, (3, 3))
    sim = simulate_vehicle(
        3000, "car", soft_iron=(w + w.T) / 2, hard_iron=rng.normal(0, 0.5, 3) * 50,
        mounting=Rotation.from_euler("xyz", rng.normal(0, 5, 3), degrees=True).as_matrix(), field_strength=50.0,
        inclination_deg=60, declination_deg=5, noise=0.3, attitude_noise_deg=0.5, gyro_noise=0.002,
        gyro_bias=[0.01, -0.005, 0.003], accel_noise=0.05, lag_s=0.02, seed=seed,
    )  # fmt: skip
    ypr = Rotation.from_matrix(sim.attitude_measured).as_euler("ZYX", degrees=True)
    ref = np.tile(sim.field_world, (len(sim.samples), 1))
    names = "time mx my mz roll pitch yaw ref_n ref_e ref_d gx gy gz ax ay az".split()
    values = [sim.time_s, *sim.samples.T, ypr[:, 2], ypr[:, 1], ypr[:, 0], *ref.T, *sim.gyro.T, *sim.accel.T]
    return sim, dict(zip(names, values, strict=True))


def _save(path: Path, columns: dict[str, np.ndarray]) -> None:
    np.savetxt(path, np.column_stack(list(columns.values())), fmt="%.6f", delimiter=",", header=",".join(columns),
               comments="")  # fmt: skip


def _heading_error_on_recording(cal: magfit.Calibration, sim: object, raw: np.ndarray) -> float:
    """RMS heading error (degrees) of a vehicle-frame calibration over the recording, with the TRUE attitude."""
    world = np.einsum("kij,kj->ki", sim.attitude, cal.apply(raw))  # type: ignore[attr-defined]
    truth = np.arctan2(sim.field_world[1], sim.field_world[0])  # type: ignore[attr-defined]
    wrapped = (np.degrees(np.arctan2(world[:, 1], world[:, 0]) - truth) + 180.0) % 360.0 - 180.0
    return float(np.sqrt(np.mean(wrapped**2)))


@pytest.mark.xfail(strict=True, reason="gyro method, magnetometer x/y swapped (left-handed): exit 0, heading 180° off")
def test_gyro_with_a_left_handed_magnetometer_is_not_a_confident_reversed_field(tmp_path: Path) -> None:
    sim, columns = _car()
    columns["mx"], columns["my"] = columns["my"], columns["mx"]  # a wiring or driver mix-up: left-handed axes
    path, cal = tmp_path / "car.csv", tmp_path / "cal.json"
    _save(path, columns)
    result = CliRunner().invoke(cli, ["calibrate", str(path), "--unit", "uT", "--method", "gyro", "-o", str(cal)])
    if result.exit_code in (1, 2):  # refused or told the axes' handedness: honest
        return
    assert result.exit_code == 0, result.output
    fitted = magfit.Calibration.from_json(cal.read_text())
    error = _heading_error_on_recording(fitted, sim, sim.clean[:, [1, 0, 2]])  # type: ignore[attr-defined]
    assert error <= 3 * fitted.gyro.heading_sigma_deg, (error, fitted.gyro.heading_sigma_deg)


@pytest.mark.xfail(strict=True, reason="vector method, time in ms: blamed on the gyro's unit (no time_unit code)")
def test_vector_with_time_in_milliseconds_names_the_time_column(tmp_path: Path) -> None:
    _, columns = _car()
    columns["time"] = columns["time"] * 1000.0  # the logger's milliseconds in a column named 'time'
    path = tmp_path / "car.csv"
    _save(path, columns)
    result = CliRunner().invoke(cli, ["calibrate", str(path), "--unit", "uT", "--method", "vector"])
    assert result.exit_code == 2, result.output
    with pytest.raises(magfit.MagfitError) as refused:
        magfit.calibrate_file(path, method="vector", unit="uT")
    # Ground truth: the gyroscope is in rad/s; the time column is what is in the wrong unit (the gyro method
    # says so with time_unit on the same file).
    assert "time_unit" in refused.value.codes, (refused.value.codes, str(refused.value)[:200])


@pytest.mark.xfail(strict=True, reason="a ROS (ENU/FLU) recording read as NED: exit 0, heading 145° off, ±2.3° stated")
def test_vector_on_a_ros_recording_without_its_convention_is_not_confidently_mirrored(tmp_path: Path) -> None:
    from scipy.spatial.transform import Rotation

    sim, columns = _car()
    ned = Rotation.from_euler("ZYX", np.column_stack([columns["yaw"], columns["pitch"], columns["roll"]]), degrees=True)
    ned_to_enu, frd_to_flu = np.array([[0.0, 1, 0], [1, 0, 0], [0, 0, -1]]), np.diag([1.0, -1, -1])
    yaw, pitch, roll = Rotation.from_matrix(ned_to_enu @ ned.as_matrix() @ frd_to_flu).as_euler("ZYX", degrees=True).T
    columns |= {"roll": roll, "pitch": pitch, "yaw": yaw}  # ROS: body forward-left-up to East-North-Up
    columns |= {"ref_n": columns["ref_e"], "ref_e": columns["ref_n"], "ref_d": -columns["ref_d"]}  # E, N, U
    for axis in ("gy", "gz", "ay", "az"):  # the IMU in the body's forward-left-up axes
        columns[axis] = -columns[axis]
    path, cal = tmp_path / "ros.csv", tmp_path / "cal.json"
    _save(path, columns)
    enu = CliRunner().invoke(cli, ["calibrate", str(path), "--unit", "uT", "-m", "vector", "--attitude-convention",
                                   "enu", "-o", str(cal)])  # fmt: skip
    assert enu.exit_code == 0, enu.output  # told the convention: the right calibration
    right = magfit.Calibration.from_json(cal.read_text())
    assert _heading_error_on_recording(right, sim, sim.clean) < 3 * right.diagnostics.uncertainty.heading_sigma_deg
    result = CliRunner().invoke(cli, ["calibrate", str(path), "--unit", "uT", "-m", "vector", "-o", str(cal)])
    if result.exit_code in (1, 2):  # the accelerometer's gravity points up in the NED reading: refused or told
        return
    fitted = magfit.Calibration.from_json(cal.read_text())
    error = _heading_error_on_recording(fitted, sim, sim.clean)  # type: ignore[attr-defined]
    assert error <= 3 * fitted.diagnostics.uncertainty.heading_sigma_deg, error
