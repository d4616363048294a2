"""Betaflight CLI: ``set mag_calibration = x,y,z``, the hard-iron offset in raw counts.

Betaflight's ``compassUpdate`` (src/main/sensors/compass.c, betaflight/betaflight 58ae3fd and
0270127) reads the sensor (int16 counts), applies the mag alignment, then subtracts
``compassConfig()->magZero``::

    magADC = align(magADCRaw) - magZero        # no scale, no soft iron

``mag_calibration`` is that magZero: an int16 array of three (VAR_INT16, MODE_ARRAY,
``magZero.raw`` in the CLI settings table, settings.c). So ``mag_calibration = round(offset)``, with
the offset fitted on Betaflight's aligned magADC counts (the board frame, as Betaflight logs them). Betaflight holds no
soft-iron correction at all: what that costs, and the rounding, is said in the file as a heading
error computed for the calibration at hand (:func:`._heading.heading_error_deg`). For a soft-iron
free sensor, ``method="sphere"`` is the fit that matches what Betaflight can hold.

Refused: a physical unit (Betaflight needs the counts it reads), an offset outside int16.
"""

from __future__ import annotations

import numpy as np

from ..calibration import Calibration
from ..errors import ExportError
from ._common import describe, plain, raw_counts, unit_phrase
from ._heading import ASSUMPTION, heading_error_deg

INT16 = (-32768, 32767)


def betaflight_offset(calibration: Calibration, unit: str | None = None) -> tuple[int, int, int]:
    """The three integers of ``mag_calibration``.

    Raises
    ------
    ExportError
        The samples are in a physical unit, or the offset does not fit int16.
    OptionError
        ``unit`` is not a unit magfit knows.
    """
    raw_counts(calibration, unit, "betaflight")
    zero = np.rint(calibration.offset)
    low, high = INT16
    if not np.all((zero >= low) & (zero <= high)):
        raise ExportError(
            f"Betaflight's mag_calibration is an int16 array, but the offset is {np.array2string(zero)}; are the "
            "samples the sensor's raw counts?"
        )
    x, y, z = (int(v) for v in zero)
    return x, y, z


def write_betaflight(calibration: Calibration, unit: str | None = None) -> str:
    """Betaflight CLI commands (``set mag_calibration = x,y,z``, then ``save``); see the module docstring."""
    offset = betaflight_offset(calibration, unit)
    label = raw_counts(calibration, unit, "betaflight")
    loss = heading_error_deg(calibration, np.eye(3), np.array(offset, dtype=np.float64))
    lines = [
        "# Betaflight magnetometer calibration: paste into the CLI (Configurator > CLI), the 'save' line reboots.",
        *(f"# {plain(line)}" for line in describe(calibration, label)),
        "# Betaflight corrects each reading (compassUpdate in sensors/compass.c), after the mag alignment:",
        "#   magADC = align(magADCRaw) - mag_calibration",
        "# mapping: mag_calibration = round(offset), in counts.",
        f"# Samples: {unit_phrase(label)}; they must be Betaflight's aligned magADC counts, logged uncalibrated",
        "#   (mag_calibration = 0,0,0).",
        "# Lost: Betaflight holds the hard-iron offset only. Dropping magfit's matrix (soft iron) and the rounding",
        f"#   cost a heading error of up to {loss:.2f} deg ({ASSUMPTION}).",
        f"set mag_calibration = {offset[0]},{offset[1]},{offset[2]}",
        "save",
    ]
    return "\n".join(lines) + "\n"
