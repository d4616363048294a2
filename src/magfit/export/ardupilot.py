"""ArduPilot compass parameters (``.param``): COMPASS_OFS_*, COMPASS_DIA_*, COMPASS_ODI_*, COMPASS_SCALE.

ArduPilot's convention, from ``AP_Compass_Backend::correct_field`` (libraries/AP_Compass), applied
to every sample in milligauss, in the body frame (after COMPASS_ORIENT / AHRS_ORIENTATION)::

    mag += (OFS_X, OFS_Y, OFS_Z)                  # offsets are ADDED
    mag *= SCALE                                  # only when 0.85 <= SCALE <= 1.4 (have_scale_factor)
    mag  = [[DIA_X, ODI_X, ODI_Y],
            [ODI_X, DIA_Y, ODI_Z],
            [ODI_Y, ODI_Z, DIA_Z]] @ mag          # a SYMMETRIC matrix

magfit's ``corrected = matrix @ (raw - offset)`` (paper eq. 5) maps onto it with ``k`` the factor
from the samples' unit to milligauss (10 for µT, 1000 for gauss)::

    OFS = -k * offset      DIA = diag(matrix)      ODI = (matrix[0,1], matrix[0,2], matrix[1,2])
    SCALE = 1

so ArduPilot's corrected field is ``k`` times magfit's. SCALE = 1 is a no-op inside ArduPilot's
accepted range: magfit's field is already in physical milligauss (a physical unit is required), so
no further scaling is wanted; if the local field strength B is known (World Magnetic Model), set
SCALE = B / field_strength by hand, as ArduPilot's own calibrator does. A Cholesky-root matrix is
replaced by its symmetric root (same ellipsoid, see :func:`._common.symmetric_matrix`).

Refused, rather than written wrong (ArduPilot would reject, ignore or fail to arm):

- no unit or raw counts: ArduPilot needs milligauss;
- ``|OFS| > 1800`` mG: the arming check fails when the offset length exceeds COMPASS_OFFS_MAX
  (default 1800, AP_Compass.cpp) and the calibrator rejects any axis beyond it;
- a diagonal outside (0.2, 5) or an off-diagonal with ``|ODI| >= 1``: outside what
  ``CompassCalibrator::fit_acceptable`` accepts;
- a field strength outside [185, 875] mG: the arming check "Check mag field"
  (AP_ARMING_COMPASS_MAGFIELD_MIN/MAX, 0.35 and 1.65 x 530 mG) fails; usually a wrong unit;
- a non-symmetric matrix other than a Cholesky root.

Written with a ``# WARNING`` line: an offset axis beyond +-400 mG, the ``@Range`` of COMPASS_OFS_*
in AP_Compass.cpp's parameter documentation. ArduPilot itself accepts it, but Mission Planner checks
the documented range when a value is loaded or edited (ConfigRawParams.cs) and asks "COMPASS_OFS_X
value is out of range. Do you want to continue?"; answering No keeps the old value.

**Several compasses.** ArduPilot calibrates up to three: slot 0 is ``COMPASS_OFS_*``,
``COMPASS_DIA_*``, ``COMPASS_ODI_*``, ``COMPASS_SCALE``, ``COMPASS_ORIENT``; slot 1 the same names with 2
(``COMPASS_OFS2_X``, ``COMPASS_SCALE2``), slot 2 with 3. The slot and the device id come from the
``slot=`` / ``device_id=`` options or from ``calibration.sensor`` (filled from a flight log);
:func:`magfit.export.export_several` writes several compasses in one file. ``COMPASS_DEV_ID*`` is written
as a comment, not a parameter: ArduPilot sets it itself at boot (``@ReadOnly``) from the detected sensor,
and ``Compass::configured`` (AP_Compass.cpp) treats a compass whose stored ``COMPASS_DEV_ID`` differs from
the detected one as not calibrated ("Compass not calibrated" at arming), so a loaded id can only break a
vehicle whose compass order differs; the comment tells the user which id to check before loading.

**COMPASS_SCALE** (option ``expected_field``, the World Magnetic Model's field strength in the
calibration's unit): ``CompassCalibrator::fix_radius`` sets ``scale_factor = expected_radius / radius``,
where ``radius`` is the fitted sphere after DIA/ODI, and fails the calibration ("bad radius") outside
``COMPASS_MIN/MAX_SCALE_FACTOR`` = 0.85-1.4 (CompassCalibrator.h); ``Compass::have_scale_factor`` ignores
a SCALE outside that range. magfit writes ``SCALE = expected_field / field_strength`` and refuses it
outside 0.85-1.4 with the reason. Without ``expected_field``, SCALE = 1 (ArduPilot's calibrator writes 0,
"no scale", when it has no GPS position; both leave the field as fitted).

**A vehicle-frame calibration** (``frame == "vehicle"``: ``corrected_vehicle = M @ (raw - offset)``, M
general). ``AP_Compass_Backend::accumulate_sample`` calls ``rotate_field`` (the driver's rotation, then,
for an external compass, ``COMPASS_ORIENT``) *before* ``correct_field``, so ArduPilot applies::

    corrected = D @ (SCALE * (R @ raw + OFS))

With the polar split ``M = Q @ S`` (:func:`magfit.rotations.polar_decomposition`), ``R = Q`` and
``D = Q S Qᵀ`` (symmetric, as DIA/ODI must be) and ``OFS = -k Q @ offset`` (the offsets live in the
rotated frame) give ``D @ (R @ raw + OFS) = k M @ (raw - offset)`` exactly. R is written as
``COMPASS_ORIENT``: the nearest fixed rotation (:func:`magfit.rotations.nearest_rotation`) when it is
within :data:`._common.ROTATION_TOLERANCE_DEG` of Q (D then uses it, and the residual rotation, with the
heading error it costs, is stated), else ArduPilot 4.2's custom rotation ``COMPASS_ORIENT = 102`` with
``CUST_ROT2_ROLL/PITCH/YAW`` (``CUST_ROT_ENABLE = 1``), exact. Not CUST_ROT1: ArduPilot's own parameter
conversion gives CUST_ROT1 to a custom board orientation (``AP_AHRS::init``, ``AHRS_ORIENTATION = 101``) and
CUST_ROT2 to a compass (``Compass::init``), so a second compass needing a custom rotation is refused. While
``CUST_ROT_ENABLE`` is 0, ArduPilot hides ``CUST_ROT2_*`` (``AP_PARAM_FLAG_ENABLE`` on ``CUST_ROT_ENABLE`` in
AP_CustomRotations.cpp), so a ground station that fetched the parameters before cannot set them: one load
leaves ``COMPASS_ORIENT = 102`` with the identity. The file opens with :data:`LOAD_TWICE`: load, reboot,
refresh, load again. A mirror (det M < 0) is refused: ArduPilot's rotations are proper. The samples must be the
sensor's field with ``COMPASS_ORIENT = 0`` and no calibration applied; ArduPilot applies
``COMPASS_ORIENT`` to external compasses only (an internal one follows ``AHRS_ORIENTATION``), which the
file says when the rotation is not the identity.

The file uses Mission Planner's ``NAME,VALUE`` lines (MAVProxy's ``param load`` reads them too) and
``#`` comments.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from ..calibration import Calibration
from ..errors import ExportError, OptionError
from ..remedy import option
from ..rotations import custom_angles
from ..units import field_unit_reason
from ._common import (
    ROTATION_TOLERANCE_DEG,
    SlotParameters,
    VehicleSplit,
    check_distinct_slots,
    describe,
    factor,
    float32_text,
    physical_unit,
    plain,
    samples_note,
    sensor_slot,
    symmetric_matrix,
    vehicle_split,
)
from ._heading import ASSUMPTION, heading_error_deg
from ._motor import ARDUPILOT_MOTCT, MOT_RANGE_MG, ardupilot_mot, chosen_regressor, describe_term, mismatch_comment

#: COMPASS_OFFS_MAX default (AP_COMPASS_OFFSETS_MAX_DEFAULT), mG: arming fails when |COMPASS_OFS| exceeds it.
OFFSET_MAX_MG = 1800.0
#: The documented @Range of COMPASS_OFS_* (mG); Mission Planner asks before loading a value outside it.
OFFSET_RANGE_MG = 400.0
#: CompassCalibrator::fit_acceptable: 0.2 < DIA < 5.0 (exclusive).
DIAGONAL_RANGE = (0.2, 5.0)
#: CompassCalibrator::fit_acceptable: |ODI| < 1.0.
OFFDIAGONAL_MAX = 1.0
#: AP_Arming "Check mag field": 185 <= |field| <= 875 mG.
FIELD_RANGE_MG = (185.0, 875.0)
#: COMPASS_MIN/MAX_SCALE_FACTOR (CompassCalibrator.h): outside, Compass::have_scale_factor() ignores SCALE
#: and CompassCalibrator::fix_radius fails the calibration ("bad radius").
SCALE_RANGE = (0.85, 1.4)
#: The documented @Range of COMPASS_SCALE* (AP_Compass.cpp): Mission Planner asks before loading a value above it.
SCALE_DOCUMENTED_MAX = 1.3
#: The COMPASS_SCALE written without an expected field: magfit's corrected field is already in milligauss.
SCALE = 1.0
#: Compasses ArduPilot calibrates (COMPASS_OFS, OFS2, OFS3).
COMPASS_COUNT = 3
#: The custom rotation a compass gets: CUST_ROT2, COMPASS_ORIENT = 102 (ROTATION_CUSTOM_2 in rotations.h,
#: ArduPilot 4.2+). ArduPilot has two (NUM_CUST_ROT, AP_CustomRotations.h), and its own parameter conversion
#: gives CUST_ROT1 to the board (AP_AHRS::init: AHRS_ORIENTATION 100 becomes 101, AHRS_CUSTOM_ROLL/PIT/YAW go
#: to CUST_ROT1_*) and CUST_ROT2 to a compass (Compass::init: COMPASS_ORIENT 100 becomes 102). Writing CUST_ROT1
#: would turn the board of a vehicle with AHRS_ORIENTATION = 101, so a compass never gets it.
COMPASS_CUSTOM_ROTATION = 2
#: COMPASS_ORIENT's value for CUST_ROTn is 100 + n.
ROTATION_CUSTOM_BASE = 100
#: CUST_ROTn_* exist only while CUST_ROT_ENABLE is 1: AP_CustomRotations declares CUST_ROT_ENABLE with
#: AP_PARAM_FLAG_ENABLE, and AP_Param hides the rest of such a group while it is 0 (_hide_disabled_groups),
#: so a ground station that fetched the parameters before has no CUST_ROTn_* to set. The file says so.
LOAD_TWICE = (
    "# LOAD THIS FILE TWICE. CUST_ROT2_ROLL/PITCH/YAW exist only while CUST_ROT_ENABLE = 1 (AP_CustomRotations;",
    "#   ArduPilot hides them while it is 0): the first load sets CUST_ROT_ENABLE (Mission Planner reports the",
    "#   CUST_ROT2_* lines missing, MAVProxy skips them). Reboot, refresh the parameters (Mission Planner:",
    "#   Refresh Params; MAVProxy: param fetch), load this file again and reboot. After the first load alone,",
    "#   COMPASS_ORIENT = 102 turns the field by CUST_ROT2 = 0, 0, 0: no rotation at all. Do not fly in between.",
)


def suffix(slot: int) -> str:
    """The parameter suffix of compass ``slot`` (0-based): ``""``, ``"2"``, ``"3"``."""
    return "" if slot == 0 else str(slot + 1)


def external(slot: int) -> str:
    """The parameter that marks compass ``slot`` external: COMPASS_EXTERNAL, then COMPASS_EXTERN2, EXTERN3."""
    return "COMPASS_EXTERNAL" if slot == 0 else f"COMPASS_EXTERN{slot + 1}"


def parameter_names(slot: int) -> tuple[str, ...]:
    """The ten calibration parameters of compass ``slot`` (0-based), offsets first, SCALE last."""
    n = suffix(slot)
    return (
        *(f"COMPASS_OFS{n}_{a}" for a in "XYZ"),
        *(f"COMPASS_DIA{n}_{a}" for a in "XYZ"),
        *(f"COMPASS_ODI{n}_{a}" for a in "XYZ"),
        f"COMPASS_SCALE{n}",
    )


NAMES = parameter_names(0)


def ardupilot_parameters(
    calibration: Calibration,
    unit: str | None = None,
    *,
    slot: int | None = None,
    device_id: int | None = None,
    expected_field: float | None = None,
) -> dict[str, float]:
    """The COMPASS_* values of one compass (milligauss offsets), after checking ArduPilot's limits.

    Parameters
    ----------
    calibration : Calibration
        The calibration; ``offset`` and ``field_strength`` in the samples' unit.
    unit : str or None
        The samples' unit, overriding ``calibration.unit``; must be physical (not counts).
    slot, device_id : int or None
        ArduPilot's compass slot (0-based: 0 writes COMPASS_OFS_*, 1 COMPASS_OFS2_*) and the sensor's
        device id; default from ``calibration.sensor``, else slot 0.
    expected_field : float or None
        The local field strength (World Magnetic Model) in the calibration's unit: fills COMPASS_SCALE.

    Returns
    -------
    dict
        Parameter name -> value: offsets, DIA, ODI, SCALE, then for a vehicle-frame calibration
        COMPASS_ORIENT (and CUST_ROT_ENABLE, CUST_ROT1_* for a custom rotation).

    Raises
    ------
    ExportError
        No physical unit, ArduPilot would reject the values (see the module docstring), or a mirror.
    OptionError
        ``unit`` is not a unit magfit knows, or an option is out of range.
    """
    return _compass(calibration, unit, slot, device_id, expected_field, custom=1).parameters


def _compass(
    calibration: Calibration,
    unit: str | None,
    slot: int | None,
    device_id: int | None,
    expected_field: float | None,
    custom: int,
) -> SlotParameters:
    """The parameters and comments of one compass; ``custom`` is the CUST_ROTn it may use."""
    where = sensor_slot(calibration, "ardupilot", COMPASS_COUNT, slot, device_id)
    source = physical_unit(calibration, unit, "ardupilot", "milligauss")
    k = factor(source, "mG")
    # The field first: a wrong unit shows there, before it inflates the offset.
    field = k * calibration.field_strength
    if not FIELD_RANGE_MG[0] <= field <= FIELD_RANGE_MG[1]:
        mismatch = field_unit_reason(calibration.field_strength, source.name)
        raise ExportError(
            f"ArduPilot would refuse to arm ('Check mag field'): the corrected field is {field:.4g} mG, outside "
            f"{FIELD_RANGE_MG[0]:.0f}-{FIELD_RANGE_MG[1]:.0f} mG; "
            + f"check the unit of the samples ({option('unit', source.name)} was used)"
            + (f": {mismatch}" if mismatch else ""),
            codes=("unit_mismatch",) if mismatch else (),
            remedy=mismatch.remedy if mismatch else (),
        )
    length = k * float(np.linalg.norm(calibration.offset))
    if length > OFFSET_MAX_MG:
        raise ExportError(
            f"ArduPilot would refuse to arm: the compass offset is {length:.0f} mG long, above COMPASS_OFFS_MAX "
            f"({OFFSET_MAX_MG:.0f} mG by default); mount the compass further from magnetised parts and recalibrate"
        )
    n = suffix(where.slot)
    comments: list[str] = []
    orientation: dict[str, float] = {}
    if calibration.frame == "vehicle":
        split = vehicle_split(calibration, "ardupilot", "ardupilot")
        rotation, orientation, comments = _orientation(calibration, split, where.slot, custom)
        matrix = rotation @ split.symmetric @ rotation.T  # D = R S R^T: symmetric, D R = R S
        offsets = -k * (rotation @ calibration.offset)  # ArduPilot adds its offsets, after the rotation
    else:
        matrix = symmetric_matrix(calibration, "ardupilot").matrix
        offsets = -k * calibration.offset  # ArduPilot adds its offsets: mag += OFS
    diagonal = np.diag(matrix)
    offdiagonal = np.array([matrix[0, 1], matrix[0, 2], matrix[1, 2]])
    low, high = DIAGONAL_RANGE
    if not np.all((diagonal > low) & (diagonal < high)):
        raise ExportError(
            f"ArduPilot's calibrator accepts COMPASS_DIA only in ({low}, {high}), got "
            f"{np.array2string(diagonal, precision=4)}; the soft-iron distortion is too strong for ArduPilot"
        )
    if not np.all(np.abs(offdiagonal) < OFFDIAGONAL_MAX):
        raise ExportError(
            f"ArduPilot's calibrator accepts |COMPASS_ODI| < {OFFDIAGONAL_MAX} only, got "
            f"{np.array2string(offdiagonal, precision=4)}; the soft-iron distortion is too strong for ArduPilot"
        )
    scale = _scale(calibration, k, expected_field)
    values = [*offsets, *diagonal, *offdiagonal, scale]
    parameters = dict(zip(parameter_names(where.slot), (float(v) for v in values), strict=True)) | orientation
    if calibration.motor is not None:  # the motors' field, added after the matrix (export/_motor.py)
        mot = ardupilot_mot(calibration, matrix @ rotation if calibration.frame == "vehicle" else matrix, k, scale)
        parameters |= {f"COMPASS_MOT{n}_{axis}": float(v) for axis, v in zip("XYZ", mot, strict=True)}
        parameters["COMPASS_MOTCT"] = float(ARDUPILOT_MOTCT[calibration.motor.regressor])
        comments.append(describe_term(calibration))
        if np.any(np.abs(mot) > MOT_RANGE_MG):
            comments.append(f"# WARNING: a COMPASS_MOT{n}_* value is beyond +-{MOT_RANGE_MG:.0f}, its documented range")
    if expected_field is not None:
        comments.insert(
            0,
            f"#   COMPASS_SCALE{n} = expected field {float32_text(k * expected_field)} mG / fitted "
            f"{float32_text(field)} mG (CompassCalibrator::fix_radius)",
        )
    sensor = f" ({where.name})" if where.name else ""
    if where.device_id is not None:
        head = [
            f"# compass {where.slot + 1}{sensor}: COMPASS_*{n} parameters, fitted for the sensor with "
            f"COMPASS_DEV_ID{n} = {where.device_id}",
            f"#   (ArduPilot sets COMPASS_DEV_ID{n} at boot: load this only if the vehicle shows that id there)",
        ]
    else:
        head = [f"# compass {where.slot + 1}{sensor}: COMPASS_*{n} parameters (the sensor's device id is not known)"]
    comments[:0] = head
    beyond = [name for name in parameter_names(where.slot)[:3] if abs(parameters[name]) > OFFSET_RANGE_MG]
    if beyond:
        comments += [
            f"# WARNING: {', '.join(beyond)} beyond +-{OFFSET_RANGE_MG:.0f} mG, the documented range: Mission Planner",
            "#   asks '<name> value is out of range. Do you want to continue?' when loading this file; answer Yes,",
            "#   or it keeps the old value (ArduPilot itself accepts offsets up to COMPASS_OFFS_MAX).",
        ]
    if scale > SCALE_DOCUMENTED_MAX:
        comments.append(
            f"# WARNING: COMPASS_SCALE{n} = {scale:.3f} is above its documented range (0-{SCALE_DOCUMENTED_MAX}): "
            "Mission Planner asks before loading it; ArduPilot itself uses it up to 1.4 (Compass::have_scale_factor)"
        )
    note = symmetric_matrix(calibration, "ardupilot").note if calibration.frame == "sensor" else None
    if note is not None:
        comments.append(f"# NOTE: {plain(note)}")
    return SlotParameters(where.slot, parameters, comments)


def _orientation(
    calibration: Calibration, split: VehicleSplit, slot: int, custom: int
) -> tuple[NDArray[np.float64], dict[str, float], list[str]]:
    """The rotation R ArduPilot will apply to compass ``slot``, its parameters and comment lines.

    The nearest fixed COMPASS_ORIENT within the tolerance, else the custom rotation CUST_ROT``custom``.
    """
    n = suffix(slot)
    comments: list[str] = []
    orientation: dict[str, float] = {}
    assert split.standard is not None
    if split.standard.angle_deg <= ROTATION_TOLERANCE_DEG:
        rotation = np.asarray(split.standard.matrix)
        applied = rotation @ split.symmetric
        loss = heading_error_deg(calibration, applied, calibration.offset)
        orientation[f"COMPASS_ORIENT{n}"] = float(split.standard.id)
        comments.append(
            f"# COMPASS_ORIENT{n} = {split.standard.id} ({split.standard.name}) is "
            f"{split.standard.angle_deg:.2f} deg from the fitted alignment (tolerance "
            f"{ROTATION_TOLERANCE_DEG} deg): a heading error of up to {loss:.2f} deg ({ASSUMPTION})"
        )
    else:
        if custom > 1:
            raise ExportError(
                f"compass slot {slot} needs a custom rotation too (its alignment is {split.standard.angle_deg:.1f} "
                "deg from every fixed COMPASS_ORIENT), and another compass of this file has CUST_ROT2; ArduPilot's "
                "other one, CUST_ROT1, is the board's (its parameter conversion gives it to AHRS_ORIENTATION 101), "
                "so magfit does not write it: mount one compass on a fixed orientation (within "
                f"{ROTATION_TOLERANCE_DEG} deg), or export the compasses in separate files and set the second's "
                "rotation by hand where AHRS_ORIENTATION is not 101"
            )
        rotation = split.rotation
        roll, pitch, yaw = custom_angles(rotation, "ardupilot")
        k = COMPASS_CUSTOM_ROTATION
        orientation["CUST_ROT_ENABLE"] = 1.0
        orientation[f"COMPASS_ORIENT{n}"] = float(ROTATION_CUSTOM_BASE + k)
        orientation |= {
            f"CUST_ROT{k}_{axis}": value
            for axis, value in zip(("ROLL", "PITCH", "YAW"), (roll, pitch, yaw), strict=True)
        }
        comments.append(
            f"# COMPASS_ORIENT{n} = {ROTATION_CUSTOM_BASE + k}: custom rotation CUST_ROT{k} (ArduPilot 4.2+), the "
            f"fitted alignment exactly; the nearest fixed one, {split.standard.name}, is "
            f"{split.standard.angle_deg:.2f} deg away. CUST_ROT1 is left to the board (AHRS_ORIENTATION 101)"
        )
    if not np.allclose(rotation, np.eye(3)):
        comments.append(
            f"# WARNING: ArduPilot applies COMPASS_ORIENT{n} to an external compass only "
            f"({external(slot)} = 1, AP_Compass_Backend::rotate_field); an internal one follows "
            "AHRS_ORIENTATION, which turns the board"
        )
    return rotation, orientation, comments


def _scale(calibration: Calibration, k: float, expected_field: float | None) -> float:
    """COMPASS_SCALE: expected / fitted field, as CompassCalibrator::fix_radius sets it; 1 without a model."""
    if expected_field is None:
        return SCALE
    if isinstance(expected_field, bool) or not isinstance(expected_field, (int, float, np.floating, np.integer)):
        raise OptionError(f"expected_field must be a field strength in the calibration's unit; got {expected_field!r}")
    expected = float(expected_field)
    if not math.isfinite(expected) or expected <= 0:
        raise OptionError(f"expected_field must be a positive field strength in the calibration's unit; got {expected}")
    scale = expected / calibration.field_strength
    low, high = SCALE_RANGE
    if not low <= scale <= high:
        raise ExportError(
            f"ArduPilot's calibrator rejects a scale factor outside {low}-{high} ('bad radius', "
            f"CompassCalibrator::fix_radius) and ignores COMPASS_SCALE there: the fitted field "
            f"{k * calibration.field_strength:.4g} mG is {1 / scale:.3g} x the expected {k * expected:.4g} mG; "
            "check the samples' unit, the expected field's unit and place, or a magnetic disturbance in the recording"
        )
    return scale


def write_ardupilot(
    calibration: Calibration,
    unit: str | None = None,
    *,
    slot: int | None = None,
    device_id: int | None = None,
    expected_field: float | None = None,
) -> str:
    """The calibration as an ArduPilot ``.param`` file (``NAME,VALUE`` lines; see the module docstring)."""
    compass = _compass(calibration, unit, slot, device_id, expected_field, custom=1)
    return _file([calibration], [compass], unit)


def write_ardupilot_several(
    calibrations: Sequence[Calibration],
    unit: str | None = None,
    *,
    slots: Sequence[int | None] | None = None,
    device_ids: Sequence[int | None] | None = None,
    expected_field: float | None = None,
) -> str:
    """Several compasses of one vehicle in one ``.param`` file; each in its own slot."""
    compasses: list[SlotParameters] = []
    custom = 1
    calibrations = list(calibrations)
    for index, calibration in enumerate(calibrations):
        slot = None if slots is None else slots[index]
        device_id = None if device_ids is None else device_ids[index]
        compass = _compass(calibration, unit, slot, device_id, expected_field, custom)
        if any(name.startswith("CUST_ROT") for name in compass.parameters):
            custom += 1
        compasses.append(compass)
    check_distinct_slots([c.slot for c in compasses], lambda slot: f"ardupilot compass slot {slot}")
    compasses = _one_motct(calibrations, compasses)
    order = sorted(range(len(compasses)), key=lambda i: compasses[i].slot)
    return _file([calibrations[i] for i in order], [compasses[i] for i in order], unit)


def _one_motct(calibrations: Sequence[Calibration], compasses: list[SlotParameters]) -> list[SlotParameters]:
    """COMPASS_MOTCT is one setting for all compasses (export/_motor.py): the chosen regressor's; a compass whose
    term follows the other one, or that has none, gets zero COMPASS_MOTn_* (never the vehicle's old values)."""
    chosen = chosen_regressor(calibrations)
    if chosen is None:
        return compasses
    result = []
    for calibration, compass in zip(calibrations, compasses, strict=True):
        n = suffix(compass.slot)
        parameters, comments = dict(compass.parameters), list(compass.comments)
        if calibration.motor is None or calibration.motor.regressor != chosen:
            if calibration.motor is not None:
                comments += mismatch_comment(calibration, chosen, "COMPASS_MOTCT")
            parameters |= {f"COMPASS_MOT{n}_{axis}": 0.0 for axis in "XYZ"}
        parameters["COMPASS_MOTCT"] = float(ARDUPILOT_MOTCT[chosen])
        result.append(SlotParameters(compass.slot, parameters, comments))
    return result


def _file(calibrations: Sequence[Calibration], compasses: list[SlotParameters], unit: str | None) -> str:
    first = calibrations[0]
    source = physical_unit(first, unit, "ardupilot", "milligauss")
    k = factor(source, "mG")
    which = ", ".join(f"{c.slot + 1} (COMPASS_*{suffix(c.slot)})" for c in compasses)
    custom = any("CUST_ROT_ENABLE" in c.parameters for c in compasses)
    lines = [
        f"# ArduPilot compass calibration: compass {which}",
        *(LOAD_TWICE if custom else ()),
        *(f"# {line}" for line in describe(first, source.name) if len(compasses) == 1),
        "# ArduPilot corrects each sample (AP_Compass_Backend::correct_field), in milligauss, body frame:",
        "#   mag += (OFS_X, OFS_Y, OFS_Z)",
        f"#   mag *= SCALE   (only if {SCALE_RANGE[0]} <= SCALE <= {SCALE_RANGE[1]}: Compass::have_scale_factor)",
        "#   mag = [[DIA_X, ODI_X, ODI_Y], [ODI_X, DIA_Y, ODI_Z], [ODI_Y, ODI_Z, DIA_Z]] * mag",
    ]
    if any(c.frame == "vehicle" for c in calibrations):
        lines += [
            "# after rotate_field has turned the sensor's reading by COMPASS_ORIENT (R): mag = R * raw first.",
            "# vehicle frame: magfit's matrix M = Q S (rotation Q after the soft-iron S) maps onto R = Q,",
            "#   DIA/ODI = Q S Q^T, OFS = -Q * offset * k: ArduPilot's corrected field = k * M (raw - offset).",
            *samples_note(
                next(c for c in calibrations if c.frame == "vehicle"),
                ["# Samples must be the sensor's field logged with COMPASS_ORIENT = 0 and no calibration applied."],
            ),
        ]
    if any(c.frame == "sensor" for c in calibrations):
        lines += [
            f"# mapping: OFS = -offset * {float32_text(k)} ({source.name} -> mG), DIA/ODI = magfit's matrix, "
            "SCALE = 1 or expected / fitted field;",
            f"#   ArduPilot's corrected field = {float32_text(k)} x magfit's, radius "
            f"{float32_text(k * first.field_strength)} mG",
            "# Samples must be ArduPilot's body-frame field logged with no calibration applied",
            "#   (COMPASS_OFS = 0, COMPASS_DIA = 1, COMPASS_ODI = 0, COMPASS_SCALE = 0).",
        ]
    if any(c.motor is not None for c in calibrations):
        lines += [
            "#   mag += MOT * x   (after the matrix; x: the throttle 0-1 if COMPASS_MOTCT = 1, the current in A if 2)",
            "# motors' field: MOT = -k * SCALE * (D R) * k_m, magfit's term k_m c removed before the offset",
        ]
    lines.append(
        "# Load: Mission Planner > Config > Full Parameter List > Load from file, or MAVProxy 'param load <file>'."
    )
    written: set[str] = set()
    for calibration, compass in zip(calibrations, compasses, strict=True):
        if len(compasses) > 1:
            lines += [f"# {line}" for line in describe(calibration, source.name)]
        lines += compass.comments
        # CUST_ROT_ENABLE is one parameter for both custom rotations: written once.
        lines += [f"{name},{float32_text(v)}" for name, v in compass.parameters.items() if name not in written]
        written |= set(compass.parameters)
    return "\n".join(lines) + "\n"
