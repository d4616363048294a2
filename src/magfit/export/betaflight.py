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

**A vehicle-frame calibration** (``frame == "vehicle"``, ``corrected_vehicle = M @ (raw - offset)``): the
alignment goes into ``align_mag``, which Betaflight applies *before* subtracting ``mag_calibration``
(``alignSensorViaRotation`` / ``alignSensorViaMatrix`` in src/main/sensors/boardalignment.c). With the polar
split ``M = Q @ S``, ``align_mag = Q`` and ``mag_calibration = round(Q @ offset)`` (the offset in the aligned
frame) give ``Q @ (raw - offset)``; the soft iron S is dropped as for any calibration (the heading error
stated). Q is written as a fixed ``align_mag`` (``CW90``, ``CW270FLIP`` ...) when one is within
:data:`._common.ROTATION_TOLERANCE_DEG`, else as ``align_mag = CUSTOM`` with ``mag_align_roll/pitch/yaw`` in
whole decidegrees (:func:`magfit.rotations.custom_rotation`, Betaflight 2026.6's convention; the values for
Betaflight 4.1-2025.12, which turned the other way, are given in a comment). A mirror is refused. The
samples must be Betaflight's magADC counts logged with ``align_mag = CW0`` and no board alignment.
"""

from __future__ import annotations

import numpy as np

from ..calibration import Calibration
from ..errors import ExportError
from ..rotations import custom_angles, custom_rotation
from ._common import ROTATION_TOLERANCE_DEG, describe, plain, raw_counts, samples_note, unit_phrase, vehicle_split
from ._heading import ASSUMPTION, heading_error_deg

INT16 = (-32768, 32767)


#: Betaflight's CLI names of align_mag (lookupTableAlignment in src/main/cli/settings.c), by value.
ALIGNMENT_NAMES = {
    1: "CW0", 2: "CW90", 3: "CW180", 4: "CW270", 5: "CW0FLIP", 6: "CW90FLIP", 7: "CW180FLIP", 8: "CW270FLIP"
}  # fmt: skip


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
    zero = np.rint(_alignment(calibration)[0] @ calibration.offset)
    low, high = INT16
    if not np.all((zero >= low) & (zero <= high)):
        raise ExportError(
            f"Betaflight's mag_calibration is an int16 array, but the offset is {np.array2string(zero)}; are the "
            "samples the sensor's raw counts?"
        )
    x, y, z = (int(v) for v in zero)
    return x, y, z


def _alignment(calibration: Calibration) -> tuple[np.ndarray, list[str], list[str]]:
    """(the rotation Betaflight will apply, its CLI lines, comment lines); the identity for a sensor frame."""
    if calibration.frame != "vehicle":
        return np.eye(3), [], []
    split = vehicle_split(calibration, "betaflight", "betaflight")
    standard = split.standard
    assert standard is not None
    if standard.angle_deg <= ROTATION_TOLERANCE_DEG:
        name = ALIGNMENT_NAMES[standard.id]
        comments = [f"# align_mag = {name} is {standard.angle_deg:.2f} deg from the fitted alignment"]
        return np.asarray(standard.matrix), [f"set align_mag = {name}"], comments
    angles = [round(a) for a in custom_angles(split.rotation, "betaflight")]
    legacy = [round(a) for a in custom_angles(split.rotation, "inav")]  # 4.1-2025.12 turned the other way
    names = ("mag_align_roll", "mag_align_pitch", "mag_align_yaw")
    commands = ["set align_mag = CUSTOM", *(f"set {n} = {a}" for n, a in zip(names, angles, strict=True))]
    comments = [
        f"# align_mag = CUSTOM: the fitted alignment to 0.1 deg (the nearest fixed one, "
        f"{ALIGNMENT_NAMES[standard.id]}, is {standard.angle_deg:.1f} deg away);",
        "#   mag_align_* in decidegrees, Betaflight 2026.6 or later. Betaflight",
        "#   4.1-2025.12 applied these angles reversed (fixed by 'Fix mag_align_yaw', 2026.6): there use "
        + ", ".join(f"{n} = {a}" for n, a in zip(names, legacy, strict=True)),
    ]
    return custom_rotation("betaflight", *angles), commands, comments


def write_betaflight(calibration: Calibration, unit: str | None = None) -> str:
    """Betaflight CLI commands (``set mag_calibration = x,y,z``, then ``save``); see the module docstring."""
    offset = betaflight_offset(calibration, unit)
    label = raw_counts(calibration, unit, "betaflight")
    rotation, commands, comments = _alignment(calibration)
    # Betaflight: align(raw) - zero = A (raw - A^T zero)
    loss = heading_error_deg(calibration, rotation, rotation.T @ np.array(offset, dtype=np.float64))
    lines = [
        "# Betaflight magnetometer calibration: paste into the CLI (Configurator > CLI), the 'save' line reboots.",
        *(f"# {plain(line)}" for line in describe(calibration, label)),
        "# Betaflight corrects each reading (compassUpdate in sensors/compass.c), after the mag alignment:",
        "#   magADC = align(magADCRaw) - mag_calibration",
    ]
    if calibration.frame == "vehicle":
        lines += [
            "# vehicle frame: magfit's matrix M = Q S (rotation Q after the soft iron S): align = Q,",
            "#   mag_calibration = round(Q * offset), in counts; S is dropped.",
            *samples_note(
                calibration,
                [
                    f"# Samples: {unit_phrase(label)}; they must be Betaflight's magADC counts logged with "
                    "align_mag = CW0,",
                    "#   no board alignment and mag_calibration = 0,0,0.",
                ],
            ),
            *comments,
        ]
    else:
        lines += [
            "# mapping: mag_calibration = round(offset), in counts.",
            f"# Samples: {unit_phrase(label)}; they must be Betaflight's aligned magADC counts, logged uncalibrated",
            "#   (mag_calibration = 0,0,0).",
        ]
    lines += [
        "# Lost: Betaflight holds the hard-iron offset only. Dropping magfit's matrix (soft iron) and the rounding",
        f"#   cost a heading error of up to {loss:.2f} deg ({ASSUMPTION}).",
        *commands,
        f"set mag_calibration = {offset[0]},{offset[1]},{offset[2]}",
        "save",
    ]
    return "\n".join(lines) + "\n"
