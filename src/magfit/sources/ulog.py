"""PX4 ULog files (``.ulg``), read with pyulog (the ``ulog`` extra, imported here only).

Two topics carry the magnetometers:

- ``sensor_mag`` (one instance per compass): the raw field in gauss in the sensor's own frame, with the
  ``device_id`` that PX4's ``CAL_MAGn_ID`` refers to (before v1.11, when the topic also had ``x_raw``, the
  driver published it already corrected by ``CAL_MAGn_*OFF``/``*SCALE``: undone here as below). This is
  what a calibration is fitted to. PX4's default logging profile records it at about **1 Hz**, too slow for
  a fit: set ``SDLOG_PROFILE`` to include "high rate" (bit 1) or "sensor comparison" (bit 6), or list
  ``sensor_mag`` with a rate in ``etc/logging/logger_topics.txt`` on the SD card, then record the tumble again.
- ``vehicle_magnetometer``: the field **after** PX4's calibration, at 15-50 Hz, in the body frame.
  PX4 corrects (``calibration::Magnetometer::Correct``)::

      corrected = R · S · (raw + power · COMP - OFF)

  with OFF = CAL_MAGn_{X,Y,Z}OFF, S the symmetric matrix of CAL_MAGn_{X,Y,Z}SCALE (diagonal) and
  CAL_MAGn_{X,Y,Z}ODIAG (xy, xz, yz), R the rotation (CAL_MAGn_ROT for an external compass, the board's
  SENS_BOARD_ROT and SENS_BOARD_*_OFF for an internal one) and COMP the power compensation
  (CAL_MAG_COMP_TYP). This reader undoes it (``raw = S⁻¹ · Rᵀ · corrected + OFF``) when no power
  compensation is configured, the CAL_MAGn index found by the message's ``device_id`` and R known: the
  rotation ``CAL_MAGn_ROT`` names (0 and up: an external compass), or ``SENS_BOARD_ROT`` for an internal one
  (``CAL_MAGn_ROT`` -1) without the level fine-tuning ``SENS_BOARD_X/Y/Z_OFF`` (which some PX4 versions fold
  into the board rotation and others do not); otherwise the stream is listed with the reason it cannot be
  undone. The samples undone are in the sensor's frame, as ``sensor_mag``'s.

A calibration changed during the log (a recalibration, the estimator saving learned offsets): ULog records each
parameter change with its time (pyulog's ``changed_parameters``), so every sample is undone with the
CAL_MAGn_*OFF/*SCALE/*ODIAG in effect at its time stamp (:func:`_calibration_at`). A change of the rotation
(CAL_MAGn_ROT, SENS_BOARD_ROT) or of the device (CAL_MAGn_ID) is not followed: such a stream is refused.

Frames (``calibration::Magnetometer::Correct``, src/lib/sensor_calibration/Magnetometer.hpp, and
``PX4Magnetometer::update``, src/lib/drivers/magnetometer/PX4Magnetometer.cpp): ``sensor_mag`` is published
after the driver's own fixed chip rotation and before ``CAL_MAGn_ROT``/``SENS_BOARD_ROT``, so
:meth:`~magfit.sources.Source.read_motion` gives it as ``magnetometer_frame="sensor"`` with that rotation as
``mounting``. ``vehicle_attitude.q`` is the rotation from the FRD body frame to NED (w, x, y, z);
``vehicle_angular_velocity`` and ``sensor_combined`` are in the body frame (calibrated, rotated); the raw
``sensor_gyro``/``sensor_accel`` are in the sensor's frame.
"""

from __future__ import annotations

import contextlib
import io
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..errors import DataFileError
from ..rotations import standard_rotations
from .identity import ulog_identity
from .motion import Motion, Stream, align, quaternion_wxyz
from .types import SLOW_RATE_HZ, LogSamples, Magnetometer, Position, Source, median_position

__all__ = ["open_ulog", "undo_px4_calibration"]

#: Topics listed by `magfit inspect` beside the magnetometers, when logged.
_ALSO = (
    "vehicle_attitude",
    "vehicle_angular_velocity",
    "sensor_combined",
    "sensor_gyro",
    "sensor_accel",
    "vehicle_gps_position",
    "sensor_gps",
    "estimator_status",
)
_HOW_TO_LOG_MORE = (
    "set SDLOG_PROFILE to include high rate (bit 1) or sensor comparison (bit 6), or add 'sensor_mag 0' to "
    "etc/logging/logger_topics.txt on the SD card, and record again"
)


def _pyulog() -> Any:
    try:
        import pyulog
    except ImportError:
        raise DataFileError(
            "reading PX4 ULog files needs pyulog, which is not installed (the ulog extra): pip install 'magfit[ulog]'"
        ) from None
    return pyulog


class _Stuck(Exception):
    """pyulog read far more than the file holds: it is going round in circles on damaged data."""


class _BudgetedFile(io.BufferedReader):
    """A file that refuses to be sought in more often than it has bytes.

    pyulog resynchronises on damaged data by seeking back; on some damaged definitions sections (found by the
    fuzz test) it seeks back as far as it read, and loops for ever. A sound parse seeks rarely, and even a
    resynchronisation byte by byte seeks at most once per byte of the file, so the budget is never reached by a
    log pyulog can read, and ends such a loop within a second or so. Counting seeks, not reads, keeps the cost
    out of the parse of a sound log (counting reads cost 50 % on PX4's sample logs).
    """

    def __init__(self, path: Path) -> None:
        super().__init__(io.FileIO(path, "rb"))
        self._seeks_left = path.stat().st_size + 10_000

    def seek(self, offset: int, whence: int = 0, /) -> int:
        self._seeks_left -= 1
        if self._seeks_left < 0:
            raise _Stuck("pyulog went round in circles on damaged data")
        return super().seek(offset, whence)


def undo_px4_calibration(
    corrected: NDArray[np.float64],
    *,
    offsets: NDArray[np.float64],
    scales: NDArray[np.float64],
    offdiagonals: NDArray[np.float64],
    rotation: NDArray[np.float64] | None = None,
) -> NDArray[np.float64]:
    """The raw field (sensor frame) from PX4's corrected one (body frame), for a compass without power compensation.

    Parameters
    ----------
    corrected : ndarray, shape (N, 3)
        ``vehicle_magnetometer.magnetometer_ga`` (gauss).
    offsets, scales, offdiagonals : ndarray, shape (3,)
        CAL_MAGn_{X,Y,Z}OFF, CAL_MAGn_{X,Y,Z}SCALE and CAL_MAGn_{X,Y,Z}ODIAG (xy, xz, yz).
    rotation : ndarray, shape (3, 3), optional
        R of ``corrected = R · S · (raw - OFF)``: CAL_MAGn_ROT's matrix, or SENS_BOARD_ROT's (None: identity).
    """
    sx, sy, sz = np.asarray(scales, dtype=np.float64)
    xy, xz, yz = np.asarray(offdiagonals, dtype=np.float64)
    matrix = np.array([[sx, xy, xz], [xy, sy, yz], [xz, yz, sz]])
    field = np.asarray(corrected, dtype=np.float64)
    if rotation is not None:
        field = field @ np.asarray(rotation, dtype=np.float64)  # rows: (Rᵀ · v)ᵀ = vᵀ · R
    return np.linalg.solve(matrix, field.T).T + np.asarray(offsets, dtype=np.float64)


#: Most messages of a magnetometer or GNSS topic instance kept while a log is read (a power of two): beyond,
#: a regular stride of them (every 2nd, 4th ...), so a long log is read in bounded memory.
_KEPT = 1 << 19
#: Most messages kept of a topic read only to be listed (``everything=True``) or to name an older PX4's
#: compass (sensor_combined): their count and span are exact, their samples are not used.
_LISTED = 1 << 10


class _Thinned(bytearray):
    """pyulog's buffer of one topic instance's messages that keeps a regular stride of at most ``cap`` of them.

    pyulog appends each message's payload (``buffer += payload``, fixed size); while fewer than ``cap`` are
    kept every one is, then every other kept one is dropped and the stride doubles. The messages kept are
    those at multiples of ``every`` (the first among them); ``seen`` counts them all, ``last`` is the last.
    """

    def __init__(self, cap: int) -> None:
        super().__init__()
        self.cap, self.every, self.seen, self.last = cap, 1, 0, b""
        self.full = 0  # bytes of ``cap`` messages, once the first one's size is known
        self.timestamp_offset = 0  # where the uint64 timestamp starts in a payload

    def __iadd__(self, payload: Any) -> _Thinned:  # type: ignore[misc]
        # Called once per message while pyulog reads: kept short (a stride that is a power of two: a mask).
        seen = self.seen
        self.seen = seen + 1
        self.last = payload
        if seen & (self.every - 1):
            return self
        if len(self) >= self.full:
            if not self.full:
                self.full = self.cap * len(payload)
            else:  # full: every other one kept, the stride doubled
                rows = np.frombuffer(bytes(self), dtype=np.uint8).reshape(-1, len(payload))
                self[:] = rows[::2].tobytes()
                self.every *= 2
                if seen & (self.every - 1):
                    return self
        self.extend(payload)
        return self


def _parse(path: Path, file: Path, topics: list[str] | None, caps: dict[str, int] | None = None) -> Any:
    """pyulog's reading of ``topics`` (None: all), its damage a one-line DataFileError.

    ``caps``: the most messages kept per instance of a topic (the rest: :data:`_LISTED` when ``topics`` is
    None, else every one), a regular stride beyond (:class:`_Thinned`); each data item read then has
    ``magfit_seen`` (its messages), ``magfit_every`` (the stride kept) and ``magfit_last_s`` (its last stamp).
    """
    pyulog = _pyulog()
    buffers: dict[int, _Thinned] = {}
    subscribed: list[str] = []
    limits = dict(caps or {})
    try:
        size = file.stat().st_size
    except OSError:
        size = 1 << 62  # (reported by the parse below)

    class _AddLogged(pyulog.ULog._MessageAddLogged):  # type: ignore[name-defined]
        def __init__(self, *args: Any) -> None:
            super().__init__(*args)
            subscribed.append(self.message_name)  # (every subscription, the topics filtered out too)
            cap = limits.get(self.message_name, _LISTED if topics is None else None)
            # A file too small to hold more than ``cap`` of its messages (5 bytes of header each) needs no
            # thinning: pyulog's own buffer then, without a Python call per message.
            if cap is not None and size // (self.dtype.itemsize + 5) > cap:
                self.buffer = buffers[self.msg_id] = _Thinned(cap)
                self.buffer.timestamp_offset = self.timestamp_offset

    class _ULog(pyulog.ULog):  # type: ignore[name-defined]
        _MessageAddLogged = _AddLogged

    try:
        # pyulog prints its warnings about damaged data on stdout, which is magfit's output: captured.
        with contextlib.redirect_stdout(io.StringIO()) as said, _BudgetedFile(file) as handle:
            ulog = _ULog(handle, topics)
    except Exception as error:  # pyulog raises what its parser meets (struct.error, IndexError, ...)
        reason = " ".join(str(error).split()) or type(error).__name__
        raise DataFileError(
            f"{path}: is a PX4 ULog that cannot be read ({reason}); the file is damaged or cut short: download the "
            "log again"
        ) from None
    if not subscribed:  # no topic subscribed: the file ends before its data section
        raise DataFileError(
            f"{path}: is a PX4 ULog cut short inside its header (it ends after {size} bytes, in the formats and "
            "parameters written before any logged data: the logger stopped or the copy broke off); download the "
            "log again"
        )
    ulog.magfit_said = said.getvalue()
    for data in ulog.data_list:
        kept = buffers.get(data.msg_id)
        data.magfit_seen = len(next(iter(data.data.values()), ()))
        data.magfit_every, data.magfit_last_s = 1, None
        if kept is not None and kept.every > 1:
            data.magfit_seen, data.magfit_every = kept.seen, kept.every
            at = kept.timestamp_offset
            if "timestamp" in data.data and len(kept.last) >= at + 8:
                data.magfit_last_s = int.from_bytes(kept.last[at : at + 8], "little") / 1e6
    return ulog


def open_ulog(path: Path, file: Path, *, everything: bool = True) -> Source:
    """Read a PX4 ULog into a :class:`~magfit.sources.Source` (``file``: its bytes on disk).

    ``everything=False`` reads only the magnetometer topics (nothing listed in ``other``); :meth:`read_motion`
    then reads the file again for the attitude and IMU topics. Of each magnetometer and GNSS topic instance
    at most :data:`_KEPT` messages are kept, a regular stride beyond (said in the samples' notes), and of
    the motion topics when ``everything``; of the topics only listed, :data:`_LISTED` (their counts stay
    exact): the memory does not grow with the log.
    The sensor_combined topic is read beside the magnetometers, in case an older PX4 logged its compass
    only there (one pass, not a second parse).
    """
    caps = dict.fromkeys((*_FIELDS, *_GPS_TOPICS), _KEPT)
    if everything:  # the motion topics kept as the magnetometers' (read_motion reads them again if thinned)
        caps.update(dict.fromkeys(_MOTION_TOPICS, _KEPT))
    else:
        caps["sensor_combined"] = _LISTED
    ulog = _parse(path, file, None if everything else [*_FIELDS, *_GPS_TOPICS, "sensor_combined"], caps)
    # A parameter of an unexpected type (bytes in a damaged log) is dropped: the stream it concerns is then
    # refused for want of it, rather than undone with a wrong value.
    parameters = {k: v for k, v in ulog.initial_parameters.items() if isinstance(v, (int, float))}
    changed = [(int(t), str(name), v) for t, name, v in ulog.changed_parameters if isinstance(v, (int, float))]
    streams: dict[str, Any] = {}
    magnetometers = []
    for data in sorted(ulog.data_list, key=lambda d: (d.name, d.multi_id)):
        if data.name == "sensor_mag":
            sid = f"sensor_mag/{data.multi_id}"
            streams[sid] = data
            magnetometers.append(_raw(sid, data, parameters, changed))
    for data in sorted(ulog.data_list, key=lambda d: (d.name, d.multi_id)):
        if data.name == "vehicle_magnetometer":
            sid = f"vehicle_magnetometer/{data.multi_id}"
            streams[sid] = data
            magnetometers.append(_calibrated(sid, data, parameters, changed))
    for data in ulog.data_list:
        if data.name == "sensor_combined" and data.multi_id == 0 and "magnetometer_ga[0]" in data.data:
            if everything or not magnetometers:  # an older PX4 logs its compass only in sensor_combined: say so
                magnetometers.append(_combined(data))
    slots = _slots(parameters, [m.device_id for m in magnetometers])
    magnetometers = [replace(m, slot=slots.get(m.device_id)) if m.device_id else m for m in magnetometers]
    counts: dict[str, int] = {}
    for data in ulog.data_list:
        if everything or data.name != "sensor_combined":  # (read for an older PX4's compass only)
            counts[data.name] = counts.get(data.name, 0) + data.magfit_seen
    other = tuple(f"{name} ({counts[name]})" for name in _ALSO if name in counts)
    rest = sorted(set(counts) - set(_ALSO) - {"sensor_mag", "vehicle_magnetometer"})
    if rest:
        other += (f"{len(rest)} other topics: {', '.join(rest)}",)
    notes = []
    if getattr(ulog, "file_corruption", False) or "corrupt" in ulog.magfit_said.lower():
        notes.append("pyulog found damaged data in the file and skipped it")
    described = "PX4 ULog" + (f", firmware {ulog.msg_info_dict['ver_sw']}" if "ver_sw" in ulog.msg_info_dict else "")
    position = _position(ulog)
    thinned = any(data.magfit_every > 1 for data in ulog.data_list if data.name in _MOTION_TOPICS)
    motion_log: list[Any] = [ulog] if everything and not thinned else []

    def read(magnetometer: Magnetometer, stamp: str = "timestamp") -> LogSamples:
        data = streams[magnetometer.id]
        if magnetometer.id.startswith("sensor_mag/"):
            with np.errstate(invalid="ignore"):  # damaged values become NaN: dropped below as non-finite samples
                samples = np.column_stack([np.asarray(data.data[axis], dtype=np.float64) for axis in "xyz"])
            columns: tuple[str, ...] = ("x", "y", "z")
            if not magnetometer.raw:  # calibrated by an old PX4's driver (_raw): undone, no rotation involved
                index = _calibration_index(parameters, magnetometer.device_id)
                assert index is not None  # _raw made it a problem otherwise; Source.read refused it
                stamps = np.asarray(data.data["timestamp"], dtype=np.float64)
                samples = _undo_in_effect(samples, stamps, parameters, changed, index, None)
        else:
            columns = tuple(f"magnetometer_ga[{i}]" for i in range(3))
            with np.errstate(invalid="ignore"):  # as above: damaged values become NaN, dropped below
                corrected = np.column_stack([np.asarray(data.data[c], dtype=np.float64) for c in columns])
            index = _calibration_index(parameters, magnetometer.device_id)
            assert index is not None  # _calibrated made it a problem otherwise; Source.read refused it
            rotation, _, problem = _rotation(parameters, index)
            assert problem is None  # likewise
            stamps = np.asarray(data.data["timestamp"], dtype=np.float64)
            samples = _undo_in_effect(corrected, stamps, parameters, changed, index, rotation)
        times = np.asarray(data.data[_stamp(data, stamp)], dtype=np.float64) / 1e6
        finite = np.all(np.isfinite(samples), axis=1)
        notes = magnetometer.notes
        if data.magfit_every > 1:
            notes += (
                f"one message in every {data.magfit_every} kept while the log was read ({len(samples)} of "
                f"{data.magfit_seen}): the topic holds more than {_KEPT}, so a regular stride over the whole log",
            )
        return LogSamples(magnetometer, samples[finite], times[finite], columns, notes, every=data.magfit_every)

    def motion(magnetometer: Magnetometer) -> Motion:
        if not motion_log:  # opened for the magnetometers only: the motion topics are read now, once
            motion_log.append(_parse(path, file, list(_MOTION_TOPICS)))
        return _motion(motion_log[0], parameters, read(magnetometer, "timestamp_sample"), position)

    return Source(
        path=path,
        position=position,
        identity=ulog_identity(ulog.msg_info_dict),
        kind="ulog",
        format=described,
        time_base="seconds since boot (timestamp)",
        magnetometers=tuple(magnetometers),
        other=other,
        notes=tuple(notes),
        _reader=read,
        _motion=motion,
    )


#: The topics read_motion uses, in the order of preference for each stream.
_ATTITUDE_TOPICS = ("vehicle_attitude",)
_GYRO_TOPICS = (
    ("vehicle_angular_velocity", "xyz", "body (FRD)"),
    ("sensor_combined", "gyro_rad", "body (FRD)"),
    ("sensor_gyro", "", "sensor (before SENS_BOARD_ROT and the gyro calibration)"),
)
_ACCEL_TOPICS = (
    ("sensor_combined", "accelerometer_m_s2", "body (FRD)"),
    ("vehicle_acceleration", "xyz", "body (FRD), bias removed"),
    ("sensor_accel", "", "sensor (before SENS_BOARD_ROT and the accelerometer calibration)"),
)
_MOTION_TOPICS = tuple(dict.fromkeys([*_ATTITUDE_TOPICS, *(t for t, _, _ in _GYRO_TOPICS + _ACCEL_TOPICS)]))


def _stamp(data: Any, wanted: str) -> str:
    """``wanted`` when the topic has it, else ``timestamp``. read_motion puts every stream on
    ``timestamp_sample`` (when the sensor measured, PX4 1.11 on), not on ``timestamp`` (when the message was
    published, a few ms later and by a different amount per topic)."""
    return wanted if wanted in data.data else "timestamp"


def _vector(data: Any, prefix: str) -> NDArray[np.float64] | None:
    """Fields ``prefix[0..2]`` (an array field), or ``x, y, z`` when ``prefix`` is empty; None when absent."""
    names = [f"{prefix}[{i}]" for i in range(3)] if prefix else ["x", "y", "z"]
    if not all(name in data.data for name in names):
        return None
    with np.errstate(invalid="ignore"):
        return np.column_stack([np.asarray(data.data[name], dtype=np.float64) for name in names])


def _topic(ulog: Any, name: str) -> Any:
    for data in ulog.data_list:
        if data.name == name and data.multi_id == 0 and "timestamp" in data.data:
            return data
    return None


def _vector_stream(ulog: Any, choices: tuple[tuple[str, str, str], ...], what: str) -> Stream | None:
    for name, prefix, frame in choices:
        data = _topic(ulog, name)
        values = _vector(data, prefix) if data is not None else None
        if values is not None:
            time = np.asarray(data.data[_stamp(data, "timestamp_sample")], dtype=np.float64) / 1e6
            relative = data.data.get("accelerometer_timestamp_relative") if prefix == "accelerometer_m_s2" else None
            if relative is not None:
                # sensor_combined's timestamp is the gyro's; its accelerometer was sampled this many µs later
                # (sensor_combined.msg; RELATIVE_TIMESTAMP_INVALID, 0x7fffffff, when it was not).
                offset = np.asarray(relative, dtype=np.float64)
                time = time + np.where(offset == 2147483647, 0.0, offset) / 1e6
            return Stream(f"{name}.{prefix or 'x/y/z'} ({what})", time, values, frame)
    return None


def _motion(ulog: Any, parameters: dict[str, Any], read: LogSamples, position: Position | None) -> Motion:
    attitude = None
    data = _topic(ulog, "vehicle_attitude")
    quaternion = _vector4(data, "q") if data is not None else None
    if quaternion is not None:
        time = np.asarray(data.data[_stamp(data, "timestamp_sample")], dtype=np.float64) / 1e6
        attitude = Stream("vehicle_attitude.q", time, quaternion_wxyz(quaternion), "body (FRD)")
    index = _calibration_index(parameters, read.magnetometer.device_id)
    mounting, note = None, "the log has no CAL_MAGn_ID for this device: its mounting rotation is unknown"
    if index is not None:
        mounting, note, problem = _rotation(parameters, index)
        note = problem or note
    return align(
        read.magnetometer.id,
        read.magnetometer.unit,
        read.time_s,
        read.samples,
        magnetometer_frame="sensor",
        attitude=attitude,
        gyro=_vector_stream(ulog, _GYRO_TOPICS, "rad/s"),
        accel=_vector_stream(ulog, _ACCEL_TOPICS, "m/s²"),
        mounting=mounting,
        mounting_note=note,
        position=position,
        notes=(
            "magnetometer: in the sensor's frame (sensor_mag, or vehicle_magnetometer undone), before CAL_MAGn_ROT or "
            f"SENS_BOARD_ROT (calibration::Magnetometer::Correct); mounting: {note}",
        ),
    )


def _vector4(data: Any, prefix: str) -> NDArray[np.float64] | None:
    names = [f"{prefix}[{i}]" for i in range(4)]
    if not all(name in data.data for name in names):
        return None
    with np.errstate(invalid="ignore"):
        return np.column_stack([np.asarray(data.data[name], dtype=np.float64) for name in names])


def _slots(parameters: dict[str, Any], devices: list[int | None]) -> dict[int | None, int]:
    """Each device's CAL_MAGn index: the one whose CAL_MAGn_ID is the device, else the next free one (no
    CAL_MAGn_ID, or 0), in the order the devices come; what PX4's calibration does (FindCalibrationIndex,
    src/lib/sensor_calibration/Utilities.cpp)."""
    slots: dict[int | None, int] = {}
    taken = {i for i in range(4) if parameters.get(f"CAL_MAG{i}_ID")}
    for device in devices:
        if not device or device in slots:
            continue
        index = _calibration_index(parameters, device)
        if index is None:
            free = [i for i in range(4) if i not in taken]
            if not free:
                continue
            index = free[0]
            taken.add(index)
        slots[device] = index
    return slots


def _rotation(parameters: dict[str, Any], index: int) -> tuple[NDArray[np.float64] | None, str, str | None]:
    """R of PX4's Correct for CAL_MAG{index}: (matrix sensor -> body, what it is, why it is unknown or None).

    ``CAL_MAGn_ROT`` 0 and up: an external compass, that rotation; -1: an internal one, turned by the board's
    ``SENS_BOARD_ROT`` (calibration::Magnetometer::ParametersUpdate, src/lib/sensor_calibration/Magnetometer.cpp).
    """
    name = f"CAL_MAG{index}"
    value = int(parameters.get(f"{name}_ROT", -1))
    table = standard_rotations("px4")
    if value >= 0:
        found = table.get(value)
        if found is None:
            return None, "", f"{name}_ROT {value} is a rotation magfit does not know"
        return found.matrix, f"{name}_ROT {value} ({found.name}; external compass)", None
    board = int(parameters.get("SENS_BOARD_ROT", 0))
    tilt = [float(parameters.get(f"SENS_BOARD_{axis}_OFF", 0.0)) for axis in "XYZ"]
    if any(abs(t) > 1e-3 for t in tilt):
        return (
            None,
            "",
            (
                f"it is an internal compass on a board fine-tuned by SENS_BOARD_X/Y/Z_OFF {tilt}, which some PX4 "
                "versions fold into its rotation and others do not"
            ),
        )
    found = table.get(board)
    if found is None:
        return None, "", f"SENS_BOARD_ROT {board} is a rotation magfit does not know"
    return found.matrix, f"SENS_BOARD_ROT {board} ({found.name}; internal compass, {name}_ROT -1)", None


#: The fields each magnetometer topic must have; a damaged format definition may lack them.
_FIELDS = {
    "sensor_mag": ("timestamp", "x", "y", "z"),
    "vehicle_magnetometer": ("timestamp", *(f"magnetometer_ga[{i}]" for i in range(3))),
}


#: The GNSS topics: vehicle_gps_position (every version), sensor_gps (the raw receiver, newer versions).
_GPS_TOPICS = ("vehicle_gps_position", "sensor_gps")


def _position(ulog: Any) -> Position | None:
    """The median of the first GNSS topic's 3-D fixes (fix_type >= 3) and the UTC time of the first one."""
    try:
        return _gnss_position(ulog)
    except (TypeError, ValueError, KeyError):  # a damaged topic format: the log has no position to give
        return None


def _gnss_position(ulog: Any) -> Position | None:
    for topic in _GPS_TOPICS:
        for data in ulog.data_list:
            if data.name != topic or data.multi_id != 0 or "fix_type" not in data.data:
                continue
            fields = data.data
            fixed = np.asarray(fields["fix_type"]) >= 3
            with np.errstate(invalid="ignore"):
                if "latitude_deg" in fields:  # PX4 1.14 on: degrees and metres as doubles
                    lat, lon = np.asarray(fields["latitude_deg"], float), np.asarray(fields["longitude_deg"], float)
                    alt = np.asarray(fields.get("altitude_msl_m", np.full(len(lat), np.nan)), float)
                elif "lat" in fields:  # before: 1e-7 degrees and millimetres as integers
                    lat, lon = np.asarray(fields["lat"], float) * 1e-7, np.asarray(fields["lon"], float) * 1e-7
                    alt = np.asarray(fields.get("alt", np.full(len(lat), np.nan)), float) / 1000
                else:
                    continue
                time = np.asarray(fields.get("time_utc_usec", np.zeros(len(lat))), float) / 1e6
            return median_position(lat[fixed], lon[fixed], alt[fixed], time[fixed])
    return None


def _lacking(data: Any) -> str | None:
    """Why ``data`` cannot be read as its topic (fields missing from its format), or None."""
    missing = [name for name in _FIELDS[data.name] if name not in data.data]
    if not missing:
        return None
    return f"its format in this log has no {', '.join(missing)} field: the log is damaged"


def _span(data: Any) -> tuple[int, float, float]:
    """How many messages (all of them, a thinned topic's too), the first and the last stamp (seconds)."""
    count = getattr(data, "magfit_seen", None)
    if "timestamp" not in data.data:
        return count or len(next(iter(data.data.values()), ())), float("nan"), float("nan")
    times = np.asarray(data.data["timestamp"], dtype=np.float64) / 1e6
    if not len(times):
        return 0, float("nan"), float("nan")
    last = getattr(data, "magfit_last_s", None)
    return count or len(times), float(times[0]), float(times[-1]) if last is None else last


def _device(data: Any) -> int | None:
    ids = data.data.get("device_id")
    if ids is None or not len(ids):
        return None
    return int(np.asarray(ids)[-1])


def _raw(sid: str, data: Any, parameters: dict[str, Any], changed: list[tuple[int, str, float]]) -> Magnetometer:
    n, start, end = _span(data)
    device = _device(data)
    problem = _lacking(data)
    notes: list[str] = []
    raw = "x_raw" not in data.data
    if not raw and problem is None:
        # PX4 before v1.11 calibrated sensor_mag in the driver: PX4Magnetometer::update publishes
        # x = SCALE · (rotated raw - OFF), with the CAL_MAGn_*OFF/*SCALE the sensors module set (MAGIOCSSCALE),
        # and x_raw, the ADC counts, beside it (src/lib/drivers/magnetometer/PX4Magnetometer.cpp, v1.10).
        index = _calibration_index(parameters, device)
        if index is None:
            problem = (
                f"this PX4 version calibrates sensor_mag in its driver (the topic has x_raw) and no CAL_MAGn_ID holds "
                f"its device_id {device}, so the calibration cannot be undone"
            )
        elif not all(f"CAL_MAG{index}_{a}{k}" in parameters for k in ("OFF", "SCALE") for a in "XYZ") or not all(
            _invertible(cal) for cal in _settings(parameters, changed, index)
        ):
            problem = (
                f"this PX4 version calibrates sensor_mag in its driver and CAL_MAG{index}_*OFF/*SCALE are unusable"
            )
        else:
            notes.append(
                f"this PX4 version (before v1.11: the topic has x_raw) calibrates sensor_mag in its driver; undone "
                f"with CAL_MAG{index}_*OFF and *SCALE from the log's parameters"
            )
            notes.extend(_changes_note(parameters, changed, index, start))
    magnetometer = Magnetometer(
        id=sid,
        description=("raw sensor_mag" if raw else "sensor_mag, calibrated by the driver")
        + (f", device_id {device}" if device is not None else ""),
        unit="G",
        n_samples=n,
        start_s=start,
        end_s=end,
        device_id=device,
        raw=raw,
        notes=tuple(notes),
        problem=problem,
    )
    rate = magnetometer.rate_hz
    if n < 2 or (np.isfinite(rate) and rate < SLOW_RATE_HZ):
        how = f"logged at only {rate:.1f} Hz" if np.isfinite(rate) else f"only {n} sample(s) logged"
        note = f"{how} (PX4's default logging profile): too few samples for a fit; {_HOW_TO_LOG_MORE}"
        magnetometer = replace(magnetometer, notes=(*notes, note))
    return magnetometer


def _combined(data: Any) -> Magnetometer:
    """An older PX4's sensor_combined.magnetometer_ga, listed with the reason it cannot be fitted."""
    n, start, end = _span(data)
    return Magnetometer(
        id="sensor_combined/0",
        description="calibrated sensor_combined.magnetometer_ga (an older PX4: its primary compass)",
        unit="G",
        n_samples=n,
        start_s=start,
        end_s=end,
        raw=False,
        problem=(
            "this older PX4 logs only its primary compass's field after the calibration and the rotation, at the "
            "sensor_combined rate, without saying which compass it is: it cannot be undone; log sensor_mag "
            "(a PX4 that has it) or fit a recording of the raw field"
        ),
    )


def _calibration_index(parameters: dict[str, Any], device: int | None) -> int | None:
    if not device:
        return None
    for index in range(4):
        if parameters.get(f"CAL_MAG{index}_ID") == device:
            return index
    return None


def _invertible(cal: dict[str, NDArray[np.float64]]) -> bool:
    sx, sy, sz = cal["scales"]
    xy, xz, yz = cal["offdiagonals"]
    matrix = np.array([[sx, xy, xz], [xy, sy, yz], [xz, yz, sz]])
    if not (np.all(np.isfinite(matrix)) and np.all(np.isfinite(cal["offsets"]))):
        return False
    return bool(np.linalg.cond(matrix) < 1e6)


def _calibrated(sid: str, data: Any, parameters: dict[str, Any], changed: list[tuple[int, str, float]]) -> Magnetometer:
    n, start, end = _span(data)
    device = _device(data)
    index = _calibration_index(parameters, device)
    problem = _lacking(data)
    if problem is not None:
        pass
    elif device is None:
        problem = "this PX4 version's vehicle_magnetometer does not say which compass it is (no device_id)"
    elif index is None:
        problem = f"no CAL_MAGn_ID parameter holds its device_id {device}, so its calibration is unknown"
    else:
        name = f"CAL_MAG{index}"
        _, _, unknown = _rotation(parameters, index)
        comp = int(parameters.get("CAL_MAG_COMP_TYP", 0))
        # ODIAG came with PX4 1.11 (absent before: zero); OFF and SCALE are in every version's log.
        missing = [f"{name}_{a}{k}" for k in ("OFF", "SCALE") for a in "XYZ" if f"{name}_{a}{k}" not in parameters]
        if missing:
            problem = f"the log's parameters lack {', '.join(missing)}, so its calibration cannot be undone"
        elif unknown is not None:
            problem = f"its rotation into the body frame cannot be undone: {unknown}"
        elif not all(_invertible(cal) for cal in _settings(parameters, changed, index)):
            problem = (
                f"its calibration parameters ({name}_*OFF, *SCALE, *ODIAG) are not finite or form a singular matrix, "
                "so the logged field cannot be undone"
            )
        elif comp != 0:
            problem = f"power compensation is configured (CAL_MAG_COMP_TYP {comp}) and cannot be undone from the log"
        else:
            turned = (f"{name}_ROT", f"{name}_ID", "SENS_BOARD_ROT")
            moved = sorted({p for t, p, v in changed if p in turned and t > start * 1e6 and v != parameters.get(p)})
            if moved:
                problem = (
                    f"{', '.join(moved)} changed during the log: the samples were turned or attributed two ways, which "
                    "cannot be undone; fit a log recorded after the change"
                )
    notes = []
    if problem is None and index is not None:
        notes.append(
            f"calibrated by PX4 (body frame); undone to the sensor's frame with CAL_MAG{index}_*OFF, *SCALE, *ODIAG "
            f"and {_rotation(parameters, index)[1]} from the log's parameters"
        )
        notes.extend(_changes_note(parameters, changed, index, start))
    return Magnetometer(
        id=sid,
        description="calibrated vehicle_magnetometer" + (f", device_id {device}" if device is not None else ""),
        unit="G",
        n_samples=n,
        start_s=start,
        end_s=end,
        device_id=device,
        raw=False,
        notes=tuple(notes),
        problem=problem,
    )


#: The calibration parameters of CAL_MAGn that a sample is corrected with, in _cal's order (offsets, scales,
#: offdiagonals; X, Y, Z each) and their defaults (ODIAG came with PX4 1.11: absent before, zero).
_CAL_KINDS = (("OFF", 0.0), ("SCALE", 1.0), ("ODIAG", 0.0))


def _history(parameters: dict[str, Any], changed: list[tuple[int, str, float]], name: str, default: float) -> Any:
    """(times in µs, values) of parameter ``name``: its initial value from the start, then each change."""
    stamps = [-np.inf] + [float(t) for t, p, _ in changed if p == name]
    values = [float(parameters.get(name, default))] + [float(v) for _, p, v in changed if p == name]
    order = np.argsort(np.array(stamps), kind="stable")
    return np.array(stamps)[order], np.array(values)[order]


def _calibration_at(
    parameters: dict[str, Any], changed: list[tuple[int, str, float]], index: int, stamps_us: NDArray[np.float64]
) -> NDArray[np.float64]:
    """CAL_MAG{index}'s offsets, scales and offdiagonals in effect at each time stamp (µs), shape (N, 9)."""
    columns = []
    for kind, default in _CAL_KINDS:
        for axis in "XYZ":
            times, values = _history(parameters, changed, f"CAL_MAG{index}_{axis}{kind}", default)
            columns.append(values[np.clip(np.searchsorted(times, stamps_us, side="right") - 1, 0, None)])
    return np.column_stack(columns)


def _settings(
    parameters: dict[str, Any], changed: list[tuple[int, str, float]], index: int
) -> list[dict[str, NDArray[np.float64]]]:
    """Every calibration CAL_MAG{index} had during the log: the initial one, and the one after each change."""
    moments = np.array([-np.inf, *sorted(float(t) for t, p, _ in changed if p.startswith(f"CAL_MAG{index}_"))])
    return [_as_cal(row) for row in np.unique(_calibration_at(parameters, changed, index, moments), axis=0)]


def _as_cal(row: NDArray[np.float64]) -> dict[str, NDArray[np.float64]]:
    return {"offsets": row[0:3], "scales": row[3:6], "offdiagonals": row[6:9]}


def _undo_in_effect(
    corrected: NDArray[np.float64],
    stamps_us: NDArray[np.float64],
    parameters: dict[str, Any],
    changed: list[tuple[int, str, float]],
    index: int,
    rotation: NDArray[np.float64] | None,
) -> NDArray[np.float64]:
    """:func:`undo_px4_calibration` of each sample with the CAL_MAG{index} calibration in effect at its time."""
    settings = _calibration_at(parameters, changed, index, stamps_us)
    samples = np.full(np.shape(corrected), np.nan)
    for setting in np.unique(settings, axis=0):
        rows = np.all(settings == setting, axis=1)
        samples[rows] = undo_px4_calibration(corrected[rows], **_as_cal(setting), rotation=rotation)
    return samples


def _changes_note(
    parameters: dict[str, Any], changed: list[tuple[int, str, float]], index: int, start_s: float
) -> list[str]:
    """The note that CAL_MAG{index}'s calibration changed during the log, when it did."""
    kinds = tuple(f"{axis}{kind}" for kind, _ in _CAL_KINDS for axis in "XYZ")
    moved = sorted({(t, p) for t, p, _ in changed if p.startswith(f"CAL_MAG{index}_") and p.endswith(kinds)})
    values = _calibration_at(parameters, changed, index, np.array([-np.inf, *(t for t, _ in moved)], dtype=float))
    if len(np.unique(values, axis=0)) < 2:  # set again to the values it had: no change
        return []
    later = [(t, p) for t, p in moved if not np.isfinite(start_s) or t > start_s * 1e6]
    if not later:
        return []
    names = sorted({p for _, p in later})
    return [
        f"the calibration changed during the log ({', '.join(names[:3])}{' ...' if len(names) > 3 else ''}, first at "
        f"{later[0][0] / 1e6:.1f} s): each sample undone with the CAL_MAG{index} parameters in effect at its time"
    ]
