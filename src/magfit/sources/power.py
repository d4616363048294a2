"""What drives the motors' field, as a log records it: the battery's current and the throttle (:func:`read_power`).

Each comes on its own clock, the log's time base (the magnetometer's: :meth:`Source.read` gives its stamps on
it), and is put on the compass's stamps, at a lag, by :func:`magfit.motor.regressor_at`. What is read:

- **ArduPilot DataFlash**: ``BAT.Curr`` (amperes) of the primary battery (instance 0: the one
  ``COMPASS_MOTCT`` 2 uses, ``AP_BattMonitor::current_amps()``), ``CURR.Curr`` in older logs (an integer
  field there: centiamperes);
  the throttle ``CTUN.ThO`` (0 to 1, what ``COMPASS_MOTCT`` 1 uses: ``motors->get_throttle()``), ``CTUN.ThrOut``
  (0 to 1000) in old logs.
- **PX4 ULog**: ``battery_status.current_a`` of instance 0 (amperes; negative is "unknown"), the thrust
  ``|vehicle_thrust_setpoint.xyz|`` (PX4 1.14 on), else ``actuator_controls_0.control[3]`` (the throttle).
- **MAVLink telemetry log**: ``BATTERY_STATUS.current_battery`` of battery 0, else ``SYS_STATUS.current_battery``
  (centiamperes, −1 unknown), and ``VFR_HUD.throttle`` (percent), on the vehicle's clock as the tlog reader sets it.

Nothing here edits the readers: a log is opened again for these streams (the readers keep their own jobs).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..errors import DataFileError

__all__ = ["Power", "Signal", "read_power"]


@dataclass(frozen=True)
class Signal:
    """One regressor on its own clock.

    Attributes
    ----------
    kind : {"current", "throttle"}
    name : str
        Where it came from (``BAT.Curr``, ``battery_status.current_a``).
    time_s, values : ndarray, shape (M,)
        Stamps on the log's time base (seconds) and values (amperes, or the throttle 0 to 1), finite.
    """

    kind: str
    name: str
    time_s: NDArray[np.float64]
    values: NDArray[np.float64]


@dataclass(frozen=True)
class Power:
    """The current and the throttle a log holds (None where it holds none), and notes in words."""

    current: Signal | None = None
    throttle: Signal | None = None
    notes: tuple[str, ...] = ()

    def get(self, kind: str) -> Signal | None:
        return self.current if kind == "current" else self.throttle if kind == "throttle" else None


def _signal(kind: str, name: str, time_s: Any, values: Any, valid: Any = None) -> Signal | None:
    time = np.asarray(time_s, dtype=np.float64)
    value = np.asarray(values, dtype=np.float64)
    keep = np.isfinite(time) & np.isfinite(value)
    if valid is not None:
        keep &= np.asarray(valid, dtype=bool)
    time, value = time[keep], value[keep]
    order = np.argsort(time, kind="stable")
    time, value = time[order], value[order]
    unique = np.concatenate([[True], np.diff(time) > 0]) if len(time) else np.zeros(0, dtype=bool)
    time, value = time[unique], value[unique]
    return Signal(kind, name, time, value) if len(time) >= 2 else None


def read_power(path: str | os.PathLike[str]) -> Power:
    """The current and throttle of a flight log (see the module docstring); an empty :class:`Power` for a
    format that holds neither.

    Raises
    ------
    DataFileError
        The log cannot be read.
    """
    from ..io.sources import data_file
    from .detect import log_kind

    kind = log_kind(path)
    if kind == "dataflash":
        return _dataflash(Path(path), data_file(path))
    if kind == "ulog":
        return _ulog(Path(path), data_file(path))
    if kind == "tlog":
        return _tlog(Path(path), data_file(path))
    return Power(notes=(f"a {kind or 'samples'} file holds no current or throttle magfit reads",))


def _dataflash(path: Path, file: Path) -> Power:
    from .dataflash import DataFlashLog, _time_s

    try:
        with open(file, "rb"):
            pass
        log = DataFlashLog(path, file)  # read in blocks, as open_source reads it (bounded memory)
    except OSError as error:
        raise DataFileError(f"{path}: cannot be read ({error.strerror})") from None
    current = throttle = None
    for name in ("BAT", "CURR"):
        if current is None and log.has(name):
            records = log.messages(name)
            labels = records.dtype.names or ()
            if "Curr" not in labels:
                continue
            if "Instance" in labels or "Inst" in labels:  # the primary battery: what COMPASS_MOTCT 2 reads
                records = records[records["Instance" if "Instance" in labels else "Inst"] == 0]
            values = log.value(records, name, "Curr")
            letter = log.formats[log._by_name[name]].letters[labels.index("Curr")]
            described = f"{name}.Curr"
            if letter in "hHiI":  # an integer field: centiamperes (Copter 3.3's CURR: current_amps() * 100)
                values, described = values / 100.0, f"{name}.Curr / 100"
            current = _signal("current", described, _time_s(log, name, records), values)
    if log.has("CTUN"):
        records = log.messages("CTUN")
        labels = records.dtype.names or ()
        if "ThO" in labels:
            throttle = _signal("throttle", "CTUN.ThO", _time_s(log, "CTUN", records), log.value(records, "CTUN", "ThO"))
        elif "ThrOut" in labels:
            values = log.value(records, "CTUN", "ThrOut") / 1000.0
            throttle = _signal("throttle", "CTUN.ThrOut / 1000", _time_s(log, "CTUN", records), values)
    return Power(current, throttle)


def _ulog(path: Path, file: Path) -> Power:
    from .ulog import _parse

    ulog = _parse(path, file, ["battery_status", "vehicle_thrust_setpoint", "actuator_controls_0"])
    current = throttle = None
    for data in ulog.data_list:
        stamps = np.asarray(data.data["timestamp"], dtype=np.float64) / 1e6
        if data.name == "battery_status" and data.multi_id == 0 and "current_a" in data.data:
            values = np.asarray(data.data["current_a"], dtype=np.float64)
            valid = values >= 0  # -1: the battery does not measure its current
            if "connected" in data.data:
                valid &= np.asarray(data.data["connected"]) != 0
            current = _signal("current", "battery_status.current_a", stamps, values, valid)
        elif data.name == "vehicle_thrust_setpoint" and data.multi_id == 0 and "xyz[2]" in data.data:
            xyz = np.column_stack([np.asarray(data.data[f"xyz[{i}]"], dtype=np.float64) for i in range(3)])
            throttle = _signal("throttle", "|vehicle_thrust_setpoint.xyz|", stamps, np.linalg.norm(xyz, axis=1))
        elif data.name == "actuator_controls_0" and throttle is None and "control[3]" in data.data:
            throttle = _signal("throttle", "actuator_controls_0.control[3]", stamps, data.data["control[3]"])
    return Power(current, throttle)


#: MAVLink payloads read here (wire order, full length with extensions; pymavlink's ``all`` dialect).
_TLOG_LAYOUTS: dict[str, tuple[int, str]] = {
    "SYS_STATUS": (
        1,
        "onboard_control_sensors_present:<u4 onboard_control_sensors_enabled:<u4 onboard_control_sensors_health:<u4 "
        "load:<u2 voltage_battery:<u2 current_battery:<i2 drop_rate_comm:<u2 errors_comm:<u2 errors_count1:<u2 "
        "errors_count2:<u2 errors_count3:<u2 errors_count4:<u2 battery_remaining:i1 present_extended:<u4 "
        "enabled_extended:<u4 health_extended:<u4",
    ),
    "VFR_HUD": (74, "airspeed:<f4 groundspeed:<f4 alt:<f4 climb:<f4 heading:<i2 throttle:<u2"),
    "BATTERY_STATUS": (
        147,
        "current_consumed:<i4 energy_consumed:<i4 temperature:<i2 "
        + " ".join(f"voltage{i}:<u2" for i in range(10))
        + " current_battery:<i2 id:u1 battery_function:u1 type:u1 battery_remaining:i1 time_remaining:<i4 "
        "charge_state:u1 " + " ".join(f"voltage_ext{i}:<u2" for i in range(4)) + " mode:u1 fault_bitmask:<u4",
    ),
}


def _tlog(path: Path, file: Path) -> Power:
    from . import tlog

    layouts = {msgid: np.dtype([tuple(f.split(":")) for f in text.split()]) for msgid, text in _TLOG_LAYOUTS.values()}
    log = tlog.TelemetryLog(path, file, also={msgid: dtype.itemsize for msgid, dtype in layouts.items()})
    sources = log.sources()
    if not sources:
        return Power()
    # The system that sent the most frames (the vehicle, as the reader chooses it), on its own clock.
    source = max(sources, key=lambda s: sum(log.counts(s).values()))
    vehicle = tlog._vehicle(log, source)
    current = throttle = None
    for name, (msgid, _) in _TLOG_LAYOUTS.items():
        frames = log.frames_of(msgid, source)
        if not len(frames):
            continue
        records = log.messages_of(frames, layouts[msgid])
        times = vehicle.clock[frames]
        if name == "BATTERY_STATUS":  # the first battery's (id 0), preferred to SYS_STATUS's when sent
            values = records["current_battery"].astype(np.float64)
            first = _signal(
                "current", "BATTERY_STATUS.current_battery", times, values / 100.0, (values >= 0) & (records["id"] == 0)
            )
            current = first or current
        elif name == "SYS_STATUS":
            values = records["current_battery"].astype(np.float64)
            current = _signal("current", "SYS_STATUS.current_battery", times, values / 100.0, values >= 0)
        else:
            throttle = _signal("throttle", "VFR_HUD.throttle / 100", times, records["throttle"] / 100.0)
    return Power(current, throttle)
