"""MATLAB ``magcal`` form: a ``.m`` snippet assigning ``A``, ``b`` and ``expmfs``.

MATLAB's ``[A, b, expmfs] = magcal(D)`` works on row vectors, one sample per row of ``D``::

    C = (D - b) * A

With magfit's column-vector ``corrected = matrix @ (raw - offset)`` (paper eq. 5), transposing one
sample gives ``correctedᵀ = (raw - offset)ᵀ matrixᵀ``, hence::

    A = matrixᵀ      b = offset (a 1x3 row)      expmfs = field_strength

in the samples' unit (no conversion; raw counts are fine). Values are written with 17 significant
digits, so MATLAB's doubles hold exactly magfit's numbers. No limits: every calibration can be written;
a non-symmetric matrix (``root="cholesky"``) is written as fitted with a warning giving the rotation it adds.
"""

from __future__ import annotations

from ..calibration import Calibration
from ._common import describe, label_unit, plain, rotated_frame_warning, unit_phrase


def _double(value: float) -> str:
    return f"{float(value):.17g}"


def write_magcal(calibration: Calibration, unit: str | None = None) -> str:
    """The calibration as MATLAB code in magcal's row-vector form (``C = (D - b) * A``).

    Raises
    ------
    OptionError
        ``unit`` is not a unit magfit knows.
    """
    label = label_unit(calibration, unit)
    a = calibration.matrix.T  # row-vector form: C = (D - b) * A with A = matrixᵀ
    rows = ";\n     ".join(", ".join(_double(v) for v in row) for row in a)
    offset = ", ".join(_double(v) for v in calibration.offset)
    facts = "\n".join(f"% {plain(line)}" for line in describe(calibration, label))
    warning = rotated_frame_warning(calibration)
    if warning:
        facts += f"\n% {plain(warning)}"
    return f"""% magfit magnetometer calibration in MATLAB magcal's form. Generated file: re-export instead of editing.
%
%     C = (D - b) * A
%
% D: raw samples, one [x y z] row per sample; C: corrected samples, on a sphere of radius expmfs.
% From magfit's corrected = matrix * (raw - offset): A = matrix.' (transposed), b = offset, expmfs = field strength.
% D, b, C and expmfs: {unit_phrase(label)}; A: dimensionless.
{facts}
A = [{rows}];
b = [{offset}];
expmfs = {_double(calibration.field_strength)};
"""
