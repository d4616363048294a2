"""ROS bags: ROS 1 ``.bag`` files, ROS 2 bag folders (sqlite3 or MCAP storage) and bare ``.mcap``/``.db3`` files.

Read with ``rosbags`` (the ``ros`` extra: pure Python, no ROS install), imported when a bag is first read.
Every ``sensor_msgs/MagneticField`` topic becomes one magnetometer: its ``magnetic_field`` x, y, z are
in tesla by the message's definition, its ``header.frame_id`` names the sensor frame. Every
``sensor_msgs/Imu`` topic is kept beside them (orientation quaternion, angular velocity, linear
acceleration) for :meth:`~magfit.sources.Source.read_motion`.

Frames (REP-103, REP-145): an Imu's ``orientation`` turns its ``frame_id`` (x forward, y left, z up) into a
world frame that is East-North-Up; ``read_motion`` turns it into North-East-Down (``R_ned = C · R_enu`` with C
swapping x and y and negating z) and keeps the body axes of the ``frame_id``. A driver that reports its
orientation in NED breaks REP-145: its attitude would come out mirrored, and the notes say which convention
was assumed. ``angular_velocity`` (rad/s) and ``linear_acceleration`` (m/s²) are in the Imu's ``frame_id``.

Times are the messages' ``header.stamp`` in seconds since the epoch: the time the sensor measured. A
driver that leaves the stamps at zero (it happens) gets the bag's receive times instead, and the topic
says so (``time_base``).

A bag is recognised by its content, not its name: ``#ROSBAG V2.0`` (ROS 1), the MCAP magic, an SQLite
database, or a folder holding ``metadata.yaml``. A damaged bag (a recording killed before its index was
written, a truncated copy) is a one-line :class:`~magfit.errors.DataFileError` naming the file, what
failed and how to repair it (``rosbag reindex`` / ``ros2 bag reindex``).
"""

from __future__ import annotations

import os
import tempfile
from array import array
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

import numpy as np
from numpy.typing import NDArray

from ..errors import DataFileError
from .motion import Motion, Stream, align

if TYPE_CHECKING:
    from .types import Source

__all__ = [
    "BagContents",
    "ImuTopic",
    "MagneticTopic",
    "bag_kind",
    "frame_rotation",
    "open_rosbag",
    "read_bag",
    "read_bag_contents",
]

INSTALL_HINT = "pip install 'magfit[ros]'"

#: The message types read, by their ROS 2 names (rosbags names ROS 1 types the same way).
MAGNETIC_FIELD = "sensor_msgs/msg/MagneticField"
IMU = "sensor_msgs/msg/Imu"
NAV_SAT_FIX = "sensor_msgs/msg/NavSatFix"
TF_MESSAGE = "tf2_msgs/msg/TFMessage"

BagKind = Literal["ros1", "mcap", "sqlite3", "folder"]

_MAGIC: tuple[tuple[bytes, BagKind], ...] = (
    (b"#ROSBAG V2.0\n", "ros1"),
    (b"\x89MCAP0\r\n", "mcap"),
    (b"SQLite format 3\x00", "sqlite3"),
)
#: The suffix rosbags needs to pick its reader for each kind.
#: Bags up to this size that run out of memory in the parser are damaged, not too big (see read_bag_contents).
DAMAGED_IF_OUT_OF_MEMORY_BELOW = 1 << 30
_SUFFIX: dict[BagKind, str] = {"ros1": ".bag", "mcap": ".mcap", "sqlite3": ".db3"}


@dataclass(frozen=True, eq=False)
class MagneticTopic:
    """One ``sensor_msgs/MagneticField`` topic: one magnetometer.

    Attributes
    ----------
    topic : str
        The topic name (``/imu/mag``).
    frame_id : str
        The sensor frame of the first message (``header.frame_id``); frames that change along the topic
        are listed in :attr:`frame_ids`.
    samples : ndarray, shape (N, 3)
        The field in tesla, in message order.
    timestamps : ndarray, shape (N,)
        Seconds since the epoch (float64): ``header.stamp``, or the bag's receive time (:attr:`time_base`).
    time_base : str
        ``"header"`` or ``"bag"`` (the stamps were zero).
    frame_ids : tuple of str
        Every distinct ``frame_id`` seen, in order of appearance.
    """

    topic: str
    frame_id: str
    samples: NDArray[np.float64]
    timestamps: NDArray[np.float64]
    time_base: str = "header"
    frame_ids: tuple[str, ...] = ()

    @property
    def unit(self) -> str:
        """Always ``"T"``: the message's field is in tesla."""
        return "T"

    @property
    def rate_hz(self) -> float | None:
        """Median message rate, or None with fewer than two distinct times."""
        return _rate(self.timestamps)


@dataclass(frozen=True, eq=False)
class ImuTopic:
    """One ``sensor_msgs/Imu`` topic.

    Attributes
    ----------
    topic, frame_id : str
        As for :class:`MagneticTopic`.
    orientation : ndarray, shape (N, 4)
        Quaternions (x, y, z, w) as the message orders them; rows whose covariance's first element is -1
        ("no orientation", by the message's definition) are NaN.
    linear_acceleration : ndarray, shape (N, 3)
        m/s², the sensor's specific force (gravity included).
    timestamps : ndarray, shape (N,)
        Seconds since the epoch, as for :class:`MagneticTopic`.
    time_base : str
        ``"header"`` or ``"bag"``.
    angular_velocity : ndarray, shape (N, 3)
        rad/s; rows whose covariance's first element is -1 (not given) are NaN.
    """

    topic: str
    frame_id: str
    orientation: NDArray[np.float64]
    linear_acceleration: NDArray[np.float64]
    timestamps: NDArray[np.float64]
    time_base: str = "header"
    angular_velocity: NDArray[np.float64] = field(default_factory=lambda: np.empty((0, 3)))


@dataclass(frozen=True, eq=False)
class BagContents:
    """What a bag holds for magfit.

    Attributes
    ----------
    path : Path
        The bag (a file or a ROS 2 bag folder).
    kind : str
        ``"ros1"``, ``"mcap"``, ``"sqlite3"`` or ``"folder"`` (a ROS 2 bag folder, either storage).
    magnetometers : tuple of MagneticTopic
        Every MagneticField topic with at least one message, sorted by topic name.
    imus : tuple of ImuTopic
        Every Imu topic with at least one message, sorted by topic name.
    topics : dict
        Every topic of the bag and its message type (for messages that list what the bag holds).
    fixes : ndarray, shape (K, 4)
        The GNSS fixes of every ``sensor_msgs/NavSatFix`` topic whose status says there is one: latitude,
        longitude (degrees), altitude (m above the WGS-84 ellipsoid, NaN when not given) and time (seconds
        since the epoch); see :meth:`position`.
    static_transforms : dict
        The ``/tf_static`` transforms: child frame -> (parent frame, rotation quaternion x, y, z, w), where
        ``v_parent = R(q) · v_child`` (geometry_msgs/Transform); the last one given for each child.
    """

    path: Path
    kind: str
    magnetometers: tuple[MagneticTopic, ...]
    imus: tuple[ImuTopic, ...]
    topics: dict[str, str]
    fixes: NDArray[np.float64] = field(default_factory=lambda: np.empty((0, 4)))
    static_transforms: dict[str, tuple[str, tuple[float, float, float, float]]] = field(default_factory=dict)

    def position(self) -> tuple[float, float, float, float] | None:
        """Where and when the bag was recorded, from its ``sensor_msgs/NavSatFix`` messages with a fix:
        (latitude, longitude in degrees, altitude in km above the WGS-84 ellipsoid, time in seconds since the
        epoch of the first fix); the median of the fixes, so that a few wild ones do not move it. None without
        a fix."""
        if not len(self.fixes):
            return None
        lat, lon = np.median(self.fixes[:, :2], axis=0)
        heights = self.fixes[:, 2][np.isfinite(self.fixes[:, 2])]
        alt_km = float(np.median(heights)) / 1000.0 if heights.size else 0.0  # no altitude: the ellipsoid's
        return float(lat), float(lon), alt_km, float(self.fixes[0, 3])


def bag_kind(path: str | os.PathLike[str]) -> BagKind | None:
    """What kind of bag ``path`` is, from its content (magic bytes, or a folder with ``metadata.yaml``); None
    when it is no bag."""
    path = Path(path)
    if path.is_dir():
        return "folder" if (path / "metadata.yaml").is_file() else None
    try:
        with open(_bytes_of(path), "rb") as handle:
            head = handle.read(16)
    except OSError:
        return None
    for magic, kind in _MAGIC:
        if head.startswith(magic):
            return kind
    return None


def read_bag(path: str | os.PathLike[str]) -> list[MagneticTopic]:
    """Every ``sensor_msgs/MagneticField`` topic of a bag: (topic, frame_id, samples (N, 3) in tesla, timestamps).

    Raises
    ------
    DataFileError
        Not a bag, a damaged bag, or a bag with no MagneticField message (naming the topics it has).
    ImportError
        The ``ros`` extra is not installed (the message is the install command).
    """
    contents = read_bag_contents(path)
    if not contents.magnetometers:
        listed = ", ".join(f"{name} ({kind})" for name, kind in sorted(contents.topics.items())) or "no topics"
        raise DataFileError(
            f"{path}: the bag has no sensor_msgs/MagneticField messages to calibrate (it holds {listed}); record the "
            "magnetometer's MagneticField topic"
        )
    return list(contents.magnetometers)


def read_bag_contents(path: str | os.PathLike[str]) -> BagContents:
    """The MagneticField and Imu topics of a bag, read in one pass (see :func:`read_bag`)."""
    path = Path(path)
    if not path.exists():
        raise DataFileError(f"{path}: no such file or folder")
    kind = bag_kind(path)
    if kind is None:
        what = (
            "folder has no metadata.yaml" if path.is_dir() else "file does not start like a ROS 1 bag, MCAP or SQLite"
        )
        raise DataFileError(f"{path}: not a ROS bag (the {what})")
    rosbags = _rosbags()
    try:
        with _readable(path if kind == "folder" else _bytes_of(path), kind) as readable:
            return _read(path, kind, readable, rosbags)
    except DataFileError:
        raise
    except MemoryError as error:
        # rosbags allocates what a record's length field announces: a damaged length asks for terabytes. A bag
        # this small cannot need that much (its messages are read one at a time): it is damaged.
        if _size(path) > DAMAGED_IF_OUT_OF_MEMORY_BELOW:
            raise
        error.args = ("a record announces more bytes than the file holds",)
        raise DataFileError(_damaged(path, kind, error)) from None
    except Exception as error:  # a damaged bag can fail anywhere in the parser: one line, never a traceback
        raise DataFileError(_damaged(path, kind, error)) from None


def open_rosbag(path: str | os.PathLike[str]) -> Source:
    """A bag as a :class:`~magfit.sources.Source`: one magnetometer per MagneticField topic (its id is the topic).

    The samples are given in µT (the messages' tesla times 10⁶, an exact power of ten): the unit of the
    calibration and of the exports. The Imu topics and the other topics are listed in ``other``.
    """
    from .types import SLOW_RATE_HZ, LogSamples, Magnetometer, Position, Source

    path = Path(path)
    contents = read_bag_contents(path)
    magnetometers = []
    for topic in contents.magnetometers:
        rate = topic.rate_hz
        notes = [f"{topic.topic}: the header stamps are zero; the bag's receive times are used"] * (
            topic.time_base == "bag"
        )
        if len(topic.frame_ids) > 1:
            notes.append(f"{topic.topic}: the frame_id changes along the topic ({', '.join(topic.frame_ids)})")
        if rate is not None and rate < SLOW_RATE_HZ:
            notes.append(
                f"{topic.topic} is published at only {rate:.2g} Hz: too few samples for a fit unless the recording is "
                "long; raise the driver's publishing rate"
            )
        magnetometers.append(
            Magnetometer(
                id=topic.topic,
                description=f"sensor_msgs/MagneticField (tesla, read as uT), frame {topic.frame_id or '(none)'}"
                + (f", {rate:.3g} Hz" if rate is not None else ""),
                unit="uT",
                n_samples=int(topic.samples.shape[0]),
                start_s=float(topic.timestamps[0]) if topic.timestamps.size else float("nan"),
                end_s=float(topic.timestamps[-1]) if topic.timestamps.size else float("nan"),
                notes=tuple(notes),
            )
        )
    by_id = {topic.topic: topic for topic in contents.magnetometers}
    read_topics = set(by_id) | {imu.topic for imu in contents.imus}
    counts = {imu.topic: imu.timestamps.size for imu in contents.imus}
    other = tuple(f"{name} (sensor_msgs/Imu, {counts[name]})" for name in sorted(counts))
    rest = sorted(set(contents.topics) - read_topics)
    if rest:
        other += (f"{len(rest)} other topics: {', '.join(rest)}",)

    def read(magnetometer: Magnetometer) -> LogSamples:
        topic = by_id[magnetometer.id]
        return LogSamples(
            magnetometer=magnetometer,
            samples=topic.samples * 1e6,  # tesla -> µT
            time_s=topic.timestamps,
            columns=("magnetic_field.x", "magnetic_field.y", "magnetic_field.z"),
        )

    place = contents.position()
    position = (
        Position(lat_deg=place[0], lon_deg=place[1], alt_km=place[2], time_s=place[3], n_fixes=len(contents.fixes))
        if place is not None
        else None
    )

    def motion(magnetometer: Magnetometer) -> Motion:
        return _motion(by_id[magnetometer.id], contents, read(magnetometer), position)

    names = {"ros1": "ROS 1 bag", "mcap": "MCAP file", "sqlite3": "ROS 2 sqlite3 bag", "folder": "ROS 2 bag folder"}
    return Source(
        path=path,
        kind="rosbag",
        format=names[contents.kind],
        time_base="seconds since the epoch (header.stamp)",
        magnetometers=tuple(magnetometers),
        other=other,
        position=position,
        _reader=read,
        _motion=motion,
    )


#: ENU -> NED: x and y swapped, z negated (a proper rotation: 180° about the axis between north and east).
_ENU_TO_NED = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])


def _companion(mag: MagneticTopic, imus: Sequence[ImuTopic]) -> tuple[ImuTopic | None, str]:
    """The Imu topic that goes with a magnetometer: the same frame_id, else the same namespace, else the first;
    among those, one that gives an orientation."""
    if not imus:
        return None, "the bag has no sensor_msgs/Imu topic"
    # An Imu with an orientation first (imu/data before imu/data_raw, which has none by the message's rule).
    imus = sorted(imus, key=lambda imu: not np.any(np.isfinite(imu.orientation)))
    for imu in imus:
        if imu.frame_id == mag.frame_id:
            return imu, f"{imu.topic}: the same frame_id as {mag.topic} ({mag.frame_id})"
    namespace = mag.topic.rsplit("/", 1)[0]
    for imu in imus:
        if imu.topic.rsplit("/", 1)[0] == namespace:
            return imu, f"{imu.topic}: the same namespace as {mag.topic} (frame_id {imu.frame_id})"
    return imus[0], f"{imus[0].topic}: the bag's first Imu topic (no Imu shares {mag.topic}'s frame_id or namespace)"


def _motion(mag: MagneticTopic, contents: BagContents, read: Any, position: Any) -> Motion:
    from scipy.spatial.transform import Rotation

    imu, why = _companion(mag, contents.imus)
    attitude = gyro = accel = None
    notes = [f"imu: {why}"]
    same = imu is not None and imu.frame_id == mag.frame_id
    if imu is not None:
        frame = f"frame_id {imu.frame_id or '(none)'} (REP-103: x forward, y left, z up)"
        quaternions = imu.orientation
        known = np.all(np.isfinite(quaternions), axis=1) & (np.linalg.norm(quaternions, axis=1) > 0.5)
        if np.any(known):
            ned = np.full_like(quaternions, np.nan)
            ned[known] = (Rotation.from_matrix(_ENU_TO_NED) * Rotation.from_quat(quaternions[known])).as_quat()
            attitude = Stream(f"{imu.topic} orientation, ENU turned into NED", imu.timestamps, ned, frame)
            notes.append(
                "attitude: the Imu's orientation taken as REP-145's (its frame_id in East-North-Up) and turned into "
                "NED; the body axes stay the frame_id's"
            )
        else:
            notes.append(f"attitude: {imu.topic} gives no orientation (orientation_covariance[0] = -1)")
        gyro = Stream(f"{imu.topic} angular_velocity", imu.timestamps, imu.angular_velocity, frame)
        accel = Stream(f"{imu.topic} linear_acceleration", imu.timestamps, imu.linear_acceleration, frame)
    mounting: NDArray[np.float64] | None = np.eye(3) if same else None
    mounting_note = "the same frame_id as the Imu" if same else ""
    if imu is not None and not same:
        mounting = frame_rotation(contents.static_transforms, mag.frame_id, imu.frame_id)
        if mounting is not None:
            mounting_note = (
                f"/tf_static: {mag.frame_id} -> {imu.frame_id} (v_{imu.frame_id} = mounting · v_{mag.frame_id})"
            )
        else:
            mounting_note = f"no /tf_static transform joins {mag.frame_id or '(none)'} and {imu.frame_id or '(none)'}"
    if not same:
        notes.append(f"magnetometer: frame_id {mag.frame_id or '(none)'} is not the Imu's; mounting: {mounting_note}")
    return align(
        mag.topic,
        "uT",
        read.time_s,
        read.samples,
        magnetometer_frame="body" if same else "sensor",
        attitude=attitude,
        gyro=gyro,
        accel=accel,
        mounting=mounting,
        mounting_note=mounting_note,
        position=position,
        # header stamps are UTC seconds since the epoch (a bag's receive times too): the recording's own date,
        # unless the clock was a simulation's (stamps from 0: before 2001 is no real recording's date)
        start_utc_s=float(read.time_s[0]) if len(read.time_s) and read.time_s[0] > 1e9 else None,
        notes=tuple(notes),
    )


def _rosbags() -> Any:
    try:
        import rosbags.highlevel
        import rosbags.typesys
    except ImportError:
        raise ImportError(
            f"reading ROS bags needs rosbags, which is not installed (the ros extra): {INSTALL_HINT}", name="rosbags"
        ) from None
    return rosbags


def _bytes_of(path: Path) -> Path:
    """The regular file holding ``path``'s bytes: the file itself, or the copy that a named pipe or a compressed
    file is read into once (:func:`magfit.io.sources.data_file`): a pipe opened a second time would wait for
    a writer that is gone."""
    from ..io.sources import data_file

    return data_file(path)


@contextmanager
def _readable(path: Path, kind: BagKind) -> Iterator[Path]:
    """``path``, or a link to it under the suffix rosbags needs to pick its reader (a bag is known by content)."""
    suffix = _SUFFIX.get(kind)
    if suffix is None or path.suffix == suffix:
        yield path
        return
    with tempfile.TemporaryDirectory(prefix="magfit-bag-") as folder:
        link = Path(folder) / f"bag{suffix}"
        try:
            link.symlink_to(path.resolve())
        except OSError:  # no symbolic links here (some Windows setups): a copy
            import shutil

            shutil.copyfile(path, link)
        yield link


def _read(path: Path, kind: BagKind, readable: Path, rosbags: Any) -> BagContents:
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    # A ROS 1 bag carries its message definitions; an older ROS 2 bag may not: the standard ones stand in.
    default = get_typestore(Stores.ROS1_NOETIC if kind == "ros1" else Stores.ROS2_HUMBLE)
    with AnyReader([readable], default_typestore=default) as reader:
        topics = {connection.topic: connection.msgtype for connection in reader.connections}
        wanted = [c for c in reader.connections if c.msgtype in (MAGNETIC_FIELD, IMU, NAV_SAT_FIX)]
        wanted += [c for c in reader.connections if c.msgtype == TF_MESSAGE and c.topic.endswith("tf_static")]
        static: dict[str, tuple[str, tuple[float, float, float, float]]] = {}
        mag: dict[str, _Collector] = {}
        imu: dict[str, _Collector] = {}
        fixes: list[tuple[float, float, float, float]] = []
        if wanted:
            for connection, bag_time, raw in reader.messages(connections=wanted):
                message: Any = reader.deserialize(raw, connection.msgtype)
                if connection.msgtype == MAGNETIC_FIELD:
                    b = message.magnetic_field
                    mag.setdefault(connection.topic, _Collector()).add(message, bag_time, (b.x, b.y, b.z))
                elif connection.msgtype == NAV_SAT_FIX:
                    fix = _fix(message, bag_time)
                    if fix is not None:
                        fixes.append(fix)
                elif connection.msgtype == TF_MESSAGE:
                    for transform in message.transforms:
                        q = transform.transform.rotation
                        parent, child = str(transform.header.frame_id), str(transform.child_frame_id)
                        static[child.lstrip("/")] = (parent.lstrip("/"), (q.x, q.y, q.z, q.w))
                else:
                    q, a, w = message.orientation, message.linear_acceleration, message.angular_velocity
                    # covariance[0] == -1: the IMU does not give this quantity (sensor_msgs/Imu's definition)
                    known = message.orientation_covariance[0] != -1
                    quaternion = (q.x, q.y, q.z, q.w) if known else (np.nan,) * 4
                    rate = (w.x, w.y, w.z) if message.angular_velocity_covariance[0] != -1 else (np.nan,) * 3
                    imu.setdefault(connection.topic, _Collector()).add(
                        message, bag_time, quaternion, (a.x, a.y, a.z), rate
                    )
    return BagContents(
        path=path,
        kind=kind,
        magnetometers=tuple(mag[name].magnetic(name) for name in sorted(mag)),
        imus=tuple(imu[name].imu(name) for name in sorted(imu)),
        topics=topics,
        fixes=np.array(sorted(fixes, key=lambda row: row[3]), dtype=np.float64).reshape(-1, 4),
        static_transforms=static,
    )


def frame_rotation(
    transforms: dict[str, tuple[str, tuple[float, float, float, float]]], source: str, target: str
) -> NDArray[np.float64] | None:
    """R with ``v_target = R · v_source`` from the static transforms (both frames under one root), else None."""
    from scipy.spatial.transform import Rotation

    def to_root(frame: str) -> tuple[str, Any]:
        rotation, seen = Rotation.identity(), {frame}
        while frame in transforms:
            parent, quaternion = transforms[frame]
            rotation = Rotation.from_quat(quaternion) * rotation  # v_parent = R(q) · v_frame
            frame = parent
            if frame in seen:  # a cycle in a damaged tree: no answer rather than a loop
                return "", rotation
            seen.add(frame)
        return frame, rotation

    source_root, from_source = to_root(source.lstrip("/"))
    target_root, from_target = to_root(target.lstrip("/"))
    if not source_root or source_root != target_root:
        return None
    matrix: NDArray[np.float64] = (from_target.inv() * from_source).as_matrix()
    return matrix


def _fix(message: Any, bag_time: int) -> tuple[float, float, float, float] | None:
    """(lat, lon, alt_m, time_s) of a NavSatFix that has a fix (status >= 0, finite, in range), else None."""
    lat, lon, alt = float(message.latitude), float(message.longitude), float(message.altitude)
    if message.status.status < 0 or not (np.isfinite(lat) and np.isfinite(lon)) or abs(lat) > 90 or abs(lon) > 360:
        return None
    stamp = int(message.header.stamp.sec) * 1_000_000_000 + int(message.header.stamp.nanosec)
    return lat, lon, alt if np.isfinite(alt) else float("nan"), (stamp or int(bag_time)) / 1e9


class _Collector:
    """The messages of one topic, gathered into arrays: packed as they come (8 bytes a number, not a Python
    object each), so a long bag's compass and IMU take 40 and 96 bytes a message."""

    def __init__(self) -> None:
        self.frames: list[str] = []
        self.stamps = array("q")
        self.bag_times = array("q")
        self.values = array("d")
        self.extra = array("d")
        self.more = array("d")

    def add(
        self,
        message: Any,
        bag_time: int,
        values: Sequence[float],
        extra: Sequence[float] = (),
        more: Sequence[float] = (),
    ) -> None:
        header = message.header
        frame = str(header.frame_id)
        if not self.frames or frame != self.frames[-1]:
            self.frames.append(frame)
        self.stamps.append(int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec))
        self.bag_times.append(int(bag_time))
        self.values.extend(values)
        self.extra.extend(extra)
        self.more.extend(more)

    def times(self) -> tuple[NDArray[np.float64], str]:
        stamps = np.frombuffer(self.stamps, dtype=np.int64)
        if np.all(stamps == 0):
            return np.frombuffer(self.bag_times, dtype=np.int64) / 1e9, "bag"
        return stamps / 1e9, "header"

    def magnetic(self, topic: str) -> MagneticTopic:
        times, base = self.times()
        frames = tuple(dict.fromkeys(self.frames))
        return MagneticTopic(
            topic=topic,
            frame_id=frames[0] if frames else "",
            samples=np.frombuffer(self.values, dtype=np.float64).reshape(-1, 3),
            timestamps=times,
            time_base=base,
            frame_ids=frames,
        )

    def imu(self, topic: str) -> ImuTopic:
        times, base = self.times()
        return ImuTopic(
            topic=topic,
            frame_id=self.frames[0] if self.frames else "",
            orientation=np.frombuffer(self.values, dtype=np.float64).reshape(-1, 4),
            linear_acceleration=np.frombuffer(self.extra, dtype=np.float64).reshape(-1, 3),
            timestamps=times,
            time_base=base,
            angular_velocity=np.frombuffer(self.more, dtype=np.float64).reshape(-1, 3),
        )


def _size(path: Path) -> int:
    """Bytes of a bag: its file, or the files of its folder."""
    try:
        if path.is_dir():
            return sum(file.stat().st_size for file in path.iterdir() if file.is_file())
        return path.stat().st_size
    except OSError:
        return 0


def _rate(times: NDArray[np.float64]) -> float | None:
    steps = np.diff(times)
    steps = steps[steps > 0]
    return float(1.0 / np.median(steps)) if steps.size else None


def _damaged(path: Path, kind: BagKind, error: Exception) -> str:
    """The one line for a bag the parser could not read."""
    reason = " ".join(str(error).split()).rstrip(".") or type(error).__name__
    if len(reason) > 160:
        reason = reason[:157] + "..."
    if kind == "ros1":
        fix = "if the recording was interrupted, 'rosbag reindex' repairs its index"
        name = "ROS 1 bag"
    elif kind == "folder":
        fix = "if the recording was interrupted, 'ros2 bag reindex' rebuilds its metadata.yaml"
        name = "ROS 2 bag folder"
    else:
        fix = "the file may be truncated or damaged: copy it again from the recorder"
        name = "MCAP file" if kind == "mcap" else "ROS 2 sqlite3 bag"
    return f"{path}: this {name} cannot be read ({type(error).__name__}: {reason}); {fix}"
