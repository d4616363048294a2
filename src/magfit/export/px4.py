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
- a non-symmetric matrix other than a Cholesky root.

An offset above 1.3 G on an axis only draws a warning in PX4 (the sensor may saturate), so the file
is written with a ``# WARNING`` line.

PX4 ignores small changes: ``calibration::Magnetometer::set_offset``, ``set_scale`` and
``set_offdiagonal`` (src/lib/sensor_calibration/Magnetometer.cpp, PX4-Autopilot a412449) take a new
OFF, SCALE or ODIAG vector only when it differs from the value in use by more than 0.01 (Euclidean
length of the three-vector); otherwise the old value stays. From PX4's defaults (OFF 0, SCALE 1,
ODIAG 0: a new vehicle, or after a reset) a mild soft iron is therefore dropped without a word. When a
vector of this calibration lies within 0.01 of its default, the file says so with the heading error
that leaves (:func:`._heading.heading_error_deg`) and gives PX4 shell commands that survive the rule:
each parameter first set 0.05 away from its final value, then to it (every single step then moves
by more than 0.01, whatever the value in use).

The file is QGroundControl's parameter file format: ``#`` comments, then tab-separated
``Vehicle-Id Component-Id Name Value Type`` lines (type 9 = MAV_PARAM_TYPE_REAL32), for the vehicle
``system_id`` (1 unless given: older QGroundControl refuses a file whose id differs from the
vehicle's), component 1 and the first magnetometer (CAL_MAG0_*). PX4 applies CAL_MAG0_* only to the
sensor whose device id is CAL_MAG0_ID, so calibrate once in QGroundControl first (it sets the id).
"""

from __future__ import annotations

import numpy as np

from ..calibration import Calibration
from ..errors import ExportError, OptionError
from ._common import describe, factor, float32_text, physical_unit, plain, symmetric_matrix
from ._heading import ASSUMPTION, heading_error_deg

#: check_calibration_result: sphere radius in [0.2, 0.7) gauss.
FIELD_RANGE_G = (0.2, 0.7)
#: MAG_MAX_OFFSET_LEN: above it on any axis PX4 warns "large offsets" (the sensor may saturate).
OFFSET_WARNING_G = 1.3
#: Magnetometer::set_offset/set_scale/set_offdiagonal: a new vector is taken only if it moves by more than this.
CHANGE_THRESHOLD = 0.01
#: The step of the two-step fix: each parameter first set this far from its final value (> CHANGE_THRESHOLD).
DETOUR = 0.05
#: MAVLink system ids a vehicle can have (0 is the broadcast id).
SYSTEM_ID_RANGE = (1, 255)
#: MAV_PARAM_TYPE_REAL32, the type column of a QGroundControl parameter file.
REAL32 = 9
NAMES = (
    "CAL_MAG0_XOFF",
    "CAL_MAG0_YOFF",
    "CAL_MAG0_ZOFF",
    "CAL_MAG0_XSCALE",
    "CAL_MAG0_YSCALE",
    "CAL_MAG0_ZSCALE",
    "CAL_MAG0_XODIAG",
    "CAL_MAG0_YODIAG",
    "CAL_MAG0_ZODIAG",
)


def px4_parameters(calibration: Calibration, unit: str | None = None) -> dict[str, float]:
    """The nine CAL_MAG0_* values (gauss offsets), after checking PX4's limits.

    Parameters
    ----------
    calibration : Calibration
        The calibration; ``offset`` and ``field_strength`` in the samples' unit.
    unit : str or None
        The samples' unit, overriding ``calibration.unit``; must be physical (not counts).

    Returns
    -------
    dict
        Parameter name -> value, in the order of :data:`NAMES`.

    Raises
    ------
    ExportError
        No physical unit, or PX4 would reject the values (see the module docstring).
    OptionError
        ``unit`` is not a unit magfit knows.
    """
    source = physical_unit(calibration, unit, "px4", "gauss")
    k = factor(source, "G")
    field = k * calibration.field_strength
    low, high = FIELD_RANGE_G
    if not low <= field < high:
        raise ExportError(
            f"PX4 rejects a magnetometer calibration whose sphere radius is outside [{low}, {high}) G; the "
            f"corrected field is {field:.4g} G; check the unit of the samples (unit={source.name!r} was used)"
        )
    matrix = symmetric_matrix(calibration, "px4").matrix
    diagonal = np.diag(matrix)
    if not np.all(diagonal > 0):
        raise ExportError(
            f"PX4 ignores non-positive CAL_MAG0_*SCALE values, got {np.array2string(diagonal, precision=4)}; "
            "the calibration flips an axis: check the samples' axis order and signs"
        )
    offdiagonal = [matrix[0, 1], matrix[0, 2], matrix[1, 2]]
    values = [*(k * calibration.offset), *diagonal, *offdiagonal]
    return dict(zip(NAMES, (float(v) for v in values), strict=True))


def ignored_vectors(parameters: dict[str, float]) -> list[str]:
    """The CAL_MAG0 vectors (``"OFF"``, ``"SCALE"``, ``"ODIAG"``) PX4 would keep at its defaults.

    PX4 takes a new vector only when it moves by more than :data:`CHANGE_THRESHOLD` from the value
    in use; from the defaults (OFF 0, SCALE 1, ODIAG 0), a vector closer than that (and not equal
    to the default: then nothing is lost) is ignored.
    """
    defaults = {"OFF": np.zeros(3), "SCALE": np.ones(3), "ODIAG": np.zeros(3)}
    ignored = []
    for group, default in defaults.items():
        vector = np.array([parameters[name] for name in NAMES if name.endswith(group)])
        if 0.0 < np.linalg.norm(vector - default) <= CHANGE_THRESHOLD:
            ignored.append(group)
    return ignored


def _as_applied(parameters: dict[str, float], ignored: list[str], k: float) -> tuple[np.ndarray, np.ndarray]:
    """The matrix and offset (in the samples' unit) PX4 applies when the ``ignored`` vectors keep their defaults."""
    p = dict(parameters)
    for group, default in (("OFF", 0.0), ("SCALE", 1.0), ("ODIAG", 0.0)):
        if group in ignored:
            for name in NAMES:
                if name.endswith(group):
                    p[name] = default
    s = np.array(
        [
            [p["CAL_MAG0_XSCALE"], p["CAL_MAG0_XODIAG"], p["CAL_MAG0_YODIAG"]],
            [p["CAL_MAG0_XODIAG"], p["CAL_MAG0_YSCALE"], p["CAL_MAG0_ZODIAG"]],
            [p["CAL_MAG0_YODIAG"], p["CAL_MAG0_ZODIAG"], p["CAL_MAG0_ZSCALE"]],
        ]
    )
    offset = np.array([p["CAL_MAG0_XOFF"], p["CAL_MAG0_YOFF"], p["CAL_MAG0_ZOFF"]]) / k
    return s, offset


def _check_system_id(system_id: int) -> int:
    low, high = SYSTEM_ID_RANGE
    if isinstance(system_id, bool) or not isinstance(system_id, (int, np.integer)) or not low <= system_id <= high:
        raise OptionError(
            f"system_id must be the vehicle's MAVLink system id, an integer from {low} to {high}; got {system_id!r}"
        )
    return int(system_id)


def write_px4(calibration: Calibration, unit: str | None = None, *, system_id: int = 1) -> str:
    """The calibration as a QGroundControl parameter file for PX4 (see the module docstring).

    Parameters
    ----------
    calibration : Calibration
        The calibration.
    unit : str or None
        The samples' unit, overriding ``calibration.unit``; must be physical (not counts).
    system_id : int
        The vehicle's MAVLink system id (MAV_SYS_ID), 1 to 255, written in the first column.

    Raises
    ------
    ExportError
        No physical unit, or PX4 would reject the values.
    OptionError
        ``unit`` is not a unit magfit knows, or ``system_id`` is not 1 to 255.
    """
    system_id = _check_system_id(system_id)
    parameters = px4_parameters(calibration, unit)
    source = physical_unit(calibration, unit, "px4", "gauss")
    k = factor(source, "G")
    symmetric = symmetric_matrix(calibration, "px4")
    note = symmetric.note
    # The loss below is measured against what this file holds in full: the symmetric root for a Cholesky one.
    reference = Calibration(calibration.method, calibration.offset, symmetric.matrix, calibration.field_strength)
    lines = [
        f"# Onboard parameters for Vehicle {system_id}",
        "#",
        "# PX4 magnetometer calibration (first magnetometer: CAL_MAG0_* parameters)",
        *(f"# {line}" for line in describe(calibration, source.name)),
        "# PX4 corrects each sensor_mag sample (calibration::Magnetometer::Correct), in gauss, sensor frame:",
        "#   corrected = R * (S * (raw - (XOFF, YOFF, ZOFF))),  R = CAL_MAG0_ROT / board rotation",
        "#   S = [[XSCALE, XODIAG, YODIAG], [XODIAG, YSCALE, ZODIAG], [YODIAG, ZODIAG, ZSCALE]]",
        f"# mapping: OFF = offset * {float32_text(k)} ({source.name} -> G), SCALE/ODIAG = magfit's matrix;",
        f"#   PX4's corrected field = {float32_text(k)} x magfit's, "
        f"radius {float32_text(k * calibration.field_strength)} G",
        "# PX4 uses CAL_MAG0_* only for the sensor whose id is CAL_MAG0_ID: calibrate once in QGroundControl first.",
        "# Load: QGroundControl > Vehicle Setup > Parameters > Tools > Load from file.",
    ]
    if note is not None:
        lines.append(f"# NOTE: {plain(note)}")
    offsets = np.array([parameters[name] for name in NAMES[:3]])
    if np.any(np.abs(offsets) > OFFSET_WARNING_G):
        lines.append(
            f"# WARNING: an offset exceeds {OFFSET_WARNING_G} G on some axis; PX4 warns that the sensor may saturate"
        )
    lines.append(
        f"# PX4 takes a new OFF, SCALE or ODIAG vector only if it moves by more than {CHANGE_THRESHOLD} (Magnetometer)"
    )
    ignored = ignored_vectors(parameters)
    matrix, offset = _as_applied(parameters, ignored, k)
    error = heading_error_deg(reference, matrix, offset) if ignored else 0.0
    if error >= 0.005:  # shown with 2 decimals: below, nothing worth a warning is lost
        names = [name for name in NAMES if name.rsplit("_", 1)[1][1:] in ignored]
        lines += [
            f"# WARNING: {', '.join(ignored)} within {CHANGE_THRESHOLD} of PX4's defaults: a vehicle at its defaults",
            f"#   keeps them, a heading error of up to {error:.2f} deg ({ASSUMPTION}).",
            "#   To make PX4 take every value, run in QGroundControl's MAVLink Console (each step moves > 0.01):",
            *(f"#     param set {name} {float32_text(parameters[name] + DETOUR)}" for name in names),
            *(f"#     param set {name} {float32_text(parameters[name])}" for name in names),
        ]
    lines += ["#", "# Vehicle-Id\tComponent-Id\tName\tValue\tType"]
    lines += [f"{system_id}\t1\t{name}\t{float32_text(value)}\t{REAL32}" for name, value in parameters.items()]
    return "\n".join(lines) + "\n"
