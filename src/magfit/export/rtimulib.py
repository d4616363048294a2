"""RTIMULib settings (``RTIMULib.ini``): the compass min/max and ellipsoid calibration keys, in µT.

RTIMULib (RTIMULib/IMUDrivers/RTIMU.cpp, ``RTIMU::calibrateAverageCompass``, RPi-Distro/RTIMULib
6a6e784) corrects the compass in µT (its drivers scale the counts to µT) in two stages, the second
only when the first is valid (``getCompassCalibrationValid``)::

    c[i] = (compass[i] - minmax_offset[i]) * minmax_scale[i]         # CompassCalValid
    e = c - compassCalOffset                                            # compassCalEllipsoidValid
    compass[i] = sum over j of compassCalCorr(i+1)(j+1) * e[j]

with ``minmax_offset = (max + min) / 2`` and ``minmax_scale = max half-range / this half-range``
(``RTIMU::setCalibrationData``). The file sets every min to ``-R`` and every max to ``+R``
(``R`` = the field strength in µT), which makes the first stage the identity, then
``compassCalOffset = k * offset`` and ``compassCalCorr = matrix`` (row i, column j), with ``k``
the factor from the samples' unit to µT.

The keys are those ``RTIMUSettings::loadSettings`` compares with ``strcmp`` (RTIMUSettings.h):
``CompassCalValid``, ``CompassCalMinX`` ... ``CompassCalMaxZ``, ``compassCalEllipsoidValid``,
``compassCalOffsetX/Y/Z``, ``compassCalCorr11`` ... ``compassCalCorr33`` (the Python binding calls the
same values ``CompassCalEllipsoidOffset`` and ``CompassCalEllipsoidCorr11``). Lines are
``key=value`` with no space (``sscanf("%[^=]=%s")``); lines starting with ``#``, a space or a newline
are skipped. The file holds these keys only: merge them into the RTIMULib.ini that holds the IMU's
type and bus (a key given twice takes the later value; ``saveSettings`` rewrites the whole file).

Lines: ``RTIMUSettings::loadSettings`` reads the file with ``fgets(buf, 200, m_fd)`` and aborts at the first
line ``sscanf`` cannot parse, so every comment is wrapped to :data:`LINE_WIDTH` characters: a longer one
would come back from fgets in two pieces, the second no comment.

Refused: no physical unit, values outside float32. A non-symmetric matrix is written as fitted with
the warning of :func:`._common.rotated_frame_warning`.
"""

from __future__ import annotations

from ..calibration import Calibration
from ._common import check_float32, comment_lines, describe, factor, float32_text, physical_unit, rotated_frame_warning

AXES = "XYZ"
#: RTIMUSettings::loadSettings reads with ``fgets(buf, 200, m_fd)``: at most 199 characters, the newline
#: included, per call; the rest of a longer line comes back as a line of its own, which, unless it happens
#: to start with '#', ' ' or a newline, ``sscanf("%[^=]=%s")`` rejects ("Bad line in settings file"), and
#: loadSettings returns false with the settings read so far. Every line written is at most this long.
LINE_WIDTH = 100
#: The longest line (without its newline) fgets(buf, 200) returns whole, with the newline.
READER_LINE_MAX = 198


def rtimulib_settings(calibration: Calibration, unit: str | None = None) -> dict[str, str]:
    """The RTIMULib.ini keys and their text values, in µT (see the module docstring).

    Raises
    ------
    ExportError
        No physical unit, or a value outside float32's range.
    OptionError
        ``unit`` is not a unit magfit knows.
    """
    k = factor(physical_unit(calibration, unit, "rtimulib", "uT"), "uT")
    radius = k * calibration.field_strength
    offset = k * calibration.offset
    check_float32({"offset": offset, "matrix": calibration.matrix, "field_strength": radius}, "rtimulib")
    settings = {"CompassCalValid": "true"}
    for axis in AXES:  # equal ranges centred on 0: the min/max stage is the identity
        settings[f"CompassCalMin{axis}"] = float32_text(-radius)
        settings[f"CompassCalMax{axis}"] = float32_text(radius)
    settings["compassCalEllipsoidValid"] = "true"
    for axis, value in zip(AXES, offset, strict=True):
        settings[f"compassCalOffset{axis}"] = float32_text(value)
    for i in range(3):
        for j in range(3):
            settings[f"compassCalCorr{i + 1}{j + 1}"] = float32_text(calibration.matrix[i, j])
    return settings


def write_rtimulib(calibration: Calibration, unit: str | None = None) -> str:
    """The compass keys of RTIMULib.ini (see the module docstring)."""
    settings = rtimulib_settings(calibration, unit)
    source = physical_unit(calibration, unit, "rtimulib", "uT")
    k = factor(source, "uT")
    lines = [
        "# RTIMULib compass calibration (RTIMULib.ini keys, uT). Generated file: re-export instead of editing.",
        "# Merge these lines into your RTIMULib.ini (it also holds the IMU type and bus): replace the keys of",
        "# the same names.",
        *(wrapped for line in describe(calibration, source.name) for wrapped in comment_lines(line, width=LINE_WIDTH)),
        "# RTIMULib corrects the compass (RTIMU::calibrateAverageCompass), in uT:",
        "#   c = (compass - (max + min) / 2) * (largest half-range / half-range)   min/max stage",
        "#   compass = compassCalCorr * (c - compassCalOffset)                     ellipsoid stage",
        "# mapping: min = -R, max = +R on every axis (the min/max stage does nothing), R = field strength;",
        f"#   compassCalOffset = offset * {float32_text(k)} ({source.name} -> uT), compassCalCorr = matrix.",
    ]
    warning = rotated_frame_warning(calibration)
    if warning:
        lines += comment_lines(warning, width=LINE_WIDTH)
    lines += [f"{key}={value}" for key, value in settings.items()]
    return "\n".join(lines) + "\n"
