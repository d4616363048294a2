"""A self-contained C header: ``static const float`` offset, matrix and field strength, in input units.

The header states magfit's convention, ``corrected = matrix * (raw - offset)`` (the column-vector
form of paper eq. 5), and provides ``magfit_correct()`` that applies it. ``magfit_matrix[i][j]`` is
row i, column j of ``Calibration.matrix``. Values keep the input unit (no conversion, so raw
counts are fine) and are written with 9 significant digits (``%.9g``), enough to round-trip a
float. The text carries no date, so exporting the same calibration twice gives the same file.
A value beyond float32's range is refused (the literal would be infinity), and a non-symmetric
matrix (``root="cholesky"``) is written as fitted with a warning giving the rotation it adds.
"""

from __future__ import annotations

from ..calibration import Calibration
from ._common import c_float, check_float32, describe, label_unit, plain, rotated_frame_warning, unit_phrase

GUARD = "MAGFIT_CALIBRATION_H"


def write_c_header(calibration: Calibration, unit: str | None = None) -> str:
    """The calibration as a C header (``.h``).

    Parameters
    ----------
    calibration : Calibration
        The calibration to write.
    unit : str or None
        The samples' unit, overriding ``calibration.unit``; only printed in the comments.

    Raises
    ------
    OptionError
        ``unit`` is not a unit magfit knows.
    ExportError
        A value does not fit in a C ``float``.
    """
    check_float32(
        {"offset": calibration.offset, "matrix": calibration.matrix, "field_strength": calibration.field_strength}, "c"
    )
    motor = _motor_block(calibration)
    label = label_unit(calibration, unit)
    units = unit_phrase(label)
    warning = rotated_frame_warning(calibration)
    offset = ", ".join(c_float(v) for v in calibration.offset)
    rows = "\n".join("    {" + ", ".join(c_float(v) for v in row) + "}," for row in calibration.matrix)
    facts = "\n".join(f" * {line}" for line in describe(calibration, label))
    if warning:
        facts += f"\n * {plain(warning)}"
    return f"""/* magfit magnetometer calibration. Generated file: re-export instead of editing.
 *
 *     corrected = matrix * (raw - offset)
 *     corrected[i] = sum over j of magfit_matrix[i][j] * (raw[j] - magfit_offset[j])
 *
 * raw, magfit_offset and corrected: {units}. magfit_matrix: dimensionless (row-major, det = 1).
 * The corrected field lies on a sphere of radius magfit_field_strength.
{facts}
 */
#ifndef {GUARD}
#define {GUARD}

static const float magfit_offset[3] = {{{offset}}};

static const float magfit_matrix[3][3] = {{
{rows}
}};

static const float magfit_field_strength = {c_float(calibration.field_strength)};

/* Correct one sample: corrected = matrix * (raw - offset); raw and corrected may be the same array. */
static inline void magfit_correct(const float raw[3], float corrected[3])
{{
    const float d[3] = {{raw[0] - magfit_offset[0], raw[1] - magfit_offset[1], raw[2] - magfit_offset[2]}};
    for (int i = 0; i < 3; i++) {{
        corrected[i] = magfit_matrix[i][0] * d[0] + magfit_matrix[i][1] * d[1] + magfit_matrix[i][2] * d[2];
    }}
}}
{motor}
#endif /* {GUARD} */
"""


def _motor_block(calibration: Calibration) -> str:
    """The motors' field (magfit.motorterm), when the calibration holds it: its coefficients, lag and a
    ``magfit_correct_motor()`` taking the regressor; empty otherwise (the header is then as before)."""
    term = calibration.motor
    if term is None:
        return ""
    check_float32({"motor": term.coefficients}, "c")
    what = "the battery's current in A" if term.regressor == "current" else "the throttle, 0 to 1"
    values = ", ".join(c_float(v) for v in term.coefficients)
    return f"""
/* The motors' field: corrected = matrix * (raw - offset - magfit_motor * x), x = {what},
 * taken magfit_motor_lag_s seconds before the sample (negative: after). magfit_motor: raw units per unit of x. */
static const float magfit_motor[3] = {{{values}}};
static const float magfit_motor_lag_s = {c_float(term.lag_s)};

static inline void magfit_correct_motor(const float raw[3], float x, float corrected[3])
{{
    const float d[3] = {{raw[0] - magfit_offset[0] - magfit_motor[0] * x,
                        raw[1] - magfit_offset[1] - magfit_motor[1] * x,
                        raw[2] - magfit_offset[2] - magfit_motor[2] * x}};
    for (int i = 0; i < 3; i++) {{
        corrected[i] = magfit_matrix[i][0] * d[0] + magfit_matrix[i][1] * d[1] + magfit_matrix[i][2] * d[2];
    }}
}}
"""
