"""magfit.alignment against the truth of simulated vehicles (magfit.vehicle): the rotation, its one-sigma, the
rotations the motion does not determine, mirrors, the nearest firmware rotations, bad input."""

from __future__ import annotations

import re

import numpy as np
import pytest

from magfit import CalibrationError, OptionError, SampleError
from magfit.alignment import align
from magfit.rotations import angle_between_deg, euler_matrix
from magfit.vehicle import GRAVITY, simulate_vehicle

#: Accelerometer noise equivalent to 1° of tilt per sample (as 1° of attitude noise).
ONE_DEGREE = GRAVITY * np.sin(np.radians(1.0))


def _vehicle(motion: str, mounting: np.ndarray, n: int, seed: int = 1, **options: float):
    sim = simulate_vehicle(
        n, motion, mounting=mounting, noise=0.005, accel_noise=ONE_DEGREE, gyro_noise=0.002, seed=seed, **options
    )
    return sim, sim.truth_sensor.apply(sim.samples)


@pytest.mark.parametrize(
    "angles",
    [(5.0, 0.0, 0.0), (10.0, -20.0, 30.0), (-35.0, 12.0, -25.0), (180.0, 0.0, 90.0), (0.0, 90.0, 0.0)],
)
@pytest.mark.slow
def test_tumble_recovers_the_mounting_within_half_a_degree(angles):
    mounting = euler_matrix(*angles)
    sim, calibrated = _vehicle("tumble", mounting, 4000)
    # A hand-held tumble turns all the time, about the sensor itself: no rate gate.
    result = align(calibrated, sim.accel, inclination_deg=64.0, max_rate_dps=None)
    error = angle_between_deg(result.matrix, mounting)
    assert error < 0.5
    assert result.verdict == "supported" and not result.mirror
    # The one-sigma is honest: the error is within a few of them, and they are not absurdly wide.
    assert error < 5.0 * np.linalg.norm(result.axis_sigma_deg)
    assert np.all(result.axis_sigma_deg < 0.5)
    assert np.allclose(euler_matrix(result.roll_deg, result.pitch_deg, result.yaw_deg), result.matrix, atol=1e-9)


def test_standard_rotation_is_named_for_each_firmware():
    # 180° about x, as between the magnetometer and the accelerometer of the real MPU-9250 rig
    # (../shared/data/real/mxl_umich_mpu9250_rm3100).
    sim, calibrated = _vehicle("tumble", euler_matrix(180.0, 0.0, 0.0), 3000, seed=2)
    result = align(calibrated, sim.accel, inclination_deg=64.0, max_rate_dps=None)
    ardupilot, px4 = result.nearest_for("ardupilot"), result.nearest_for("px4")
    assert (ardupilot.rotation.id, ardupilot.rotation.name) == (8, "ROTATION_ROLL_180")
    assert (px4.rotation.id, px4.parameter) == (8, "CAL_MAG0_ROT")
    assert result.nearest_for("betaflight").rotation.name == "CW180_DEG_FLIP"
    assert ardupilot.rotation.angle_deg < 0.5
    with pytest.raises(OptionError, match="valid firmwares"):
        result.nearest_for("nuttx")


def test_off_table_mounting_reports_the_angle_to_the_nearest_entry():
    sim, calibrated = _vehicle("tumble", euler_matrix(0.0, 0.0, 20.0), 3000, seed=3)
    result = align(calibrated, sim.accel, inclination_deg=64.0, max_rate_dps=None)
    nearest = result.nearest_for("ardupilot").rotation
    assert nearest.name == "ROTATION_NONE"
    assert abs(nearest.angle_deg - 20.0) < 0.5
    assert abs(result.yaw_deg - 20.0) < 0.5


def test_fitted_inclination_matches_the_field():
    sim, calibrated = _vehicle("tumble", euler_matrix(10.0, -20.0, 30.0), 4000, seed=4, inclination_deg=58.0)
    result = align(calibrated, sim.accel, max_rate_dps=None)
    assert result.inclination_fitted
    assert abs(result.inclination_deg - 58.0) < 0.5
    assert 0.0 < result.inclination_sigma_deg < 0.5
    assert angle_between_deg(result.matrix, sim.mounting) < 0.5


def test_mirror_is_detected_and_the_inverted_axis_named():
    # Sensor z inverted (a left-handed magnetometer), then turned 90° in yaw.
    mounting = euler_matrix(0.0, 0.0, 90.0) @ np.diag([1.0, 1.0, -1.0])
    sim, calibrated = _vehicle("tumble", mounting, 3000, seed=5)
    result = align(calibrated, sim.accel, inclination_deg=64.0, max_rate_dps=None)
    assert result.mirror and np.linalg.det(result.matrix) < 0
    assert np.abs(result.matrix - mounting).max() < 0.01
    # Inverting the named axis leaves a table rotation (within the fit's error).
    assert result.nearest_for("ardupilot").rotation.angle_deg < 0.5
    assert np.abs(result.proper_matrix - result.nearest_for("ardupilot").rotation.matrix).max() < 0.01
    assert result.verdict == "weak"
    assert any("mirror image" in w and f"invert its {result.inverted_axis} axis" in w for w in result.warnings)


def test_gravity_with_the_wrong_sign_shows_as_a_mirror():
    sim, calibrated = _vehicle("tumble", np.eye(3), 2000, seed=6)
    result = align(calibrated, -sim.accel, inclination_deg=64.0, max_rate_dps=None)
    assert result.mirror
    assert any("specific force" in w for w in result.warnings)


@pytest.mark.slow
def test_level_yaw_turns_leave_the_mount_yaw_undetermined():
    sim, calibrated = _vehicle("yaw", euler_matrix(10.0, -20.0, 30.0), 6000, seed=7)
    with pytest.raises(CalibrationError, match=r"body z \(down; the mount's yaw\) is not determined"):
        align(calibrated, sim.accel, inclination_deg=64.0, gyro=sim.gyro, time_s=sim.time_s)
    result = align(
        calibrated, sim.accel, inclination_deg=64.0, gyro=sim.gyro, time_s=sim.time_s, allow_undetermined=True
    )
    assert result.verdict == "refused"
    # What the motion does determine, the tilt of the mount (where body down lies in the sensor's axes), is right.
    down_fitted, down_true = result.matrix.T @ [0, 0, 1], sim.mounting.T @ [0, 0, 1]
    assert np.degrees(np.arccos(np.clip(down_fitted @ down_true, -1, 1))) < 0.5


@pytest.mark.slow
def test_level_flight_within_half_a_degree():
    mounting = euler_matrix(-15.0, 25.0, 35.0)
    sim, calibrated = _vehicle("flight", mounting, 20000, seed=8)
    kwargs = {"inclination_deg": 64.0, "gyro": sim.gyro, "time_s": sim.time_s}
    # Nearly level: a reflection across the vertical plane of the pitching changes no dip angle. By default
    # right-handed axes are then assumed (weak, said); allow_mirror=True insists on knowing (refused).
    with pytest.raises(CalibrationError, match="mirror image"):
        align(calibrated, sim.accel, allow_mirror=True, **kwargs)
    assumed = align(calibrated, sim.accel, **kwargs)
    assert assumed.verdict == "weak" and "right-handed axes are assumed" in assumed.warnings[-1]
    result = align(calibrated, sim.accel, allow_mirror=False, **kwargs)
    np.testing.assert_allclose(assumed.matrix, result.matrix)
    assert angle_between_deg(result.matrix, mounting) < 0.5
    assert sum(result.dropped.values()) + result.n_used == result.n_samples
    assert any("turning faster than 0.3°/s" in reason for reason in result.dropped)


def test_a_car_that_always_turns_or_accelerates_is_refused_with_the_counts():
    sim, calibrated = _vehicle("car", np.eye(3), 5000, seed=9)
    kwargs = {"inclination_deg": 64.0, "gyro": sim.gyro, "time_s": sim.time_s}
    # Turns are dropped, the straight stretches kept: their few attitudes see the mount's yaw through a short
    # lever (weak, said).
    result = align(calibrated, sim.accel, allow_undetermined=True, **kwargs)
    assert result.verdict == "weak" and any("seen through only" in w for w in result.warnings)
    assert result.dropped["turning faster than 0.3°/s in heading (from the gyroscope)"] > 1000
    assert sum(result.dropped.values()) + result.n_used == result.n_samples
    # A gate that allows no turn at all: refused with the counts.
    with pytest.raises(CalibrationError, match=r"only \d+ of 5000 samples see gravity alone.*turning faster"):
        align(calibrated, sim.accel, max_rate_dps=0.001, **kwargs)


def test_a_rolling_boat_keeps_its_samples_and_finds_the_mount_tilt():
    # Rolling in waves accelerates nothing at the sensor: the gate on the turn about the vertical keeps it
    # (a gate on the whole rate kept none). The heading hardly changes, so the rotation about the field's
    # east-west plane is what the boat determines: the mount's tilt within half a degree.
    mounting = euler_matrix(10.0, -5.0, 30.0)
    sim, calibrated = _vehicle("boat", mounting, 6000, seed=21)
    result = align(calibrated, sim.accel, inclination_deg=64.0, gyro=sim.gyro, time_s=sim.time_s,
                   allow_mirror=False, allow_undetermined=True)  # fmt: skip
    assert result.n_used > 1000  # the heading wanders at up to 0.8°/s in this short recording: those turns are dropped
    down_fitted, down_true = result.matrix.T @ [0, 0, 1], sim.mounting.T @ [0, 0, 1]
    assert np.degrees(np.arccos(np.clip(down_fitted @ down_true, -1, 1))) < 0.5


def test_rate_gate_from_the_field_and_gravity_without_a_gyroscope():
    sim, calibrated = _vehicle("flight", np.eye(3), 20000, seed=10)
    with_gyro = align(calibrated, sim.accel, inclination_deg=64.0, gyro=sim.gyro, time_s=sim.time_s, allow_mirror=False)
    without = align(calibrated, sim.accel, inclination_deg=64.0, time_s=sim.time_s, allow_mirror=False)
    assert any("field and gravity directions" in reason for reason in without.dropped)
    assert 0.3 < without.n_used / with_gyro.n_used < 3.0
    # The tilt of the mount stays within half a degree; the yaw, seen through the ±5° pitch of straight legs
    # only, is within its own (wider, stated) one-sigma.
    assert np.degrees(np.arccos(min(1.0, without.matrix[2, 2]))) < 0.5
    assert angle_between_deg(without.matrix, np.eye(3)) < 2.0 * without.axis_sigma_deg[2] + 0.5
    if without.axis_sigma_deg[2] > 1.0:
        assert without.verdict == "weak" and "body z" in without.warnings[0]


def test_turning_the_magnetometer_frame_turns_the_result():
    # Equivariance: m' = Q m is the same recording seen by a sensor turned by Qᵀ, so R' = R Qᵀ exactly.
    sim, calibrated = _vehicle("tumble", euler_matrix(10.0, -20.0, 30.0), 2000, seed=12)
    first = align(calibrated, sim.accel, inclination_deg=64.0, max_rate_dps=None)
    turn = euler_matrix(33.0, -71.0, 140.0)
    second = align(calibrated @ turn.T, sim.accel, inclination_deg=64.0, max_rate_dps=None)
    np.testing.assert_allclose(second.matrix, first.matrix @ turn.T, atol=1e-6)
    np.testing.assert_allclose(second.axis_sigma_deg, first.axis_sigma_deg, rtol=1e-4)


def test_real_mpu9250_magnetometer_is_its_accelerometer_turned_180_about_x(real_data_dir):
    # ../shared/data/real/mxl_umich_mpu9250_rm3100: raw counts, the accelerometer not calibrated (a 5-6° scatter
    # of the dips, named), recorded in Ann Arbor (WMM inclination 68.5° in February 2025).
    import magfit

    path = real_data_dir / "mxl_umich_mpu9250_rm3100" / "preflight_data_original.csv"
    table = np.genfromtxt(path, delimiter=",", names=True, usecols=range(19))
    raw = np.column_stack([table["imu_mx"], table["imu_my"], table["imu_mz"]])
    accel = np.column_stack([table["imu_ax"], table["imu_ay"], table["imu_az"]])
    calibrated = magfit.fit(raw).apply(raw)
    result = align(calibrated, accel, inclination_deg=68.5, max_rate_dps=None)
    nearest = result.nearest_for("ardupilot").rotation
    assert nearest.name == "ROTATION_ROLL_180" and nearest.angle_deg < 3.0
    assert not result.mirror and result.verdict == "weak"
    assert any("dip angles scatter" in w for w in result.warnings)
    # The samples' dip is 64.3°, the model's 68.5°: said, and the rotation's one-sigma widened by it.
    assert any(getattr(w, "code", None) == "inclination" for w in result.warnings)
    assert np.all(result.axis_sigma_deg > 4.0) and np.all(result.axis_sigma_deg < 6.0)


def test_an_uncalibrated_gyroscope_bias_is_taken_off():
    # 0.5°/s of bias per axis, above the 0.3°/s gate: without taking it off no sample would be kept.
    bias = np.radians([0.5, -0.4, 0.45])
    sim, calibrated = _vehicle("flight", euler_matrix(5.0, -10.0, 20.0), 20000, seed=13, gyro_bias=bias)
    result = align(calibrated, sim.accel, inclination_deg=64.0, gyro=sim.gyro, time_s=sim.time_s, allow_mirror=False)
    note = next(w for w in result.warnings if "gyroscope's bias" in w)
    found = np.array([float(v) for v in note.split("(")[-1].split(")")[0].split(",")])
    np.testing.assert_allclose(found, np.degrees(bias), atol=0.05)
    assert np.degrees(np.arccos(min(1.0, (result.matrix.T @ [0, 0, 1]) @ (sim.mounting.T @ [0, 0, 1])))) < 0.5
    # Without time stamps the still samples cannot be found independently of the gyroscope: no bias is taken,
    # the turns the bias hides let too few attitudes through, and the alignment is refused.
    with pytest.raises(CalibrationError, match="turning faster than 0.3°/s|not determined"):
        align(calibrated, sim.accel, inclination_deg=64.0, gyro=sim.gyro, allow_mirror=False)


@pytest.mark.parametrize(
    ("mag", "accel", "options", "error", "match"),
    [
        (np.zeros((10, 2)), np.ones((10, 3)), {}, SampleError, r"calibrated_mag must have shape \(N, 3\)"),
        (np.ones((10, 3)), np.ones((9, 3)), {}, SampleError, "accel has 9 rows but the magnetometer has 10"),
        (np.ones((10, 3)), np.full((10, 3), np.nan), {}, SampleError, "accel contains NaN"),
        (np.ones((10, 3)), np.ones((10, 3)), {"inclination_deg": 95.0}, OptionError, "inclination_deg"),
        (np.ones((10, 3)), np.ones((10, 3)), {"max_rate_dps": -1.0}, OptionError, "max_rate_dps"),
        (np.ones((10, 3)), np.ones((10, 3)), {"time_s": np.arange(9.0)}, SampleError, "time_s must be 10"),
        (np.ones((10, 3)), np.zeros((10, 3)), {}, SampleError, "accelerometer reads zero"),
        (np.ones((10, 3)), np.ones((10, 3)), {}, CalibrationError, r"only 10 of 10 samples .* at least 50"),
    ],
)
def test_bad_input_is_named(mag, accel, options, error, match):
    with pytest.raises(error, match=match):
        align(mag, accel, **options)


# --- magfit align ----------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def roll_180_csv(tmp_path_factory):
    """A hand-held tumble, magnetometer turned 180° about x, soft and hard iron, in µT, with accelerometer."""
    sim = simulate_vehicle(
        3000, "tumble", mounting=euler_matrix(180.0, 0.0, 0.0), soft_iron=np.diag([1.1, 0.95, 1.0]),
        hard_iron=[12.0, -8.0, 4.0], field_strength=50.0, noise=0.2, accel_noise=ONE_DEGREE, seed=11,
    )  # fmt: skip
    path = tmp_path_factory.mktemp("align") / "imu.csv"
    table = np.column_stack([sim.time_s, sim.samples, sim.accel])
    np.savetxt(path, table, delimiter=",", header="t,mx,my,mz,ax,ay,az", comments="")
    return path


def _run(capsys, *args):
    from magfit.cli import main

    status = main(["align", *map(str, args)])
    captured = capsys.readouterr()
    return status, captured.out, captured.err


def test_cli_prints_the_rotation_and_each_firmware_parameter(roll_180_csv, capsys):
    status, out, err = _run(capsys, roll_180_csv, "--inclination", "64", "--max-rate", "none")
    assert status == 0, err
    assert "COMPASS_ORIENT 8   # ROTATION_ROLL_180" in out
    assert "CAL_MAG0_ROT 8" in out
    assert "set align_mag = CW180FLIP" in out
    assert "verdict          supported" in out
    roll = float(out.split("roll pitch yaw")[1].split("±")[0])
    assert abs(abs(roll) - 180.0) < 0.5


def test_cli_exit_statuses(roll_180_csv, tmp_path, capsys):
    # The tumble turns all the time: with the default rate gate nothing is still -> the data cannot (1).
    status, _, err = _run(capsys, roll_180_csv, "--inclination", "64")
    assert status == 1 and "see gravity alone" in err and "--max-rate" in err and "Traceback" not in err
    status, _, err = _run(capsys, roll_180_csv, "--max-rate", "fast")
    assert status == 2 and "--max-rate takes a number" in err
    status, _, err = _run(capsys, roll_180_csv, "--max-tilt-rate", "0")
    assert status == 2 and "--max-tilt-rate" in err and "Traceback" not in err
    no_accel = tmp_path / "mag.csv"
    no_accel.write_text("mx,my,mz\n1,2,3\n2,3,4\n")
    status, _, err = _run(capsys, no_accel)
    assert status == 2 and "no accelerometer columns found" in err and "--accel-columns" in err
    status, _, err = _run(capsys, roll_180_csv, "--inclination", "64", "--location", "47.4,8.5")
    assert status == 2 and "not both" in err


@pytest.mark.slow
def test_cli_on_a_dataflash_log_combines_the_orientation_the_firmware_applied(tmp_path, capsys):
    # A synthetic ArduPilot log (tests/test_sources_motion.py): a tumble with IMU and ATT, COMPASS_ORIENT 6
    # (YAW_270) already applied to MAG; here the compass is really turned 45° more, so the right setting is
    # YAW_270 followed by 45°: ROTATION_YAW_315 (7).
    from test_sources_motion import ORIENT, dataflash_messages, raw_field, write_bin

    formats, rows = dataflash_messages()
    extra = euler_matrix(0.0, 0.0, 45.0)
    times = np.array([row[0] for row in rows["MAG"]]) / 1e6
    rows["MAG"] = [(row[0], 0, *field) for row, field in zip(rows["MAG"], raw_field(times, extra), strict=True)]
    log = write_bin(tmp_path / "turned.bin", formats, rows)
    status, out, err = _run(capsys, log, "--max-rate", "none", "--inclination", "63.4")
    assert status == 0, err
    assert ORIENT == 6 and "COMPASS_ORIENT 6 (ROTATION_YAW_270" in out
    assert "COMPASS_ORIENT 7   # ROTATION_YAW_315, 0.0° from the fit" in out
    assert "CAL_MAG0_ROT 7" in out
    yaw = float(out.split("roll pitch yaw")[1].split(",")[2].split("±")[0])
    assert abs(yaw - 45.0) < 0.2  # the rotation found is the one left after the log's own


def test_cli_reads_a_magnitude_only_calibration_and_refuses_an_aligned_one(roll_180_csv, tmp_path, capsys):
    import magfit
    from magfit.io.readers import read_samples

    raw = read_samples(roll_180_csv).samples
    calibration = magfit.fit(raw, method="ellipsoid")
    sensor = tmp_path / "cal.json"
    sensor.write_text(calibration.to_json())
    status, out, err = _run(capsys, roll_180_csv, "--calibration", sensor, "--inclination", "64", "--max-rate", "none")
    assert status == 0, err
    assert f"ellipsoid (read from {sensor}, supported)" in out and "COMPASS_ORIENT 8" in out
    aligned = magfit.Calibration("truth", calibration.offset, calibration.matrix, calibration.field_strength,
                                 frame="vehicle")  # fmt: skip
    vehicle = tmp_path / "aligned.json"
    vehicle.write_text(aligned.to_json())
    status, _, err = _run(capsys, roll_180_csv, "--calibration", vehicle, "--inclination", "64")
    assert status == 2 and "vehicle-frame calibration, already aligned" in err


@pytest.mark.slow
def test_cli_time_in_milliseconds(roll_180_csv, tmp_path, capsys):
    table = np.loadtxt(roll_180_csv, delimiter=",", skiprows=1)
    table[:, 0] *= 1000.0
    in_ms = tmp_path / "imu_ms.csv"
    np.savetxt(in_ms, table, delimiter=",", header="t,mx,my,mz,ax,ay,az", comments="")
    # Read as seconds, the tumble would look slow enough to pass the rate gate: said on stderr.
    status, _, err = _run(capsys, in_ms, "--inclination", "64")
    assert status == 0 and "steps by 20 s" in err and "--time-unit ms" in err
    # Read as milliseconds, it is the tumble it is: nothing turns slower than 0.3°/s.
    status, _, err = _run(capsys, in_ms, "--inclination", "64", "--time-unit", "ms")
    assert status == 1 and "see gravity alone" in err and "steps by" not in err


def test_cli_says_how_to_give_a_calibration_when_its_own_fit_is_refused(tmp_path, capsys):
    # Level yaw turns: no magnitude-only calibration to start from; the advice is for `magfit calibrate`.
    sim = simulate_vehicle(2000, "yaw", hard_iron=[12.0, -8.0, 4.0], field_strength=50.0, noise=0.2, seed=12)
    path = tmp_path / "level.csv"
    np.savetxt(path, np.column_stack([sim.samples, sim.accel]), delimiter=",", header="mx,my,mz,ax,ay,az", comments="")
    status, _, err = _run(capsys, path, "--inclination", "64")
    assert status == 1 and "Traceback" not in err and len(err.strip().splitlines()) == 1
    assert "the magnitude-only calibration the alignment starts from could not be fitted" in err
    assert err.strip().endswith("and give it with --calibration cal.json")


def _boat_csv(tmp_path, mounting):
    """A boat rolling on one heading, 10 min at 10 Hz, soft and hard iron, with gyroscope and time."""
    sim = simulate_vehicle(
        6000, "boat", rate_hz=10.0, mounting=mounting, soft_iron=np.array([[1.02, 0.01, 0.0], [0.01, 0.98, 0.0],
        [0.0, 0.0, 1.01]]), hard_iron=[0.2, -0.1, 0.3], noise=0.005, accel_noise=0.05, gyro_noise=0.002,
        gyro_bias=[0.004, -0.006, 0.003], seed=31,
    )  # fmt: skip
    path = tmp_path / "boat.csv"
    table = np.column_stack([sim.time_s, sim.samples, sim.accel, sim.gyro])
    np.savetxt(path, table, delimiter=",", header="t,mx,my,mz,ax,ay,az,gx,gy,gz", comments="")
    return sim, path


@pytest.mark.slow
def test_cli_starts_from_the_gyro_aided_calibration_where_it_has_a_gyroscope(tmp_path, capsys):
    # A boat cannot tumble: auto leaves the field's vertical part loose, which the dips rest on; the gyro-aided
    # fit's magnitude-only part pins it (accuracy_vehicle's boats: 0.33° RMS against auto's 1.5°).
    mounting = euler_matrix(4.0, -6.0, 25.0)
    _, path = _boat_csv(tmp_path, mounting)
    status, out, err = _run(capsys, path, "--gyro-columns", "gx,gy,gz", "--inclination", "64", "--no-mirror")
    assert status == 0, err
    assert "gyro (its magnitude-only part) (fitted," in out
    angles = [float(v) for v in re.findall(r"([+-]\d+\.\d+) ± ", out.split("roll pitch yaw")[1].splitlines()[0])]
    found = euler_matrix(*angles)
    assert angle_between_deg(found, mounting) < 0.5


@pytest.mark.slow
def test_an_alignment_is_no_better_supported_than_its_calibration(tmp_path, capsys):
    import magfit

    sim, path = _boat_csv(tmp_path, euler_matrix(4.0, -6.0, 25.0))
    # A boat: from the field's magnitude alone the distortion a tumble would show is not determined (auto refuses);
    # forced, then marked weak, as a calibration that holds near the attitudes seen.
    fitted = magfit.fit(sim.samples, method="auto", allow_undetermined=True).to_dict()
    fitted["support"] = {**fitted["support"], "verdict": "weak", "refusals": [], "refusal_codes": [],
                         "weaknesses": ["near the attitudes seen"], "weakness_codes": ["weakly_determined"],
                         "forced": False}  # fmt: skip
    weak = magfit.Calibration.from_dict(fitted)
    given = tmp_path / "weak.json"
    given.write_text(weak.to_json())
    status, out, err = _run(capsys, path, "--calibration", given, "--gyro-columns", "gx,gy,gz", "--inclination", "64",
                            "--no-mirror")  # fmt: skip
    assert status == 0, err
    assert re.search(r"verdict\s+weak", out) and "the calibration it starts from (auto) is weak" in out
    # A calibration forced past its refusal: the alignment from it says so, weak at best.
    forced = weak.to_dict()
    forced["support"] = {**forced["support"], "verdict": "refused", "refusals": ["too few"],
                         "refusal_codes": ["undetermined"]}  # fmt: skip
    given.write_text(magfit.Calibration.from_dict(forced).to_json())
    status, out, err = _run(capsys, path, "--calibration", given, "--gyro-columns", "gx,gy,gz", "--inclination", "64",
                            "--no-mirror")  # fmt: skip
    assert status == 0, err
    assert re.search(r"verdict\s+weak", out) and "was refused by its samples (forced) (too few)" in out


@pytest.mark.slow
def test_a_wrong_inclination_is_refused_not_absorbed_by_a_tilted_mount():
    # A boat rolling on one heading, given 30° for a dip of 64°: the mount came out 34° off at a stated ±0.3°.
    from scipy.spatial.transform import Rotation

    mounting = Rotation.from_euler("xyz", [5.0, -10.0, 20.0], degrees=True).as_matrix()
    sim = simulate_vehicle(6000, "boat", rate_hz=10.0, mounting=mounting, noise=0.003, accel_noise=0.05,
                           gyro_noise=0.002, inclination_deg=64.0, seed=1)  # fmt: skip
    mag = sim.truth_sensor.apply(sim.samples)
    for wrong in (30.0, 50.0):
        with pytest.raises(CalibrationError) as caught:
            align(mag, sim.accel, inclination_deg=wrong, gyro=sim.gyro, time_s=sim.time_s)
        assert caught.value.codes == ("inclination",)
    right = align(mag, sim.accel, inclination_deg=64.0, gyro=sim.gyro, time_s=sim.time_s)
    assert not any(getattr(w, "code", None) == "inclination" for w in right.warnings)
    error = np.degrees(Rotation.from_matrix(right.matrix @ mounting.T).magnitude())
    assert error < 3.0 * max(np.linalg.norm(right.axis_sigma_deg), 0.05)
    # Fitted, the dip is pulled towards the vertical on a boat (72.5° for 64°): refused as not determined.
    with pytest.raises(CalibrationError) as caught:
        align(mag, sim.accel, gyro=sim.gyro, time_s=sim.time_s)
    assert caught.value.codes == ("inclination",)
