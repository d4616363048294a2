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

The file is QGroundControl's parameter file format: ``#`` comments, then tab-separated
``Vehicle-Id Component-Id Name Value Type`` lines (type 9 = MAV_PARAM_TYPE_REAL32), for vehicle 1,
component 1 and the first magnetometer (CAL_MAG0_*). PX4 applies CAL_MAG0_* only to the sensor
whose device id is CAL_MAG0_ID, so calibrate once in QGroundControl first (it sets the id).
"""

from __future__ import annotations

import numpy as np

from ..calibration import Calibration
from ..errors import ExportError
from ._common import describe, factor, float32_text, physical_unit, plain, symmetric_matrix

#: check_calibration_result: sphere radius in [0.2, 0.7) gauss.
FIELD_RANGE_G = (0.2, 0.7)
#: MAG_MAX_OFFSET_LEN: above it on any axis PX4 warns "large offsets" (the sensor may saturate).
OFFSET_WARNING_G = 1.3
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


def write_px4(calibration: Calibration, unit: str | None = None) -> str:
    """The calibration as a QGroundControl parameter file for PX4 (see the module docstring)."""
    parameters = px4_parameters(calibration, unit)
    source = physical_unit(calibration, unit, "px4", "gauss")
    k = factor(source, "G")
    note = symmetric_matrix(calibration, "px4").note
    lines = [
        "# Onboard parameters for Vehicle 1",
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
    lines += ["#", "# Vehicle-Id\tComponent-Id\tName\tValue\tType"]
    lines += [f"1\t1\t{name}\t{float32_text(value)}\t{REAL32}" for name, value in parameters.items()]
    return "\n".join(lines) + "\n"
