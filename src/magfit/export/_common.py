"""Helpers shared by the export targets: units, the symmetric matrix, number formatting, header facts."""

from __future__ import annotations

import math
import textwrap
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from ..calibration import CONVENTION, Calibration
from ..errors import ExportError, OptionError
from ..remedy import option
from ..rotations import StandardRotation, angle_between_deg, nearest_rotation, polar_decomposition
from ..units import Unit, conversion_factor, get_unit
from ._heading import ASSUMPTION, heading_error_deg

#: Largest finite float32: a C ``float`` literal beyond it is infinity.
FLOAT32_MAX = float(np.finfo(np.float32).max)

#: Largest relative asymmetry max|M − Mᵀ| / max|M| still treated as a symmetric matrix (rounding only).
SYMMETRY_TOLERANCE = 1e-9

#: Largest angle (degrees) between a vehicle-frame calibration's rotation and a firmware's fixed rotation for
#: the fixed one to stand in for it. The residual turns every corrected vector by that angle, so a heading
#: by at most as much: 0.5 deg is below the heading error magfit's fits leave in its level-flight benchmark
#: (auto: 0.85 deg RMS, benchmarks/README.md) and equals the alignment accuracy asked of a vector fit
#: at 1 deg of attitude noise, so a fixed rotation that close loses nothing the data could vouch for.
ROTATION_TOLERANCE_DEG = 0.5

#: The formats that write the matrix whole (``matrix @ (raw - offset)``): a vehicle frame and a mirror fit.
FULL_MATRIX_FORMATS = ("c", "fusion", "magcal", "adafruit", "adafruit-json", "json", "yaml", "rtimulib")


def version() -> str:
    """magfit's version, written into every export (no date, so the output is reproducible)."""
    from .. import __version__

    return __version__


def plain(text: object) -> str:
    """``text`` as printable ASCII on one line, safe inside any comment (C, MATLAB, shell, params)."""
    ascii_text = "".join(ch if " " <= ch <= "~" else "?" for ch in str(text))
    return ascii_text.replace("*/", "*_/")


def comment_lines(text: str, prefix: str = "# ", width: int = 100) -> list[str]:
    """``text`` as comment lines of at most ``width`` characters, each starting with ``prefix``.

    For readers with a line buffer (RTIMULib's ``fgets(buf, 200, ...)``): a long line would be split into a
    second "line" that is no comment. Continuation lines are indented by two more spaces.
    """
    return textwrap.wrap(
        plain(text),
        width=width,
        initial_indent=prefix,
        subsequent_indent=prefix + "  ",
        break_on_hyphens=False,
    ) or [prefix.rstrip()]


def yaml_float(value: float) -> str:
    """The shortest text that reads back as the same double in every YAML reader, 1.1 and 1.2.

    ``repr`` gives ``3e-05`` for 0.00003; YAML 1.1's float pattern (PyYAML, ROS 1's ``rosparam``) needs a
    ``.`` in the mantissa, ``[-+]?([0-9][0-9_]*)?\\.[0-9.]*([eE][-+][0-9]+)?``, and reads ``3e-05`` as the
    string "3e-05". ``3.0e-05`` matches it and YAML 1.2's core schema,
    ``[-+]?(\\.[0-9]+|[0-9]+(\\.[0-9]*)?)([eE][-+]?[0-9]+)?``, alike (Python's exponent always has its sign).
    """
    text = repr(float(value))
    if not math.isfinite(value):
        return {"inf": ".inf", "-inf": "-.inf"}.get(text, ".nan")
    mantissa, e, exponent = text.partition("e")
    if "." not in mantissa:
        mantissa += ".0"
    return mantissa + e + exponent


def float32_text(value: float) -> str:
    """Shortest text that still round-trips a float32 (9 significant digits, ``%.9g``)."""
    return f"{float(value):.9g}"


def check_float32(values: dict[str, NDArray[np.float64] | float], target: str) -> None:
    """Refuse values a C ``float`` cannot hold: ``1e39f`` is infinity, not the calibration.

    ``values`` maps a name (``"offset"``) to a number or an array; the message names the first
    element out of range, so the user can see which unit to change.
    """
    for name, value in values.items():
        array = np.atleast_1d(np.asarray(value, dtype=np.float64))
        with np.errstate(over="ignore"):
            as_float32 = array.astype(np.float32)
        bad = np.flatnonzero(~np.isfinite(as_float32))
        if bad.size:
            index = np.unravel_index(int(bad[0]), np.shape(value)) if np.ndim(value) else ()
            where = name + "".join(f"[{i}]" for i in index)
            raise ExportError(
                f"the {target} export writes C floats, but {where} = {float(array.flat[bad[0]]):.6g} is outside "
                f"float32's range (+-{FLOAT32_MAX:.4g}); fit samples in a larger unit (e.g. uT instead of nT)"
            )


def c_float(value: float) -> str:
    """A C ``float`` literal with 9 significant digits (``1`` becomes ``1.0f``, never the invalid ``1f``).

    Check the values with :func:`check_float32` first: this only formats.
    """
    text = float32_text(value)
    if not any(ch in text for ch in ".en"):
        text += ".0"
    return text + "f"


def label_unit(calibration: Calibration, unit: str | None) -> str | None:
    """The unit to print for targets that keep the input unit (no conversion).

    An explicit ``unit`` must be a known unit (:class:`OptionError` otherwise) and is written by its
    canonical name; ``calibration.unit`` is only a label, written canonically when magfit knows it.
    """
    if unit is not None:
        return get_unit(unit).name
    if calibration.unit is None:
        return None
    try:
        return get_unit(calibration.unit).name
    except OptionError:
        return plain(calibration.unit)


def unit_phrase(unit: str | None) -> str:
    """``"uT"`` or a phrase saying that the unit was not recorded."""
    return unit if unit is not None else "the samples' unit (not recorded: pass unit=...)"


def physical_unit(calibration: Calibration, unit: str | None, target: str, target_unit: str) -> Unit:
    """The samples' unit for a target that converts to ``target_unit``; refuses counts and unknown units."""
    if unit is not None:
        resolved = get_unit(unit)  # OptionError for a misspelt explicit unit
    elif calibration.unit is None:
        raise ExportError(
            f"the {target} export needs values in {target_unit}, but the calibration does not record the unit "
            f"of its samples; pass {option('unit', 'uT')} (or nT, mT, G, mG)"
        )
    else:
        try:
            resolved = get_unit(calibration.unit)
        except OptionError:
            raise ExportError(
                f"the {target} export needs values in {target_unit}, but the calibration's unit "
                f"{calibration.unit!r} is not one magfit knows; pass {option('unit', 'uT')} (or nT, mT, G, mG)"
            ) from None
    if not resolved.is_physical:
        raise ExportError(
            f"the {target} export needs values in {target_unit}, but the samples are raw counts of unknown "
            f"scale; pass the physical unit of the samples (e.g. {option('unit', 'uT')}) or refit on samples in a "
            "physical unit"
        )
    return resolved


def raw_counts(calibration: Calibration, unit: str | None, target: str) -> str | None:
    """The unit label for targets that store the sensor's raw counts; refuses a physical unit.

    Such targets (INAV, Betaflight) apply their numbers to the integers the driver reads, so a
    calibration fitted on samples in µT or gauss has no place there: the scale of the counts is not
    known to magfit. Counts, or no unit recorded, pass.
    """
    label = label_unit(calibration, unit)
    if label is None:
        return None
    try:
        resolved = get_unit(label)
    except OptionError:
        return label  # a label magfit does not know: the user's own name for the counts
    if resolved.is_physical:
        raise ExportError(
            f"the {target} export writes the sensor's raw counts, but the samples are in {resolved.name}; fit the "
            f"counts {target} reads from the sensor ({option('unit', 'counts')}), not a converted field"
        )
    return resolved.name


def factor(source: Unit, target_unit: str) -> float:
    """The exact conversion factor from ``source`` to ``target_unit`` (both physical)."""
    return conversion_factor(source.name, target_unit)


@dataclass(frozen=True)
class SymmetricMatrix:
    """A symmetric soft-iron matrix for targets that store only six numbers, and how it was obtained."""

    matrix: NDArray[np.float64]
    #: Rotation (degrees) between the exported vectors and ``Calibration.apply``; 0 when unchanged.
    rotation_deg: float
    #: A comment line explaining a conversion, or None when the matrix was already symmetric.
    note: str | None


def symmetric_matrix(calibration: Calibration, target: str) -> SymmetricMatrix:
    """The calibration's matrix as the symmetric matrix ArduPilot and PX4 store.

    A symmetric matrix passes through. A Cholesky root (``details["root"] == "cholesky"``) is
    replaced by the symmetric root ``S = sqrtm(Mᵀ M)``: both satisfy ``Mᵀ M = S² = B² A`` (paper,
    eq. 2), so they fit the same ellipsoid and give the same ``|corrected|``; they differ by the
    rotation ``Q = M S⁻¹``, which the samples cannot identify (the rotation is an artefact of the
    factorisation), and the symmetric root is the one that adds no rotation. Any other
    non-symmetric matrix may carry a real axis alignment, which a symmetric matrix would silently
    drop, so it is refused.
    """
    m = calibration.matrix
    asymmetry = _asymmetry(m)
    if asymmetry <= SYMMETRY_TOLERANCE:
        return SymmetricMatrix(0.5 * (m + m.T), 0.0, None)
    if calibration.details.get("root") != "cholesky" or np.linalg.det(m) <= 0:
        raise ExportError(
            f"the {target} export stores a symmetric soft-iron matrix, but this calibration's matrix is not "
            f"symmetric (max|M - M^T| / max|M| = {asymmetry:.3g}) and may encode an axis rotation that {target} "
            "cannot represent; refit with root='sqrt' or export to 'c', 'fusion', 'magcal' or 'json'"
        )
    root, angle = _polar(m)
    note = (
        "magfit's matrix is a Cholesky root (not symmetric); this file holds the symmetric root "
        f"sqrtm(matrix^T matrix): same ellipsoid and same |corrected|, but the corrected vector is rotated "
        f"by {angle:.3f} deg from magfit's apply() (that rotation is an artefact of the Cholesky factor)"
    )
    return SymmetricMatrix(root, angle, note)


def _asymmetry(m: NDArray[np.float64]) -> float:
    return float(np.max(np.abs(m - m.T)) / np.max(np.abs(m)))


def _polar(m: NDArray[np.float64]) -> tuple[NDArray[np.float64], float]:
    """The symmetric root ``S = sqrtm(Mᵀ M)`` and the angle (degrees) of the rotation ``Q = M S⁻¹``."""
    rotation, root = polar_decomposition(m)  # orthogonal: M = Q S
    angle = math.degrees(math.acos(min(1.0, max(-1.0, (float(np.trace(rotation)) - 1.0) / 2.0))))
    return root, angle


def rotated_frame_warning(calibration: Calibration) -> str | None:
    """A warning for targets that keep the full matrix, when that matrix turns the corrected field.

    A vehicle-frame calibration (``frame == "vehicle"``) gets a NOTE that the matrix includes the
    magnetometer-to-vehicle alignment (and, for a negative determinant, a mirror).

    A Cholesky root (``root="cholesky"``) fits the same ellipsoid as the symmetric root but turns every
    corrected vector by a fixed rotation that the samples do not determine (14 deg with strong soft
    iron): a compass heading made from it is off by up to that angle. These targets keep the matrix
    as fitted, so the file reproduces ``Calibration.apply`` and the user's explicit choice, and say so.
    None when the matrix is symmetric (then the rotation is zero by construction).
    """
    m = calibration.matrix
    if calibration.frame == "vehicle":
        rotation, _ = polar_decomposition(m)
        mirror = np.linalg.det(rotation) < 0
        proper = rotation @ np.diag([1.0, 1.0, -1.0]) if mirror else rotation
        angle = math.degrees(math.acos(min(1.0, max(-1.0, (float(np.trace(proper)) - 1.0) / 2.0))))
        what = (
            f"a mirror (left-handed sensor axes: z flipped, then turned by {angle:.2f} deg)"
            if mirror
            else f"a rotation of {angle:.2f} deg"
        )
        return (
            "NOTE: frame 'vehicle': the matrix also aligns the magnetometer with the vehicle "
            f"({what} after the soft-iron correction), so the corrected field is in the vehicle's axes; "
            "apply it to the sensor's own readings, with no further mounting rotation"
        )
    if _asymmetry(m) <= SYMMETRY_TOLERANCE or np.linalg.det(m) <= 0:
        return None
    root, angle = _polar(m)
    symmetric = Calibration(calibration.method, calibration.offset, root, calibration.field_strength)
    heading = heading_error_deg(symmetric, m, calibration.offset)
    if calibration.details.get("root") == "cholesky":
        return (
            f"WARNING: the matrix is a Cholesky root (root='cholesky'), not symmetric: it turns the corrected "
            f"field by {angle:.2f} deg from the symmetric root, a rotation the samples do not determine; headings "
            f"differ by up to {heading:.2f} deg ({ASSUMPTION}); for a compass, refit with root='sqrt' (the default)"
        )
    return (
        f"NOTE: the matrix is not symmetric: it turns the corrected field by {angle:.2f} deg from the symmetric "
        "root sqrtm(matrix^T matrix); keep it only if that rotation is a real sensor-to-body alignment"
    )


def describe(calibration: Calibration, unit: str | None) -> list[str]:
    """Facts every export states in its header comment (plain ASCII, no date)."""
    root = calibration.details.get("root")
    method = plain(calibration.method) + (f" (root: {plain(root)})" if root else "")
    samples = f"{calibration.n_samples} samples" if calibration.n_samples is not None else "sample count not recorded"
    label = unit if unit is not None else "input units"
    return [
        f"written by magfit {version()}; method: {method}; {samples}",
        f"magfit convention: {CONVENTION}",
        f"field strength (radius of the corrected sphere): {float32_text(calibration.field_strength)} {label}",
    ]


@dataclass(frozen=True)
class VehicleSplit:
    """A vehicle-frame matrix as the firmwares apply it: ``matrix = rotation @ symmetric`` (first S, then R).

    ``symmetric`` is the magnitude-only soft-iron correction (``sqrtm(Mᵀ M)``), ``rotation`` the proper
    rotation into the vehicle frame. ``standard`` is the firmware's nearest fixed rotation, or None when
    the firmware's table was not asked for.
    """

    rotation: NDArray[np.float64]
    symmetric: NDArray[np.float64]
    standard: StandardRotation | None


def vehicle_split(calibration: Calibration, target: str, firmware: str | None) -> VehicleSplit:
    """Split a vehicle-frame calibration into its rotation and symmetric part; refuse a mirror.

    ``firmware`` (``"ardupilot"``, ``"px4"``, ``"betaflight"``, ``"inav"`` or None) names the rotation
    table to search for the nearest fixed rotation.
    """
    rotation, symmetric = polar_decomposition(calibration.matrix)
    if np.linalg.det(rotation) < 0:
        raise ExportError(
            f"the {target} export cannot hold this vehicle-frame calibration: its matrix is a mirror (negative "
            "determinant: left-handed sensor axes) and the firmware's rotations are all proper; swap two axes of the "
            f"samples and refit, or export to a full-matrix format ({', '.join(FULL_MATRIX_FORMATS)})"
        )
    standard = nearest_rotation(rotation, firmware) if firmware is not None else None
    return VehicleSplit(rotation, symmetric, standard)


@dataclass(frozen=True)
class SlotParameters:
    """One compass's parameters (in file order) in its firmware slot, and the comment lines that explain them."""

    slot: int
    parameters: dict[str, float]
    comments: list[str]


def check_distinct_slots(slots: Sequence[int], slot_name: Callable[[int], str]) -> None:
    """Refuse two calibrations for one slot of a multi-compass file (``slot_name(2)``: how the firmware names it)."""
    for slot in slots:
        if slots.count(slot) > 1:
            raise ExportError(f"two calibrations are for {slot_name(slot)}; give each compass its own slot (slots=...)")


@dataclass(frozen=True)
class SensorSlot:
    """Which of a vehicle's compasses a calibration is for: the firmware's 0-based slot and its device id."""

    slot: int
    device_id: int | None
    name: str | None


def sensor_slot(
    calibration: Calibration, target: str, count: int, slot: int | None, device_id: int | None
) -> SensorSlot:
    """The slot and device id to write: the explicit options first, else ``calibration.sensor``, else slot 0.

    ``calibration.sensor`` (:class:`magfit.facts.LogCompass`: id, slot, device id) is filled by the pipeline
    from the log's magnetometer (:class:`magfit.sources.Magnetometer`).

    Raises
    ------
    OptionError
        An explicit ``slot`` or ``device_id`` of the wrong type or range.
    ExportError
        The calibration's own slot is beyond the ``count`` compasses ``target`` calibrates.
    """
    sensor = calibration.sensor
    name = sensor.id if sensor is not None else None
    own_slot = sensor.slot if sensor is not None else None
    if slot is not None:
        if not _is_int(slot) or not 0 <= slot < count:
            raise OptionError(f"slot must be the {target} compass slot, an integer from 0 to {count - 1}; got {slot!r}")
        chosen = int(slot)
    elif own_slot is not None:
        chosen = own_slot
        if not 0 <= chosen < count:
            raise ExportError(
                f"{target} calibrates {count} compasses (slots 0-{count - 1}), but this calibration is for slot "
                f"{chosen} ({plain(name)}); pass slot=... to write it to another slot"
            )
    else:
        chosen = 0
    if device_id is not None:
        if not _is_int(device_id) or not 0 < device_id < 2**32:
            raise OptionError(
                f"device_id must be the firmware's device id, a positive 32-bit integer; got {device_id!r}"
            )
        chosen_id: int | None = int(device_id)
    else:
        chosen_id = sensor.device_id if sensor is not None else None
    return SensorSlot(chosen, chosen_id, plain(name) if name is not None else None)


def _is_int(value: object) -> bool:
    return isinstance(value, (int, np.integer)) and not isinstance(value, bool)


def with_applied_rotation(calibration: Calibration, applied_rotation: object) -> Calibration:
    """A vehicle-frame calibration re-expressed for the sensor's own readings, when its samples were turned first.

    A flight log may hold the field after the firmware's mounting rotation R0 (ArduPilot logs MAG after
    COMPASS_ORIENT or AHRS_ORIENTATION): a vector fit on those samples gives ``M @ (R0 raw - o)``. The
    rotation an export writes replaces R0 in the firmware, so it must include it:
    ``M @ (R0 raw - o) = (M R0) @ (raw - R0ᵀ o)``. ``applied_rotation`` is R0 (``board = R0 @ sensor``), or
    None; it comes from the option or from ``calibration.sensor.applied_rotation``. A sensor-frame
    calibration is returned unchanged: its firmware keeps the rotation in force. The calibration returned
    keeps its facts, its ``sensor`` without the rotation (which it now includes).

    Raises
    ------
    OptionError
        ``applied_rotation`` is not a proper rotation matrix.
    """
    if applied_rotation is None and calibration.sensor is not None:
        applied_rotation = calibration.sensor.applied_rotation
    if applied_rotation is None or calibration.frame != "vehicle":
        return calibration
    try:
        r0 = np.array(applied_rotation, dtype=np.float64)
        angle = angle_between_deg(np.eye(3), r0)  # also checks: a proper rotation
    except (ValueError, TypeError) as error:
        raise OptionError(f"applied_rotation must be the 3x3 rotation applied before logging: {error}") from None
    details = {**calibration.details, "applied_rotation": r0.tolist(), "applied_rotation_deg": angle}
    return replace(
        calibration,
        offset=r0.T @ calibration.offset,
        matrix=calibration.matrix @ r0,
        details=details,
        motor=None if calibration.motor is None else replace(  # the term lives in the raw axes too
            calibration.motor, coefficients=r0.T @ calibration.motor.coefficients
        ),
        sensor=None if calibration.sensor is None else replace(calibration.sensor, applied_rotation=None),
    )


def samples_note(calibration: Calibration, default: list[str]) -> list[str]:
    """The comment lines on what the samples must be: ``default``, or the applied rotation's account."""
    if "applied_rotation_deg" not in calibration.details:
        return default
    return [
        f"# The samples were logged after a mounting rotation of {calibration.details['applied_rotation_deg']:.2f} deg "
        "(applied_rotation); the rotation written here includes it",
        "#   and replaces it: this file applies to the sensor's own readings.",
    ]
