"""The export targets and the entry points: :data:`FORMATS`, :func:`export`, :func:`export_several`.

Each target's writer lives in its own module (``ardupilot.py``, ``px4.py`` ...); this module holds the table
of targets, checks the options each takes, refuses what no target may hold (a residual calibration, a unit that
is no Earth field, the motors' field where the format has no place for it) and calls the writer.
:mod:`magfit.export` re-exports the public names (see its docstring for the table of targets).
"""

from __future__ import annotations

import json
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any

from numpy.typing import ArrayLike

from ..calibration import Calibration
from ..errors import ExportError, MagfitError, OptionError
from ..findings import Reason
from ..remedy import option
from ..temperature import TemperatureDrift
from ..units import field_unit_reason, get_unit
from ._common import comment_lines, with_applied_rotation
from ._motor import refuse_motor
from .adafruit import write_adafruit, write_adafruit_json
from .ardupilot import write_ardupilot, write_ardupilot_several
from .betaflight import write_betaflight
from .c_header import write_c_header
from .fusion import write_fusion
from .inav import write_inav
from .jsonfile import write_json, write_json_dict
from .magcal import write_magcal
from .px4 import write_px4, write_px4_several
from .ros_madgwick import write_ros_madgwick
from .rtimulib import write_rtimulib
from .yamlfile import write_yaml

__all__ = ["FORMATS", "MOTOR_FORMATS", "SEVERAL", "UNIT_CHECKED", "FormatSpec", "export", "export_several"]


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
        "mG", write_ardupilot, ("slot", "device_id", "expected_field", "applied_rotation"),
    ),
    FormatSpec(
        "px4", ".params", "PX4 CAL_MAG0_OFF/SCALE/ODIAG parameters in gauss (QGroundControl parameter file)",
        "G", write_px4, ("system_id", "slot", "device_id", "applied_rotation", "temperature"),
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
        "counts", write_inav, ("applied_rotation",),
    ),
    FormatSpec(
        "betaflight", ".txt", "Betaflight CLI set mag_calibration in raw counts (hard iron only; the loss is stated)",
        "counts", write_betaflight, ("applied_rotation",),
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


def export(
    calibration: Calibration,
    format: str,
    *,
    unit: str | None = None,
    system_id: int | None = None,
    slot: int | None = None,
    device_id: int | None = None,
    expected_field: float | None = None,
    applied_rotation: ArrayLike | None = None,
    allow_unit_mismatch: bool = False,
    temperature: TemperatureDrift | None = None,
) -> str:
    """The text of a file that carries ``calibration`` in the convention of ``format``.

    Parameters
    ----------
    calibration : Calibration
        The calibration to write (``corrected = matrix @ (raw - offset)``, input units). A vehicle-frame
        calibration (``frame == "vehicle"``) is written whole by the full-matrix formats, split into the
        firmware's rotation and symmetric matrix by ``ardupilot``, ``px4``, ``betaflight`` and ``inav``, and
        refused, with the reason and the alternative, where the target cannot hold it.
    format : str
        A name in :data:`FORMATS`: ``"json"``, ``"c"``, ``"ardupilot"``, ``"px4"``, ``"fusion"``, ``"magcal"``,
        ``"adafruit"``, ``"adafruit-json"``, ``"inav"``, ``"betaflight"``, ``"rtimulib"``, ``"ros-madgwick"``,
        ``"yaml"``.
    unit : str or None
        Unit of the samples the calibration was fitted on (``"uT"``, ``"nT"``, ``"mT"``, ``"mG"``,
        ``"G"``/``"gauss"``, ``"counts"``; aliases such as ``"µT"`` accepted), overriding
        ``calibration.unit``. ArduPilot and PX4 need a physical unit to convert to mG / G.
    system_id : int or None
        ``px4``: the vehicle's MAVLink system id (1 unless given).
    slot, device_id : int or None
        ``ardupilot``, ``px4``: the firmware's 0-based compass slot (ArduPilot 0-2: ``COMPASS_OFS_*``,
        ``COMPASS_OFS2_*``, ``COMPASS_OFS3_*``; PX4 0-3: ``CAL_MAG0..3_*``) and the sensor's device id.
        Default: ``calibration.sensor`` (:class:`magfit.facts.LogCompass`: id, slot, device id, filled from
        a flight log), else slot 0 and no id. The explicit option wins.
    expected_field : float or None
        ``ardupilot``: the local field strength (World Magnetic Model) in the calibration's unit;
        ``COMPASS_SCALE`` becomes expected / fitted field, as ArduPilot's calibrator sets it.
    applied_rotation : array_like, shape (3, 3), or None
        ``ardupilot``, ``px4``, ``betaflight``, ``inav``, vehicle frame only: the mounting rotation the
        firmware had applied to the samples before they were logged (``board = R0 @ sensor``; ArduPilot
        logs MAG after COMPASS_ORIENT). The rotation written replaces it, so it includes it. Default:
        ``calibration.sensor.applied_rotation``, else none (the samples are the sensor's own readings).
    allow_unit_mismatch : bool
        The formats of :data:`UNIT_CHECKED` write the field in a physical unit, and refuse a calibration
        whose field strength is no place's Earth field in the declared unit
        (:func:`magfit.units.field_unit_reason`: a wrong ``unit``); True writes it all the same.
    temperature : TemperatureDrift or None
        ``px4``: the offset's drift with temperature a log determined (:func:`magfit.temperature.log_drifts`),
        written as PX4's ``TC_M_ENABLE``/``TC_Mn_*`` thermal compensation (a straight line about the log's
        mean temperature; refused, code ``undetermined``, when the log does not determine it).

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
        The target cannot represent the calibration (out of its accepted range, a non-symmetric matrix,
        a rotation or a mirror it has no parameter for), needs a unit conversion that the unit does not
        allow (counts, none), or the field strength is not the Earth's in the declared unit (code
        ``"unit_mismatch"``, unless ``allow_unit_mismatch``).
    """
    spec = _spec(format)
    if not isinstance(calibration, Calibration):
        raise MagfitError(f"export() takes a magfit.Calibration, got {type(calibration).__name__}")
    _refuse_residual(calibration, format)
    options = {"system_id": system_id, "slot": slot, "device_id": device_id, "expected_field": expected_field,
               "temperature": temperature}  # fmt: skip
    given = _options(spec, {**options, "applied_rotation": applied_rotation})
    mismatch = _refuse_unit_mismatch(calibration, format, unit, allow_unit_mismatch)
    given.pop("applied_rotation", None)
    if "applied_rotation" in spec.options:
        calibration = with_applied_rotation(calibration, applied_rotation)
    text: str = spec.writer(calibration, unit, **given)
    text = _marked_if_forced(text, calibration, format)
    return text if mismatch is None else _with_warning(text, format, f"WARNING (written although): {mismatch}")


#: The formats :func:`export_several` writes: several compasses of one vehicle in one file.
SEVERAL = ("ardupilot", "px4", "json")


def export_several(
    calibrations: Sequence[Calibration],
    format: str,
    *,
    unit: str | None = None,
    system_id: int | None = None,
    slots: Sequence[int | None] | None = None,
    device_ids: Sequence[int | None] | None = None,
    expected_field: float | None = None,
    allow_unit_mismatch: bool = False,
) -> str:
    """One file holding every compass of a vehicle: ``ardupilot``, ``px4`` or ``json``.

    Parameters
    ----------
    calibrations : sequence of Calibration
        One calibration per compass, each for its own slot.
    format : {"ardupilot", "px4", "json"}
        ``ardupilot``: COMPASS_*, COMPASS_*2, COMPASS_*3 in one ``.param`` file; ``px4``: CAL_MAG0..3_* in
        one QGroundControl file; ``json``: a JSON array of magfit's own calibrations (each element reads back
        with ``Calibration.from_dict``).
    unit, system_id, expected_field, allow_unit_mismatch
        As for :func:`export`, applied to every calibration.
    slots, device_ids : sequence of (int or None), optional
        Per calibration, in the same order: the firmware slot and the device id; None (or an entry None)
        takes the calibration's ``sensor`` (its slot and device id).

    Raises
    ------
    ExportError
        A format that holds one compass (the message says to export each on its own), two calibrations for
        the same slot, or anything :func:`export` refuses for one of them.
    OptionError
        Unknown format or option, or ``slots``/``device_ids`` not one per calibration.
    """
    spec = _spec(format)
    calibrations = list(calibrations)
    if not calibrations or not all(isinstance(c, Calibration) for c in calibrations):
        raise MagfitError("export_several() takes a non-empty sequence of magfit.Calibration")
    for calibration in calibrations:
        _refuse_residual(calibration, format)
        _refuse_unit_mismatch(calibration, format, unit, allow_unit_mismatch)
    if format in ("ardupilot", "px4"):  # their mounting rotations, as in export()
        calibrations = [with_applied_rotation(c, None) for c in calibrations]
    if format not in SEVERAL:
        raise ExportError(
            f"the {format} export holds one compass; export each calibration on its own with export(), or use "
            f"{', '.join(SEVERAL)} for several in one file"
        )
    for name, values in (("slots", slots), ("device_ids", device_ids)):
        if values is not None and len(values) != len(calibrations):
            raise OptionError(f"{name} must give one entry per calibration ({len(calibrations)}), got {len(values)}")
    if format == "json":
        _options(spec, {"system_id": system_id, "expected_field": expected_field})
        if slots is not None or device_ids is not None:
            raise OptionError(
                "the json export keeps each calibration's details; slots and device_ids apply to: ardupilot, px4"
            )
        return json.dumps([write_json_dict(c, unit) for c in calibrations], indent=2) + "\n"
    _options(spec, {"system_id": system_id, "expected_field": expected_field})
    if format == "ardupilot":
        text = write_ardupilot_several(
            calibrations, unit, slots=slots, device_ids=device_ids, expected_field=expected_field
        )
    else:
        text = write_px4_several(
            calibrations, unit, system_id=1 if system_id is None else system_id, slots=slots, device_ids=device_ids
        )
    for calibration in calibrations:
        text = _marked_if_forced(text, calibration, format)
    return text


#: The formats that write the field in a physical unit and refuse a calibration whose field strength is not the
#: Earth's in the declared unit (a wrong unit), unless forced: the values a consumer reads in µT, tesla or the
#: unit the file names would be wrong by a power of ten. ``ardupilot`` and ``px4`` refuse any field outside
#: their own narrower arming and calibration ranges, forced or not (their messages name the likely unit too).
#: ``json`` is magfit's lossless record and keeps every calibration; ``magcal``, ``inav`` and ``betaflight``
#: name no unit.
UNIT_CHECKED = ("c", "fusion", "adafruit", "adafruit-json", "rtimulib", "ros-madgwick", "yaml")


def _refuse_unit_mismatch(calibration: Calibration, format: str, unit: str | None, allow: bool) -> Reason | None:
    """Refuse a field strength that no place on Earth has in the declared unit (see :data:`UNIT_CHECKED`).

    Returns the reason when ``allow`` writes the calibration all the same (the file then says so), else None.
    """
    if format not in UNIT_CHECKED:
        return None
    declared = calibration.unit if unit is None else get_unit(unit).name  # OptionError for a misspelt unit
    reason = field_unit_reason(calibration.field_strength, declared)
    if reason is not None and allow:
        return reason
    if reason is not None:
        raise ExportError(
            f"the {format} export writes the field in {declared}, and {reason}; or write it all the same "
            f"({option('allow_unit_mismatch', True)})",
            codes=(reason.code,),
            remedy=reason.remedy,
        )
    return None


def _with_warning(text: str, format: str, warning: str) -> str:
    """``text`` with ``warning`` as comment lines after its first line (C block comments, MATLAB's ``%`` or
    ``#``; JSON has none: magfit's own holds the verdict, Adafruit's cannot say it)."""
    if format in ("adafruit-json", "json"):
        return text
    first, rest = text.split("\n", 1)
    prefix = " * " if first.startswith("/*") else "% " if first.startswith("%") else "# "
    return "\n".join([first, *comment_lines(warning, prefix=prefix), rest])


def _marked_if_forced(text: str, calibration: Calibration, format: str) -> str:
    """A calibration the samples do not support, written all the same (``allow_undetermined``, ``--force``),
    says so in the file: the refusal must not stay behind in a terminal while the file loads like any other."""
    support = calibration.support
    if support is None or support.verdict != "refused":
        return text
    why = support.refusals[0] if support.refusals else "the samples do not determine it"
    return _with_warning(
        text, format, f"NOT SUPPORTED by the samples, written because forced: do not use these numbers ({why})"
    )


#: The formats that hold the motors' field (export/_motor.py).
MOTOR_FORMATS = ("ardupilot", "px4", "c", "json")


def _refuse_residual(calibration: Calibration, format: str) -> None:
    """A fit on samples that still carry the firmware's calibration is a residual: only json may hold it."""
    if format not in MOTOR_FORMATS:  # the motors' field: written by these, refused with its cost by the others
        refuse_motor(calibration, format)
    in_use = calibration.sensor.calibration_in_use if calibration.sensor is not None else None
    if in_use and format != "json":
        raise ExportError(
            f"this calibration was fitted on samples that already carry the firmware's calibration ({in_use}): it "
            f"is a residual correction on top of that one, and written as {format} it would replace it; record "
            "the raw field (or the parameters with it) and calibrate again, or export json to keep the residual"
        )


def _spec(format: str) -> FormatSpec:
    spec = FORMATS.get(format) if isinstance(format, str) else None
    if spec is None:
        valid = ", ".join(f"{name} ({s.extension})" for name, s in FORMATS.items())
        raise OptionError(f"unknown export format {format!r}; valid formats: {valid}")
    return spec


def _options(spec: FormatSpec, options: Mapping[str, Any]) -> dict[str, Any]:
    """The options given (not None), after checking that ``spec`` takes each (``slots``/``device_ids``: all)."""
    given = {name: value for name, value in options.items() if value is not None}
    for name in given:
        if name not in (*spec.options, "slots", "device_ids"):
            takers = ", ".join(s.name for s in FORMATS.values() if name in s.options)
            raise OptionError(f"the {spec.name} export takes no {name}; {name} applies to: {takers}")
    return given
