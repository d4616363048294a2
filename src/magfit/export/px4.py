"""PX4 magnetometer parameters (QGroundControl ``.params``): CAL_MAG0_{X,Y,Z}OFF, _{X,Y,Z}SCALE, _{X,Y,Z}ODIAG.

PX4's convention, from ``calibration::Magnetometer::Correct`` (src/lib/sensor_calibration), applied
to every ``sensor_mag`` sample in gauss, in the sensor frame, before the rotation R (CAL_MAG0_ROT or
the board rotation)::

    corrected = R @ (S @ (raw - (XOFF, YOFF, ZOFF)))        # offsets are SUBTRACTED
    S = [[XSCALE, XODIAG, YODIAG],
         [XODIAG, YSCALE, ZODIAG],
         [YODIAG, ZODIAG, ZSCALE]]                          # a SYMMETRIC matrix

(``Magnetometer::set_offdiagonal`` puts XODIAG at (0,1), YODIAG at (0,2), ZODIAG at (1,2).)
magfit's ``corrected = matrix @ (raw - offset)`` (paper eq. 5) maps onto it with ``k`` the factor
from the samples' unit to gauss (0.01 for µT, 1e-5 for nT)::

    OFF = k * offset      SCALE = diag(matrix)      ODIAG = (matrix[0,1], matrix[0,2], matrix[1,2])

so PX4's corrected field (before R) is ``k`` times magfit's. A Cholesky-root matrix is replaced by
its symmetric root (same ellipsoid, see :func:`._common.symmetric_matrix`).

Refused, rather than written wrong:

- no unit or raw counts: PX4 needs gauss;
- a field strength outside [0.2, 0.7) G: PX4's own calibration rejects such a sphere radius
  (``check_calibration_result`` in mag_calibration.cpp); usually a wrong unit;
- a diagonal <= 0: ``Magnetometer::set_scale`` silently keeps the old scales;
- a vehicle rotation more than :data:`._common.ROTATION_TOLERANCE_DEG` from every rotation 0-40: the
  rotations of current PX4 (:data:`magfit.rotations.PX4_ROTATION_MAX`; ``ParametersUpdate`` resets
  ``CAL_MAGn_ROT`` >= ``ROTATION_MAX`` to 0, no rotation, so 41-47 of mid-2020 releases are not written);
- a non-symmetric matrix other than a Cholesky root.

An offset above 1.3 G on an axis only draws a warning in PX4 (the sensor may saturate), so the file
is written with a ``# WARNING`` line.

PX4 ignores small changes: ``calibration::Magnetometer::set_offset``, ``set_scale`` and
``set_offdiagonal`` (src/lib/sensor_calibration/Magnetometer.cpp, PX4-Autopilot a412449) take a new
OFF, SCALE or ODIAG vector only when it differs from the value in use by more than 0.01 (Euclidean
length of the three-vector); otherwise the old value stays. And at every boot the value in use is the
default: the ``Magnetometer`` object starts with ``Reset()`` (OFF 0, SCALE 1, ODIAG 0), then
``set_device_id`` calls ``ParametersUpdate``, which passes the stored parameters through the same three
setters. So a stored vector within 0.01 of its default is dropped at every boot, whatever was set before
the reboot: no parameter value can make PX4 keep it (setting a value 0.05 away and back, which passes
the rule at run time, lasts only until the next reboot). When a vector of this calibration lies within
0.01 of its default, the file says so with the heading error PX4 flies with
(:func:`._heading.heading_error_deg`).

The file is QGroundControl's parameter file format: ``#`` comments, then tab-separated
``Vehicle-Id Component-Id Name Value Type`` lines (type 9 = MAV_PARAM_TYPE_REAL32, 6 = INT32), for the
vehicle ``system_id`` (1 unless given: older QGroundControl refuses a file whose id differs from the
vehicle's) and component 1.

**Several magnetometers**: PX4 keeps four calibration slots, ``CAL_MAG0_*`` .. ``CAL_MAG3_*``,
and applies slot n to the sensor whose device id is ``CAL_MAGn_ID`` (``FindCalibrationIndex`` in
src/lib/sensor_calibration/Utilities.cpp, called by ``Magnetometer::ParametersUpdate``). The slot and the
device id come from the ``slot=`` / ``device_id=`` options or from ``calibration.sensor`` (filled from the
log's ``sensor_mag.device_id``); with a device id the file writes ``CAL_MAGn_ID`` (INT32), so PX4 finds the
calibration; without one, PX4 applies the slot only if it already holds the sensor's id (calibrate once in
QGroundControl first). :func:`magfit.export.export_several` writes several in one file.

**A vehicle-frame calibration** (``frame == "vehicle"``, ``corrected_vehicle = M @ (raw - offset)``).
``Magnetometer::Correct`` (Magnetometer.hpp) applies the rotation *after* the scale matrix: ``R @ (S @ (raw -
OFF))``, so the polar split ``M = Q @ S`` (:func:`magfit.rotations.polar_decomposition`) maps onto it with
``S`` as SCALE/ODIAG, ``OFF = k offset`` (in the sensor frame) and R = Q. PX4 has no custom rotation:
``CAL_MAGn_ROT`` takes only the fixed rotations of rotation.h, 0-40 in current PX4 (``ParametersUpdate``
resets any other value to 0, no rotation), so the file writes the nearest fixed one when it is within
:data:`._common.ROTATION_TOLERANCE_DEG` of Q (the residual's heading error stated) and refuses otherwise. An
internal magnetometer ignores ``CAL_MAGn_ROT`` (PX4 resets it to -1 and uses ``SENS_BOARD_ROT``), which the
file says when R is not the identity. A mirror is refused.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from ..calibration import Calibration
from ..errors import ExportError, OptionError
from ..remedy import option
from ..rotations import PX4_ROTATION_MAX
from ..temperature import TemperatureDrift
from ..units import field_unit_reason
from ._common import (
    ROTATION_TOLERANCE_DEG,
    SlotParameters,
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
from ._motor import PX4_COMP_TYP, chosen_regressor, describe_term, mismatch_comment, px4_comp
from .px4_temperature import px4_temperature

#: check_calibration_result: sphere radius in [0.2, 0.7) gauss.
FIELD_RANGE_G = (0.2, 0.7)
#: MAG_MAX_OFFSET_LEN: above it on any axis PX4 warns "large offsets" (the sensor may saturate).
OFFSET_WARNING_G = 1.3
#: Magnetometer::set_offset/set_scale/set_offdiagonal: a new vector is taken only if it moves by more than this.
CHANGE_THRESHOLD = 0.01
#: MAVLink system ids a vehicle can have (0 is the broadcast id).
SYSTEM_ID_RANGE = (1, 255)
#: MAV_PARAM_TYPE_REAL32 and MAV_PARAM_TYPE_INT32, the type column of a QGroundControl parameter file.
REAL32 = 9
INT32 = 6
#: Calibration slots (Magnetometer::MAX_SENSOR_COUNT): CAL_MAG0 .. CAL_MAG3.
SLOT_COUNT = 4
#: Parameters PX4 stores as integers.
INTEGER_SUFFIXES = ("_ID", "_ROT", "_COMP_TYP", "_ENABLE")


def parameter_names(slot: int) -> tuple[str, ...]:
    """The nine calibration parameters of slot ``slot``: offsets, scales, off-diagonals."""
    p = f"CAL_MAG{slot}_"
    return (
        *(f"{p}{a}OFF" for a in "XYZ"),
        *(f"{p}{a}SCALE" for a in "XYZ"),
        *(f"{p}{a}ODIAG" for a in "XYZ"),
    )


NAMES = parameter_names(0)


def px4_parameters(
    calibration: Calibration, unit: str | None = None, *, slot: int | None = None, device_id: int | None = None
) -> dict[str, float]:
    """The CAL_MAGn_* values of one magnetometer (gauss offsets), after checking PX4's limits.

    Parameters
    ----------
    calibration : Calibration
        The calibration; ``offset`` and ``field_strength`` in the samples' unit.
    unit : str or None
        The samples' unit, overriding ``calibration.unit``; must be physical (not counts).
    slot, device_id : int or None
        PX4's calibration slot n (0-3) and the sensor's device id (``CAL_MAGn_ID``); default from
        ``calibration.sensor``, else slot 0 and no id.

    Returns
    -------
    dict
        Parameter name -> value: offsets, scales, off-diagonals, then ``CAL_MAGn_ROT`` for a vehicle-frame
        calibration and ``CAL_MAGn_ID`` when the device id is known.

    Raises
    ------
    ExportError
        No physical unit, PX4 would reject the values (see the module docstring), or the rotation is no
        fixed PX4 rotation.
    OptionError
        ``unit`` is not a unit magfit knows, or an option is out of range.
    """
    return _slot(calibration, unit, slot, device_id).parameters


def _slot(calibration: Calibration, unit: str | None, slot: int | None, device_id: int | None) -> SlotParameters:
    where = sensor_slot(calibration, "px4", SLOT_COUNT, slot, device_id)
    source = physical_unit(calibration, unit, "px4", "gauss")
    k = factor(source, "G")
    field = k * calibration.field_strength
    low, high = FIELD_RANGE_G
    if not low <= field < high:
        mismatch = field_unit_reason(calibration.field_strength, source.name)
        raise ExportError(
            f"PX4 rejects a magnetometer calibration whose sphere radius is outside [{low}, {high}) G; the "
            f"corrected field is {field:.4g} G; "
            + f"check the unit of the samples ({option('unit', source.name)} was used)"
            + (f": {mismatch}" if mismatch else ""),
            codes=("unit_mismatch",) if mismatch else (),
            remedy=mismatch.remedy if mismatch else (),
        )
    prefix = f"CAL_MAG{where.slot}_"
    comments: list[str] = []
    extra: dict[str, float] = {}
    if calibration.frame == "vehicle":
        split = vehicle_split(calibration, "px4", "px4")
        standard = split.standard
        assert standard is not None
        if standard.angle_deg > ROTATION_TOLERANCE_DEG:
            raise ExportError(
                f"PX4's CAL_MAGn_ROT holds only its fixed rotations (0-{PX4_ROTATION_MAX}), and the fitted "
                f"alignment is {standard.angle_deg:.2f} deg from the nearest ({standard.id}, {standard.name}; "
                f"tolerance {ROTATION_TOLERANCE_DEG} deg); export to 'ardupilot' (custom rotation) or a full-matrix "
                "format, or mount the magnetometer on a fixed rotation"
            )
        matrix = split.symmetric
        loss = heading_error_deg(calibration, np.asarray(standard.matrix) @ matrix, calibration.offset)
        extra[f"{prefix}ROT"] = float(standard.id)
        comments.append(
            f"# {prefix}ROT = {standard.id} ({standard.name}) is {standard.angle_deg:.2f} deg from the fitted "
            f"alignment (tolerance {ROTATION_TOLERANCE_DEG} deg): a heading error of up to {loss:.2f} deg"
        )
        comments.append(
            f"#   (chosen among 0-{PX4_ROTATION_MAX}, the rotations of every PX4 since late 2020; mid-2020 releases "
            "also had 41-47, which PX4 now resets to 0, no rotation)"
        )
        comments.append(
            f"# WARNING: PX4 applies {prefix}ROT to an external magnetometer only; for an internal one it resets it "
            "to -1 and applies SENS_BOARD_ROT (Magnetometer::ParametersUpdate): the alignment then holds only if "
            f"SENS_BOARD_ROT = {standard.id}"
        )
    else:
        matrix = symmetric_matrix(calibration, "px4").matrix
    diagonal = np.diag(matrix)
    if not np.all(diagonal > 0):
        raise ExportError(
            f"PX4 ignores non-positive {prefix}*SCALE values, got {np.array2string(diagonal, precision=4)}; "
            "the calibration flips an axis: check the samples' axis order and signs"
        )
    offdiagonal = [matrix[0, 1], matrix[0, 2], matrix[1, 2]]
    values = [*(k * calibration.offset), *diagonal, *offdiagonal]
    parameters = dict(zip(parameter_names(where.slot), (float(v) for v in values), strict=True)) | extra
    if calibration.motor is not None:  # the motors' field, added before the offset (export/_motor.py)
        comp = px4_comp(calibration, k)
        parameters |= {f"{prefix}{axis}COMP": float(v) for axis, v in zip("XYZ", comp, strict=True)}
        parameters["CAL_MAG_COMP_TYP"] = float(PX4_COMP_TYP[calibration.motor.regressor])
        comments.append(describe_term(calibration))
    sensor = f" ({where.name})" if where.name else ""
    if where.device_id is not None:
        parameters[f"{prefix}ID"] = float(where.device_id)
        comments.insert(0, f"# magnetometer slot {where.slot}{sensor}: {prefix}ID = {where.device_id}, its device id")
    else:
        comments.insert(
            0,
            f"# magnetometer slot {where.slot}{sensor}: device id not known; PX4 applies {prefix}* only to the sensor "
            f"whose id is {prefix}ID: calibrate once in QGroundControl first",
        )
    return SlotParameters(where.slot, parameters, comments)


def ignored_vectors(parameters: dict[str, float], slot: int = 0) -> list[str]:
    """The CAL_MAGn vectors (``"OFF"``, ``"SCALE"``, ``"ODIAG"``) PX4 drops at every boot.

    PX4 takes a new vector only when it moves by more than :data:`CHANGE_THRESHOLD` from the value
    in use, and at boot the value in use is the default (OFF 0, SCALE 1, ODIAG 0: ``Reset`` before
    ``ParametersUpdate``), so a stored vector closer than that to its default (and not equal to it:
    then nothing is lost) is never applied.
    """
    defaults = {"OFF": np.zeros(3), "SCALE": np.ones(3), "ODIAG": np.zeros(3)}
    ignored = []
    for group, default in defaults.items():
        vector = np.array([parameters[name] for name in parameter_names(slot) if name.endswith(group)])
        if 0.0 < np.linalg.norm(vector - default) <= CHANGE_THRESHOLD:
            ignored.append(group)
    return ignored


def _as_applied(
    parameters: dict[str, float], ignored: list[str], k: float, slot: int
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The matrix and offset (in the samples' unit) PX4 applies when the ``ignored`` vectors keep their defaults."""
    p = dict(parameters)
    names = parameter_names(slot)
    for group, default in (("OFF", 0.0), ("SCALE", 1.0), ("ODIAG", 0.0)):
        if group in ignored:
            for name in names:
                if name.endswith(group):
                    p[name] = default
    x, y, z = (p[name] for name in names[3:6])
    xy, xz, yz = (p[name] for name in names[6:9])
    s = np.array([[x, xy, xz], [xy, y, yz], [xz, yz, z]])
    offset = np.array([p[name] for name in names[:3]]) / k
    return s, offset


def _check_system_id(system_id: int) -> int:
    low, high = SYSTEM_ID_RANGE
    if isinstance(system_id, bool) or not isinstance(system_id, (int, np.integer)) or not low <= system_id <= high:
        raise OptionError(
            f"system_id must be the vehicle's MAVLink system id, an integer from {low} to {high}; got {system_id!r}"
        )
    return int(system_id)


def write_px4(
    calibration: Calibration,
    unit: str | None = None,
    *,
    system_id: int = 1,
    slot: int | None = None,
    device_id: int | None = None,
    temperature: TemperatureDrift | None = None,
) -> str:
    """The calibration as a QGroundControl parameter file for PX4 (see the module docstring).

    Parameters
    ----------
    calibration : Calibration
        The calibration.
    unit : str or None
        The samples' unit, overriding ``calibration.unit``; must be physical (not counts).
    system_id : int
        The vehicle's MAVLink system id (MAV_SYS_ID), 1 to 255, written in the first column.
    slot, device_id : int or None
        The calibration slot (CAL_MAGn, 0-3) and the sensor's device id (see :func:`px4_parameters`).
    temperature : TemperatureDrift or None
        The offset's drift with temperature the log determined (:func:`magfit.temperature.log_drifts`): written
        as PX4's ``TC_M_ENABLE`` and ``TC_Mn_*`` (:mod:`.px4_temperature`), n the calibration's slot.

    Raises
    ------
    ExportError
        No physical unit, PX4 would reject the values, or ``temperature`` is not determined.
    OptionError
        ``unit`` is not a unit magfit knows, ``system_id`` is not 1 to 255, or ``slot``/``device_id`` out of range.
    """
    system_id = _check_system_id(system_id)
    entry = _slot(calibration, unit, slot, device_id)
    if temperature is not None:
        known = entry.parameters.get(f"CAL_MAG{entry.slot}_ID")
        block = px4_temperature(temperature, slot=entry.slot, device_id=None if known is None else int(known))
        entry = SlotParameters(entry.slot, entry.parameters | block.parameters, entry.comments + block.comments)
    return _file([calibration], [entry], unit, system_id)


def write_px4_several(
    calibrations: Sequence[Calibration],
    unit: str | None = None,
    *,
    system_id: int = 1,
    slots: Sequence[int | None] | None = None,
    device_ids: Sequence[int | None] | None = None,
) -> str:
    """Several magnetometers of one vehicle in one QGroundControl parameter file, each in its own slot."""
    system_id = _check_system_id(system_id)
    entries = [
        _slot(c, unit, None if slots is None else slots[i], None if device_ids is None else device_ids[i])
        for i, c in enumerate(calibrations)
    ]
    check_distinct_slots([entry.slot for entry in entries], lambda slot: f"PX4 slot CAL_MAG{slot}")
    entries = _one_comp_typ(calibrations, entries)
    order = sorted(range(len(entries)), key=lambda i: entries[i].slot)
    return _file([calibrations[i] for i in order], [entries[i] for i in order], unit, system_id)


def _one_comp_typ(calibrations: Sequence[Calibration], entries: list[SlotParameters]) -> list[SlotParameters]:
    """CAL_MAG_COMP_TYP is one setting for all magnetometers (export/_motor.py), as COMPASS_MOTCT in ardupilot.py."""
    chosen = chosen_regressor(calibrations)
    if chosen is None:
        return entries
    result: list[SlotParameters] = []
    for calibration, entry in zip(calibrations, entries, strict=True):
        parameters, comments = dict(entry.parameters), list(entry.comments)
        if calibration.motor is None or calibration.motor.regressor != chosen:
            if calibration.motor is not None:
                comments += mismatch_comment(calibration, chosen, "CAL_MAG_COMP_TYP")
            parameters |= {f"CAL_MAG{entry.slot}_{axis}COMP": 0.0 for axis in "XYZ"}
        parameters.pop("CAL_MAG_COMP_TYP", None)
        if not result:  # written once, with the first magnetometer
            parameters["CAL_MAG_COMP_TYP"] = float(PX4_COMP_TYP[chosen])
        result.append(SlotParameters(entry.slot, parameters, comments))
    return result


def _file(calibrations: Sequence[Calibration], entries: list[SlotParameters], unit: str | None, system_id: int) -> str:
    first = calibrations[0]
    source = physical_unit(first, unit, "px4", "gauss")
    k = factor(source, "G")
    slots = ", ".join(f"CAL_MAG{entry.slot}_*" for entry in entries)
    lines = [
        f"# Onboard parameters for Vehicle {system_id}",
        "#",
        f"# PX4 magnetometer calibration ({slots} parameters)",
        *(f"# {line}" for line in describe(first, source.name) if len(entries) == 1),
        "# PX4 corrects each sensor_mag sample (calibration::Magnetometer::Correct), in gauss, sensor frame:",
        "#   corrected = R * (S * (raw - (XOFF, YOFF, ZOFF))),  R = CAL_MAGn_ROT / board rotation",
        "#   S = [[XSCALE, XODIAG, YODIAG], [XODIAG, YSCALE, ZODIAG], [YODIAG, ZODIAG, ZSCALE]]",
        f"# mapping: OFF = offset * {float32_text(k)} ({source.name} -> G), SCALE/ODIAG = magfit's matrix;",
        f"#   PX4's corrected field = {float32_text(k)} x magfit's, radius {float32_text(k * first.field_strength)} G",
    ]
    if any(c.frame == "vehicle" for c in calibrations):
        lines.append(
            "# vehicle frame: magfit's matrix M = Q S (rotation Q after the soft-iron S): SCALE/ODIAG = S, R = Q"
        )
        lines += samples_note(next(c for c in calibrations if c.frame == "vehicle"), [])
    if any(c.motor is not None for c in calibrations):
        lines += [
            "#   with the motors' field: corrected = R * (S * ((raw + power * COMP) - OFF)), power = the thrust",
            "#   (CAL_MAG_COMP_TYP = 1) or battery 0's current in kA (2); COMP = -k_m * 1000 (G/kA) or -k_m (G)",
        ]
    lines.append("# Load: QGroundControl > Vehicle Setup > Parameters > Tools > Load from file.")
    lines.append(
        f"# PX4 takes a new OFF, SCALE or ODIAG vector only if it moves by more than {CHANGE_THRESHOLD} (Magnetometer)"
    )
    for calibration, entry in zip(calibrations, entries, strict=True):
        if len(entries) > 1:
            lines += [f"# {line}" for line in describe(calibration, source.name)]
        lines += entry.comments
        lines += _warnings(calibration, entry, k)
    lines += ["#", "# Vehicle-Id\tComponent-Id\tName\tValue\tType"]
    for entry in entries:
        for name, value in entry.parameters.items():
            if name.endswith(INTEGER_SUFFIXES):
                lines.append(f"{system_id}\t1\t{name}\t{int(value)}\t{INT32}")
            else:
                lines.append(f"{system_id}\t1\t{name}\t{float32_text(value)}\t{REAL32}")
    return "\n".join(lines) + "\n"


def _warnings(calibration: Calibration, entry: SlotParameters, k: float) -> list[str]:
    """The NOTE and WARNING lines of one slot: a Cholesky root, large offsets, terms PX4 would ignore."""
    lines = []
    parameters = entry.parameters
    names = parameter_names(entry.slot)
    if calibration.frame == "sensor":
        symmetric = symmetric_matrix(calibration, "px4")
        if symmetric.note is not None:
            lines.append(f"# NOTE: {plain(symmetric.note)}")
        reference_matrix = symmetric.matrix
    else:
        reference_matrix = vehicle_split(calibration, "px4", None).symmetric
    offsets = np.array([parameters[name] for name in names[:3]])
    if np.any(np.abs(offsets) > OFFSET_WARNING_G):
        lines.append(
            f"# WARNING: an offset exceeds {OFFSET_WARNING_G} G on some axis; PX4 warns that the sensor may saturate"
        )
    # The loss is measured against what this file holds in full (the symmetric part), in the sensor frame.
    reference = Calibration(calibration.method, calibration.offset, reference_matrix, calibration.field_strength)
    ignored = ignored_vectors(parameters, entry.slot)
    matrix, offset = _as_applied(parameters, ignored, k, entry.slot)
    error = heading_error_deg(reference, matrix, offset) if ignored else 0.0
    if error >= 0.005:  # shown with 2 decimals: below, nothing worth a warning is lost
        lines += [
            f"# WARNING: {', '.join(ignored)} within {CHANGE_THRESHOLD} of PX4's defaults: PX4 never applies them.",
            "#   At every boot calibration::Magnetometer starts from its defaults (Reset), and ParametersUpdate",
            f"#   ignores a stored vector closer than {CHANGE_THRESHOLD} to them (set_offset, set_scale,",
            "#   set_offdiagonal). The vehicle flies without them:",
            f"#   a heading error of up to {error:.2f} deg ({ASSUMPTION}).",
        ]
    return lines
