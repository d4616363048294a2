"""A samples file's other streams: the attitude, the reference field, the gyroscope, the accelerometer, the time
and the place, found by their column names or named by the caller, and read beside the magnetometer.

Names (after the normalisation of :func:`magfit.io.columns.normalise_name`: lower case, units dropped,
camelCase split), each group complete or not at all:

- attitude: ``roll, pitch, yaw`` (or ``phi, theta, psi``; ``heading`` for yaw), or a quaternion
  ``qw, qx, qy, qz`` (``q0..q3``, ``quat_w``...), scalar first;
- reference: ``ref_n, ref_e, ref_d`` (``ref``/``reference``/``model``/``wmm``/``igrf``/``expected`` with the
  axis ``n e d`` or ``north east down``), in the samples' unit, in the world frame (NED);
- gyroscope: ``gx, gy, gz``, ``gyro_x``..., ``wx``...: rad/s (the methods refuse what looks like °/s);
- accelerometer: ``ax, ay, az``, ``acc_x``, ``accel_x``...: any unit (gravity's direction is what counts);
- time: ``t``, ``time``, ``time_s``, ``timestamp``, ``seconds`` (seconds), ``time_ms`` (ms), ``time_us``,
  ``timeus`` (µs); a clock's name before or after (``gps_time``, ``GPS_Time_s``, ``unix_time``, ``time_unix``,
  ``timestamp_s``, ``utc_time``, ``epoch_ms``, ``time_boot_ms``) with the unit its last word says (``s``,
  ``ms``, ``us``, ``ns``), seconds when it says none (the caller reads microseconds from the rows' spacing);
- place: ``lat``/``latitude``, ``lon``/``lng``/``longitude`` (degrees), optionally ``alt`` (metres).

Columns are given as names or 0-based numbers, as ``columns=`` takes the magnetometer's.
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from ..errors import OptionError
from ..remedy import option
from .columns import normalise_name
from .layout import FileFormat, pandas_module, pandas_options
from .selection import _match_name
from .sources import file_error

__all__ = ["STREAM_SIZES", "StreamColumns", "find_stream_columns", "read_stream_columns", "resolve_stream"]

#: How many columns each stream has (the attitude: 3 angles or a 4-component quaternion).
STREAM_SIZES: dict[str, tuple[int, ...]] = {
    "attitude": (3, 4),
    "reference": (3,),
    "gyro": (3,),
    "accel": (3,),
    "time": (1,),
    "place": (2, 3),
}

_ANGLES = (("roll", "phi"), ("pitch", "theta"), ("yaw", "psi", "heading", "hdg"))
_QUATERNION = re.compile(r"^(?:att_|attitude_|orientation_)?(?:q|quat|quaternion)_?([wxyz0123])$")
_REFERENCE = re.compile(r"^(?:ref|reference|model|wmm|igrf|expected)_?(?:field_|mag_|b_)?(n|e|d|north|east|down)$")
_GYRO = re.compile(r"^(?:imu_)?(?:g|gyr|gyro|gyroscope|w|omega|rate)_?([xyz])$")
_ACCEL = re.compile(r"^(?:imu_)?(?:a|acc|accel|accl|accelerometer)_?([xyz])$")
_TIME = {"t": 1.0, "time": 1.0, "time_s": 1.0, "timestamp": 1.0, "seconds": 1.0, "sec": 1.0, "time_ms": 1e-3,
         "timems": 1e-3, "time_us": 1e-6, "timeus": 1e-6, "time_u_s": 1e-6}  # fmt: skip
#: A time column named after its clock (``gps_time``, ``unix_time_ms``, ``time_boot_ms``, ``timestamp_s``): the
#: clock before or after the word, the unit last (:data:`_TIME_UNITS`).
_CLOCK = r"(?:gps|unix|utc|epoch|posix|system|sys|boot|log|sample|rtc)"
_TIMED = re.compile(
    rf"^(?:(?:{_CLOCK}_)?(?:t|time|timestamp|time_stamp|stamp|seconds|sec)(?:_{_CLOCK})?|epoch|unix|posix)"
    r"(?:_(?P<unit>[a-z_]+))?$"
)
_TIME_UNITS = {"s": 1.0, "sec": 1.0, "secs": 1.0, "seconds": 1.0, "ms": 1e-3, "msec": 1e-3, "us": 1e-6,
               "usec": 1e-6, "u_s": 1e-6, "ns": 1e-9, "nsec": 1e-9}  # fmt: skip
_LAT = ("lat", "latitude", "lat_deg")
_LON = ("lon", "lng", "long", "longitude", "lon_deg")
_ALT = ("alt", "altitude", "alt_m", "height")


@dataclass(frozen=True)
class StreamColumns:
    """Where one stream is in a file: its columns (0-based) and their labels, and how it was found."""

    name: str
    indices: tuple[int, ...]
    labels: tuple[str, ...]
    by_name: bool
    scale: float = 1.0  # the time column's seconds per unit

    def describe(self) -> str:
        return ", ".join(self.labels)


def _key(name: str) -> str:
    """A name as compared: normalised (:func:`normalise_name`; units dropped) without the ``(s)`` of time."""
    return normalise_name(name).strip("_ ")


def find_stream_columns(header: Sequence[str]) -> dict[str, StreamColumns]:
    """The streams a header names (module docstring), each only when all its columns are there."""
    keys = [_key(name) for name in header]
    found: dict[str, StreamColumns] = {}

    def add(stream: str, indices: Sequence[int], scale: float = 1.0) -> None:
        found[stream] = StreamColumns(stream, tuple(indices), tuple(header[i] for i in indices), True, scale)

    angles = [next((i for i, key in enumerate(keys) if key in names), None) for names in _ANGLES]
    if all(i is not None for i in angles):
        add("attitude", [i for i in angles if i is not None])
    else:
        parts: dict[str, int] = {}
        for i, key in enumerate(keys):
            match = _QUATERNION.match(key)
            if match:
                parts.setdefault({"0": "w", "1": "x", "2": "y", "3": "z"}.get(match.group(1), match.group(1)), i)
        if set(parts) == set("wxyz"):
            add("attitude", [parts[a] for a in "wxyz"])
    for stream, pattern, axes in (
        ("reference", _REFERENCE, ("n", "e", "d")),
        ("gyro", _GYRO, ("x", "y", "z")),
        ("accel", _ACCEL, ("x", "y", "z")),
    ):
        parts = {}
        for i, key in enumerate(keys):
            match = pattern.match(key)
            if match:
                parts.setdefault(match.group(1)[0], i)
        if set(parts) == set(axes):
            add(stream, [parts[a] for a in axes])
    raw = [name.strip().lower().replace(" ", "_").replace("[", "_").replace("]", "").rstrip("_") for name in header]
    for i, name in enumerate(raw):
        unit = {"time_(s)": 1.0, "time_(ms)": 1e-3, "time_(us)": 1e-6}.get(name, _TIME.get(name, _TIME.get(keys[i])))
        if unit is None:
            unit = _clock_time_unit(name) if _TIMED.match(name) else _clock_time_unit(keys[i])
        if unit is not None:
            add("time", [i], unit)
            break
    lat = next((i for i, key in enumerate(keys) if key in _LAT), None)
    lon = next((i for i, key in enumerate(keys) if key in _LON), None)
    if lat is not None and lon is not None:
        alt = next((i for i, key in enumerate(keys) if key in _ALT), None)
        add("place", [lat, lon] + ([alt] if alt is not None else []))
    return found


def _clock_time_unit(name: str) -> float | None:
    """Seconds per unit of a time column named after its clock (:data:`_TIMED`), 1.0 when the name says no
    unit; None when the name is no time column's."""
    match = _TIMED.match(name)
    if match is None:
        return None
    unit = match.group("unit")
    return 1.0 if unit is None else _TIME_UNITS.get(unit)


def resolve_stream(path: Path, fmt: FileFormat, stream: str, given: Sequence[str | int]) -> StreamColumns:
    """The columns ``given`` for ``stream`` (names, ``column N`` labels or 0-based numbers) as positions; a
    time column's unit from its name as :func:`find_stream_columns` reads it (seconds when it says none)."""
    sizes = STREAM_SIZES[stream]
    items = list(given)
    if len(items) not in sizes:
        wanted = " or ".join(str(size) for size in sizes)
        raise OptionError(
            f"{option(stream, '...')} takes {wanted} columns (names or 0-based numbers), got {len(items)}: {items}"
        )
    labels = [fmt.column_label(i) for i in range(fmt.n_columns)]
    positions = []
    for item in items:
        if isinstance(item, (int, np.integer)) and not isinstance(item, bool):
            if not 0 <= int(item) < fmt.n_columns:
                raise file_error(
                    path, f"{stream} column {item} is out of range: the file has {fmt.n_columns} columns, 0 to "
                    f"{fmt.n_columns - 1} (0-based)",
                )  # fmt: skip
            positions.append(int(item))
        else:
            positions.append(_match_name(path, str(item), labels, fmt.header is not None))
    chosen = tuple(labels[i] for i in positions)
    scale = 1.0
    if stream == "time" and fmt.header is not None and "time" in (named := find_stream_columns(chosen)):
        scale = named["time"].scale
    return StreamColumns(stream, tuple(positions), chosen, False, scale)


def read_stream_columns(
    path: Path, fmt: FileFormat, columns: Mapping[str, Sequence[int]]
) -> dict[str, NDArray[np.float64]]:
    """Every row of the columns each stream names, as float64 (NaN where a cell is empty), in one pass.

    The rows are the file's data rows in order (for text, blank lines skipped), so that the streams and
    the magnetometer stay row for row together; the caller drops rows with a NaN in any of them.
    """
    used = sorted({i for indices in columns.values() for i in indices})
    if fmt.kind == "npy":
        table = np.asarray(np.load(path, mmap_mode="r", allow_pickle=False), dtype=np.float64)
        if table.ndim != 2:
            raise file_error(path, f"holds a {table.ndim}-D array; the streams need one (N, k) table")
        values = table[:, used]
    elif fmt.kind == "text":
        with open(path, "rb") as handle:
            handle.seek(fmt.data_offset)
            try:
                frame = pandas_module().read_csv(handle, **pandas_options(fmt, used))
            except ValueError as error:
                raise file_error(path, f"cannot read the columns {used} as numbers ({error})") from None
        values = frame.to_numpy(dtype=np.float64)
    elif fmt.kind == "npz" and fmt.header is not None:  # one 1-D key per column, the keys in the header's order
        with np.load(path, allow_pickle=False) as members:
            arrays = [np.asarray(members[fmt.header[i]], dtype=np.float64) for i in used]
        if any(array.ndim != 1 or len(array) != len(arrays[0]) for array in arrays):
            shapes = ", ".join(f"{fmt.header[i]} {array.shape}" for i, array in zip(used, arrays, strict=True))
            raise file_error(path, f"the streams need 1-D keys of one length, one value per sample: {shapes}")
        values = np.column_stack(arrays)
    else:
        raise file_error(path, "the attitude, reference and motion columns are read from text, .npy or .npz files")
    return {name: values[:, [used.index(i) for i in indices]] for name, indices in columns.items()}
