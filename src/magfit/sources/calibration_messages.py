"""What a log says of the firmware's own compass calibration: its reports, its messages, its acceptance settings.

ArduPilot's onboard calibrator (``CompassCalibrator``) tells the ground station how it went:

- ``MAG_CAL_PROGRESS`` (MAVLink 191) while it samples: the compass, its status and ``completion_pct``;
- ``MAG_CAL_REPORT`` (192) at the end: ``cal_status`` (``MAG_CAL_STATUS``: 4 success, 5 failed, 6 bad
  orientation, 7 bad radius), ``fitness`` (the RMS residual, mG, compared with ``COMPASS_CAL_FIT``), the
  offsets, diagonal and off-diagonal it found, ``orientation_confidence``, the old and new orientation and
  ``scale_factor``;
- ``STATUSTEXT`` (253) lines: ``Mag(0) bad radius 456 expected 523``, ``Mag(1) bad orientation: 6/0 0.9``,
  ``Mag(0) good orientation: 0 4.2`` (``CompassCalibrator::calculate_orientation``, ``fix_radius``), and the
  pre-arm failures (``PreArm: Compasses inconsistent``, ``PreArm: Compass offsets too high``).

A telemetry log (``.tlog``) holds them as the station received them. A DataFlash log holds the text lines
as ``MSG`` messages (``Message``) and the settings as ``PARM``. PX4 says its calibration's outcome in
``[cal]`` text lines (``Retry calibration (mag 0 sphere radius invalid 0.812)``), which a tlog keeps as
``STATUSTEXT`` too.

:func:`read_calibration_messages` gathers them; :mod:`magfit.firmware_checks` replays the tests and explains.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import DataFileError

__all__ = ["CalibrationMessages", "FirmwareMessage", "MagCalReport", "read_calibration_messages"]

#: MAV_CAL_STATUS / MAG_CAL_STATUS (MAVLink common.xml), as CompassCalibrator::Status numbers them.
MAG_CAL_STATUS = {
    0: "NOT_STARTED",
    1: "WAITING_TO_START",
    2: "RUNNING_STEP_ONE",
    3: "RUNNING_STEP_TWO",
    4: "SUCCESS",
    5: "FAILED",
    6: "BAD_ORIENTATION",
    7: "BAD_RADIUS",
}
#: The settings the acceptance tests read (ArduPilot and PX4 parameter names).
SETTINGS = (
    "COMPASS_CAL_FIT",
    "COMPASS_OFFS_MAX",
    "COMPASS_AUTO_ROT",
    "COMPASS_ORIENT",
    "COMPASS_ORIENT2",
    "COMPASS_ORIENT3",
    "COMPASS_EXTERNAL",
    "COMPASS_EXTERN2",
    "COMPASS_EXTERN3",
    "COM_ARM_MAG_ANG",
    "COMPASS_USE",
    "COMPASS_USE2",
    "COMPASS_USE3",
)
#: A text line about the compass or its calibration (ArduPilot's and PX4's wordings).
_ABOUT_COMPASS = re.compile(r"Mag\(\d\)|[Cc]ompass|\bmag\b|\[cal\]|MagCal|[Cc]alibration", re.ASCII)


@dataclass(frozen=True)
class FirmwareMessage:
    """A text line of the firmware about the compass.

    Attributes
    ----------
    time_s : float
        When (the log's time base: a tlog's receive time in UTC seconds, a DataFlash log's seconds since boot).
    text : str
        The line.
    severity : int or None
        MAV_SEVERITY (0 emergency .. 7 debug) for a STATUSTEXT, None for a DataFlash MSG.
    """

    time_s: float
    text: str
    severity: int | None = None


@dataclass(frozen=True)
class MagCalReport:
    """One ``MAG_CAL_REPORT``: the outcome of the onboard calibration of one compass.

    Attributes
    ----------
    time_s : float
        When it was received (UTC seconds).
    compass_id : int
        The compass (0-based, the calibrator's index).
    status : str
        ``SUCCESS``, ``FAILED``, ``BAD_ORIENTATION``, ``BAD_RADIUS`` ...
    fitness : float
        RMS residual of the fit, mG.
    offsets, diagonal, off_diagonal : tuple of float
        What it found (``COMPASS_OFS``, ``DIA``, ``ODI``), mG and dimensionless.
    orientation_confidence : float
        The second-best orientation's variance over the best's (higher is surer); NaN when not sent.
    old_orientation, new_orientation : int or None
        ``COMPASS_ORIENT`` before and the orientation it found.
    scale_factor : float
        The scale it found against the World Magnetic Model's field (0: no GPS fix).
    autosaved : bool
        The result was saved.
    """

    time_s: float
    compass_id: int
    status: str
    fitness: float
    offsets: tuple[float, float, float]
    diagonal: tuple[float, float, float]
    off_diagonal: tuple[float, float, float]
    orientation_confidence: float = float("nan")
    old_orientation: int | None = None
    new_orientation: int | None = None
    scale_factor: float = float("nan")
    autosaved: bool = False


@dataclass(frozen=True)
class CalibrationMessages:
    """What :func:`read_calibration_messages` found.

    Attributes
    ----------
    messages : tuple of FirmwareMessage
        The firmware's lines about the compass (its calibration, its pre-arm checks), in log order.
    reports : tuple of MagCalReport
        Every ``MAG_CAL_REPORT`` (a tlog only).
    progress : dict
        compass id -> the highest ``completion_pct`` its ``MAG_CAL_PROGRESS`` reached (a tlog only).
    settings : dict
        The acceptance settings the log's parameters hold (last value): ``COMPASS_CAL_FIT``,
        ``COMPASS_OFFS_MAX``, ``COMPASS_AUTO_ROT``, the orientations, ``COM_ARM_MAG_ANG`` ...
    """

    messages: tuple[FirmwareMessage, ...] = ()
    reports: tuple[MagCalReport, ...] = ()
    progress: dict[int, int] = field(default_factory=dict)
    settings: dict[str, float] = field(default_factory=dict)


def _text(raw: bytes) -> str:
    return raw.split(b"\x00", 1)[0].decode("utf-8", "replace").strip()


def _settings(parameters: dict[str, list[tuple[float, float]]]) -> dict[str, float]:
    return {name: parameters[name][-1][1] for name in SETTINGS if parameters.get(name)}


def read_calibration_messages(path: str | Path) -> CalibrationMessages:
    """The firmware's reports and messages about its compass calibration in a tlog or a DataFlash log.

    Other files give an empty :class:`CalibrationMessages`.

    Raises
    ------
    DataFileError
        The log cannot be read (as :func:`magfit.sources.open_source` would say).
    """
    from .detect import log_kind

    target = Path(path)
    kind = log_kind(target)
    if kind not in ("tlog", "dataflash"):
        return CalibrationMessages()
    if kind == "dataflash":  # read in blocks (bounded memory), as open_source reads it
        return _from_dataflash(target)
    try:
        data = target.read_bytes()
    except OSError as error:
        raise DataFileError(f"{target}: cannot be read ({error.strerror}); check the file's permissions") from None
    return _from_tlog(target, data)


def _from_dataflash(path: Path) -> CalibrationMessages:
    from ..io.sources import data_file
    from .dataflash import DataFlashLog

    log = DataFlashLog(path, data_file(path))
    messages: list[FirmwareMessage] = []
    if log.has("MSG"):
        records = log.messages("MSG")
        labels = records.dtype.names or ()
        if "Message" in labels:
            if "TimeUS" in labels:
                times = records["TimeUS"].astype(np.float64) / 1e6
            elif "TimeMS" in labels:
                times = records["TimeMS"].astype(np.float64) / 1e3
            else:
                times = np.full(len(records), np.nan)
            for time, raw in zip(times, records["Message"], strict=True):
                text = _text(bytes(raw))
                if _ABOUT_COMPASS.search(text):
                    messages.append(FirmwareMessage(float(time), text))
    return CalibrationMessages(tuple(messages), settings=_settings(log.parameters()))


def _from_tlog(path: Path, data: bytes) -> CalibrationMessages:
    from .tlog import TelemetryLog, _parameters

    log = TelemetryLog(path, data)
    messages: list[FirmwareMessage] = []
    reports: list[MagCalReport] = []
    progress: dict[int, int] = {}
    settings: dict[str, float] = {}
    for source in log.sources():
        frames = log.frames("STATUSTEXT", source)
        for record, time in zip(log.messages("STATUSTEXT", frames), log.receipt_s[frames], strict=True):
            text = _text(bytes(record["text"]))
            if _ABOUT_COMPASS.search(text):
                messages.append(FirmwareMessage(float(time), text, int(record["severity"])))
        frames = log.frames("MAG_CAL_PROGRESS", source)
        for record in log.messages("MAG_CAL_PROGRESS", frames):
            compass = int(record["compass_id"])
            progress[compass] = max(progress.get(compass, 0), int(record["completion_pct"]))
        frames = log.frames("MAG_CAL_REPORT", source)
        for r, time in zip(log.messages("MAG_CAL_REPORT", frames), log.receipt_s[frames], strict=True):
            reports.append(
                MagCalReport(
                    float(time),
                    int(r["compass_id"]),
                    MAG_CAL_STATUS.get(int(r["cal_status"]), f"status {int(r['cal_status'])}"),
                    float(r["fitness"]),
                    (float(r["ofs_x"]), float(r["ofs_y"]), float(r["ofs_z"])),
                    (float(r["diag_x"]), float(r["diag_y"]), float(r["diag_z"])),
                    (float(r["offdiag_x"]), float(r["offdiag_y"]), float(r["offdiag_z"])),
                    float(r["orientation_confidence"]),
                    int(r["old_orientation"]),
                    int(r["new_orientation"]),
                    float(r["scale_factor"]),
                    bool(r["autosaved"]),
                )
            )
        parameters, _ = _parameters(log, source)
        settings.update(_settings(parameters))
    order = np.argsort([m.time_s for m in messages], kind="stable")
    return CalibrationMessages(tuple(messages[i] for i in order), tuple(reports), progress, settings)
