"""ArduPilot's parameters as its logs carry them (DataFlash ``PARM``, a telemetry log's ``PARAM_VALUE``): the
compass calibration the firmware applied and how to undo it, the compass's mounting, the attitude's trim.

``parameters`` maps a name to its ``(time_s, value)`` pairs in the order the log gave them. Shared by
:mod:`magfit.sources.dataflash` and :mod:`magfit.sources.tlog`: the firmware is the same, only the log differs.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..rotations import custom_rotation, standard_rotations
from .motion import Stream

__all__ = [
    "SCALE_RANGE",
    "CompassParameters",
    "Parameters",
    "compass_mounting",
    "compass_parameters",
    "first_value",
    "parameter_suffix",
    "soft_iron_matrix",
    "undo_calibration",
    "untrimmed",
    "value_in_effect",
]

#: A log's parameters: name -> [(time_s, value), ...] in the log's order.
Parameters = dict[str, list[tuple[float, float]]]
#: COMPASS_SCALE is applied only inside this range (AP_Compass's have_scale_factor, CompassCalibrator.h).
SCALE_RANGE = (0.85, 1.4)


def first_value(parameters: Parameters, name: str) -> float | None:
    """The parameter's first value in the log (a change later on is the caller's to refuse or follow)."""
    values = parameters.get(name)
    return values[0][1] if values else None


def value_in_effect(parameters: Parameters, name: str, times: NDArray[np.float64]) -> Any:
    """The parameter's value in effect at each of ``times`` (its first value before it was first logged), 0 when
    the log does not have it."""
    values = sorted(parameters.get(name) or [(0.0, 0.0)])
    stamps = np.array([stamp for stamp, _ in values], dtype=np.float64)
    settings = np.array([value for _, value in values], dtype=np.float64)
    return settings[np.clip(np.searchsorted(stamps, times, side="right") - 1, 0, None)]


def parameter_suffix(k: int) -> str:
    """The parameter suffix of compass k (0-based): '' for the first, '2', '3' for the others."""
    return "" if k == 0 else str(k + 1)


@dataclass(frozen=True)
class CompassParameters:
    """The parameters ArduPilot corrected one compass with, read from PARM."""

    index: int  # k: the parameter set (COMPASS_OFS{k}...)
    offsets: NDArray[np.float64]
    diagonals: NDArray[np.float64]
    offdiagonals: NDArray[np.float64]
    scale: float
    device_id: int | None
    motor_compensation: bool


def soft_iron_matrix(diagonals: Any, offdiagonals: Any) -> NDArray[np.float64]:
    """ArduPilot's soft-iron matrix: COMPASS_DIA* (all zero: ones, as the firmware), COMPASS_ODI* (xy, xz, yz)."""
    diagonal = np.ones(3) if not np.any(diagonals) else np.asarray(diagonals, dtype=np.float64)
    xy, xz, yz = np.asarray(offdiagonals, dtype=np.float64)
    return np.array([[diagonal[0], xy, xz], [xy, diagonal[1], yz], [xz, yz, diagonal[2]]])


def undo_calibration(
    logged: NDArray[np.float64],
    *,
    offsets: NDArray[np.float64],
    diagonals: NDArray[np.float64],
    offdiagonals: NDArray[np.float64],
    scale: float = 0.0,
    motor_offsets: NDArray[np.float64] | None = None,
) -> NDArray[np.float64]:
    """The board-frame raw field from MAG's logged field: the inverse of ``correct_field`` (module docstring).

    Parameters
    ----------
    logged : ndarray, shape (N, 3)
        MagX, MagY, MagZ (mG).
    offsets, diagonals, offdiagonals : ndarray, shape (3,)
        COMPASS_OFS*, COMPASS_DIA* (all zero means 1, as the firmware does) and COMPASS_ODI* (xy, xz, yz).
    scale : float
        COMPASS_SCALE*; outside 0.85..1.4 (0 by default) the firmware does not apply it.
    motor_offsets : ndarray, shape (N, 3), optional
        MOX, MOY, MOZ: the motor compensation added after the matrix.
    """
    matrix = soft_iron_matrix(diagonals, offdiagonals)
    field = np.asarray(logged, dtype=np.float64)
    if motor_offsets is not None:
        field = field - motor_offsets
    unscaled = np.linalg.solve(matrix, field.T).T
    if SCALE_RANGE[0] <= scale <= SCALE_RANGE[1]:
        unscaled = unscaled / scale
    return unscaled - np.asarray(offsets, dtype=np.float64)


def compass_parameters(
    parameters: Parameters, slot: int, first_time: float
) -> tuple[CompassParameters | None, str | None]:
    """The parameters compass slot ``slot`` was corrected with, or the reason they cannot be known."""
    k = slot
    prio = first_value(parameters, f"COMPASS_PRIO{slot + 1}_ID")
    if prio is not None and prio != 0:
        matches = [j for j in range(3) if first_value(parameters, f"COMPASS_DEV_ID{parameter_suffix(j)}") == prio]
        if not matches:
            return None, (
                f"COMPASS_PRIO{slot + 1}_ID is {int(prio)} but no COMPASS_DEV_ID* holds it, so its calibration "
                "parameters are unknown"
            )
        k = matches[0]
    s = parameter_suffix(k)
    names = {
        "offsets": [f"COMPASS_OFS{s}_{axis}" for axis in "XYZ"],
        "diagonals": [f"COMPASS_DIA{s}_{axis}" for axis in "XYZ"],
        "offdiagonals": [f"COMPASS_ODI{s}_{axis}" for axis in "XYZ"],
    }
    missing = [name for group in names.values() for name in group if name not in parameters]
    if missing:
        return None, (
            f"the log's PARM messages lack {', '.join(missing[:3])}{' ...' if len(missing) > 3 else ''}, so the "
            "calibration the firmware applied cannot be undone; log the parameters (ArduPilot writes them at the "
            "start of every log)"
        )
    every = [*names["offsets"], *names["diagonals"], *names["offdiagonals"], f"COMPASS_SCALE{s}"]
    for name in every:
        changes = [(t, v) for t, v in parameters.get(name, []) if t > first_time]
        if changes and any(v != parameters[name][0][1] for _, v in changes):
            return None, (
                f"{name} changed during the log (at {changes[0][0]:.1f} s): the samples were corrected with two "
                "calibrations; fit a log recorded after the change"
            )
    used = [first_value(parameters, name) for name in every if name in parameters]
    matrix = soft_iron_matrix(
        [first_value(parameters, n) or 0.0 for n in names["diagonals"]],
        [first_value(parameters, n) or 0.0 for n in names["offdiagonals"]],
    )
    if (
        not all(np.isfinite(v) for v in used if v is not None)
        or not np.isfinite(np.linalg.cond(matrix))
        or np.linalg.cond(matrix) > 1e6
    ):
        return None, (
            f"its calibration parameters (COMPASS_OFS{s}, DIA{s}, ODI{s}, SCALE{s}) are not finite or form a "
            "singular matrix, so the logged field cannot be undone (a damaged log, or a calibration that lost an axis)"
        )
    motor = (first_value(parameters, "COMPASS_MOTCT") or 0) != 0 or (
        k == 0 and (first_value(parameters, "COMPASS_PMOT_EN") or 0)
    )
    device = first_value(parameters, f"COMPASS_DEV_ID{s}")
    return (
        CompassParameters(
            index=k,
            offsets=np.array([first_value(parameters, n) for n in names["offsets"]], dtype=np.float64),
            diagonals=np.array([first_value(parameters, n) for n in names["diagonals"]], dtype=np.float64),
            offdiagonals=np.array([first_value(parameters, n) for n in names["offdiagonals"]], dtype=np.float64),
            scale=float(first_value(parameters, f"COMPASS_SCALE{s}") or 0.0),
            device_id=int(device) if device else None,
            motor_compensation=bool(motor),
        ),
        None,
    )


def compass_mounting(parameters: Parameters, index: int) -> tuple[NDArray[np.float64] | None, str]:
    """The rotation ArduPilot applied to compass ``index`` before logging it (AP_Compass_Backend::rotate_field,
    libraries/AP_Compass/AP_Compass_Backend.cpp): COMPASS_ORIENT* for an external compass, AHRS_ORIENTATION for
    an internal one (the chip's own orientation on its board, MAG_BOARD_ORIENTATION, is the driver's and is
    not logged)."""
    s = parameter_suffix(index)
    external = first_value(parameters, f"COMPASS_EXTERN{s}")
    if external is None:
        external = first_value(parameters, f"COMPASS_EXTERNAL{s}")
    if external is None:
        return None, f"the log has no COMPASS_EXTERN{s}: which orientation the firmware applied is unknown"
    name = f"COMPASS_ORIENT{s}" if external else "AHRS_ORIENTATION"
    value = first_value(parameters, name)
    if value is None:
        return None, f"the log has no {name}"
    index_value = int(value)
    where = "external" if external else "internal"
    found = standard_rotations("ardupilot").get(index_value)
    if found is not None:
        return np.array(found.matrix), (
            f"{name} {index_value} ({found.name}; {where} compass), already applied by the firmware before logging"
        )
    if index_value in (101, 102):  # ROTATION_CUSTOM_1/2: CUST_ROTn_ROLL/PITCH/YAW (AP_CustomRotations, 4.2 on)
        n = index_value - 100
        angles = [first_value(parameters, f"CUST_ROT{n}_{axis}") for axis in ("ROLL", "PITCH", "YAW")]
        if all(a is not None for a in angles):
            roll, pitch, yaw = (float(a) for a in angles)  # type: ignore[arg-type]
            return custom_rotation("ardupilot", roll, pitch, yaw), (
                f"{name} {index_value} (custom: CUST_ROT{n}_ROLL/PITCH/YAW {roll:g}, {pitch:g}, {yaw:g}; {where} "
                "compass), already applied by the firmware before logging"
            )
    return None, f"{name} {index_value}: a rotation whose matrix the log does not give"


def untrimmed(attitude: Stream | None, parameters: Parameters) -> Stream | None:
    """The attitude in the autopilot's body frame (the IMU's and MAG's), the trim AHRS_TRIM_X/Y taken off.

    AP_AHRS reports the attitude of the *vehicle* body, the autopilot's turned by the trim, while the IMU and
    the compasses are logged in the autopilot's body (board orientation only): the EKF's Euler angles have the
    trim subtracted (``NavEKF3_core::getEulerAngles``: ``euler = euler - dal.get_trim()``,
    libraries/AP_NavEKF3/AP_NavEKF3_Outputs.cpp), which ATT logs; the DCM's are those of
    ``_dcm_matrix * get_rotation_vehicle_body_to_autopilot_body()`` (libraries/AP_AHRS/AP_AHRS_DCM.cpp), which
    AHR2's angles log. XKQ's quaternion (and AHR2's) is the estimator's own, untrimmed. Left as it is, a trim
    of a degree turns the reference field against the magnetometer and the accelerometer by that degree.
    """
    trim = [first_value(parameters, f"AHRS_TRIM_{axis}") for axis in "XY"]
    changed = any(len({value for _, value in parameters.get(f"AHRS_TRIM_{axis}", [])}) > 1 for axis in "XY")
    if attitude is None or not (any(trim) or changed) or "Roll/Pitch/Yaw" not in attitude.name:
        return attitude
    from scipy.spatial.transform import Rotation

    # The trim in effect at each attitude: a "Calibrate Level" during the log changes it from then on.
    trim_x, trim_y = (value_in_effect(parameters, f"AHRS_TRIM_{axis}", attitude.time_s) for axis in "XY")
    rotations = Rotation.from_quat(np.where(np.isfinite(attitude.values), attitude.values, [0.0, 0.0, 0.0, 1.0]))
    offsets = np.column_stack([np.zeros_like(trim_x), trim_y, trim_x])
    if attitude.name.startswith("ATT"):  # the EKF's angles minus the trim: add it back (3-2-1, radians)
        untrimmed = Rotation.from_euler("ZYX", rotations.as_euler("ZYX") + offsets).as_quat()
    else:  # the DCM's: body_dcm = dcm · Tᵀ, T = from_euler(trim_x, trim_y, 0) (AP_AHRS::update_trig)
        untrimmed = (rotations * Rotation.from_euler("ZYX", offsets)).as_quat()
    untrimmed[~np.all(np.isfinite(attitude.values), axis=1)] = np.nan
    shown = f"AHRS_TRIM_X/Y {np.degrees(trim_x[0]):.2f}°, {np.degrees(trim_y[0]):.2f}°"
    if changed:
        last = f"{np.degrees(trim_x[-1]):.2f}°, {np.degrees(trim_y[-1]):.2f}°"
        shown += f" (changed during the log, to {last} at the end: each attitude with the trim then in effect)"
    return replace(attitude, name=f"{attitude.name}, {shown} taken off", values=untrimmed)
