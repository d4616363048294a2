"""ArduPilot's parameters as its logs carry them (DataFlash ``PARM``, a telemetry log's ``PARAM_VALUE``): the
compass calibration the firmware applied and how to undo it, the compass's mounting, the attitude's trim.

``parameters`` maps a name to its ``(time_s, value)`` pairs in the order the log gave them. Shared by
:mod:`magfit.sources.dataflash` and :mod:`magfit.sources.tlog`: the firmware is the same, only the log differs.

Logs as they are:

- A parameter the firmware did not have means its default. COMPASS_DIA/ODI came with the onboard calibrator
  (Copter 3.3), COMPASS_SCALE later (4.0): a log whose parameters hold COMPASS_OFS_X but no COMPASS_DIA_X was
  written by a firmware that applied no soft-iron matrix (all-zero diagonals are the identity, as the firmware
  reads them), and no scale.
- A calibration changed during the log (a recalibration, COMPASS_LEARN): each record is undone with the
  parameters in effect when it was logged (:func:`value_in_effect`). Where the record carries the offsets it was
  corrected with (DataFlash MAG's OfsX/Y/Z) and they are not the parameters' (offsets learned in flight and not
  saved), the record's own are used.
- A damaged record (offsets or a time stamp unlike both its neighbours, which agree) is skipped and counted
  (:func:`undo_records`).
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
    "UndoneRecords",
    "compass_mounting",
    "compass_parameters",
    "describe_parameters",
    "first_value",
    "parameter_suffix",
    "soft_iron_matrix",
    "undo_calibration",
    "undo_records",
    "untrimmed",
    "value_in_effect",
    "without_damaged_changes",
]

#: A log's parameters: name -> [(time_s, value), ...] in the log's order.
Parameters = dict[str, list[tuple[float, float]]]
#: COMPASS_SCALE is applied only inside this range (AP_Compass's have_scale_factor, CompassCalibrator.h).
SCALE_RANGE = (0.85, 1.4)


def first_value(parameters: Parameters, name: str) -> float | None:
    """The parameter's first value in the log (:func:`value_in_effect` follows the changes after it)."""
    values = parameters.get(name)
    return values[0][1] if values else None


def value_in_effect(
    parameters: Parameters, name: str, times: NDArray[np.float64], default: float = 0.0
) -> NDArray[np.float64]:
    """The parameter's value in effect at each of ``times`` (its first value before it was first logged),
    ``default`` when the log does not have it.

    Values logged at the same time keep the log's order (the later one wins); a value logged without a time
    (a firmware whose PARM has no time stamp) cannot be placed and counts only when it is the first."""
    logged = parameters.get(name) or []
    values = [pair for i, pair in enumerate(logged) if i == 0 or np.isfinite(pair[0])]
    if not values:
        return np.full(np.shape(times), default, dtype=np.float64)
    values = sorted(values, key=lambda pair: pair[0] if np.isfinite(pair[0]) else -np.inf)
    stamps = np.array([stamp if np.isfinite(stamp) else -np.inf for stamp, _ in values], dtype=np.float64)
    settings = np.array([value for _, value in values], dtype=np.float64)
    moments = np.asarray(times, dtype=np.float64)
    index = np.clip(np.searchsorted(stamps, moments, side="right") - 1, 0, None)
    return settings[np.where(np.isfinite(moments), index, 0)]


def without_damaged_changes(parameters: Parameters) -> tuple[Parameters, int]:
    """The parameters without the values logged after a parameter's first that are not numbers (NaN, inf: a
    damaged PARM message, since a firmware stores none), and how many were dropped. A first value that is not a
    number stays: what the firmware had is then unknown, and the stream that needs it is refused."""
    kept: Parameters = {}
    dropped = 0
    for name, values in parameters.items():
        sound = [pair for i, pair in enumerate(values) if i == 0 or np.isfinite(pair[1])]
        dropped += len(values) - len(sound)
        kept[name] = sound
    return kept, dropped


def parameter_suffix(k: int) -> str:
    """The parameter suffix of compass k (0-based): '' for the first, '2', '3' for the others."""
    return "" if k == 0 else str(k + 1)


@dataclass(frozen=True)
class CompassParameters:
    """The parameters ArduPilot corrected one compass with, read from PARM (their first values; ``changes``
    says which changed later, :func:`undo_records` follows them)."""

    index: int  # k: the parameter set (COMPASS_OFS{k}...)
    offsets: NDArray[np.float64]
    diagonals: NDArray[np.float64]
    offdiagonals: NDArray[np.float64]
    scale: float
    device_id: int | None
    motor_compensation: bool
    defaults: tuple[str, ...] = ()  # the parameters this firmware did not have, taken at their defaults
    changes: tuple[str, ...] = ()  # "COMPASS_OFS_X at 120.3 s": the calibration parameters changed in the log

    @property
    def names(self) -> dict[str, list[str]]:
        """The parameter names of this compass: offsets, diagonals, offdiagonals (X, Y, Z each) and scale."""
        return _names(self.index)


def _names(k: int) -> dict[str, list[str]]:
    s = parameter_suffix(k)
    return {
        "offsets": [f"COMPASS_OFS{s}_{axis}" for axis in "XYZ"],
        "diagonals": [f"COMPASS_DIA{s}_{axis}" for axis in "XYZ"],
        "offdiagonals": [f"COMPASS_ODI{s}_{axis}" for axis in "XYZ"],
        "scale": [f"COMPASS_SCALE{s}"],
    }


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
    parameters: Parameters, slot: int, first_time: float, *, absent_means_default: bool = True
) -> tuple[CompassParameters | None, str | None]:
    """The parameters compass slot ``slot`` was corrected with, or the reason they cannot be known.

    ``absent_means_default``: the log holds every parameter the firmware had (a DataFlash log's PARM dump, a
    telemetry log's complete list), so one it lacks is one the firmware did not have, at its default. It
    applies only when the log holds COMPASS_OFS_X at all: without it the log carries no compass parameters.
    """
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
    names = _names(k)
    calibration = [*names["offsets"], *names["diagonals"], *names["offdiagonals"]]
    missing = [name for name in calibration if name not in parameters]
    complete = absent_means_default and "COMPASS_OFS_X" in parameters
    if missing and not complete:
        return None, (
            f"the log's PARM messages lack {', '.join(missing[:3])}{' ...' if len(missing) > 3 else ''}, so the "
            "calibration the firmware applied cannot be undone; log the parameters (ArduPilot writes them at the "
            "start of every log)"
        )
    defaults = tuple(name for name in [*calibration, *names["scale"]] if name not in parameters)
    every = [*calibration, *names["scale"]]
    changes = []
    for name in every:
        later = [(t, v) for t, v in parameters.get(name, [])[1:] if v != parameters[name][0][1]]
        if not later:
            continue
        if not all(np.isfinite(t) for t, _ in parameters[name]) and name not in names["offsets"]:
            return None, (
                f"{name} changed during the log and its PARM messages carry no time, so which records were "
                "corrected with which value is unknown; fit a log recorded after the change"
            )
        during = [(t, v) for t, v in later if not (np.isfinite(t) and np.isfinite(first_time) and t <= first_time)]
        if during:  # (a change before the first record is the calibration every record had)
            changes.append(f"{name} at {during[0][0]:.1f} s" if np.isfinite(during[0][0]) else f"{name} (no time)")
    values = [v for name in every for _, v in parameters.get(name, [])]
    # Every calibration the log applied must be invertible: the first, and each one a change brought.
    moments = sorted({t for name in every for t, _ in parameters.get(name, []) if np.isfinite(t)} | {first_time})
    moments_array = np.array([m for m in moments if np.isfinite(m)] or [np.nan])
    diagonals = np.column_stack([value_in_effect(parameters, n, moments_array) for n in names["diagonals"]])
    offdiagonals = np.column_stack([value_in_effect(parameters, n, moments_array) for n in names["offdiagonals"]])
    conditions = [np.linalg.cond(soft_iron_matrix(d, o)) for d, o in zip(diagonals, offdiagonals, strict=True)]
    if not all(np.isfinite(v) for v in values) or not all(np.isfinite(c) and c <= 1e6 for c in conditions):
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
            offsets=np.array([first_value(parameters, n) or 0.0 for n in names["offsets"]], dtype=np.float64),
            diagonals=np.array([first_value(parameters, n) or 0.0 for n in names["diagonals"]], dtype=np.float64),
            offdiagonals=np.array([first_value(parameters, n) or 0.0 for n in names["offdiagonals"]], dtype=np.float64),
            scale=float(first_value(parameters, f"COMPASS_SCALE{s}") or 0.0),
            device_id=int(device) if device else None,
            motor_compensation=bool(motor),
            defaults=defaults,
            changes=tuple(changes),
        ),
        None,
    )


def describe_parameters(compass: CompassParameters, where: str) -> list[str]:
    """The notes that say how a compass's calibration was undone: with which parameters (``where``: from the
    log's parameters, from PARAM_VALUE), which the firmware did not have, and which changed during the log."""
    s = parameter_suffix(compass.index)
    lacked = [name for name in compass.defaults if not name.startswith("COMPASS_SCALE")]
    groups = sorted({name.split("_")[1].rstrip("0123456789") for name in lacked})
    # Only the parameters the log has (a firmware without DIA/ODI applied the identity: the next note says so).
    absent = {name.split("_")[1].rstrip("0123456789") for name in compass.defaults}
    used = [g for g in ("OFS", "DIA", "ODI", "SCALE") if g not in absent] or ["OFS"]
    named = [f"COMPASS_{used[0]}{s}", *(f"{g}{s}" for g in used[1:])]
    notes = [f"undone with {', '.join(named[:-1])} and {named[-1]} {where}" if len(named) > 1 else
             f"undone with {named[0]} {where}"]  # fmt: skip
    if lacked:
        what = {"OFS": "no offsets", "DIA": "no soft-iron matrix", "ODI": "no soft-iron matrix"}
        default = {"OFS": "zero offsets", "DIA": "the identity matrix", "ODI": "the identity matrix"}
        applied = sorted({what[g] for g in groups if g in what})
        defaults = sorted({default[g] for g in groups if g in default}, reverse=True)
        notes.append(
            f"this firmware has no {', '.join(f'COMPASS_{g}{s}' for g in groups)} parameters, so it applied "
            f"{' and '.join(applied)} (the default{'s' if len(defaults) > 1 else ''}: {', '.join(defaults)})"
        )
    if compass.changes:
        notes.append(
            f"the calibration changed during the log ({', '.join(compass.changes[:3])}"
            f"{' ...' if len(compass.changes) > 3 else ''}): each record undone with the parameters in effect when "
            "it was logged"
        )
    return notes


@dataclass(frozen=True)
class UndoneRecords:
    """The raw field of a compass's records (:func:`undo_records`).

    Attributes
    ----------
    samples : ndarray, shape (N, 3)
        The board-frame raw field of every record (NaN where a record could not be undone).
    damaged : ndarray of bool, shape (N,)
        Records skipped as damaged.
    notes : tuple of str
        What was done: records undone with their own logged offsets, damaged records skipped.
    """

    samples: NDArray[np.float64]
    damaged: NDArray[np.bool_]
    notes: tuple[str, ...]


#: A record's logged offsets (whole mG) are the parameters' when they differ by at most this (int16 truncation).
_OFFSET_TOLERANCE = 1.0
#: A record whose offsets differ from both its neighbours' (which agree) by more than this is damaged, not
#: learning: in-flight learning moves the offsets by a milligauss or so between records.
_DAMAGE_STEP = 3.0


def _isolated(values: NDArray[np.float64], step: float) -> NDArray[np.bool_]:
    """Rows unlike both neighbours (by more than ``step`` on some axis) while the neighbours agree with each
    other (within ``step``): a single damaged record, not a change that lasts."""
    n = len(values)
    flagged = np.zeros(n, dtype=bool)
    if n < 3:
        return flagged
    before, here, after = values[:-2], values[1:-1], values[2:]
    with np.errstate(invalid="ignore"):
        unlike = np.any(np.abs(here - before) > step, axis=1) & np.any(np.abs(here - after) > step, axis=1)
        agree = np.all(np.abs(after - before) <= step, axis=1)
    flagged[1:-1] = unlike & agree
    return flagged


def undo_records(
    logged: NDArray[np.float64],
    times: NDArray[np.float64],
    *,
    parameters: Parameters,
    compass: CompassParameters,
    motor_offsets: NDArray[np.float64] | None = None,
    logged_offsets: NDArray[np.float64] | None = None,
) -> UndoneRecords:
    """The board-frame raw field of each record, undone with the calibration in effect when it was logged.

    Parameters
    ----------
    logged : ndarray, shape (N, 3)
        The logged field (mG), after the firmware's calibration.
    times : ndarray, shape (N,)
        The records' times, on the clock of the parameters' times (NaN: the first values apply).
    parameters, compass : the log's parameters and the compass's (:func:`compass_parameters`).
    motor_offsets : ndarray, shape (N, 3), optional
        The motor compensation added to each record (MAG's MOX/MOY/MOZ).
    logged_offsets : ndarray, shape (N, 3), optional
        The offsets each record was corrected with (MAG's OfsX/Y/Z, whole mG). A record whose offsets are not
        the parameters' in effect is undone with its own (offsets learned in flight and not saved, or saved
        without a PARM message); one unlike both its neighbours is damaged and skipped.
    """
    field = np.asarray(logged, dtype=np.float64)
    n = len(field)
    moments = np.asarray(times, dtype=np.float64)
    names = compass.names
    offsets = np.column_stack([value_in_effect(parameters, name, moments) for name in names["offsets"]])
    diagonals = np.column_stack([value_in_effect(parameters, name, moments) for name in names["diagonals"]])
    offdiagonals = np.column_stack([value_in_effect(parameters, name, moments) for name in names["offdiagonals"]])
    scale = value_in_effect(parameters, names["scale"][0], moments)
    damaged = np.zeros(n, dtype=bool)
    with np.errstate(invalid="ignore"):
        if np.any(np.isfinite(moments)):  # a time stamp unlike both neighbours' (which run on) is damage
            damaged |= ~np.isfinite(moments) | _isolated(moments[:, None], _time_step(moments))
    notes: list[str] = []
    if logged_offsets is not None:
        used = np.asarray(logged_offsets, dtype=np.float64)
        damaged |= ~np.all(np.isfinite(used), axis=1) | _isolated(used, _DAMAGE_STEP)
        with np.errstate(invalid="ignore"):
            own = ~damaged & np.any(np.abs(used - np.trunc(offsets)) > _OFFSET_TOLERANCE, axis=1)
        if np.any(own):
            offsets = np.where(own[:, None], used, offsets)
            notes.append(
                f"{int(np.count_nonzero(own))} of {n} records were corrected with offsets that are not the "
                f"COMPASS_OFS{parameter_suffix(compass.index)} parameters then in effect (learned in flight, or "
                "changed without a PARM message): undone with the offsets each record logged (OfsX/Y/Z, whole mG)"
            )
    if motor_offsets is not None:
        motor = np.asarray(motor_offsets, dtype=np.float64)
        field = field - np.where(np.isfinite(motor), motor, np.nan)
    samples = np.full((n, 3), np.nan)
    settings = np.column_stack([diagonals, offdiagonals, scale])
    changed = np.ones(n, dtype=bool)  # the settings change rarely: the unique ones are among the runs' first rows
    changed[1:] = np.any(settings[1:] != settings[:-1], axis=1)
    for setting in np.unique(settings[changed], axis=0):
        rows = np.all(settings == setting, axis=1)
        samples[rows] = undo_calibration(
            field[rows], offsets=offsets[rows], diagonals=setting[:3], offdiagonals=setting[3:6], scale=setting[6]
        )
    if np.any(damaged):
        notes.append(
            f"{int(np.count_nonzero(damaged))} of {n} records skipped as damaged (their offsets or time stamp "
            "unlike both neighbours')"
        )
    return UndoneRecords(samples=samples, damaged=damaged, notes=tuple(notes))


def _time_step(times: NDArray[np.float64]) -> float:
    """How far a time stamp may stray from its neighbours before it is damage: ten times the median interval."""
    finite = times[np.isfinite(times)]
    steps = np.diff(finite)
    steps = steps[steps > 0]
    return float(10 * np.median(steps)) if len(steps) else np.inf


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
