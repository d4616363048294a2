"""A samples file with the vehicle's attitude, the reference field, the gyroscope and the accelerometer in
columns beside the magnetometer, as a :class:`magfit.sources.Source`: :func:`samples_source`.

The streams are found by their names (:func:`magfit.io.streams.find_stream_columns`) or named by the caller,
read row for row with the magnetometer (rows with a missing value in any column used are dropped and
counted), and handed to :func:`magfit.pipeline.streams.method_streams` as a flight log's are: one path for
logs and files, the reference field turned into the body frame by the attitude there.

The attitude's convention: ``"ned"`` (default) is the aerospace one, 3-2-1 Euler angles ``Rz(yaw) Ry(pitch)
Rx(roll)`` (or a quaternion, scalar first) from the body's forward-right-down axes into North-East-Down:
``v_ned = R v_body``; ``"enu"`` is ROS's (REP-103), from forward-left-up into East-North-Up, turned here into
the former (``R_ned = T R_enu F`` with ``T`` swapping east and north and flipping up, ``F = diag(1, -1, -1)``).
Angles in degrees or radians: :func:`angle_unit`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from ..errors import DataFileError, OptionError
from ..io.layout import FileFormat
from ..remedy import option
from ..sources import LogSamples, Magnetometer, Position, Source, median_position
from ..sources.motion import Motion
from .streams import ENU_MARK

__all__ = ["ANGLE_UNITS", "CONVENTIONS", "SamplesStreams", "StreamSpec", "angle_unit", "samples_source"]

CONVENTIONS = ("ned", "enu")
ANGLE_UNITS = ("auto", "deg", "rad")
#: ENU <-> NED (east and north swapped, up flipped) and FLU <-> FRD.
_T = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
_F = np.diag([1.0, -1.0, -1.0])
#: Angles all within this many radians in magnitude could be degrees of a vehicle that hardly moved, or
#: radians: the file is refused as ambiguous unless the unit is given.
AMBIGUOUS_RAD = 1.0
#: A time column in seconds by its name that steps by this much or more per row counts microseconds (PX4's
#: ``timestamp``: a magnetometer logged once in 17 minutes is no recording).
MICROSECONDS_STEP = 1000.0


@dataclass(frozen=True)
class StreamSpec:
    """The columns the caller named for each stream (None: found by name), and how to read the attitude."""

    attitude: Sequence[str | int] | None = None
    reference: Sequence[str | int] | None = None
    gyro: Sequence[str | int] | None = None
    accel: Sequence[str | int] | None = None
    time: Sequence[str | int] | None = None
    convention: Literal["ned", "enu"] = "ned"
    angle_unit: Literal["auto", "deg", "rad"] = "auto"
    gyro_unit: Literal["rad/s", "deg/s"] = "rad/s"


@dataclass(frozen=True)
class SamplesStreams:
    """What :func:`samples_source` read: the file as a :class:`Source`, the reference field's N/E/D rows (None
    when the file has none), where each stream came from (notes), and the rows read and dropped."""

    source: Source
    reference_ned: NDArray[np.float64] | None
    notes: tuple[str, ...]
    n_rows: int
    n_dropped: int
    columns: tuple[str, ...]
    column_indices: tuple[int, ...]
    header: bool
    n_columns: int
    hints: tuple[str, ...] = ()


def angle_unit(path: Path, angles: NDArray[np.float64], given: str) -> str:
    """``"deg"`` or ``"rad"`` for Euler angles (N, 3): given, or from the values. Any beyond 2π: degrees; any
    beyond :data:`AMBIGUOUS_RAD` (and none beyond 2π): radians (in degrees the vehicle's heading, roll and
    pitch would all have stayed within ±6.3°); all within it: refused as ambiguous."""
    if given != "auto":
        return given
    largest = float(np.nanmax(np.abs(angles))) if angles.size else 0.0
    if largest > 2 * math.pi + 1e-6:
        return "deg"
    if largest > AMBIGUOUS_RAD:
        return "rad"
    raise DataFileError(
        f"{path}: the attitude's angles all lie within ±{largest:.3g}: radians, or degrees of a vehicle that "
        f"hardly turned; say which with {option('angle_unit', 'deg')} or {option('angle_unit', 'rad')}"
    )


def _matrices(values: NDArray[np.float64], unit: str, convention: str) -> NDArray[np.float64]:
    """Body -> NED rotation matrices from (roll, pitch, yaw) or (w, x, y, z), in the convention given."""
    from scipy.spatial.transform import Rotation

    if values.shape[1] == 4:
        norms = np.linalg.norm(values, axis=1, keepdims=True)
        matrices = Rotation.from_quat(values[:, [1, 2, 3, 0]] / norms).as_matrix()
    else:
        roll, pitch, yaw = values.T
        matrices = Rotation.from_euler("ZYX", np.column_stack([yaw, pitch, roll]), degrees=unit == "deg").as_matrix()
    if convention == "enu":
        matrices = np.einsum("ij,njk,kl->nil", _T, matrices, _F)
    return np.asarray(matrices)


def samples_source(
    path: Path,
    columns: Sequence[str | int] | None,
    spec: StreamSpec,
    wanted: Sequence[str],
    location: tuple[float, float, float] | None = None,
    nonfinite: Literal["skip", "error"] = "skip",
) -> SamplesStreams:
    """The samples file as a :class:`Source` whose ``read_motion`` gives the magnetometer with the streams
    ``wanted`` holds (``attitude``, ``reference``, ``gyro``, ``accel``, ``time``, ``place``) that the file
    has, with the reference field's N/E/D rows and notes (where each came from). ``nonfinite="error"``
    refuses a row with a missing value in a column used, ``"skip"`` drops it (counted).

    For a file without a header, ``hints`` says which columns look like angles or a reference field (the
    content rule of :func:`magfit.io.columns.choose_columns_by_content`), for the message that asks for them.
    """
    from ..io import ChunkReader
    from ..io.streams import find_stream_columns, read_stream_columns, resolve_stream

    chosen = ChunkReader(path, columns=columns, nonfinite="skip")  # the magnetometer's columns and layout only
    fmt = chosen.format
    named = find_stream_columns(fmt.header) if fmt.header is not None else {}
    found = {}
    # The accelerometer is read beside an attitude even for a method that does not take it: the attitude's
    # convention is checked against its gravity (magfit.pipeline.streams, _check_attitude_up).
    for stream in (*wanted, *(("accel",) if "attitude" in wanted and "accel" not in wanted else ())):
        given = getattr(spec, stream, None)
        if given is not None:
            found[stream] = resolve_stream(path, fmt, stream, given)
        elif stream in named:
            found[stream] = named[stream]
    magnetometer_columns = tuple(chosen.column_indices)
    if fmt.kind == "npz":  # the keys are the columns: the magnetometer's by their names
        if fmt.header is None or not all(str(name) in fmt.header for name in chosen.columns):
            raise DataFileError(
                f"{path}: the magnetometer is columns of one 2-D key ({', '.join(map(str, chosen.columns))}); the "
                "other streams are read from 1-D keys beside three 1-D magnetometer keys"
            )
        magnetometer_columns = tuple(fmt.header.index(str(name)) for name in chosen.columns)
    for columns_of in found.values():
        if set(columns_of.indices) & set(magnetometer_columns):
            raise OptionError(
                f"{path}: the {columns_of.name} columns {columns_of.describe()} include the magnetometer's "
                f"({', '.join(map(str, chosen.columns))}); name each stream's own columns"
            )
    read = read_stream_columns(path, fmt, {"mag": magnetometer_columns, **{k: v.indices for k, v in found.items()}})
    # A missing fix does not drop the sample (the place is the median of the fixes); a quaternion far from
    # unit length (zeros where the estimator had none) is no attitude.
    good = np.all(np.isfinite(np.column_stack([v for k, v in read.items() if k != "place"])), axis=1)
    if "attitude" in read and read["attitude"].shape[1] == 4:
        norms = np.linalg.norm(read["attitude"], axis=1)
        good &= (norms > 0.5) & (norms < 1.5)
    n_dropped = int(np.count_nonzero(~good))
    if n_dropped and nonfinite == "error":
        first = int(np.flatnonzero(~good)[0]) + 1
        raise DataFileError(
            f"{path}: data row {first} holds a missing value (NaN, inf or empty) in a column used; pass "
            f"{option('nonfinite', 'skip')} to drop such rows"
        )
    rows = {name: values[good] for name, values in read.items()}
    if "gyro" in rows and spec.gyro_unit == "deg/s":
        rows["gyro"] = np.radians(rows["gyro"])
    if spec.convention == "enu":  # the IMU's forward-left-up axes into the attitude's forward-right-down ones
        for stream in ("gyro", "accel"):
            if stream in rows:
                rows[stream] = rows[stream] @ _F
    samples = rows["mag"]
    unit = chosen.unit or ""
    notes = [f"{path}: magnetometer {', '.join(map(str, chosen.columns))}"]
    if chosen.column_note:
        notes[0] += f" ({chosen.column_note})"
    if n_dropped:
        notes.append(
            f"{path}: {n_dropped} of {len(good)} rows dropped: a missing value in a column used (or a quaternion "
            "far from unit length)"
        )
    how = {True: "found by name", False: "as given"}
    for name, where in found.items():
        said = f", in {spec.gyro_unit}" if name == "gyro" else ""
        notes.append(f"{path}: {name} {where.describe()} ({how[where.by_name]}{said})")
    time_s = rows["time"][:, 0] * found["time"].scale if "time" in rows else np.arange(len(samples), dtype=float)
    if "time" in rows and len(time_s) > 1 and not np.all(np.diff(time_s) > 0):
        raise DataFileError(f"{path}: the time column {found['time'].describe()} does not increase row after row")
    if "time" in rows and len(time_s) > 1 and found["time"].scale == 1.0:
        step = float(np.median(np.diff(time_s)))
        if step >= MICROSECONDS_STEP:  # PX4's ulog2csv writes `timestamp` in microseconds
            time_s = time_s * 1e-6
            notes.append(f"{path}: the time column steps by {step:g} per row: microseconds (as PX4's timestamp)")
        elif step >= 1.0:
            notes.append(
                f"{path}: the time column steps by {step:g} s per row; if it counts milliseconds, name it time_ms"
            )
    attitude = None
    if "attitude" in rows:
        values = rows["attitude"]
        if values.shape[1] == 3:
            unit_used = angle_unit(path, values, spec.angle_unit)
            notes.append(
                f"{path}: attitude as roll, pitch, yaw in {'degrees' if unit_used == 'deg' else 'radians'}, "
                "3-2-1 (yaw, pitch, roll), body to "
                + ("NED" if spec.convention == "ned" else "ENU (ROS), turned into NED")
            )
            if spec.angle_unit == "auto" and unit_used == "rad":  # an assumption: said with the option that undoes it
                largest = float(np.nanmax(np.abs(values)))
                notes.append(
                    f"{path}: the attitude's angles ({found['attitude'].describe()}) all lie within ±{largest:.3g}: "
                    f"read as radians, assumed (in degrees the vehicle would hardly have turned); if they are "
                    f"degrees, give {option('angle_unit', 'deg')}"
                )
        else:
            unit_used = "rad"
            notes.append(f"{path}: attitude as a quaternion (w, x, y, z), body to {spec.convention.upper()}")
        attitude = _matrices(values, unit_used, spec.convention)
    position = None
    if "place" in rows:
        place = rows["place"]
        alt = place[:, 2] if place.shape[1] > 2 else np.zeros(len(place))
        position = median_position(place[:, 0], place[:, 1], alt, np.full(len(place), np.nan))
    if location is not None:  # the place given wins over the file's own columns
        position = Position(location[0], location[1], location[2], float("nan"), 1)
    reference_ned = rows.get("reference")
    if reference_ned is not None and spec.convention == "enu":
        reference_ned = reference_ned @ _T.T  # an ENU reference (east, north, up) into N, E, D
    magnetometer = Magnetometer(id="columns", description=", ".join(map(str, chosen.columns)), unit=unit,
                                n_samples=len(samples))  # fmt: skip
    motion = Motion(
        sensor="columns", unit=unit, time_s=time_s, samples=samples, magnetometer_frame="body",
        attitude=attitude, gyro=rows.get("gyro"), accel=rows.get("accel"),
        imu_frame="body" if "gyro" in rows or "accel" in rows else "",
        sources={k: f"columns {found[k].describe()}" for k in ("attitude", "gyro", "accel") if k in found},
        frames={k: "body" if spec.convention == "ned" else f"body (FRD, {ENU_MARK} FLU)"
                for k in ("attitude", "gyro", "accel") if k in found},
        position=position, notes=(),
    )  # fmt: skip

    def read_samples_only(chosen_magnetometer: Magnetometer) -> LogSamples:
        return LogSamples(chosen_magnetometer, samples, time_s, tuple(map(str, chosen.columns)))

    source = Source(
        path=path, kind="samples", format=fmt.describe(),
        time_base="seconds (the time column)" if "time" in rows else "none (rows)",
        magnetometers=(magnetometer,), position=position, _reader=read_samples_only, _motion=lambda m: motion,
    )  # fmt: skip
    hints: tuple[str, ...] = ()
    if fmt.header is None and fmt.kind == "text":
        hints = _content_hints(path, fmt)
    return SamplesStreams(
        source, reference_ned, tuple(notes), len(good), n_dropped, tuple(map(str, chosen.columns)),
        tuple(chosen.column_indices), fmt.header is not None, fmt.n_columns, hints,
    )  # fmt: skip


def _content_hints(path: Path, fmt: FileFormat) -> tuple[str, ...]:
    """Which columns of a file without a header look like angles or a reference field, in words (0-based
    numbers, as the options take them)."""
    from ..io.selection import text_content_choice

    try:
        choice = text_content_choice(path, fmt)
    except (DataFileError, ValueError):
        return ()
    hints = []
    if choice.angles:
        hints.append(f"columns {','.join(map(str, choice.angles))} (0-based) look like angles")
    for triple, why in choice.passed:
        if "world" in why or "noise" in why:
            hints.append(f"columns {','.join(map(str, triple))} (0-based) like a reference field")
    if len(choice.constant) >= 3:
        hints.append(f"columns {','.join(map(str, choice.constant))} (0-based) are constant: a reference field?")
    return tuple(hints)
