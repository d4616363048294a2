"""What a log holds beside a magnetometer, on the magnetometer's own time stamps: :class:`Motion`.

Attitude-aided and gyro-aided calibration (and the alignment of a compass with the vehicle) need, for each
magnetometer sample, the vehicle's attitude, the gyroscope's rates and the accelerometer's specific force at
the instant of the sample. The logs record each stream on its own clock and at its own rate; this module
puts them on the magnetometer's stamps:

- the attitude by spherical linear interpolation between the two nearest attitudes
  (:class:`scipy.spatial.transform.Slerp`): the rotation turns at a constant rate between them;
- rates and accelerations linearly, component by component;
- a magnetometer sample outside another stream's first..last stamp, or inside a gap of that stream (no
  message for more than ``max(0.5 s, 10 median steps)``), is dropped, never extrapolated; the notes say how
  many and why.

Frames (every reader states them in the notes too):

- ``world``: North-East-Down (NED). ``attitude[i]`` is the rotation matrix from the vehicle's body frame
  (forward-right-down for PX4 and ArduPilot; the Imu message's ``frame_id`` for ROS) into NED:
  ``v_ned = attitude[i] @ v_body``, so the Earth's field seen by a perfectly calibrated, aligned compass is
  ``attitude[i].T @ field_ned``.
- ``gyro``, ``accel``: in the frame :attr:`Motion.imu_frame` names (the body frame where the log gives the
  rotated, calibrated IMU; the sensor's own frame for PX4's raw ``sensor_gyro``/``sensor_accel``).
- ``samples``: in :attr:`Motion.magnetometer_frame`: ``"sensor"`` (PX4's ``sensor_mag``: before
  ``CAL_MAGn_ROT``; :attr:`Motion.mounting` turns it into the body frame) or ``"body"`` (ArduPilot's MAG,
  after ``COMPASS_ORIENT``; PX4's ``vehicle_magnetometer`` undone back to the sensor frame is ``"sensor"``).
"""

from __future__ import annotations

import datetime
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from .position import Position

__all__ = ["Motion", "Stream", "align", "euler_quaternions", "quaternion_wxyz"]

#: A stream with no message for longer than this many of its median steps (and at least GAP_MIN_S) has a gap.
GAP_STEPS = 10.0
GAP_MIN_S = 0.5


@dataclass(frozen=True)
class Stream:
    """One stream of a log on its own clock, before it is put on the magnetometer's stamps.

    Attributes
    ----------
    name : str
        Where it comes from, in words (``vehicle_attitude.q``, ``IMU[0] GyrX/Y/Z``).
    time_s : ndarray, shape (M,)
        Its time stamps, seconds on the log's time base (the magnetometer's).
    values : ndarray, shape (M, 3) or (M, 4)
        Rates or accelerations (M, 3); an attitude as quaternions (M, 4), scalar last (x, y, z, w), body -> NED.
    frame : str
        The frame its values are in (``body (FRD)``, ``sensor``, a ROS ``frame_id``).
    """

    name: str
    time_s: NDArray[np.float64]
    values: NDArray[np.float64]
    frame: str = "body"


@dataclass(frozen=True)
class Motion:
    """A magnetometer's samples with the vehicle's motion at their time stamps.

    Attributes
    ----------
    sensor : str
        The magnetometer's id (as ``Source.read`` takes it).
    unit : str
        The samples' unit.
    time_s : ndarray, shape (N,)
        The magnetometer's time stamps kept (the log's time base, seconds).
    samples : ndarray, shape (N, 3)
        The samples as :meth:`Source.read` gives them, at those stamps (the firmware's calibration undone).
    magnetometer_frame : str
        ``"sensor"``: the magnetometer's own axes (PX4 ``sensor_mag``, before ``CAL_MAGn_ROT``); ``"body"``: the
        vehicle's axes (ArduPilot's MAG, after ``COMPASS_ORIENT`` or the board orientation); ``"unknown"``.
    mounting : ndarray, shape (3, 3), or None
        The rotation the firmware's parameters give from the magnetometer's axes to the body's
        (``body = mounting @ sensor``): ``CAL_MAGn_ROT`` (external) or ``SENS_BOARD_ROT`` (internal) for PX4,
        ``COMPASS_ORIENT*`` (external) or ``AHRS_ORIENTATION`` (internal) for ArduPilot — *already applied* to
        the samples when ``magnetometer_frame`` is ``"body"``. None when the log does not say.
    mounting_note : str
        Which parameter it comes from, with its value and angles.
    attitude : ndarray, shape (N, 3, 3), or None
        Body -> NED rotation matrices (``v_ned = attitude[i] @ v_body``), slerped to the stamps.
    gyro : ndarray, shape (N, 3), or None
        Angular rate, rad/s, in ``imu_frame``, linearly interpolated.
    accel : ndarray, shape (N, 3), or None
        Specific force (gravity included: about (0, 0, -9.8) m/s² in a level FRD body at rest), m/s², in
        ``imu_frame``, linearly interpolated.
    imu_frame : str
        The frame of ``gyro`` and ``accel``.
    gyro_stream : Stream or None
        The gyroscope at its own stamps (the messages that cover the samples kept, one beyond each end), for a
        method that integrates the rates at their own rate instead of their values at the magnetometer's stamps.
    sources : dict
        For each of ``attitude``, ``gyro``, ``accel`` present: the stream it came from and its rate.
    frames : dict
        For each of ``attitude``, ``gyro``, ``accel`` present: its stream's frame (:attr:`Stream.frame`), so
        that a user of two streams can tell whether they share a frame.
    position : Position or None
        Where and when the log was recorded (its GNSS fixes), for the World Magnetic Model.
    start_utc_s : float
        UTC seconds since 1970 near the start of the recording (a bag's first stamp, else the first GNSS fix's
        time), NaN when the log does not say: the date the World Magnetic Model needs.
    n_dropped : int
        Magnetometer samples dropped because another stream did not cover them.
    notes : tuple of str
        Frames, rates, interpolation, gaps, what was dropped and why.
    """

    sensor: str
    unit: str
    time_s: NDArray[np.float64]
    samples: NDArray[np.float64]
    magnetometer_frame: str
    mounting: NDArray[np.float64] | None = None
    mounting_note: str = ""
    attitude: NDArray[np.float64] | None = None
    gyro: NDArray[np.float64] | None = None
    accel: NDArray[np.float64] | None = None
    imu_frame: str = ""
    gyro_stream: Stream | None = None
    sources: dict[str, str] | None = None
    frames: dict[str, str] | None = None
    position: Position | None = None
    start_utc_s: float = float("nan")
    n_dropped: int = 0
    notes: tuple[str, ...] = ()

    @property
    def date(self) -> datetime.date | None:
        """The UTC date of :attr:`start_utc_s`, or None when it is not known."""
        if not np.isfinite(self.start_utc_s):
            return None
        return datetime.datetime.fromtimestamp(self.start_utc_s, tz=datetime.timezone.utc).date()

    @property
    def world_frame(self) -> str:
        """Always ``"NED"``: the frame ``attitude`` turns body vectors into."""
        return "NED"


def _clean(stream: Stream) -> Stream:
    """Finite rows, in increasing time, one per stamp (the first): what interpolation needs."""
    finite = np.isfinite(stream.time_s) & np.all(np.isfinite(stream.values), axis=tuple(range(1, stream.values.ndim)))
    time, values = stream.time_s[finite], stream.values[finite]
    order = np.argsort(time, kind="stable")
    time, values = time[order], values[order]
    keep = np.concatenate([[True], np.diff(time) > 0]) if len(time) else np.zeros(0, dtype=bool)
    return Stream(stream.name, time[keep], values[keep], stream.frame)


def _rate(time: NDArray[np.float64]) -> float:
    steps = np.diff(time)
    return float(1.0 / np.median(steps)) if len(steps) else float("nan")


def _covered(stream: Stream, time: NDArray[np.float64]) -> tuple[NDArray[np.bool_], str]:
    """Which of ``time`` the stream covers (inside its span, not in a gap), and what was not, in words."""
    if len(stream.time_s) < 2:
        return np.zeros(len(time), dtype=bool), f"{stream.name} has fewer than two usable messages"
    inside = (time >= stream.time_s[0]) & (time <= stream.time_s[-1])
    steps = np.diff(stream.time_s)
    limit = max(GAP_MIN_S, GAP_STEPS * float(np.median(steps)))
    gaps = np.flatnonzero(steps > limit)
    # The message at or before each stamp: the stamp is in a gap when the step after that message is one.
    before = np.clip(np.searchsorted(stream.time_s, time, side="right") - 1, 0, len(steps) - 1)
    in_gap = inside & (steps[before] > limit) & (time > stream.time_s[before]) & (time < stream.time_s[before + 1])
    said = []
    if np.any(~inside):
        said.append(f"{int(np.count_nonzero(~inside))} outside {stream.name}'s span")
    if np.any(in_gap):
        longest = float(np.max(steps[gaps]))
        said.append(f"{int(np.count_nonzero(in_gap & inside))} in its {len(gaps)} gap(s) (longest {longest:.2f} s)")
    return inside & ~in_gap, ", ".join(said)


def align(
    sensor: str,
    unit: str,
    time_s: NDArray[np.float64],
    samples: NDArray[np.float64],
    *,
    magnetometer_frame: str,
    attitude: Stream | None = None,
    gyro: Stream | None = None,
    accel: Stream | None = None,
    mounting: NDArray[np.float64] | None = None,
    mounting_note: str = "",
    position: Position | None = None,
    start_utc_s: float | None = None,
    notes: tuple[str, ...] = (),
) -> Motion:
    """Put the other streams on the magnetometer's stamps (see the module's docstring) into a :class:`Motion`.

    A stream with fewer than two usable messages is left out (None) and said; the samples none of the
    remaining streams cover are dropped. ``start_utc_s`` None: the position's time.
    """
    from scipy.spatial.transform import Rotation, Slerp  # scipy is a dependency of magfit; only this needs it

    time_s = np.asarray(time_s, dtype=np.float64)
    samples = np.asarray(samples, dtype=np.float64)
    said = list(notes)
    streams = {"attitude": attitude, "gyro": gyro, "accel": accel}
    kept = np.ones(len(time_s), dtype=bool)
    used: dict[str, Stream] = {}
    for key, stream in streams.items():
        if stream is None:
            continue
        if key == "attitude":
            norms = np.linalg.norm(stream.values, axis=1)
            good = np.isfinite(norms) & (norms > 0.5) & (norms < 1.5)  # a zero or damaged quaternion is no attitude
            stream = Stream(stream.name, stream.time_s[good], stream.values[good], stream.frame)
        stream = _clean(stream)
        covered, what = _covered(stream, time_s)
        if len(stream.time_s) < 2:
            said.append(f"{key}: {what}; left out")
            continue
        used[key] = stream
        kept &= covered
        said.append(
            f"{key}: {stream.name} ({stream.frame}), {len(stream.time_s)} messages at {_rate(stream.time_s):.1f} Hz, "
            + ("slerped" if key == "attitude" else "linearly interpolated")
            + " to the magnetometer's stamps"
            + (f"; magnetometer samples not covered: {what}" if what else "")
        )
    dropped = int(np.count_nonzero(~kept))
    if dropped:
        said.append(f"{dropped} of {len(time_s)} magnetometer samples dropped: not covered by every stream above")
    time_kept, samples_kept = time_s[kept], samples[kept]
    result: dict[str, NDArray[np.float64] | None] = {"attitude": None, "gyro": None, "accel": None}
    for key, stream in used.items():
        if key == "attitude":
            rotations = Rotation.from_quat(stream.values / np.linalg.norm(stream.values, axis=1, keepdims=True))
            result[key] = (
                Slerp(stream.time_s, rotations)(time_kept).as_matrix() if len(time_kept) else np.empty((0, 3, 3))
            )
        else:
            result[key] = np.column_stack([np.interp(time_kept, stream.time_s, stream.values[:, i]) for i in range(3)])
    frames = {used[k].frame for k in ("gyro", "accel") if k in used}
    said += _gravity_check(result["attitude"], result["accel"])
    gyro_stream = None
    if "gyro" in used and len(time_kept):
        raw = used["gyro"]
        first = max(int(np.searchsorted(raw.time_s, time_kept[0], side="right")) - 1, 0)
        last = min(int(np.searchsorted(raw.time_s, time_kept[-1], side="left")) + 1, len(raw.time_s))
        gyro_stream = Stream(raw.name, raw.time_s[first:last], raw.values[first:last], raw.frame)
    return Motion(
        sensor=sensor,
        unit=unit,
        time_s=time_kept,
        samples=samples_kept,
        magnetometer_frame=magnetometer_frame,
        mounting=mounting,
        mounting_note=mounting_note,
        attitude=result["attitude"],
        gyro=result["gyro"],
        accel=result["accel"],
        imu_frame=" / ".join(sorted(frames)),
        gyro_stream=gyro_stream,
        sources={key: f"{s.name} ({s.frame}, {_rate(s.time_s):.1f} Hz)" for key, s in used.items()},
        frames={key: s.frame for key, s in used.items()},
        position=position,
        start_utc_s=float(start_utc_s if start_utc_s is not None else (position.time_s if position else np.nan)),
        n_dropped=dropped,
        notes=tuple(said),
    )


#: Gravity turned into NED by the attitude further than this from (0, 0, -g) (m/s², the median over the
#: recording, so that manoeuvres do not count) means the attitude and the accelerometer disagree on a frame.
GRAVITY_TOLERANCE = 1.5
STANDARD_GRAVITY = 9.80665


def _gravity_check(attitude: NDArray[np.float64] | None, accel: NDArray[np.float64] | None) -> list[str]:
    """The accelerometer's specific force turned into NED by the attitude, its median: (0, 0, -g) when the
    attitude, the accelerometer and the frames stated agree; a note either way."""
    if attitude is None or accel is None or not len(accel):
        return []
    gravity = np.median(np.einsum("nij,nj->ni", attitude, accel), axis=0)
    shown = ", ".join(f"{g:.2f}" for g in gravity)
    if np.linalg.norm(gravity - [0.0, 0.0, -STANDARD_GRAVITY]) <= GRAVITY_TOLERANCE:
        return [f"check: attitude · accel = ({shown}) m/s² in NED (median), gravity where it belongs"]
    return [
        f"check FAILED: attitude · accel = ({shown}) m/s² in NED (median), not (0, 0, -9.81): the attitude and the "
        "accelerometer are not in the frames stated (a driver outside REP-145, a rotated IMU); do not trust the "
        "attitude with this magnetometer"
    ]


def quaternion_wxyz(values: NDArray[np.float64]) -> NDArray[np.float64]:
    """(w, x, y, z) quaternions (PX4, ArduPilot) as scipy's (x, y, z, w)."""
    values = np.asarray(values, dtype=np.float64)
    return np.column_stack([values[:, 1], values[:, 2], values[:, 3], values[:, 0]])


def euler_quaternions(
    roll_deg: NDArray[np.float64], pitch_deg: NDArray[np.float64], yaw_deg: NDArray[np.float64]
) -> NDArray[np.float64]:
    """Quaternions (x, y, z, w) of the 3-2-1 Euler angles in degrees: ``Rz(yaw) · Ry(pitch) · Rx(roll)``, body -> NED
    (ArduPilot's ATT and AHR2: ``Matrix3f::from_euler``)."""
    from scipy.spatial.transform import Rotation

    angles = np.column_stack([yaw_deg, pitch_deg, roll_deg]).astype(np.float64)
    return Rotation.from_euler("ZYX", angles, degrees=True).as_quat()  # intrinsic Z, Y', X'': Rz · Ry · Rx
