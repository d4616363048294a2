"""INAV CLI: ``set magzero_x/y/z`` and ``set maggain_x/y/z``, integers in the sensor's raw counts.

INAV's ``compassUpdate`` (src/main/sensors/compass.c, iNavFlight/inav 005b1ee) corrects each raw
reading ``magADCRaw`` (int16 counts, sensor frame), before the board and sensor alignment::

    magADC[axis] = (magADC[axis] - magZero.raw[axis]) * 1024 / magGain[axis]    # magADC = magADCRaw

The arithmetic is that of ``mag.magADC``'s type (``mag_t`` in src/main/sensors/compass.h): ``float`` in
current INAV, since the sensors went float internally (iNavFlight/inav PR #9075, 2023, INAV 7.0 on), so
the division is exact to float; ``int32_t`` in the releases before, so C's integer division truncates
toward zero. The file states the heading loss for both (:func:`heading_losses`) and says which is which.

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

**A vehicle-frame calibration** (``frame == "vehicle"``, ``corrected_vehicle = M @ (raw - offset)``): INAV
applies its alignment *after* the zero and gain (compassUpdate: ``applySensorAlignment``, or, when any of
``align_mag_roll/pitch/yaw`` is non-zero, ``rotationMatrixRotateVector`` with ``rotationMatrixFromAngles``).
With the polar split ``M = Q @ S``: ``magzero = round(offset)`` (sensor frame), the gains from the diagonal
of S (its off-diagonal dropped, as for any calibration), and the alignment Q as a fixed ``align_mag``
(``align_mag_roll/pitch/yaw = 0``) within :data:`._common.ROTATION_TOLERANCE_DEG`, else as
``align_mag_roll/pitch/yaw`` in whole decidegrees (:func:`magfit.rotations.custom_rotation`). With a custom
alignment INAV skips the board alignment. A mirror is refused. The samples must be INAV's raw counts.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from ..calibration import Calibration
from ..errors import ExportError
from ..rotations import custom_angles, custom_rotation
from ._common import ROTATION_TOLERANCE_DEG, describe, plain, raw_counts, samples_note, unit_phrase, vehicle_split
from ._heading import ASSUMPTION, heading_error_of

#: INAV's corrected scale: (raw - zero) * 1024 / gain.
INAV_SCALE = 1024
INT16 = (-32768, 32767)
AXES = "xyz"
#: INAV's CLI names of align_mag (the alignment table of src/main/fc/settings.yaml), by value.
ALIGNMENT_NAMES = {
    1: "CW0", 2: "CW90", 3: "CW180", 4: "CW270", 5: "CW0FLIP", 6: "CW90FLIP", 7: "CW180FLIP", 8: "CW270FLIP"
}  # fmt: skip


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
    matrix = (
        vehicle_split(calibration, "inav", None).symmetric if calibration.frame == "vehicle" else calibration.matrix
    )
    diagonal = np.diag(matrix)
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


def _alignment(calibration: Calibration) -> tuple[np.ndarray, list[str], list[str]]:
    """(the rotation INAV will apply, its CLI lines, comment lines); the identity for a sensor frame."""
    if calibration.frame != "vehicle":
        return np.eye(3), [], []
    split = vehicle_split(calibration, "inav", "inav")
    standard = split.standard
    assert standard is not None
    names = ("align_mag_roll", "align_mag_pitch", "align_mag_yaw")
    if standard.angle_deg <= ROTATION_TOLERANCE_DEG:
        name = ALIGNMENT_NAMES[standard.id]
        commands = [f"set align_mag = {name}", *(f"set {n} = 0" for n in names)]
        return np.asarray(standard.matrix), commands, [f"# align_mag = {name}: {standard.angle_deg:.2f} deg off"]
    angles = [round(a) for a in custom_angles(split.rotation, "inav")]
    comments = [
        "# align_mag_roll/pitch/yaw: the fitted alignment to 0.1 deg, in decidegrees (the nearest fixed align_mag,",
        f"#   {ALIGNMENT_NAMES[standard.id]}, is {standard.angle_deg:.1f} deg away); INAV then skips board alignment",
    ]
    commands = [f"set {n} = {a}" for n, a in zip(names, angles, strict=True)]
    return custom_rotation("inav", *angles), commands, comments


def heading_losses(
    calibration: Calibration, zero: NDArray[np.float64], gain: NDArray[np.float64], rotation: NDArray[np.float64]
) -> tuple[float, float]:
    """The heading error (degrees) INAV leaves with these integers: (float arithmetic, int32 arithmetic).

    Float (INAV 7.0 on): ``(raw - zero) * 1024 / gain``. Int32 (before): the same, truncated toward zero
    as C's integer division truncates; both then turned by the alignment. The raw values are those of the
    heading grid (:func:`._heading.heading_error_of`), not rounded to counts: the sensor's own quantization
    is the same for both and for magfit's correction, and is not the export's to state.
    """

    def in_float(raw: NDArray[np.float64]) -> NDArray[np.float64]:
        return ((raw - zero) * INAV_SCALE / gain) @ rotation.T

    def in_int32(raw: NDArray[np.float64]) -> NDArray[np.float64]:
        return np.trunc((raw - zero) * INAV_SCALE / gain) @ rotation.T

    return heading_error_of(calibration, in_float), heading_error_of(calibration, in_int32)


def write_inav(calibration: Calibration, unit: str | None = None) -> str:
    """INAV CLI commands (``set ... = ...``, then ``save``); see the module docstring."""
    settings = inav_settings(calibration, unit)
    label = raw_counts(calibration, unit, "inav")
    rotation, commands, comments = _alignment(calibration)
    zero = np.array([settings[f"magzero_{a}"] for a in AXES], dtype=np.float64)
    gain = np.array([settings[f"maggain_{a}"] for a in AXES], dtype=np.float64)
    loss, loss_int32 = heading_losses(calibration, zero, gain, rotation)
    matrix = (
        vehicle_split(calibration, "inav", None).symmetric if calibration.frame == "vehicle" else calibration.matrix
    )
    off = matrix - np.diag(np.diag(matrix))
    largest = float(np.max(np.abs(off)))
    lines = [
        "# INAV magnetometer calibration: paste into the CLI (Configurator > CLI), the 'save' line reboots.",
        *(f"# {plain(line)}" for line in describe(calibration, label)),
        "# INAV corrects each raw reading (compassUpdate in sensors/compass.c), sensor frame, integer counts:",
        "#   magADC = (magADCRaw - magzero) * 1024 / maggain",
        "# mapping: magzero = round(offset), maggain = round(field strength / diag(matrix)): radius 1024.",
        f"# Samples: {unit_phrase(label)}; they must be INAV's raw sensor counts, before any alignment.",
    ]
    if calibration.frame == "vehicle":
        lines += [
            "# vehicle frame: magfit's matrix M = Q S (rotation Q after the soft iron S): the gains come from",
            "#   diag(S), and INAV's alignment, applied after them, is Q.",
            *samples_note(calibration, []),
            *comments,
        ]
    lines += [
        f"# Lost: INAV holds a diagonal only. The matrix's off-diagonal terms (largest {largest:.4f}) and the",
        f"#   rounding cost a heading error of up to {loss:.2f} deg ({ASSUMPTION}),",
        "#   with INAV 7.0 and later, which compute in float (float magADC, sensors/compass.h);",
        f"#   up to {loss_int32:.2f} deg with earlier INAV, which computes in int32 and truncates each axis.",
    ]
    if loss >= 0.5:
        lines.append(
            "#   Fit with method 'diag' for the best correction INAV can hold, or use a target with a full matrix."
        )
    lines += commands
    lines += [f"set {name} = {value}" for name, value in settings.items()]
    lines.append("save")
    return "\n".join(lines) + "\n"
