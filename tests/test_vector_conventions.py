"""The attitude's convention (NED or ROS's ENU) and the time's unit, checked against the data by the methods that
read a samples file's attitude (vector, tilt): a ROS file read as NED fits exactly, into a body frame turned 180°
about its forward axis, so only the accelerometer's gravity (or an unearthly reference) can tell."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from scipy.spatial.transform import Rotation

import magfit
from magfit.cli import cli
from magfit.pipeline.streams import _unearthly
from magfit.vehicle import simulate_vehicle

#: ENU <-> NED and FLU <-> FRD.
SWAP, FLIP = np.array([[0.0, 1, 0], [1, 0, 0], [0, 0, -1]]), np.diag([1.0, -1, -1])


@pytest.fixture(scope="module")
def car() -> object:
    rng = np.random.default_rng(4)
    w = np.eye(3) + rng.normal(0, 0.05, (3, 3))
    return simulate_vehicle(
        1500, "car", soft_iron=(w + w.T) / 2, hard_iron=[12.0, -7.0, 20.0],
        mounting=Rotation.from_euler("xyz", [3, -2, 4], degrees=True).as_matrix(), field_strength=50.0,
        inclination_deg=60, declination_deg=5, noise=0.3, attitude_noise_deg=0.5, gyro_noise=0.002,
        accel_noise=0.05, seed=4,
    )  # fmt: skip


def _columns(sim: object, ros: bool, time_scale: float = 1.0) -> dict[str, np.ndarray]:
    """The recording's columns, NED (body forward-right-down) or ROS (forward-left-up to East-North-Up, the
    reference as E, N, U, the IMU in forward-left-up axes)."""
    attitude = sim.attitude_measured  # type: ignore[attr-defined]
    imu = FLIP if ros else np.eye(3)
    if ros:
        attitude = np.einsum("ij,njk,kl->nil", SWAP, attitude, FLIP)
    yaw, pitch, roll = Rotation.from_matrix(attitude).as_euler("ZYX", degrees=True).T
    ref = np.tile(sim.field_world @ (SWAP.T if ros else np.eye(3)), (len(sim.samples), 1))  # type: ignore[attr-defined]
    names = "time mx my mz roll pitch yaw ref_n ref_e ref_d gx gy gz ax ay az".split()
    values = [sim.time_s * time_scale, *sim.samples.T, roll, pitch, yaw, *ref.T,  # type: ignore[attr-defined]
              *(sim.gyro @ imu).T, *(sim.accel @ imu).T]  # type: ignore[attr-defined]  # fmt: skip
    return dict(zip(names, values, strict=True))


def _save(path: Path, columns: dict[str, np.ndarray], leave_out: str = "") -> Path:
    kept = {name: values for name, values in columns.items() if name[:1] not in leave_out or name in ("mx", "my", "mz")}
    np.savetxt(path, np.column_stack(list(kept.values())), fmt="%.6f", delimiter=",", header=",".join(kept),
               comments="")  # fmt: skip
    return path


def _heading_error(cal: magfit.Calibration, sim: object) -> float:
    """RMS heading error (degrees) of a vehicle-frame calibration, with the true attitude (body FRD -> NED)."""
    world = np.einsum("kij,kj->ki", sim.attitude, cal.apply(sim.clean))  # type: ignore[attr-defined]
    truth = np.arctan2(sim.field_world[1], sim.field_world[0])  # type: ignore[attr-defined]
    wrapped = (np.degrees(np.arctan2(world[:, 1], world[:, 0]) - truth) + 180.0) % 360.0 - 180.0
    return float(np.sqrt(np.mean(wrapped**2)))


@pytest.mark.parametrize("method", ["vector", "tilt"])
def test_a_ros_file_read_as_ned_is_refused_and_names_the_convention(tmp_path: Path, car: object, method: str) -> None:
    path = _save(tmp_path / "ros.csv", _columns(car, ros=True))
    with pytest.raises(magfit.OptionError) as refused:
        magfit.calibrate_file(path, method=method, unit="uT")
    assert refused.value.codes == ("attitude_convention",)
    assert refused.value.remedy == (("attitude_convention", "enu"),)
    result = CliRunner().invoke(cli, ["calibrate", str(path), "--unit", "uT", "-m", method])
    assert result.exit_code == 2, result.output
    assert "--attitude-convention enu" in result.output
    # Told the convention, the calibration is the right one: its heading error against the truth within 3 sigma.
    right = magfit.calibrate_file(path, method=method, unit="uT", attitude_convention="enu").calibration
    stated = right.diagnostics.uncertainty.heading_sigma_deg
    assert _heading_error(right, car) < 3 * stated, (_heading_error(right, car), stated)


def test_the_ros_file_fits_as_the_ned_one_once_its_convention_is_given(tmp_path: Path, car: object) -> None:
    ned = magfit.calibrate_file(_save(tmp_path / "ned.csv", _columns(car, ros=False)), method="vector", unit="uT")
    ros = magfit.calibrate_file(_save(tmp_path / "ros.csv", _columns(car, ros=True)), method="vector", unit="uT",
                                attitude_convention="enu")  # fmt: skip
    # The IMU's forward-left-up columns are turned with the attitude: the same fit, to the rounding of the file.
    np.testing.assert_allclose(ros.calibration.offset, ned.calibration.offset, atol=0.05)
    np.testing.assert_allclose(ros.calibration.matrix, ned.calibration.matrix, atol=2e-3)
    assert _heading_error(ned.calibration, car) < 3 * ned.calibration.diagnostics.uncertainty.heading_sigma_deg


def test_a_ned_file_read_as_ros_is_refused_and_names_ned(tmp_path: Path, car: object) -> None:
    path = _save(tmp_path / "ned.csv", _columns(car, ros=False))
    with pytest.raises(magfit.OptionError) as refused:
        magfit.calibrate_file(path, method="vector", unit="uT", attitude_convention="enu")
    assert refused.value.codes == ("attitude_convention",)
    assert refused.value.remedy == (("attitude_convention", "ned"),)


def test_without_an_accelerometer_an_unearthly_reference_says_which_convention_fits(tmp_path: Path,
                                                                                    car: object) -> None:  # fmt: skip
    # No accelerometer: the fit is exact either way (the frames differ by a rotation); only the reference's
    # declination, 85° at an inclination of 60°, which the Earth's field has nowhere, tells.
    path = _save(tmp_path / "ros.csv", _columns(car, ros=True), leave_out="a")
    run = magfit.calibrate_file(path, method="vector", unit="uT")
    notes = run.compasses[0].notes
    assert any("attitude_convention='enu'" in note for note in notes), notes
    told = magfit.calibrate_file(path, method="vector", unit="uT", attitude_convention="enu").compasses[0]
    assert not any("attitude_convention=" in note for note in told.notes), told.notes
    assert _heading_error(told.calibration, car) < 3 * told.calibration.diagnostics.uncertainty.heading_sigma_deg


def test_the_earths_field_is_never_unearthly_and_its_ros_reading_is() -> None:
    pytest.importorskip("pygeomag")
    from magfit.geomag import field_at

    def field(lat: float, lon: float) -> np.ndarray:
        return np.asarray(field_at(lat, lon, 0.0, date="2026-01-01").vector_in("uT"))[None, :]

    for lat, lon in ((47.4, 8.5), (-33.9, 151.2), (37.8, -122.4), (64.1, -21.9), (-54.8, -68.3), (78.2, 15.6)):
        assert _unearthly(field(lat, lon)) == "", (lat, lon)
    # Where the field dips less than 50° (most of the tropics and subtropics), its ENU columns read as NED are
    # named: a declination near 90°.
    for lat, lon in ((1.3, 103.8), (-1.3, 36.8), (19.4, -99.1), (30.0, 31.2), (19.1, 72.9), (-12.0, -77.0)):
        assert _unearthly(field(lat, lon)) == "", (lat, lon)
        assert "East, North, Up" in _unearthly(field(lat, lon) @ SWAP.T), (lat, lon)


def test_time_in_milliseconds_is_named_not_the_gyro(car: object) -> None:
    reference = np.einsum("kji,j->ki", car.attitude_measured, car.field_world)  # type: ignore[attr-defined]
    samples, time_s, gyro = car.samples, car.time_s, car.gyro  # type: ignore[attr-defined]
    common = {"method": "vector", "reference": reference, "accel": car.accel}  # type: ignore[attr-defined]
    with pytest.raises(magfit.OptionError) as refused:
        magfit.fit(samples, time_s=time_s * 1000.0, gyro=gyro, **common)
    assert refused.value.codes == ("time_unit",)
    assert refused.value.remedy == (("time_s", "time_s / 1000"),)
    with pytest.raises(magfit.OptionError) as refused:
        magfit.fit(samples, time_s=time_s, gyro=np.degrees(gyro), **common)
    assert refused.value.codes == ("gyro_unit",)
    # In seconds and rad/s: fitted, its heading error against the truth within 3 sigma.
    fitted = magfit.fit(samples, time_s=time_s, gyro=gyro, **common)
    assert _heading_error(fitted, car) < 3 * fitted.diagnostics.uncertainty.heading_sigma_deg


def test_real_logs_read_gravity_up_and_their_mirror_is_refused() -> None:
    """A real ArduPilot log (tests/data/ardupilot_real, README there): its attitude and accelerometer agree (the
    mean specific force −1.00 of |a| along down); its attitude in ROS's convention with the IMU in its axes (the
    reading of a ROS driver that breaks REP-145) is refused with the code."""
    import dataclasses

    from magfit.pipeline.streams import _check_attitude_up
    from magfit.sources import open_source

    source = open_source(Path(__file__).parent / "data" / "ardupilot_real" / "copter462_head_80k.bin")
    motion = source.read_motion(source.magnetometers[0].id)
    _check_attitude_up(source, motion, "log")  # no refusal
    mirrored = dataclasses.replace(
        motion, attitude=np.einsum("ij,njk,kl->nil", SWAP, motion.attitude, FLIP), accel=motion.accel @ FLIP
    )
    with pytest.raises(magfit.DataFileError) as refused:
        _check_attitude_up(source, mirrored, "log")
    assert refused.value.codes == ("attitude_convention",)


def test_a_comparison_of_a_ros_file_read_as_ned_runs_the_methods_without_the_attitude(tmp_path: Path,
                                                                                      car: object) -> None:  # fmt: skip
    path = _save(tmp_path / "ros.csv", _columns(car, ros=True))
    result = CliRunner().invoke(cli, ["compare", str(path), "--unit", "uT", "--methods", "vector,gyro"])
    assert result.exit_code in (0, 1), result.output
    assert "vector failed" in result.output and "--attitude-convention enu" in result.output, result.output
    assert "gyro failed" not in result.output, result.output
