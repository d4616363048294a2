"""x-io Technologies Fusion / imufusion: ``softIronMatrix`` and ``hardIronOffset``, as a C header and in Python.

Fusion's magnetometer model (``FusionModelMagnetic`` in FusionModel.h, called
``FusionCalibrationMagnetic`` in FusionCalibration.h before the rename)::

    calibrated = softIronMatrix * (uncalibrated - hardIronOffset)

is magfit's ``corrected = matrix @ (raw - offset)`` (paper eq. 5) symbol for symbol:
``softIronMatrix = matrix`` (``FusionMatrix`` is row-major: ``.array[i][j]`` is row i, column j) and
``hardIronOffset = offset``, in the samples' unit (Fusion normalises the field, so any unit works,
raw counts included). The initialisers fill the unions' first member, ``.array``, with plain braces
(no designators), so the header compiles as C99 and as C++. Fusion releases before the 2023 model
change (x-io Fusion PR #121) computed ``S * uncalibrated - h`` instead; the header gives the offset
those releases need, ``matrix @ offset``, in a comment. The same numbers appear as the Python
names ``soft_iron_matrix`` and ``hard_iron_offset`` (numpy arrays) for
``imufusion.model_magnetic(uncalibrated, soft_iron_matrix, hard_iron_offset)``. No limits: every
calibration can be written.
"""

from __future__ import annotations

from ..calibration import Calibration
from ._common import c_float, describe, float32_text, label_unit, unit_phrase

GUARD = "MAGFIT_FUSION_CALIBRATION_H"
PYTHON_BEGIN = "Python (imufusion) >>>"
PYTHON_END = "<<< Python"


def write_fusion(calibration: Calibration, unit: str | None = None) -> str:
    """The calibration as a C header for Fusion, with the Python assignments in a comment block.

    Raises
    ------
    OptionError
        ``unit`` is not a unit magfit knows.
    """
    label = label_unit(calibration, unit)
    matrix, offset = calibration.matrix, calibration.offset
    c_rows = ", ".join("{" + ", ".join(c_float(v) for v in row) + "}" for row in matrix)
    c_offset = ", ".join(c_float(v) for v in offset)
    legacy = ", ".join(c_float(v) for v in matrix @ offset)
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
{facts}
 *
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

static const FusionMatrix softIronMatrix = {{{{{c_rows}}}}};
static const FusionVector hardIronOffset = {{{{{c_offset}}}}};

#endif /* {GUARD} */
"""
