"""The flight firmwares' sensor rotations: the fixed tables, their custom angles, the nearest table entry.

One convention throughout, the firmwares' own::

    vector_in_board_frame = R @ vector_in_sensor_frame

``R`` turns a vector measured in the magnetometer's axes into the board's (vehicle's) axes. Every
matrix below was re-derived from the firmware source named next to it; ``tests/test_rotations.py``
checks each table against vectors worked out by hand from those sources.

- **ArduPilot** (``COMPASS_ORIENT``, ``AHRS_ORIENTATION``): ``enum Rotation`` in
  ``libraries/AP_Math/rotations.h``, applied by ``Vector3<T>::rotate`` in ``libraries/AP_Math/vector3.cpp``.
  Each name is a roll, a pitch and a yaw and the switch there equals ``Rz(yaw) Ry(pitch) Rx(roll)`` (the
  3-2-1 Euler sequence), except 38 (``ROTATION_ROLL_90_PITCH_68_YAW_293``: really roll 90, pitch 68.8,
  yaw 293.3; its matrix is copied as numbers from vector3.cpp). 41 (``PITCH_7``) is a rotation of the
  code but not listed in the parameter's ``@Values``. Since 4.2, 101 and 102 (``ROTATION_CUSTOM_1/2``)
  take their matrix from ``CUST_ROT1_ROLL/PITCH/YAW`` (``CUST_ROT2_*``) in degrees, built by
  ``Matrix3::from_euler`` (``libraries/AP_CustomRotations/AP_CustomRotations.cpp``): the same 3-2-1 sequence
  (the parameters' ``@Description``: "euler 321 (yaw, pitch, roll) ordering"); ``CUST_ROT_ENABLE = 1``
  turns them on. 100 (``ROTATION_CUSTOM_OLD``) is the 4.1-and-older ``COMPASS_CUS_ROLL/PIT/YAW``.
- **PX4** (``CAL_MAGn_ROT``, ``SENS_BOARD_ROT``): ``rot_lookup[]`` in ``src/lib/conversion/rotation.h``
  (roll, pitch, yaw in whole degrees, 0-47), turned into a matrix by ``get_rot_matrix`` in ``rotation.cpp``:
  ``Dcmf{Eulerf{roll, pitch, yaw}}``, the same 3-2-1 sequence (38 is then exactly roll 90, pitch 68, yaw 293,
  not ArduPilot's 38). The table here is mid-2020's (0-47, for reading the logs of those releases); current
  PX4 stops at 40: PR #15784 (September 2020) made the enum MAVLink's ``MAV_SENSOR_ORIENTATION`` and dropped
  the rest, PR #16449 removed 41, and rotation.h now ends ``ROTATION_ROLL_90_PITCH_315 = 40, ROTATION_MAX``.
  PX4 has no custom magnetometer rotation: ``calibration::Magnetometer::ParametersUpdate``
  (``src/lib/sensor_calibration/Magnetometer.cpp``) resets a ``CAL_MAGn_ROT`` at or above ``ROTATION_MAX`` to
  0 (``ROTATION_NONE``, "invalid rotation ... resetting to rotation none"), so 41-47 written for today's PX4
  mean no rotation at all; :func:`nearest_rotation` offers only 0-40 (:data:`PX4_ROTATION_MAX`). An internal
  magnetometer always follows the board rotation (``CAL_MAGn_ROT = -1``).
- **Betaflight** (``align_mag``): ``CW0_DEG`` (1) .. ``CW270_DEG_FLIP`` (8) in ``src/main/common/sensor_alignment.h``,
  applied by ``alignSensorViaRotation`` in ``src/main/sensors/boardalignment.c`` (0, ``DEFAULT``, is the
  driver's own choice, unknown here). ``ALIGN_CUSTOM`` (9) uses ``mag_align_roll/pitch/yaw`` in
  decidegrees: ``buildRotationMatrix`` (``src/main/common/vector.c``) builds ``Rx(r) Ry(p) Rz(y)`` and
  ``applyRotationMatrix`` multiplies by its transpose. Since 2026.6 (commit f788d43, "Fix mag_align_yaw",
  ``src/main/sensors/compass.c``) the angles are negated first, so the rotation is ``Rz(y) Ry(p) Rx(r)``, as
  in ArduPilot and PX4; Betaflight 4.1 to 2025.12 applied ``Rz(-y) Ry(-p) Rx(-r)``, INAV's convention
  (use ``firmware="inav"`` for those).
- **INAV** (``align_mag``): the same eight ``CW..`` alignments (``applySensorAlignment`` in
  ``src/main/sensors/boardalignment.c``); ``align_mag_roll/pitch/yaw`` (decidegrees, any non-zero one wins
  over ``align_mag``, ``src/main/sensors/compass.c``) go through ``rotationMatrixFromAngles``
  (``src/main/common/maths.c``: ``Rx(r) Ry(p) Rz(y)``) applied transposed by ``rotationMatrixRotateVector``,
  i.e. ``Rz(-y) Ry(-p) Rx(-r)``.

>>> from magfit.rotations import standard_rotations
>>> rotation = standard_rotations("ardupilot")[10]
>>> rotation.name, (rotation.matrix @ [1.0, 0.0, 0.0]).round(6).tolist()
('ROTATION_ROLL_180_YAW_90', [0.0, 1.0, 0.0])
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Mapping
from dataclasses import dataclass
from functools import cache
from types import MappingProxyType

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .errors import OptionError, SampleError

__all__ = [
    "CUSTOM",
    "FIRMWARES",
    "PX4_ROTATION_MAX",
    "StandardRotation",
    "angle_between_deg",
    "axis_words",
    "custom_angles",
    "custom_rotation",
    "euler_angles",
    "euler_matrix",
    "nearest_rotation",
    "polar_decomposition",
    "signed_permutations",
    "skew",
    "standard_rotations",
]

#: The firmwares whose rotation tables are known.
FIRMWARES = ("ardupilot", "px4", "betaflight", "inav")

#: How each firmware selects a custom (free roll/pitch/yaw) magnetometer rotation: the value of its
#: rotation parameter and the three angle parameters with their unit; PX4 has none.
CUSTOM: Mapping[str, tuple[str, int, tuple[str, str, str], str] | None] = MappingProxyType(
    {
        # CUST_ROT2 (102): ArduPilot's own parameter conversion gives CUST_ROT1 to a custom board orientation.
        "ardupilot": ("COMPASS_ORIENT", 102, ("CUST_ROT2_ROLL", "CUST_ROT2_PITCH", "CUST_ROT2_YAW"), "deg"),
        "px4": None,
        "betaflight": ("align_mag", 9, ("mag_align_roll", "mag_align_pitch", "mag_align_yaw"), "decideg"),
        "inav": ("align_mag", 0, ("align_mag_roll", "align_mag_pitch", "align_mag_yaw"), "decideg"),
    }
)

#: The largest CAL_MAGn_ROT / SENS_BOARD_ROT every PX4 since late 2020 takes (rotation.h: ROTATION_MAX = 41);
#: above it ParametersUpdate resets the parameter to 0, no rotation. Mid-2020 releases had 41-47 too.
PX4_ROTATION_MAX = 40

#: Largest |Rᵀ R − I| entry of a matrix accepted as a rotation (float32 tables pass, a soft-iron matrix does not).
ORTHOGONALITY_TOLERANCE = 1e-5

# ArduPilot's names, by value (rotations.h); each is ROLL_r, PITCH_p, YAW_y of the 3-2-1 sequence.
_ARDUPILOT_NAMES = (
    "NONE", "YAW_45", "YAW_90", "YAW_135", "YAW_180", "YAW_225", "YAW_270", "YAW_315",
    "ROLL_180", "ROLL_180_YAW_45", "ROLL_180_YAW_90", "ROLL_180_YAW_135", "PITCH_180", "ROLL_180_YAW_225",
    "ROLL_180_YAW_270", "ROLL_180_YAW_315", "ROLL_90", "ROLL_90_YAW_45", "ROLL_90_YAW_90", "ROLL_90_YAW_135",
    "ROLL_270", "ROLL_270_YAW_45", "ROLL_270_YAW_90", "ROLL_270_YAW_135", "PITCH_90", "PITCH_270",
    "PITCH_180_YAW_90", "PITCH_180_YAW_270", "ROLL_90_PITCH_90", "ROLL_180_PITCH_90", "ROLL_270_PITCH_90",
    "ROLL_90_PITCH_180", "ROLL_270_PITCH_180", "ROLL_90_PITCH_270", "ROLL_180_PITCH_270", "ROLL_270_PITCH_270",
    "ROLL_90_PITCH_180_YAW_90", "ROLL_90_YAW_270", "ROLL_90_PITCH_68_YAW_293", "PITCH_315", "ROLL_90_PITCH_315",
    "PITCH_7", "ROLL_45", "ROLL_315",
)  # fmt: skip

# ArduPilot 38 as vector3.cpp writes it (row i gives the new component i); the name's angles are rounded.
_ARDUPILOT_38 = (
    (0.14303897231223747, 0.36877648650320383, -0.91844638134308709),
    (-0.33213277779664740, -0.85628942146641884, -0.39554550256296522),
    (-0.93232380121551217, 0.36162457008209242, 0.0),
)

# PX4's rot_lookup[] (rotation.h): (roll, pitch, yaw) in degrees, index = CAL_MAGn_ROT.
_PX4_ANGLES = (
    (0, 0, 0), (0, 0, 45), (0, 0, 90), (0, 0, 135), (0, 0, 180), (0, 0, 225), (0, 0, 270), (0, 0, 315),
    (180, 0, 0), (180, 0, 45), (180, 0, 90), (180, 0, 135), (0, 180, 0), (180, 0, 225), (180, 0, 270),
    (180, 0, 315), (90, 0, 0), (90, 0, 45), (90, 0, 90), (90, 0, 135), (270, 0, 0), (270, 0, 45),
    (270, 0, 90), (270, 0, 135), (0, 90, 0), (0, 270, 0), (0, 180, 90), (0, 180, 270), (90, 90, 0),
    (180, 90, 0), (270, 90, 0), (90, 180, 0), (270, 180, 0), (90, 270, 0), (180, 270, 0), (270, 270, 0),
    (90, 180, 90), (90, 0, 270), (90, 68, 293), (0, 315, 0), (90, 315, 0), (270, 0, 180), (270, 0, 270),
    (0, 90, 180), (0, 9, 180), (0, 45, 0), (270, 0, 225), (270, 0, 315),
)  # fmt: skip

# Betaflight/INAV align_mag (sensor_alignment.h / drivers/sensor.h): the matrix of alignSensorViaRotation /
# applySensorAlignment, row i = how the new component i is made from (x, y, z).
_CW_ALIGNMENTS = {
    1: ("CW0_DEG", ((1, 0, 0), (0, 1, 0), (0, 0, 1))),
    2: ("CW90_DEG", ((0, 1, 0), (-1, 0, 0), (0, 0, 1))),
    3: ("CW180_DEG", ((-1, 0, 0), (0, -1, 0), (0, 0, 1))),
    4: ("CW270_DEG", ((0, -1, 0), (1, 0, 0), (0, 0, 1))),
    5: ("CW0_DEG_FLIP", ((-1, 0, 0), (0, 1, 0), (0, 0, -1))),
    6: ("CW90_DEG_FLIP", ((0, 1, 0), (1, 0, 0), (0, 0, -1))),
    7: ("CW180_DEG_FLIP", ((1, 0, 0), (0, -1, 0), (0, 0, -1))),
    8: ("CW270_DEG_FLIP", ((0, -1, 0), (-1, 0, 0), (0, 0, -1))),
}


@dataclass(frozen=True, eq=False)
class StandardRotation:
    """One entry of a firmware's rotation table.

    Attributes
    ----------
    id : int
        The parameter value that selects it (``COMPASS_ORIENT``, ``CAL_MAGn_ROT``, ``align_mag``).
    name : str
        The firmware's own name (``"ROTATION_ROLL_180_YAW_90"``, ``"CW270_DEG_FLIP"``).
    matrix : ndarray, shape (3, 3)
        ``vector_in_board_frame = matrix @ vector_in_sensor_frame``; read-only.
    angle_deg : float
        From :func:`nearest_rotation`: the angle (degrees) of the rotation between this entry and the
        rotation asked for; 0 in the tables.
    """

    id: int
    name: str
    matrix: NDArray[np.float64]
    angle_deg: float = 0.0


def euler_matrix(roll_deg: float, pitch_deg: float, yaw_deg: float) -> NDArray[np.float64]:
    """``Rz(yaw) @ Ry(pitch) @ Rx(roll)``, angles in degrees: the 3-2-1 sequence of ArduPilot and PX4.

    Entries within 1e-12 of 0 are set to 0, so multiples of 90° give exact signed permutations.
    """
    r, p, y = (math.radians(float(a)) for a in (roll_deg, pitch_deg, yaw_deg))
    rx = np.array([[1.0, 0.0, 0.0], [0.0, math.cos(r), -math.sin(r)], [0.0, math.sin(r), math.cos(r)]])
    ry = np.array([[math.cos(p), 0.0, math.sin(p)], [0.0, 1.0, 0.0], [-math.sin(p), 0.0, math.cos(p)]])
    rz = np.array([[math.cos(y), -math.sin(y), 0.0], [math.sin(y), math.cos(y), 0.0], [0.0, 0.0, 1.0]])
    matrix: NDArray[np.float64] = rz @ ry @ rx
    matrix[np.abs(matrix) < 1e-12] = 0.0
    return matrix


def euler_angles(matrix: ArrayLike) -> tuple[float, float, float]:
    """(roll, pitch, yaw) in degrees with ``euler_matrix(roll, pitch, yaw) == matrix``; pitch in [-90, 90].

    At pitch ±90° only roll − yaw (or roll + yaw) is determined: roll is set to 0 there.
    """
    r = _rotation_matrix(matrix)
    pitch = math.degrees(math.asin(max(-1.0, min(1.0, -r[2, 0]))))
    if abs(r[2, 0]) > 1.0 - 1e-12:  # gimbal lock: cos(pitch) = 0
        roll = 0.0
        yaw = math.degrees(math.atan2(-r[0, 1], r[1, 1]))
    else:
        roll = math.degrees(math.atan2(r[2, 1], r[2, 2]))
        yaw = math.degrees(math.atan2(r[1, 0], r[0, 0]))
    return roll, pitch, yaw


def _frozen(matrix: ArrayLike) -> NDArray[np.float64]:
    array = np.array(matrix, dtype=np.float64)
    array.flags.writeable = False
    return array


def _check_firmware(firmware: str) -> str:
    if firmware not in FIRMWARES:
        raise OptionError(f"unknown firmware {firmware!r}; valid firmwares: {', '.join(FIRMWARES)}")
    return firmware


@cache
def _table(firmware: str) -> Mapping[int, StandardRotation]:
    entries: dict[int, StandardRotation] = {}
    if firmware == "ardupilot":
        for index, name in enumerate(_ARDUPILOT_NAMES):
            if index == 38:
                matrix = np.array(_ARDUPILOT_38)
            elif name == "NONE":
                matrix = np.eye(3)
            else:
                angles = {"ROLL": 0, "PITCH": 0, "YAW": 0}
                words = name.split("_")
                for axis, value in zip(words[::2], words[1::2], strict=True):
                    angles[axis] = int(value)
                matrix = euler_matrix(angles["ROLL"], angles["PITCH"], angles["YAW"])
            entries[index] = StandardRotation(index, f"ROTATION_{name}", _frozen(matrix))
    elif firmware == "px4":
        for index, (roll, pitch, yaw) in enumerate(_PX4_ANGLES):
            words = [f"{axis}_{angle}" for axis, angle in (("ROLL", roll), ("PITCH", pitch), ("YAW", yaw)) if angle]
            name = "ROTATION_" + ("_".join(words) or "NONE")
            entries[index] = StandardRotation(index, name, _frozen(euler_matrix(roll, pitch, yaw)))
    else:  # betaflight, inav: the same eight alignments
        for index, (name, rows) in _CW_ALIGNMENTS.items():
            entries[index] = StandardRotation(index, name, _frozen(rows))
    return MappingProxyType(entries)


def standard_rotations(firmware: str) -> Mapping[int, StandardRotation]:
    """The fixed rotations of ``firmware`` by parameter value (read-only).

    Parameters
    ----------
    firmware : {"ardupilot", "px4", "betaflight", "inav"}

    Returns
    -------
    mapping
        id -> :class:`StandardRotation`, ``board = matrix @ sensor``. ArduPilot 0-43 (26 equals 14 and
        27 equals 10), PX4 0-47, Betaflight/INAV ``align_mag`` 1-8. Custom rotations are not entries:
        see :func:`custom_rotation`.

    Raises
    ------
    OptionError
        Unknown firmware (the message lists the valid ones).
    """
    return _table(_check_firmware(firmware))


def _rotation_matrix(matrix: ArrayLike, what: str = "matrix") -> NDArray[np.float64]:
    array = np.asarray(matrix, dtype=np.float64)
    if array.shape != (3, 3):
        raise SampleError(f"a rotation {what} must have shape (3, 3), got {array.shape}")
    if not np.all(np.isfinite(array)):
        raise SampleError(f"the rotation {what} contains NaN or inf")
    error = float(np.max(np.abs(array.T @ array - np.eye(3))))
    if error > ORTHOGONALITY_TOLERANCE:
        raise SampleError(
            f"the {what} is not a rotation (max|R^T R - I| = {error:.3g}); pass the rotation factor of a general "
            "matrix (magfit.rotations.polar_decomposition)"
        )
    if np.linalg.det(array) < 0:
        raise SampleError(
            f"the {what} is a mirror (determinant -1), not a rotation: no firmware rotation can represent it; "
            "check the sensor's axis order and signs"
        )
    return array


def angle_between_deg(a: ArrayLike, b: ArrayLike) -> float:
    """The angle (degrees, 0-180) of the rotation ``aᵀ b`` that turns rotation ``a`` into rotation ``b``."""
    relative = _rotation_matrix(a, "first matrix").T @ _rotation_matrix(b, "second matrix")
    cosine = (float(np.trace(relative)) - 1.0) / 2.0
    return math.degrees(math.acos(max(-1.0, min(1.0, cosine))))


def nearest_rotation(matrix: ArrayLike, firmware: str) -> StandardRotation:
    """The entry of ``firmware``'s table closest to the rotation ``matrix`` (``board = matrix @ sensor``).

    Parameters
    ----------
    matrix : array_like, shape (3, 3)
        A proper rotation (orthogonal to 1e-5, determinant +1).
    firmware : {"ardupilot", "px4", "betaflight", "inav"}

    Returns
    -------
    StandardRotation
        The entry, with ``angle_deg`` the angle between it and ``matrix``. Among entries with the same
        matrix (ArduPilot's 10/27 and 14/26) the smallest id. For PX4 only 0-:data:`PX4_ROTATION_MAX`, the
        rotations current PX4 has (41-43 of mid-2020 duplicated 31, 36 and 29; 44-47 are gone: PX4 now
        reads them as no rotation).

    Raises
    ------
    SampleError
        ``matrix`` is not a rotation, or is a mirror (no firmware rotation is).
    OptionError
        Unknown firmware.
    """
    rotation = _rotation_matrix(matrix)
    best: StandardRotation | None = None
    for entry in standard_rotations(firmware).values():
        if firmware == "px4" and entry.id > PX4_ROTATION_MAX:
            continue
        angle = angle_between_deg(entry.matrix, rotation)
        if best is None or angle < best.angle_deg - 1e-9:
            best = StandardRotation(entry.id, entry.name, entry.matrix, angle)
    assert best is not None  # every table has entries
    return best


def custom_rotation(firmware: str, roll: float, pitch: float, yaw: float) -> NDArray[np.float64]:
    """The matrix ``firmware`` applies for its custom magnetometer angles (``board = matrix @ sensor``).

    Parameters
    ----------
    firmware : {"ardupilot", "betaflight", "inav"}
    roll, pitch, yaw : float
        The parameters' values in the firmware's unit (:data:`CUSTOM`): degrees for ArduPilot's
        ``CUST_ROT1_*``, decidegrees for Betaflight's ``mag_align_*`` and INAV's ``align_mag_*``.

    Raises
    ------
    OptionError
        PX4 (no custom magnetometer rotation) or an unknown firmware.
    """
    scale = _custom_scale(firmware)
    angles = (roll * scale, pitch * scale, yaw * scale)
    if firmware == "inav":  # rotationMatrixFromAngles, applied transposed: Rz(-y) Ry(-p) Rx(-r)
        return euler_matrix(-angles[0], -angles[1], -angles[2])
    return euler_matrix(*angles)


def custom_angles(matrix: ArrayLike, firmware: str) -> tuple[float, float, float]:
    """The custom (roll, pitch, yaw) parameter values that make ``firmware`` apply the rotation ``matrix``.

    The inverse of :func:`custom_rotation`, in the parameters' unit (degrees or decidegrees), each
    angle in (-180°, 180°].
    """
    scale = _custom_scale(firmware)
    roll, pitch, yaw = euler_angles(matrix)
    if firmware == "inav":
        roll, pitch, yaw = -roll, -pitch, -yaw
    return tuple(_wrap(angle) / scale for angle in (roll, pitch, yaw))  # type: ignore[return-value]


def _custom_scale(firmware: str) -> float:
    """Degrees per unit of ``firmware``'s custom angle parameters."""
    custom = CUSTOM[_check_firmware(firmware)]
    if custom is None:
        raise OptionError(
            f"{firmware} has no custom magnetometer rotation (CAL_MAGn_ROT takes only its table's 0-47); "
            "use nearest_rotation()"
        )
    return 0.1 if custom[3] == "decideg" else 1.0


def _wrap(angle_deg: float) -> float:
    wrapped = math.remainder(angle_deg, 360.0)
    return 180.0 if wrapped == -180.0 else wrapped + 0.0  # + 0.0: no -0.0 in a parameter file


def polar_decomposition(matrix: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """``matrix = Q @ S``: Q orthogonal (det ±1, the sign of det(matrix)), S symmetric positive definite.

    S = sqrtm(matrixᵀ matrix) is the part of a calibration matrix that changes lengths (a magnitude-only
    soft-iron correction); Q turns (and, for det < 0, mirrors) the corrected vector. For a general
    vehicle-frame matrix M, ``M @ v = Q @ (S @ v)``: first S, then Q.

    Raises
    ------
    SampleError
        Not a finite (3, 3) matrix, or singular.
    """
    m = np.asarray(matrix, dtype=np.float64)
    if m.shape != (3, 3) or not np.all(np.isfinite(m)):
        raise SampleError(f"polar_decomposition takes a finite (3, 3) matrix, got shape {m.shape}")
    u, singular, vt = np.linalg.svd(m)
    if singular[-1] <= 1e-12 * singular[0]:
        raise SampleError("polar_decomposition: the matrix is singular")
    q: NDArray[np.float64] = u @ vt
    s: NDArray[np.float64] = (vt.T * singular) @ vt
    return q, 0.5 * (s + s.T)


def skew(vectors: ArrayLike) -> NDArray[np.float64]:
    """The cross-product matrices ``[v]×`` (..., 3, 3) of vectors (..., 3): ``skew(v) @ u = v × u``.

    ``[v]×_ik = ε_ijk v_j`` (the Levi-Civita symbol), i.e. rows ``(0, −v_z, v_y)``, ``(v_z, 0, −v_x)``,
    ``(−v_y, v_x, 0)``.
    """
    v = np.asarray(vectors, dtype=np.float64)
    out = np.zeros((*v.shape[:-1], 3, 3))
    x, y, z = v[..., 0], v[..., 1], v[..., 2]
    out[..., 0, 1], out[..., 0, 2] = -z, y
    out[..., 1, 0], out[..., 1, 2] = z, -x
    out[..., 2, 0], out[..., 2, 1] = -y, x
    return out


def axis_words(direction: ArrayLike, frame: str | None = None, *, within_deg: float = 15.0,
               names: tuple[str, str, str] | None = None, noun: str = "direction",
               unsigned: bool = False) -> str:  # fmt: skip
    """A direction of a sensor's or a vehicle's axes in words.

    Without ``frame``: by its axes, e.g. ``"−z"`` or ``"+x−y"`` (the components of at least 0.4 of the unit
    direction, largest first). With ``frame``: ``"the gyro's z axis"`` (or ``names[i]``) when the direction
    is within ``within_deg`` of an axis, else ``"the gyro direction (+0.10, −0.70, +0.71)"`` (``noun`` instead
    of "direction"); ``unsigned`` for a rotation axis, whose sign means nothing: the components are turned so
    that the largest is positive.
    """
    unit = np.asarray(direction, dtype=np.float64)
    unit = unit / float(np.linalg.norm(unit))
    if frame is None:
        return "".join(
            ("+" if unit[i] > 0 else "−") + "xyz"[i] for i in np.argsort(-np.abs(unit)) if abs(unit[i]) >= 0.4
        )
    axis = int(np.argmax(np.abs(unit)))
    if abs(unit[axis]) > math.cos(math.radians(within_deg)):
        return names[axis] if names is not None else f"the {frame}'s {'xyz'[axis]} axis"
    if unsigned and unit[axis] < 0:
        unit = -unit
    return f"the {frame} {noun} ({unit[0]:+.2f}, {unit[1]:+.2f}, {unit[2]:+.2f})"


def signed_permutations() -> list[NDArray[np.float64]]:
    """The 24 proper signed permutation matrices (the rotations of a cube onto itself): every rotation lies
    within 62.8° of one. Ordered by the permutation of the columns' axes, then their signs (+ before −)."""
    found = []
    for order in itertools.permutations(range(3)):
        for signs in itertools.product((1.0, -1.0), repeat=3):
            p = np.zeros((3, 3))
            for column, (row, sign) in enumerate(zip(order, signs, strict=True)):
                p[row, column] = sign  # column `column` lies along axis `row`
            if np.linalg.det(p) > 0:
                found.append(p)
    return found
