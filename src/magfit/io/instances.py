"""A samples file that interleaves several magnetometers, one column saying which row is whose.

mavlogdump writes every ArduPilot compass as a ``MAG`` row with its instance ``I``; a CSV of several sensors
often carries ``device_id``, ``instance`` or ``sensor_id``. Fitted as one cloud, two compasses give a
calibration of neither: such a file is read one magnetometer at a time, chosen by a *sensor id* of the form
``NAME=VALUE`` (``I=1``, ``device_id=592905``) or by the value alone.

The column is found by its name (:data:`INSTANCE_NAMES`) and taken when its head holds a few whole numbers
(:func:`instance_column`: ``I`` may be a current too). The values a file holds are listed from its head
when a reader opens it (:func:`head_values`: interleaved compasses show there at once) and from the whole
file by :func:`sensor_listing` (what ``magfit inspect`` shows).
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import DataFileError
from ..remedy import option
from .columns import Converter
from .layout import (
    FileFormat,
    cell_kind,
    decode_lines,
    pandas_module,
    pandas_options,
    read_head,
    sniff,
    split_fields,
)
from .selection import columns_origin, resolve_table_columns
from .sources import check_file, file_error

__all__ = [
    "INSTANCE_NAMES",
    "MAX_INSTANCES",
    "SensorColumn",
    "SensorListing",
    "choose",
    "find_instance_column",
    "head_sensors",
    "head_values",
    "instance_column",
    "interleaved_error",
    "sensor_id",
    "sensor_listing",
    "value_text",
]

#: Column names (lower-case, the part after the last ``.``: ``MAG.I`` is ``i``) that say which sensor a row is
#: from: mavlogdump's ``I`` (ArduPilot's instance), PX4's ``device_id``, and the usual spellings.
INSTANCE_NAMES = frozenset(
    {
        "i", "instance", "inst", "sensor_instance", "mag_instance", "compass_instance",
        "device_id", "deviceid", "dev_id", "devid", "sensor_id", "sensorid", "mag_id", "compass_id", "imu_id",
    }
)  # fmt: skip
#: More distinct values than this in a file's head: the column is not an instance (a vehicle has up to 3 or 4
#: compasses; a current or a counter named I has many values).
MAX_INSTANCES = 8
#: Rows read for the listing of a whole file, per block (one block in memory at a time).
LISTING_ROWS = 1 << 20


@dataclass(frozen=True)
class SensorColumn:
    """The column of a file that says which magnetometer each row is from, and which one is read.

    Attributes
    ----------
    index : int
        Its 0-based position.
    name : str
        Its header name (``I``, ``device_id``).
    value : float or None
        The magnetometer read: rows with another value are passed over. None when the file holds only one
        (``expected`` then guards against another appearing further in).
    expected : float or None
        With ``value`` None, the one value seen in the file's head: a row with another is an error.
    """

    index: int
    name: str
    value: float | None = None
    expected: float | None = None


def value_text(value: float) -> str:
    """A value as a sensor id shows it: ``1`` and ``592905``, not ``1.0``."""
    return str(int(value)) if float(value).is_integer() else repr(float(value))


def sensor_id(name: str, value: float) -> str:
    """The id of the magnetometer whose rows hold ``value`` in column ``name``: ``I=1``."""
    return f"{name}={value_text(value)}"


def find_instance_column(header: Sequence[str] | None, exclude: Sequence[int] = ()) -> int | None:
    """The position of the first column named like an instance (:data:`INSTANCE_NAMES`), not in ``exclude``."""
    if header is None:
        return None
    for index, name in enumerate(header):
        if index not in exclude and name.strip().lstrip("\ufeff").rsplit(".", 1)[-1].lower() in INSTANCE_NAMES:
            return index
    return None


def instance_column(path: Path, fmt: FileFormat, exclude: Sequence[int]) -> tuple[int, list[float]] | None:
    """The instance column of a text file and the values of its head, or None.

    A column named like one whose head holds anything but a few whole numbers (at most
    :data:`MAX_INSTANCES`, none negative) is not taken for one: ``I`` may as well be a current in amperes.
    """
    column = find_instance_column(fmt.header, exclude)
    if column is None:
        return None
    values = head_values(path, fmt, column)
    if len(values) > MAX_INSTANCES or not all(value >= 0 and value.is_integer() for value in values):
        return None
    return column, values


def head_values(path: Path, fmt: FileFormat, column: int) -> list[float]:
    """The distinct numbers in ``column`` over the data rows of the file's head, sorted."""
    head, truncated = read_head(path)
    _, lines, _ = decode_lines(path, head, truncated)
    values = set()
    for line in lines[fmt.data_line :]:
        fields = split_fields(line, fmt.delimiter)
        if len(fields) == fmt.n_columns and cell_kind(fields[column], fmt.decimal) == "number":
            values.add(float(fields[column].replace(",", ".") if fmt.decimal == "," else fields[column]))
    return sorted(value for value in values if math.isfinite(value))


def choose(path: Path, name: str, sensor: str, values: Sequence[float]) -> float:
    """The value of column ``name`` that ``sensor`` (``I=1``, ``i=1`` or ``1``) names."""
    wanted, _, text = sensor.strip().rpartition("=")
    if wanted and wanted.strip().lower() != name.strip().lower():
        raise file_error(
            path,
            f"holds no column {wanted.strip()!r}; its magnetometers are told apart by {name!r}: {_ids(name, values)}",
        )
    try:
        return float(text)
    except ValueError:
        raise file_error(
            path, f"{option('sensor', sensor)} is not a value of column {name!r}; choose one of {_ids(name, values)}"
        ) from None


def _ids(name: str, values: Sequence[float]) -> str:
    return ", ".join(sensor_id(name, value) for value in values[:12]) + (" ..." if len(values) > 12 else "")


def interleaved_error(path: Path, name: str, values: Sequence[float], where: str = "") -> DataFileError:
    """The refusal of a file whose rows come from several magnetometers when none was chosen."""
    ids = [sensor_id(name, value) for value in values]
    return file_error(
        path,
        f"{where}interleaves {len(values)} magnetometers in column {name!r} ({_ids(name, values)}): they are not "
        f"one cloud of samples; fit one at a time with {option('sensor', ids[0])}",
    )


def head_sensors(path: str | os.PathLike[str]) -> tuple[str, ...]:
    """The sensor ids in the head of a text file with an instance column (``("I=0", "I=1")``); empty without one.

    Cheap (the head only): what a caller needs to decide whether a file is read one magnetometer at a time.
    A file that cannot be read is empty here; its reader reports it.
    """
    try:
        file = check_file(path)
        fmt = sniff(file)
        if fmt.kind != "text" or fmt.header is None:
            return ()
        indices, _ = resolve_table_columns(file, fmt, None)
    except DataFileError:
        return ()
    found = instance_column(file, fmt, indices)
    if found is None:
        return ()
    column, values = found
    return tuple(sensor_id(fmt.header[column], value) for value in values)


@dataclass(frozen=True)
class SensorListing:
    """The magnetometers of a samples file that interleaves several (:func:`sensor_listing`).

    Attributes
    ----------
    column : str
        The column that tells them apart (``I``).
    columns : tuple of 3 str
        The x, y, z columns every one of them is read from.
    counts : dict of str to int
        Finite samples per sensor id (``{"I=0": 5210, "I=1": 5208}``), in the order of the values.
    values : dict of str to float
        The value of each sensor id.
    unit : str or None
        As the column names or their converter say.
    converter : Converter or None
        The converter recognised by the column names.
    """

    column: str
    columns: tuple[str, str, str]
    counts: dict[str, int]
    values: dict[str, float]
    unit: str | None
    converter: Converter | None


def sensor_listing(path: str | os.PathLike[str]) -> SensorListing | None:
    """The magnetometers a text file interleaves, counted over the whole file; None without an instance column.

    Raises
    ------
    DataFileError
        The file's layout or columns cannot be read (as :func:`magfit.io.read_samples` reports them).
    """
    file = check_file(path)
    fmt = sniff(file)
    if fmt.kind != "text" or fmt.header is None:
        return None
    indices, labels = resolve_table_columns(file, fmt, None)
    found = instance_column(file, fmt, indices)
    if found is None:
        return None
    column = found[0]
    used = sorted({*indices, column})
    counts: dict[float, int] = {}
    pandas = pandas_module()
    try:
        with open(file, "rb") as handle:
            handle.seek(fmt.data_offset)
            with pandas.read_csv(handle, chunksize=LISTING_ROWS, **pandas_options(fmt, used)) as reader:
                for frame in reader:
                    block: Any = frame.to_numpy(dtype=np.float64)
                    finite = np.isfinite(block).all(axis=1)
                    values, numbers = np.unique(block[finite, used.index(column)], return_counts=True)
                    for value, number in zip(values.tolist(), numbers.tolist(), strict=True):
                        counts[value] = counts.get(value, 0) + number
    except (ValueError, TypeError) as error:  # a cell that is not a number: the reader's own message names it
        raise file_error(
            file,
            f"cannot be listed ({' '.join(str(error).split())[:160]}); magfit.io.read_samples names the line",
        ) from None
    name = fmt.header[column]
    unit, converter = columns_origin(labels, fmt.header)
    ordered = sorted(counts)
    return SensorListing(
        column=name,
        columns=labels,
        counts={sensor_id(name, value): counts[value] for value in ordered},
        values={sensor_id(name, value): value for value in ordered},
        unit=unit,
        converter=converter,
    )
