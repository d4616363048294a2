"""Firmware exports: write a :class:`magfit.Calibration` in the convention of the code that will use it.

Every target states its own formula in the file it writes, next to how magfit's
``corrected = matrix @ (raw - offset)`` maps onto it; ``docs/exports.md`` has the table.

========== ========== ====================================================== ============
name       extension  convention written                                     values in
========== ========== ====================================================== ============
json       .json      magfit's own, lossless (``Calibration.from_json``)     input unit
c          .h         ``corrected = matrix * (raw - offset)``, C floats       input unit
ardupilot  .param     ``mag += OFS; mag *= SCALE; mag = [DIA/ODI] * mag``    milligauss
px4        .params    ``corrected = S * (raw - OFF)``, S from SCALE/ODIAG    gauss
fusion     .h         ``softIronMatrix * (uncalibrated - hardIronOffset)``   input unit
magcal     .m         MATLAB ``C = (D - b) * A``                              input unit
adafruit   .h         ``softiron * (magnetic - hardiron)``, row-major [9]    µT
adafruit-  .json      the same, Adafruit_Sensor_Calibration_SDFat's file     µT
json
inav       .txt       ``(raw - magzero) * 1024 / maggain`` (diagonal only)   raw counts
betaflight .txt       ``align(raw) - mag_calibration`` (offset only)         raw counts
rtimulib   .ini       ``compassCalCorr * (compass - compassCalOffset)``      µT
ros-       .yaml      ``magnetic_field - mag_bias`` (offset only)            tesla
madgwick
yaml       .yaml      ``corrected = matrix @ (raw - offset)``, generic        input unit
========== ========== ====================================================== ============

>>> import numpy as np, magfit
>>> from magfit.export import export
>>> cal = magfit.Calibration("ellipsoid", np.array([28.6, -40.0, -27.4]), np.eye(3), 52.9, unit="uT")
>>> print(export(cal, "ardupilot").splitlines()[-10])
COMPASS_OFS_X,-286
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from types import MappingProxyType

from ..calibration import Calibration
from ..errors import MagfitError, OptionError
from .adafruit import write_adafruit, write_adafruit_json
from .ardupilot import write_ardupilot
from .betaflight import write_betaflight
from .c_header import write_c_header
from .fusion import write_fusion
from .inav import write_inav
from .jsonfile import write_json
from .magcal import write_magcal
from .px4 import write_px4
from .ros_madgwick import write_ros_madgwick
from .rtimulib import write_rtimulib
from .yamlfile import write_yaml

__all__ = ["FORMATS", "FormatSpec", "export"]


@dataclass(frozen=True)
class FormatSpec:
    """An export target.

    Attributes
    ----------
    name : str
        The name :func:`export` takes (``"ardupilot"`` ...).
    extension : str
        File extension, with the dot (``".param"``).
    summary : str
        One line: what the file is and its convention.
    unit : str or None
        Unit of the exported values (``"mG"``), or None when they stay in the samples' unit.
    writer : callable
        ``writer(calibration, unit, **options) -> str``; use :func:`export`, which checks its arguments.
    options : tuple of str
        The keyword options of :func:`export` this target takes besides ``unit`` (``("system_id",)``).
    """

    name: str
    extension: str
    summary: str
    unit: str | None
    writer: Callable[..., str]
    options: tuple[str, ...] = ()


_SPECS = (
    FormatSpec(
        "json", ".json", "magfit's own lossless JSON (schema version 1), read back by Calibration.from_json",
        None, write_json,
    ),
    FormatSpec(
        "c", ".h", "C header: static const float offset, matrix, field strength; corrected = matrix * (raw - offset)",
        None, write_c_header,
    ),
    FormatSpec(
        "ardupilot", ".param", "ArduPilot COMPASS_OFS/DIA/ODI/SCALE parameters in milligauss (Mission Planner)",
        "mG", write_ardupilot,
    ),
    FormatSpec(
        "px4", ".params", "PX4 CAL_MAG0_OFF/SCALE/ODIAG parameters in gauss (QGroundControl parameter file)",
        "G", write_px4, ("system_id",),
    ),
    FormatSpec(
        "fusion", ".h", "x-io Fusion softIronMatrix / hardIronOffset (C header) with the imufusion Python names",
        None, write_fusion,
    ),
    FormatSpec(
        "magcal", ".m", "MATLAB magcal form: A, b, expmfs with C = (D - b) * A",
        None, write_magcal,
    ),
    FormatSpec(
        "adafruit", ".h", "Adafruit_Sensor_Calibration (MotionCal) mag_hardiron/mag_softiron/mag_field in uT, C++",
        "uT", write_adafruit,
    ),
    FormatSpec(
        "adafruit-json", ".json", "Adafruit_Sensor_Calibration_SDFat JSON file: mag_hardiron, mag_softiron, mag_field",
        "uT", write_adafruit_json,
    ),
    FormatSpec(
        "inav", ".txt", "INAV CLI set magzero_*/maggain_* in raw counts (diagonal only; the loss is stated)",
        "counts", write_inav,
    ),
    FormatSpec(
        "betaflight", ".txt", "Betaflight CLI set mag_calibration in raw counts (hard iron only; the loss is stated)",
        "counts", write_betaflight,
    ),
    FormatSpec(
        "rtimulib", ".ini", "RTIMULib.ini compass keys: compassCalOffset*/compassCalCorr* (ellipsoid stage) in uT",
        "uT", write_rtimulib,
    ),
    FormatSpec(
        "ros-madgwick", ".yaml", "ROS imu_filter_madgwick mag_bias_x/y/z in tesla (hard iron only; the loss is stated)",
        "T", write_ros_madgwick,
    ),
    FormatSpec(
        "yaml", ".yaml", "generic YAML: offset, matrix, field strength, unit, corrected = matrix @ (raw - offset)",
        None, write_yaml,
    ),
)  # fmt: skip

#: The export targets by name.
FORMATS: Mapping[str, FormatSpec] = MappingProxyType({spec.name: spec for spec in _SPECS})


def export(calibration: Calibration, format: str, *, unit: str | None = None, system_id: int | None = None) -> str:
    """The text of a file that carries ``calibration`` in the convention of ``format``.

    Parameters
    ----------
    calibration : Calibration
        The calibration to write (``corrected = matrix @ (raw - offset)``, input units).
    format : str
        A name in :data:`FORMATS`: ``"json"``, ``"c"``, ``"ardupilot"``, ``"px4"``, ``"fusion"``, ``"magcal"``,
        ``"adafruit"``, ``"adafruit-json"``, ``"inav"``, ``"betaflight"``, ``"rtimulib"``, ``"ros-madgwick"``,
        ``"yaml"``.
    unit : str or None
        Unit of the samples the calibration was fitted on (``"uT"``, ``"nT"``, ``"mT"``, ``"mG"``,
        ``"G"``/``"gauss"``, ``"counts"``; aliases such as ``"µT"`` accepted), overriding
        ``calibration.unit``. ArduPilot and PX4 need a physical unit to convert to mG / G.

    Returns
    -------
    str
        The file's text, ending with a newline. No date inside: the same input gives the same text.

    Raises
    ------
    OptionError
        Unknown ``format`` (the message lists the valid ones), unknown ``unit``, or an option the
        format does not take (``system_id`` for anything but ``px4``).
    ExportError
        The target cannot represent the calibration (out of its accepted range, or a
        non-symmetric matrix) or needs a unit conversion that the unit does not allow (counts, none).
    """
    spec = FORMATS.get(format) if isinstance(format, str) else None
    if spec is None:
        valid = ", ".join(f"{name} ({s.extension})" for name, s in FORMATS.items())
        raise OptionError(f"unknown export format {format!r}; valid formats: {valid}")
    if not isinstance(calibration, Calibration):
        raise MagfitError(f"export() takes a magfit.Calibration, got {type(calibration).__name__}")
    given = {name: value for name, value in (("system_id", system_id),) if value is not None}
    for name in given:
        if name not in spec.options:
            takers = ", ".join(s.name for s in FORMATS.values() if name in s.options)
            raise OptionError(f"the {format} export takes no {name}; {name} applies to: {takers}")
    return spec.writer(calibration, unit, **given)
