"""Vehicle-frame calibrations (issue 14) through every export, each applied the way its firmware does.

A vehicle-frame calibration's matrix M is general: ``corrected_vehicle = M @ (raw - offset)``, M = Q S with
Q the magnetometer-to-vehicle rotation (possibly a mirror) and S the soft iron. Each firmware's formula is
re-implemented here from its source, independently of magfit/export:

- ArduPilot AP_Compass_Backend.cpp: ``accumulate_sample`` = ``rotate_field`` (COMPASS_ORIENT: the fixed
  rotation, or for 101/102 ``Matrix3::from_euler(CUST_ROTn_ROLL, _PITCH, _YAW)``), then ``correct_field``
  (``mag += OFS; mag *= SCALE; mag = DIA/ODI * mag``);
- PX4 Magnetometer.hpp ``Correct``: ``R * (S * (raw - OFF))``, R = get_rot_matrix(CAL_MAGn_ROT);
- Betaflight compass.c ``compassUpdate``: ``alignSensorViaRotation``/``alignSensorViaMatrix`` (CUSTOM:
  buildRotationMatrix of the negated angles, applied transposed), then ``- magZero``;
- INAV compass.c ``compassUpdate``: ``(raw - magZero) * 1024 / magGain``, then the alignment
  (align_mag_*: rotationMatrixFromAngles applied transposed).

The fixed rotation tables come from magfit.rotations, whose every entry tests/test_rotations.py checks
against the firmwares' own code. Samples are real recordings, corrected by a fitted soft iron turned by
a known mounting rotation.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest
from numpy.typing import NDArray

import magfit
from magfit.errors import ExportError
from magfit.export import FORMATS, export
from magfit.facts import LogCompass
from magfit.rotations import angle_between_deg, euler_matrix, polar_decomposition, standard_rotations

NUMBER = r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?"
#: Float32 text (9 significant digits) on the firmware's side, relative to max|raw|.
RTOL_FLOAT32 = 2e-6


def _fxos(real_data_dir: Path) -> NDArray[np.float64]:
    # NXP FXOS8700, µT, tab-separated x y z, no header.
    return np.loadtxt(real_data_dir / "fxos8700_magneto" / "mag-readings.txt")


def _apex5(real_data_dir: Path) -> NDArray[np.float64]:
    # QMC5883 on a Betaflight quadcopter, raw int16 counts: mx, my, mz, gx, gy, gz.
    path = real_data_dir / "betaflight_apex5_qmc5883" / "20231014_apex5_mag_on_tpu_03.txt"
    return np.loadtxt(path, delimiter=",")[:, :3]


def _vehicle(cal: magfit.Calibration, rotation: NDArray[np.float64]) -> magfit.Calibration:
    """``cal``'s soft iron followed by the mounting ``rotation``: a vehicle-frame calibration with known Q."""
    return magfit.Calibration(
        "vector", cal.offset, rotation @ cal.matrix, cal.field_strength, unit=cal.unit, frame="vehicle"
    )


def _close(actual: NDArray[np.float64], expected: NDArray[np.float64], raw: NDArray[np.float64], rtol: float) -> None:
    np.testing.assert_allclose(actual, expected, rtol=0, atol=rtol * float(np.max(np.abs(raw))))


def _heading_error(seen: NDArray[np.float64], truth: NDArray[np.float64]) -> float:
    """Worst difference of atan2(y, x) between two sets of corrected vectors, degrees."""
    error = np.arctan2(seen[:, 1], seen[:, 0]) - np.arctan2(truth[:, 1], truth[:, 0])
    return float(np.degrees(np.max(np.abs((error + np.pi) % (2 * np.pi) - np.pi))))


# ---------------------------------------------------------------------- ArduPilot


def parse_ardupilot(text: str) -> dict[str, float]:
    return {
        name: float(value)
        for name, value in (line.split(",") for line in text.splitlines() if line.strip() and line[0] != "#")
    }


def _from_euler(roll_deg: float, pitch_deg: float, yaw_deg: float) -> NDArray[np.float64]:
    """ArduPilot Matrix3<T>::from_euler (AP_Math/matrix3.cpp), rows a, b, c."""
    r, p, y = (math.radians(a) for a in (roll_deg, pitch_deg, yaw_deg))
    cp, sp, sr, cr, sy, cy = math.cos(p), math.sin(p), math.sin(r), math.cos(r), math.sin(y), math.cos(y)
    return np.array(
        [
            [cp * cy, sr * sp * cy - cr * sy, cr * sp * cy + sr * sy],
            [cp * sy, sr * sp * sy + cr * cy, cr * sp * sy - sr * cy],
            [-sp, sr * cp, cr * cp],
        ]
    )


def ardupilot_field(p: dict[str, float], raw_mg: NDArray[np.float64], slot: int = 0) -> NDArray[np.float64]:
    """accumulate_sample for an external compass in ``slot``: rotate_field, then correct_field."""
    n = "" if slot == 0 else str(slot + 1)
    orient = int(p.get(f"COMPASS_ORIENT{n}", 0))
    if orient in (101, 102):
        assert p["CUST_ROT_ENABLE"] == 1
        k = orient - 100
        rotation = _from_euler(p[f"CUST_ROT{k}_ROLL"], p[f"CUST_ROT{k}_PITCH"], p[f"CUST_ROT{k}_YAW"])
    else:
        rotation = np.asarray(standard_rotations("ardupilot")[orient].matrix)
    ofs = np.array([p[f"COMPASS_OFS{n}_{a}"] for a in "XYZ"])
    dia = [p[f"COMPASS_DIA{n}_{a}"] for a in "XYZ"]
    odi = [p[f"COMPASS_ODI{n}_{a}"] for a in "XYZ"]
    mat = np.array([[dia[0], odi[0], odi[1]], [odi[0], dia[1], odi[2]], [odi[1], odi[2], dia[2]]])
    scale = p[f"COMPASS_SCALE{n}"]
    out = np.empty_like(raw_mg)
    for i, sample in enumerate(raw_mg):
        mag = rotation @ sample + ofs
        if 0.85 <= scale <= 1.4:  # Compass::have_scale_factor
            mag = mag * scale
        out[i] = mat @ mag
    return out


def test_ardupilot_custom_orientation_reproduces_the_vehicle_field(real_data_dir: Path) -> None:
    samples = _fxos(real_data_dir)
    cal = _vehicle(magfit.fit(samples, method="ellipsoid").with_unit("uT"), euler_matrix(12.0, -7.5, 131.0))
    text = export(cal, "ardupilot")
    params = parse_ardupilot(text)
    # CUST_ROT2: ArduPilot's parameter conversion gives CUST_ROT1 to a custom board orientation (AP_AHRS::init)
    assert params["COMPASS_ORIENT"] == 102 and params["CUST_ROT_ENABLE"] == 1
    assert not any(name.startswith("CUST_ROT1") for name in params)
    _close(ardupilot_field(params, 10 * samples), 10 * cal.apply(samples), 10 * samples, RTOL_FLOAT32)
    assert "(COMPASS_EXTERNAL = 1" in text  # ORIENT is ignored for an internal compass: said in the file


def _ground_station_load(text: str, known: set[str]) -> dict[str, float]:
    """Mission Planner / MAVProxy 'param load': a name the vehicle did not list when fetched is not set."""
    return {name: value for name, value in parse_ardupilot(text).items() if name in known}


def test_ardupilot_custom_rotation_needs_two_loads_and_says_so(real_data_dir: Path) -> None:
    # While CUST_ROT_ENABLE is 0, ArduPilot hides CUST_ROT2_* (AP_PARAM_FLAG_ENABLE): the ground station's list,
    # fetched before the load, lacks them. One load leaves COMPASS_ORIENT = 102 with the identity.
    samples = _fxos(real_data_dir)
    cal = _vehicle(magfit.fit(samples, method="ellipsoid").with_unit("uT"), euler_matrix(12.0, -7.5, 131.0))
    text = export(cal, "ardupilot")
    params = parse_ardupilot(text)
    listed = {name for name in params if not name.startswith("CUST_ROT2_")}  # hidden at the first fetch
    vehicle = {"CUST_ROT2_ROLL": 0.0, "CUST_ROT2_PITCH": 0.0, "CUST_ROT2_YAW": 0.0}  # the defaults
    vehicle |= _ground_station_load(text, listed)
    once = ardupilot_field(vehicle, 10 * samples)
    assert _heading_error(once, 10 * cal.apply(samples)) > 90.0  # the identity instead of the mounting
    vehicle |= _ground_station_load(text, listed | set(vehicle))  # reboot, refresh (now listed), load again
    _close(ardupilot_field(vehicle, 10 * samples), 10 * cal.apply(samples), 10 * samples, RTOL_FLOAT32)
    head = text.splitlines()[:3]
    assert head[1].startswith("# LOAD THIS FILE TWICE") and "Reboot" in text and "refresh the parameters" in text
    fixed = _vehicle(magfit.fit(samples, method="ellipsoid").with_unit("uT"), euler_matrix(180.0, 0.0, 270.0))
    assert "LOAD THIS FILE TWICE" not in export(fixed, "ardupilot")  # no custom rotation: one load


def test_ardupilot_fixed_orientation_within_tolerance(real_data_dir: Path) -> None:
    samples = _fxos(real_data_dir)
    fitted = magfit.fit(samples, method="ellipsoid").with_unit("uT")
    exact = _vehicle(fitted, np.asarray(standard_rotations("ardupilot")[14].matrix))  # ROLL_180_YAW_270
    params = parse_ardupilot(export(exact, "ardupilot"))
    assert params["COMPASS_ORIENT"] == 14 and "CUST_ROT_ENABLE" not in params
    _close(ardupilot_field(params, 10 * samples), 10 * exact.apply(samples), 10 * samples, RTOL_FLOAT32)
    # 0.3 deg off a fixed rotation: written as the fixed one, the residual's heading error stated and bounded
    near = _vehicle(fitted, euler_matrix(180.0, 0.0, 270.3))
    text = export(near, "ardupilot")
    params = parse_ardupilot(text)
    assert params["COMPASS_ORIENT"] == 14
    stated = float(re.search(r"heading error of up to ([\d.]+) deg", text).group(1))  # type: ignore[union-attr]
    measured = _heading_error(ardupilot_field(params, 10 * samples), 10 * near.apply(samples))
    assert 0.25 < measured <= stated + 0.01


def test_ardupilot_scale_from_the_expected_field(real_data_dir: Path) -> None:
    samples = _fxos(real_data_dir)
    cal = magfit.fit(samples, method="ellipsoid").with_unit("uT")
    expected = 1.05 * cal.field_strength
    params = parse_ardupilot(export(cal, "ardupilot", expected_field=expected))
    assert params["COMPASS_SCALE"] == pytest.approx(1.05, rel=1e-8)
    corrected = ardupilot_field(params, 10 * samples)
    # the radius is now the expected field's, in mG (CompassCalibrator::fix_radius)
    assert np.median(np.linalg.norm(corrected, axis=1)) == pytest.approx(10 * expected, rel=0.01)
    _close(corrected, 10 * 1.05 * cal.apply(samples), 10 * samples, RTOL_FLOAT32)
    with pytest.raises(ExportError, match=r"outside 0.85-1.4 \('bad radius'"):
        export(cal, "ardupilot", expected_field=1.5 * cal.field_strength)
    # 1.3-1.4: used by ArduPilot, but beyond the documented range Mission Planner checks
    assert "COMPASS_SCALE = 1.350 is above its documented range" in export(
        cal, "ardupilot", expected_field=1.35 * cal.field_strength
    )


def test_ardupilot_runs_out_of_custom_rotations() -> None:
    cals = [
        magfit.Calibration(
            "vector", [1.0, 2.0, 3.0], euler_matrix(10.0 * i, 5.0, 33.0), 50.0, unit="uT", frame="vehicle",
            details={"sensor": {"id": f"MAG/{i}", "slot": i, "device_id": None}},
        )
        for i in range(3)
    ]  # fmt: skip
    from magfit.export import export_several

    params = parse_ardupilot(export_several(cals[:1], "ardupilot"))
    assert params["COMPASS_ORIENT"] == 102
    # A second compass would need CUST_ROT1, the board's when AHRS_ORIENTATION = 101: refused, with words.
    with pytest.raises(ExportError, match="CUST_ROT1, is the board's"):
        export_several(cals[:2], "ardupilot")
    fixed = magfit.Calibration(
        "vector", [1.0, 2.0, 3.0], euler_matrix(0.0, 0.0, 90.0), 50.0, unit="uT", frame="vehicle",
        details={"sensor": {"id": "MAG/1", "slot": 1, "device_id": None}},
    )  # fmt: skip
    params = parse_ardupilot(export_several([cals[0], fixed], "ardupilot"))
    assert (params["COMPASS_ORIENT"], params["COMPASS_ORIENT2"]) == (102, 2)  # ROTATION_YAW_90


# ---------------------------------------------------------------------- PX4


def parse_px4(text: str) -> dict[str, float]:
    params = {}
    for line in text.splitlines():
        if line.strip() and not line.startswith("#"):
            _, _, name, value, kind = line.split("\t")
            assert kind == ("6" if name.endswith(("_ID", "_ROT")) else "9")  # INT32 / REAL32
            params[name] = float(value)
    return params


def px4_correct(p: dict[str, float], raw_g: NDArray[np.float64], slot: int = 0) -> NDArray[np.float64]:
    """calibration::Magnetometer::Correct: R * (S * (raw - offset)), R = get_rot_matrix(CAL_MAGn_ROT)."""
    c = f"CAL_MAG{slot}_"
    off = np.array([p[f"{c}{a}OFF"] for a in "XYZ"])
    x, y, z = (p[f"{c}{a}SCALE"] for a in "XYZ")
    xy, xz, yz = (p[f"{c}{a}ODIAG"] for a in "XYZ")
    s = np.array([[x, xy, xz], [xy, y, yz], [xz, yz, z]])
    rotation = np.asarray(standard_rotations("px4")[int(p.get(f"{c}ROT", 0))].matrix)
    return np.array([rotation @ (s @ (sample - off)) for sample in raw_g])


def test_px4_fixed_rotation_reproduces_the_vehicle_field(real_data_dir: Path) -> None:
    samples = _fxos(real_data_dir)
    fitted = magfit.fit(samples, method="ellipsoid").with_unit("uT")
    table = standard_rotations("px4")
    cal = _vehicle(fitted, np.asarray(table[38].matrix))  # ROLL_90_PITCH_68_YAW_293 (whole degrees in PX4)
    params = parse_px4(export(cal, "px4", device_id=396809))
    assert params["CAL_MAG0_ROT"] == 38 and params["CAL_MAG0_ID"] == 396809
    # 43 (PITCH_90_YAW_180) is the same matrix as 29 (ROLL_180_PITCH_90): the smaller id is written
    same = parse_px4(export(_vehicle(fitted, np.asarray(table[43].matrix)), "px4"))
    np.testing.assert_allclose(table[int(same["CAL_MAG0_ROT"])].matrix, table[43].matrix, atol=1e-12)
    _close(px4_correct(params, 0.01 * samples), 0.01 * cal.apply(samples), 0.01 * samples, RTOL_FLOAT32)


def test_px4_refuses_a_rotation_off_its_table(real_data_dir: Path) -> None:
    fitted = magfit.fit(_fxos(real_data_dir), method="ellipsoid").with_unit("uT")
    with pytest.raises(ExportError, match=r"only its fixed rotations \(0-40\).*export to 'ardupilot'"):
        export(_vehicle(fitted, euler_matrix(0.0, 0.0, 97.0)), "px4")


# ---------------------------------------------------------------------- Betaflight and INAV


def _build_rotation_matrix(roll: float, pitch: float, yaw: float) -> NDArray[np.float64]:
    """Betaflight buildRotationMatrix (common/vector.c) == INAV rotationMatrixFromAngles (common/maths.c)."""
    sx, cx, sy, cy, sz, cz = (
        math.sin(roll),
        math.cos(roll),
        math.sin(pitch),
        math.cos(pitch),
        math.sin(yaw),
        math.cos(yaw),
    )
    return np.array(
        [
            [cz * cy, -cy * sz, sy],
            [sz * cx + sx * cz * sy, cz * cx - sx * sz * sy, -sx * cy],
            [sx * sz - cz * cx * sy, sx * cz + sz * cx * sy, cy * cx],
        ]
    )


def _settings(text: str) -> dict[str, str]:
    return dict(re.findall(r"^set (\w+) = (\S+)$", text, re.M))


CW = {"CW0": 1, "CW90": 2, "CW180": 3, "CW270": 4, "CW0FLIP": 5, "CW90FLIP": 6, "CW180FLIP": 7, "CW270FLIP": 8}


def betaflight_correct(text: str, raw: NDArray[np.float64]) -> NDArray[np.float64]:
    """compassUpdate: align (CUSTOM: the angles negated, buildRotationMatrix, matrixTrnVectorMul), - magZero."""
    s = _settings(text)
    zero = np.array([int(v) for v in s["mag_calibration"].split(",")], dtype=np.float64)
    if s.get("align_mag") == "CUSTOM":
        r, p, y = (-math.radians(int(s[f"mag_align_{a}"]) / 10) for a in ("roll", "pitch", "yaw"))
        align = _build_rotation_matrix(r, p, y).T  # matrixTrnVectorMul: the transpose
    else:
        align = np.asarray(standard_rotations("betaflight")[CW[s.get("align_mag", "CW0")]].matrix)
    return raw @ align.T - zero


def inav_correct(text: str, raw: NDArray[np.float64]) -> NDArray[np.float64]:
    """compassUpdate: (raw - magzero) * 1024 / maggain, then align_mag_* (transposed) or align_mag."""
    s = _settings(text)
    zero = np.array([int(s[f"magzero_{a}"]) for a in "xyz"], dtype=np.float64)
    gain = np.array([int(s[f"maggain_{a}"]) for a in "xyz"], dtype=np.float64)
    angles = [int(s.get(f"align_mag_{a}", 0)) for a in ("roll", "pitch", "yaw")]
    if any(angles):
        align = _build_rotation_matrix(*(math.radians(a / 10) for a in angles)).T
    else:
        align = np.asarray(standard_rotations("inav")[CW[s.get("align_mag", "CW0")]].matrix)
    return ((raw - zero) * 1024 / gain) @ align.T


def test_betaflight_custom_alignment_and_offset_on_real_counts(real_data_dir: Path) -> None:
    raw = _apex5(real_data_dir)
    fitted = magfit.fit(raw, method="ellipsoid").with_unit("counts")
    # a mounting Betaflight can hold to its 0.1 deg: 23.4 deg roll, -8.1 pitch, 141.7 yaw
    cal = _vehicle(fitted, euler_matrix(23.4, -8.1, 141.7))
    text = export(cal, "betaflight")
    assert "set align_mag = CUSTOM" in text and "Betaflight 2026.6" in text
    seen = betaflight_correct(text, raw)
    # Betaflight drops the soft iron: what it holds is Q raw - round(Q offset), the offset in the aligned frame
    q = euler_matrix(23.4, -8.1, 141.7)
    _close(seen, raw @ q.T - np.rint(q @ fitted.offset), raw, 1e-6)


def test_betaflight_fixed_alignment() -> None:
    cal = magfit.Calibration(
        "vector", [100.0, -50.0, 20.0], np.asarray(standard_rotations("betaflight")[8].matrix), 450.0,
        unit="counts", frame="vehicle",
    )  # fmt: skip
    text = export(cal, "betaflight")
    assert "set align_mag = CW270FLIP" in text
    raw = np.random.default_rng(1).normal(size=(200, 3)) * 400
    _close(betaflight_correct(text, raw), cal.apply(raw), raw, 1e-12)


def test_inav_custom_alignment_on_real_counts(real_data_dir: Path) -> None:
    raw = _apex5(real_data_dir)
    fitted = magfit.fit(raw, method="diag").with_unit("counts")  # what INAV can hold: a diagonal
    cal = _vehicle(fitted, euler_matrix(-31.2, 4.4, 60.0))
    text = export(cal, "inav")
    seen = inav_correct(text, raw)
    truth = cal.apply(raw)
    stated = float(re.search(r"heading error of up to ([\d.]+) deg", text).group(1))  # type: ignore[union-attr]
    assert stated < 0.5  # a diagonal fit and an alignment on INAV's 0.1 deg grid: only the rounding is lost
    # every corrected vector points where the calibration's does, to the integers' rounding
    cosine = np.sum(seen * truth, axis=1) / np.linalg.norm(seen, axis=1) / np.linalg.norm(truth, axis=1)
    assert float(np.degrees(np.max(np.arccos(np.clip(cosine, -1, 1))))) < 0.1
    # and the INAV radius of 1024 counts
    assert np.median(np.linalg.norm(seen, axis=1)) == pytest.approx(1024, rel=0.02)


# ---------------------------------------------------------------------- full-matrix formats, mirrors, refusals


def _mirror(fitted: magfit.Calibration) -> magfit.Calibration:
    """A left-handed sensor: the fitted soft iron, the y axis flipped, then turned."""
    return _vehicle(fitted, euler_matrix(5.0, 10.0, -40.0) @ np.diag([1.0, -1.0, 1.0]))


def test_full_matrix_formats_keep_a_mirror_and_say_it(real_data_dir: Path) -> None:
    samples = _fxos(real_data_dir)
    cal = _mirror(magfit.fit(samples, method="ellipsoid").with_unit("uT"))
    assert np.linalg.det(cal.matrix) < 0
    c_text = export(cal, "c")
    offset = np.array(
        [float(v) for v in re.findall(rf"({NUMBER})f", c_text.split("magfit_offset[3] = {")[1].split("}")[0])]
    )
    block = c_text.split("magfit_matrix[3][3] = {")[1].split("};")[0]
    matrix = np.array([float(v) for v in re.findall(rf"({NUMBER})f", block)]).reshape(3, 3)
    _close((samples - offset) @ matrix.T, cal.apply(samples), samples, RTOL_FLOAT32)
    assert magfit.Calibration.from_json(export(cal, "json")) == cal
    for name in ("c", "fusion", "magcal", "adafruit", "yaml", "rtimulib", "json"):
        text = export(cal, name)
        assert "frame 'vehicle'" in text and "mirror" in text, name


@pytest.mark.parametrize("name", ["ardupilot", "px4", "betaflight", "inav"])
def test_firmwares_refuse_a_mirror(name: str) -> None:
    unit = "counts" if name in ("betaflight", "inav") else "uT"
    cal = magfit.Calibration(
        "vector", [1.0, 2.0, 3.0], np.diag([1.0, 1.0, -1.0]), 50.0 if unit == "uT" else 500.0, unit=unit,
        frame="vehicle",
    )  # fmt: skip
    with pytest.raises(ExportError, match="mirror.*full-matrix format") as raised:
        export(cal, name)
    assert "\n" not in str(raised.value)


def test_ros_madgwick_refuses_a_vehicle_frame() -> None:
    cal = magfit.Calibration("vector", [1.0, 2.0, 3.0], euler_matrix(0, 0, 30), 50.0, unit="uT", frame="vehicle")
    with pytest.raises(ExportError, match="no rotation.*export to 'yaml'"):
        export(cal, "ros-madgwick")


def test_every_format_carries_or_refuses_a_vehicle_frame() -> None:
    """No format writes a vehicle-frame calibration silently as if it were a sensor-frame one."""
    for unit, strength in (("uT", 50.0), ("counts", 500.0)):
        cal = magfit.Calibration(
            "vector", [1.0, 2.0, 3.0], euler_matrix(3, 4, 77) @ np.diag([1.02, 0.99, 0.99]), strength,
            unit=unit, frame="vehicle",
        )  # fmt: skip
        for name in FORMATS:
            try:
                text = export(cal, name)
            except ExportError:
                continue
            if name == "adafruit-json":  # JSON without comments: the header export states it
                continue
            assert "vehicle" in text, (name, unit)


# ---------------------------------------------------------------------- samples logged after a mounting rotation


def test_a_rotation_applied_before_logging_is_included(real_data_dir: Path) -> None:
    """ArduPilot logs MAG after COMPASS_ORIENT: a fit on those samples must not lose the rotation in force."""
    sensor_raw = _fxos(real_data_dir)
    fitted = magfit.fit(sensor_raw, method="ellipsoid").with_unit("uT")
    r0 = np.asarray(standard_rotations("ardupilot")[4].matrix)  # YAW_180 in force when the log was made
    logged = sensor_raw @ r0.T
    # the vehicle-frame calibration of the logged (already turned) samples: a further 6 deg of roll
    residual = euler_matrix(6.0, 0.0, 0.0)
    on_logged = magfit.Calibration(
        "vector", r0 @ fitted.offset, residual @ r0 @ fitted.matrix @ r0.T, fitted.field_strength, unit="uT",
        frame="vehicle",
    )  # fmt: skip
    truth = on_logged.apply(logged)
    text = export(on_logged, "ardupilot", applied_rotation=r0)
    assert "mounting rotation of 180.00 deg (applied_rotation)" in text
    # the firmware now turns the sensor's own readings by the written rotation alone
    _close(ardupilot_field(parse_ardupilot(text), 10 * sensor_raw), 10 * truth, 10 * sensor_raw, RTOL_FLOAT32)
    # the same from Calibration.sensor, as the pipeline fills it
    rotation = tuple(tuple(row) for row in r0.tolist())
    with_details = magfit.Calibration(
        "vector", on_logged.offset, on_logged.matrix, on_logged.field_strength, unit="uT", frame="vehicle",
        sensor=LogCompass("MAG/0", 0, None, rotation),
    )  # fmt: skip
    assert export(with_details, "ardupilot") == text.replace("compass 1:", "compass 1 (MAG/0):")
    # without it, the file would be for samples with COMPASS_ORIENT = 0, and says so
    assert "logged with COMPASS_ORIENT = 0" in export(on_logged, "ardupilot")
    with pytest.raises(magfit.OptionError, match="applied_rotation must be the 3x3 rotation"):
        export(on_logged, "ardupilot", applied_rotation=np.diag([1.0, 1.0, -1.0]))
    with pytest.raises(magfit.OptionError, match="the c export takes no applied_rotation"):
        export(on_logged, "c", applied_rotation=r0)


# ---------------------------------------------------------------------- a real rig with two magnetometers


def test_two_real_magnetometers_on_one_rig(real_data_dir: Path) -> None:
    """The MXL rig: an RM3100 fitted against the MPU-9250's corrected field, a real sensor-to-sensor alignment.

    The vector fit finds the RM3100 2-3 deg from the MPU-9250's axes (measured: 2.50 deg with the current
    fits): ArduPilot takes it as its custom rotation, exactly; PX4, whose fixed table has nothing closer than
    ROTATION_NONE, refuses with the reason.
    """
    folder = real_data_dir / "mxl_umich_mpu9250_rm3100"
    imu = np.loadtxt(folder / "preflight_data_original_imu.csv", delimiter=",", skiprows=1, encoding="utf-8-sig")
    pni = np.loadtxt(folder / "preflight_data_original_pni.csv", delimiter=",", skiprows=1, encoding="utf-8-sig")
    reference = magfit.fit(imu, method="ellipsoid").apply(imu)  # µT, in the MPU-9250's axes
    cal = magfit.fit(pni, method="vector", reference=reference, allow_undetermined=True).with_unit("uT")
    assert cal.frame == "vehicle"
    params = parse_ardupilot(export(cal, "ardupilot"))
    assert params["COMPASS_ORIENT"] == 102
    _close(ardupilot_field(params, 10 * pni), 10 * cal.apply(pni), 10 * pni, RTOL_FLOAT32)
    rotation, _ = polar_decomposition(cal.matrix)
    angle = angle_between_deg(np.eye(3), rotation)
    assert 1.0 < angle < 5.0
    with pytest.raises(ExportError, match="from the nearest \\(0, ROTATION_NONE"):
        export(cal, "px4")


# ---------------------------------------------------------------------- random vehicle-frame calibrations


def _random_vehicle(rng: np.random.Generator, rotation: NDArray[np.float64]) -> magfit.Calibration:
    """A random soft iron (within ArduPilot's DIA/ODI limits) after which ``rotation`` turns into the vehicle."""
    a = np.eye(3) + 0.08 * rng.normal(size=(3, 3))
    soft = sqrtm_spd(a @ a.T)
    soft /= np.cbrt(np.linalg.det(soft))
    return magfit.Calibration(
        "vector", rng.uniform(-40, 40, 3), rotation @ soft, rng.uniform(30, 60), unit="uT", frame="vehicle"
    )


def sqrtm_spd(m: NDArray[np.float64]) -> NDArray[np.float64]:
    values, vectors = np.linalg.eigh(m)
    return (vectors * np.sqrt(values)) @ vectors.T


@pytest.mark.parametrize("seed", range(8))
def test_random_vehicle_calibrations_through_ardupilot_and_px4(seed: int) -> None:
    rng = np.random.default_rng(seed)
    raw = rng.normal(size=(300, 3)) * 50 + rng.uniform(-40, 40, 3)
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    free = _random_vehicle(rng, q * np.sign(np.linalg.det(q)))  # any rotation: ArduPilot's custom one
    _close(ardupilot_field(parse_ardupilot(export(free, "ardupilot")), 10 * raw), 10 * free.apply(raw), 10 * raw,
           RTOL_FLOAT32)  # fmt: skip
    entry = standard_rotations("px4")[int(rng.integers(0, 41))]  # current PX4's 0-40
    fixed = _random_vehicle(rng, np.asarray(entry.matrix))  # on PX4's table: exact
    _close(px4_correct(parse_px4(export(fixed, "px4")), 0.01 * raw), 0.01 * fixed.apply(raw), 0.01 * raw, RTOL_FLOAT32)
    _close(ardupilot_field(parse_ardupilot(export(fixed, "ardupilot")), 10 * raw), 10 * fixed.apply(raw), 10 * raw,
           RTOL_FLOAT32)  # fmt: skip


# ---------------------------------------------------------------------- PX4 rotations 41-47


def test_px4_writes_only_the_rotations_current_px4_has() -> None:
    # Current rotation.h ends at ROTATION_ROLL_90_PITCH_315 = 40 (ROTATION_MAX 41); ParametersUpdate resets a
    # CAL_MAGn_ROT >= ROTATION_MAX to 0, no rotation. Mid-2020's 41-43 equal 31, 36 and 29 (PX4 PRs #15784,
    # #16449): written as those; 44-47 have no equal: refused, not written as no rotation.
    table = standard_rotations("px4")
    for old, same in ((41, 31), (42, 36), (43, 29)):
        assert angle_between_deg(table[old].matrix, table[same].matrix) < 1e-6
        cal = magfit.Calibration("vector", [1.0, 2.0, 3.0], np.asarray(table[old].matrix), 50.0, unit="uT",
                                 frame="vehicle")  # fmt: skip
        assert parse_px4(export(cal, "px4"))["CAL_MAG0_ROT"] == same
    for old in range(44, 48):
        cal = magfit.Calibration("vector", [1.0, 2.0, 3.0], np.asarray(table[old].matrix), 50.0, unit="uT",
                                 frame="vehicle")  # fmt: skip
        with pytest.raises(ExportError, match=r"fixed rotations \(0-40\)"):
            export(cal, "px4")
    # Written as 44 (PITCH_9_YAW_180), today's PX4 would apply no rotation: 180 deg of heading.
    assert angle_between_deg(np.eye(3), table[44].matrix) > 179.0
