"""The firmware rotation tables against vectors worked out by hand from each firmware's own code.

Each expected vector below is what the firmware's C code (cited) does to the input, step by step; the
tables in magfit.rotations are built a different way (from the names' Euler angles), so a wrong sign,
order or convention shows here.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from magfit.errors import OptionError, SampleError
from magfit.rotations import (
    FIRMWARES,
    PX4_ROTATION_MAX,
    angle_between_deg,
    custom_angles,
    custom_rotation,
    euler_angles,
    euler_matrix,
    nearest_rotation,
    polar_decomposition,
    standard_rotations,
)

H = math.sqrt(0.5)
V = np.array([1.0, 2.0, 3.0])

# ArduPilot libraries/AP_Math/vector3.cpp, Vector3<T>::rotate, applied to (1, 2, 3):
ARDUPILOT_CASES = {
    0: (1, 2, 3),
    1: (H * (1 - 2), H * (1 + 2), 3),  # YAW_45: tmp = h(x - y); y = h(x + y); x = tmp
    10: (2, 1, -3),  # ROLL_180_YAW_90: tmp = x; x = y; y = tmp; z = -z
    14: (-2, -1, -3),  # ROLL_180_YAW_270: tmp = x; x = -y; y = -tmp; z = -z
    24: (3, 2, -1),  # PITCH_90: tmp = z; z = -x; x = tmp
    36: (3, -1, -2),  # ROLL_90_PITCH_180_YAW_90: (1,-3,2) -> (-1,-3,-2) -> (3,-1,-2)
    37: (-3, -1, 2),  # ROLL_90_YAW_270: (1,-3,2), then tmp = x; x = y; y = -tmp
    39: (H * (1 - 3), 2, H * (1 + 3)),  # PITCH_315: tmp = h(x - z); z = h(x + z); x = tmp
    42: (1, H * (2 - 3), H * (2 + 3)),  # ROLL_45: tmp = h(y - z); z = h(y + z); y = tmp
    43: (1, H * (2 + 3), H * (3 - 2)),  # ROLL_315: tmp = h(y + z); z = h(z - y); y = tmp
}

# PX4 src/lib/conversion/rotation.cpp, rotate_3f (the hand-written switch; get_rot_matrix is the Euler form):
PX4_CASES = {
    6: (2, -1, 3),  # YAW_270: tmp = x; x = y; y = -tmp
    22: (-3, 1, -2),  # ROLL_270_YAW_90: tmp = x; x = -z; z = -y; y = tmp
    34: (3, -2, 1),  # ROLL_180_PITCH_270: tmp = z; z = x; x = tmp; y = -y
    35: (2, 3, 1),  # ROLL_270_PITCH_270: tmp = x; x = y; y = z; z = tmp
    40: (0.707107 * (1 - 2), -3, 0.707107 * (1 + 2)),  # ROLL_90_PITCH_315
}

# Betaflight src/main/sensors/boardalignment.c alignSensorViaRotation (INAV's applySensorAlignment is the same):
CW_CASES = {
    1: (1, 2, 3),
    2: (2, -1, 3),  # CW90_DEG: x = y; y = -x
    3: (-1, -2, 3),
    4: (-2, 1, 3),  # CW270_DEG: x = -y; y = x
    5: (-1, 2, -3),
    6: (2, 1, -3),  # CW90_DEG_FLIP: x = y; y = x; z = -z
    7: (1, -2, -3),
    8: (-2, -1, -3),  # CW270_DEG_FLIP: x = -y; y = -x; z = -z
}


@pytest.mark.parametrize("index", sorted(ARDUPILOT_CASES))
def test_ardupilot_table_matches_vector3_rotate(index: int) -> None:
    np.testing.assert_allclose(standard_rotations("ardupilot")[index].matrix @ V, ARDUPILOT_CASES[index], atol=1e-12)


def test_ardupilot_named_example_and_equal_entries() -> None:
    table = standard_rotations("ardupilot")
    assert table[10].name == "ROTATION_ROLL_180_YAW_90"
    np.testing.assert_allclose(table[10].matrix @ [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], atol=1e-12)
    # rotations.h: 26 "same as ROTATION_ROLL_180_YAW_270", 27 "same as ROTATION_ROLL_180_YAW_90"
    np.testing.assert_allclose(table[26].matrix, table[14].matrix, atol=1e-12)
    np.testing.assert_allclose(table[27].matrix, table[10].matrix, atol=1e-12)
    assert sorted(table) == list(range(44))


def test_ardupilot_38_and_pitch_7_are_the_numbers_of_vector3_cpp() -> None:
    table = standard_rotations("ardupilot")
    # ROTATION_ROLL_90_PITCH_68_YAW_293 on (1, 0, 0): the first column of vector3.cpp's matrix.
    np.testing.assert_allclose(table[38].matrix @ [1.0, 0.0, 0.0], [0.143039, -0.332133, -0.932324], atol=1e-6)
    roll, pitch, yaw = euler_angles(table[38].matrix)  # rotations.h: "actually roll 90, pitch 68.8, yaw 293.3"
    assert (round(roll, 1), round(pitch, 1), round(yaw % 360, 1)) == (90.0, 68.8, 293.3)
    # ROTATION_PITCH_7: x = cos x + sin z; z = -sin x + cos z (sin_pitch = 0.12186934340514748)
    s, c = 0.12186934340514748, 0.992546151641322
    np.testing.assert_allclose(table[41].matrix @ V, [c * 1 + s * 3, 2, -s * 1 + c * 3], atol=1e-12)


@pytest.mark.parametrize("index", sorted(PX4_CASES))
def test_px4_table_matches_rotate_3f(index: int) -> None:
    np.testing.assert_allclose(standard_rotations("px4")[index].matrix @ V, PX4_CASES[index], atol=1e-5)


def test_px4_table_is_rot_lookup_and_differs_from_ardupilot_at_38() -> None:
    px4 = standard_rotations("px4")
    assert sorted(px4) == list(range(48))
    assert px4[38].name == "ROTATION_ROLL_90_PITCH_68_YAW_293"
    # rot_lookup {90, 68, 293}: Dcmf(Eulerf) of whole degrees, 0.8 deg from ArduPilot's 38
    assert 0.3 < angle_between_deg(px4[38].matrix, standard_rotations("ardupilot")[38].matrix) < 1.5
    # rotate_3f's own numbers for 38 (float, 6 digits)
    np.testing.assert_allclose(px4[38].matrix @ [1.0, 0.0, 0.0], [0.146371, -0.344827, -0.927184], atol=2e-6)
    # PITCH_45 exists only in rot_lookup: Ry(45) turns x towards -z
    np.testing.assert_allclose(px4[45].matrix @ [1.0, 0.0, 0.0], [H, 0.0, -H], atol=1e-12)
    # 0-37 and 39-40 are the same rotations in both firmwares (MAV_SENSOR_ORIENTATION)
    ardupilot = standard_rotations("ardupilot")
    for index in [*range(38), 39, 40]:
        np.testing.assert_allclose(px4[index].matrix, ardupilot[index].matrix, atol=1e-12)


@pytest.mark.parametrize("firmware", ["betaflight", "inav"])
@pytest.mark.parametrize("index", sorted(CW_CASES))
def test_align_mag_matches_align_sensor_via_rotation(firmware: str, index: int) -> None:
    np.testing.assert_allclose(standard_rotations(firmware)[index].matrix @ V, CW_CASES[index], atol=0)


def _betaflight_build_rotation_matrix(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """buildRotationMatrix (betaflight src/main/common/vector.c) == rotationMatrixFromAngles (INAV maths.c)."""
    sx, cx = math.sin(roll), math.cos(roll)
    sy, cy = math.sin(pitch), math.cos(pitch)
    sz, cz = math.sin(yaw), math.cos(yaw)
    return np.array(
        [
            [cz * cy, -cy * sz, sy],
            [sz * cx + sx * cz * sy, cz * cx - sx * sz * sy, -sx * cy],
            [sx * sz - cz * cx * sy, sx * cz + sz * cx * sy, cy * cx],
        ]
    )


def _transposed_multiply(m: np.ndarray, v: np.ndarray) -> np.ndarray:
    """matrixTrnVectorMul / rotationMatrixRotateVector: result.x = m[0][0] x + m[1][0] y + m[2][0] z ..."""
    return np.array([m[0, i] * v[0] + m[1, i] * v[1] + m[2, i] * v[2] for i in range(3)])


def test_custom_rotations_reproduce_each_firmware() -> None:
    rng = np.random.default_rng(3)
    for _ in range(20):
        decideg = rng.uniform(-1800, 1800, 3)
        r, p, y = np.radians(decideg / 10)
        # Betaflight 2026.6+ (compass.c): the angles negated, then buildRotationMatrix, applied transposed
        expected = _transposed_multiply(_betaflight_build_rotation_matrix(-r, -p, -y), V)
        np.testing.assert_allclose(custom_rotation("betaflight", *decideg) @ V, expected, atol=1e-12)
        # INAV compass.c: rotationMatrixFromAngles of the angles as given, applied transposed
        expected = _transposed_multiply(_betaflight_build_rotation_matrix(r, p, y), V)
        np.testing.assert_allclose(custom_rotation("inav", *decideg) @ V, expected, atol=1e-12)
        # ArduPilot CUST_ROT1_* (degrees): Matrix3::from_euler, m * v
        degrees = decideg / 10
        cr, sr, cp, sp, cy, sy = (f(a) for a in np.radians(degrees) for f in (math.cos, math.sin))
        from_euler = np.array(
            [
                [cp * cy, sr * sp * cy - cr * sy, cr * sp * cy + sr * sy],
                [cp * sy, sr * sp * sy + cr * cy, cr * sp * sy - sr * cy],
                [-sp, sr * cp, cr * cp],
            ]
        )
        np.testing.assert_allclose(custom_rotation("ardupilot", *degrees), from_euler, atol=1e-12)


@pytest.mark.parametrize("firmware", ["ardupilot", "betaflight", "inav"])
def test_custom_angles_invert_custom_rotation(firmware: str) -> None:
    rng = np.random.default_rng(5)
    for _ in range(50):
        q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
        rotation = q * np.sign(np.linalg.det(q))
        angles = custom_angles(rotation, firmware)
        limit = 180.0 if firmware == "ardupilot" else 1800.0
        assert all(-limit < a <= limit for a in angles)
        np.testing.assert_allclose(custom_rotation(firmware, *angles), rotation, atol=1e-9)
    # gimbal lock: pitch 90 exactly
    rotation = euler_matrix(0, 90, 30)
    np.testing.assert_allclose(custom_rotation(firmware, *custom_angles(rotation, firmware)), rotation, atol=1e-9)


def test_nearest_rotation_finds_the_entry_and_the_angle() -> None:
    for firmware in FIRMWARES:
        table = {i: e for i, e in standard_rotations(firmware).items() if firmware != "px4" or i <= PX4_ROTATION_MAX}
        for entry in table.values():  # PX4: the rotations current PX4 has (41-47 are mid-2020's)
            tilt = euler_matrix(2.0, -1.0, 1.5)  # 2.7 deg away from the entry
            found = nearest_rotation(entry.matrix @ tilt, firmware)
            np.testing.assert_allclose(found.matrix, entry.matrix, atol=1e-12)
            assert found.angle_deg == pytest.approx(angle_between_deg(np.eye(3), tilt), abs=1e-9)
            assert found.id == min(i for i, e in table.items() if np.allclose(e.matrix, entry.matrix))
    # 45 deg of yaw is in ArduPilot's table, not in Betaflight's
    assert nearest_rotation(euler_matrix(0, 0, 45), "ardupilot").id == 1
    assert nearest_rotation(euler_matrix(0, 0, 45), "betaflight").angle_deg == pytest.approx(45.0)


def test_refusals() -> None:
    with pytest.raises(OptionError, match="valid firmwares: ardupilot, px4, betaflight, inav"):
        standard_rotations("cleanflight")
    with pytest.raises(SampleError, match="mirror"):
        nearest_rotation(np.diag([1.0, 1.0, -1.0]), "px4")
    with pytest.raises(SampleError, match="not a rotation"):
        nearest_rotation(np.diag([1.0, 2.0, 0.5]), "px4")
    with pytest.raises(OptionError, match="px4 has no custom magnetometer rotation"):
        custom_angles(np.eye(3), "px4")


def test_polar_decomposition_splits_rotation_and_symmetric_part() -> None:
    rng = np.random.default_rng(7)
    for sign in (1.0, -1.0):
        m = rng.normal(size=(3, 3))
        m *= sign * np.sign(np.linalg.det(m))
        q, s = polar_decomposition(m)
        np.testing.assert_allclose(q @ s, m, atol=1e-12)
        np.testing.assert_allclose(q.T @ q, np.eye(3), atol=1e-12)
        np.testing.assert_allclose(s, s.T, atol=0)
        assert np.all(np.linalg.eigvalsh(s) > 0)
        assert np.sign(np.linalg.det(q)) == sign


def test_tables_are_read_only() -> None:
    entry = standard_rotations("ardupilot")[2]
    with pytest.raises(ValueError):
        entry.matrix[0, 0] = 5.0
    with pytest.raises(TypeError):
        standard_rotations("px4")[99] = entry  # type: ignore[index]
