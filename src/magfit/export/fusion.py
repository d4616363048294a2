"""x-io Technologies Fusion / imufusion: ``softIronMatrix`` and ``hardIronOffset``, as a C header and in Python.

Fusion's magnetometer model (``FusionModelMagnetic`` in FusionModel.h, called
``FusionCalibrationMagnetic`` in FusionCalibration.h before the rename)::

    calibrated = softIronMatrix * (uncalibrated - hardIronOffset)

is magfit's ``corrected = matrix @ (raw - offset)`` (paper eq. 5) symbol for symbol:
``softIronMatrix = matrix`` (``FusionMatrix`` is row-major) and ``hardIronOffset = offset``, in the
samples' unit (Fusion normalises the field, so any unit works, raw counts included).

``FusionMatrix`` is a union whose first member is the array: ``float array[3][3]`` up to Fusion
1.2.x, ``float array[9]`` from 1.3.0 (FusionMath.h). A brace initialiser fills the first member, so
the header writes the nine values flat, in row order, inside one pair of braces: exact for the flat
array, and for the nested one by brace elision (C and C++ fill ``array[0][0..2]`` then
``array[1][..]``). Nested row braces ``{{a, b, c}, ...}`` are wrong for 1.3: C puts ``a``, ``d``, ``g``
into the first three elements (the first column, with a warning), C++ refuses to compile. The tests
compile the header with the real FusionMath.h of both layouts, as C and as C++. Values outside
float32's range are refused (a C ``float`` literal beyond it is infinity). Fusion releases before the 2023 model
change (x-io Fusion PR #121) computed ``S * uncalibrated - h`` instead; the header gives the offset
those releases need, ``matrix @ offset``, in a comment. The same numbers appear as the Python
names ``soft_iron_matrix`` and ``hard_iron_offset`` (numpy arrays) for
``imufusion.model_magnetic(uncalibrated, soft_iron_matrix, hard_iron_offset)``. A non-symmetric
matrix (``root="cholesky"``) is written as fitted, with a warning giving the rotation it adds
(see :func:`._common.rotated_frame_warning`).
"""

from __future__ import annotations

from ..calibration import Calibration
from ._common import (
    c_float,
    check_float32,
    describe,
    float32_text,
    label_unit,
    plain,
    rotated_frame_warning,
    unit_phrase,
)

GUARD = "MAGFIT_FUSION_CALIBRATION_H"
PYTHON_BEGIN = "Python (imufusion) >>>"
PYTHON_END = "<<< Python"


def write_fusion(calibration: Calibration, unit: str | None = None) -> str:
    """The calibration as a C header for Fusion, with the Python assignments in a comment block.

    Raises
    ------
    OptionError
        ``unit`` is not a unit magfit knows.
    ExportError
        A value does not fit in a C ``float``.
    """
    label = label_unit(calibration, unit)
    matrix, offset = calibration.matrix, calibration.offset
    check_float32({"matrix": matrix, "offset": offset, "matrix @ offset": matrix @ offset}, "fusion")
    # Flat, row order: right for both FusionMatrix layouts (see the module docstring).
    c_matrix = ",\n    ".join(", ".join(c_float(v) for v in row) for row in matrix)
    c_offset = ", ".join(c_float(v) for v in offset)
    legacy = ", ".join(c_float(v) for v in matrix @ offset)
    warning = rotated_frame_warning(calibration)
    warning_line = f" * {plain(warning)}\n" if warning else ""
    py_rows = ",\n".join(" *         [" + ", ".join(float32_text(v) for v in row) + "]" for row in matrix)
    py_offset = ", ".join(float32_text(v) for v in offset)
    facts = "\n".join(f" * {line}" for line in describe(calibration, label))
    return f"""/* Fusion (x-io Technologies) magnetometer calibration. Generated file: re-export instead of editing.
 *
 * Fusion's model (FusionModelMagnetic; FusionCalibrationMagnetic in older releases):
 *     calibrated = softIronMatrix * (uncalibrated - hardIronOffset)
 * = magfit's corrected = matrix * (raw - offset): softIronMatrix = matrix, hardIronOffset = offset.
 * uncalibrated, hardIronOffset and calibrated: {unit_phrase(label)}.
 * Fusion releases before the 2023 model change (calibrated = S * uncalibrated - h) need instead
 *     hardIronOffset = {{{legacy}}}
 * softIronMatrix is written flat in row order (xx, xy, xz, yx, ... zz): right for FusionMatrix's
 * float array[9] (Fusion 1.3 and later) and, by brace elision, for array[3][3] (earlier releases).
{facts}
{warning_line} *
 * {PYTHON_BEGIN}
 *     import numpy as np
 *     soft_iron_matrix = np.array([
{py_rows},
 *     ])
 *     hard_iron_offset = np.array([{py_offset}])
 *     # calibrated = imufusion.model_magnetic(uncalibrated, soft_iron_matrix, hard_iron_offset)
 * {PYTHON_END}
 */
#ifndef {GUARD}
#define {GUARD}

#include "Fusion.h"

static const FusionMatrix softIronMatrix = {{{{
    {c_matrix}
}}}};
static const FusionVector hardIronOffset = {{{{{c_offset}}}}};

#endif /* {GUARD} */
"""
