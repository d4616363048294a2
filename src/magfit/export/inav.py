"""INAV CLI: ``set magzero_x/y/z`` and ``set maggain_x/y/z``, integers in the sensor's raw counts.

INAV's ``compassUpdate`` (src/main/sensors/compass.c, iNavFlight/inav 005b1ee) corrects each raw
reading ``magADCRaw`` (int16 counts, sensor frame), before the board and sensor alignment::

    magADC[axis] = (magADCRaw[axis] - magZero[axis]) * 1024 / magGain[axis]     # int32, truncating

INAV's own calibration sets magGain to the largest deviation from the zero on each axis, so the
corrected field has a radius of about 1024. It holds a diagonal correction only. magfit maps its
``corrected = matrix @ (raw - offset)`` onto it with the diagonal ``d = diag(matrix)``::

    magzero = round(offset)        maggain = round(field_strength / d)

which gives a corrected radius of 1024 along each axis. What is lost is said in the file, computed
for the calibration at hand (:func:`._heading.heading_error_deg`): the off-diagonal terms of the
matrix and the rounding to integers. A fit with ``method="diag"`` is the best INAV can hold.

Settings (src/main/fc/settings.yaml): ``magzero_*`` and ``maggain_*`` are int16 (-32768 to 32767),
maggain's default 1024 (with all zeros 0) meaning "not calibrated". Refused: a physical unit (INAV
needs the driver's counts), a value outside int16, a gain below 1 (INAV divides by it).
"""

from __future__ import annotations

import numpy as np

from ..calibration import Calibration
from ..errors import ExportError
from ._common import describe, plain, raw_counts, unit_phrase
from ._heading import ASSUMPTION, heading_error_deg

#: INAV's corrected scale: (raw - zero) * 1024 / gain.
INAV_SCALE = 1024
INT16 = (-32768, 32767)
AXES = "xyz"


def inav_settings(calibration: Calibration, unit: str | None = None) -> dict[str, int]:
    """``magzero_x`` ... ``maggain_z`` as INAV's integers (see the module docstring).

    Raises
    ------
    ExportError
        The samples are in a physical unit, or a value does not fit INAV's int16 settings.
    OptionError
        ``unit`` is not a unit magfit knows.
    """
    raw_counts(calibration, unit, "inav")
    diagonal = np.diag(calibration.matrix)
    if not np.all(diagonal > 0):
        raise ExportError(
            f"INAV holds positive gains only, but the matrix's diagonal is {np.array2string(diagonal, precision=4)}; "
            "the calibration flips an axis: check the samples' axis order and signs"
        )
    zero = np.rint(calibration.offset)
    gain = np.rint(calibration.field_strength / diagonal)
    settings = {f"magzero_{a}": int(v) for a, v in zip(AXES, zero, strict=True)}
    settings |= {f"maggain_{a}": int(v) for a, v in zip(AXES, gain, strict=True)}
    low, high = INT16
    for name, value in settings.items():
        if not low <= value <= high or (name.startswith("maggain") and value < 1):
            raise ExportError(
                f"INAV's {name} is an int16 (gains from 1 to {high}), but it would be {value}; are the samples the "
                "sensor's raw counts?"
            )
    return settings


def write_inav(calibration: Calibration, unit: str | None = None) -> str:
    """INAV CLI commands (``set ... = ...``, then ``save``); see the module docstring."""
    settings = inav_settings(calibration, unit)
    label = raw_counts(calibration, unit, "inav")
    zero = np.array([settings[f"magzero_{a}"] for a in AXES], dtype=np.float64)
    gain = np.array([settings[f"maggain_{a}"] for a in AXES], dtype=np.float64)
    loss = heading_error_deg(calibration, np.diag(INAV_SCALE / gain), zero)
    off = calibration.matrix - np.diag(np.diag(calibration.matrix))
    largest = float(np.max(np.abs(off)))
    lines = [
        "# INAV magnetometer calibration: paste into the CLI (Configurator > CLI), the 'save' line reboots.",
        *(f"# {plain(line)}" for line in describe(calibration, label)),
        "# INAV corrects each raw reading (compassUpdate in sensors/compass.c), sensor frame, integer counts:",
        "#   magADC = (magADCRaw - magzero) * 1024 / maggain",
        "# mapping: magzero = round(offset), maggain = round(field strength / diag(matrix)): radius 1024.",
        f"# Samples: {unit_phrase(label)}; they must be INAV's raw sensor counts, before any alignment.",
        f"# Lost: INAV holds a diagonal only. The matrix's off-diagonal terms (largest {largest:.4f}) and the",
        f"#   rounding cost a heading error of up to {loss:.2f} deg ({ASSUMPTION}).",
    ]
    if loss >= 0.5:
        lines.append(
            "#   Fit with method 'diag' for the best correction INAV can hold, or use a target with a full matrix."
        )
    lines += [f"set {name} = {value}" for name, value in settings.items()]
    lines.append("save")
    return "\n".join(lines) + "\n"
