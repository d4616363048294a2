"""The samples a command reads from FILE: a samples file's columns, or a flight log's or bag's compasses.

``plot``, ``compare``, ``report`` and ``apply`` take a log as ``calibrate`` does: ``--sensor ID`` chooses a
compass (:meth:`magfit.sources.Source.read`), and what the log says about it (a compass logged too slowly, a
calibration undone with the log's parameters) is printed as a warning. :func:`with_streams` gives ``plot``,
``compare`` and ``report`` the streams the vector and gyro methods need, as ``calibrate`` finds them.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import click
import numpy as np
from numpy.typing import NDArray

from ..errors import DataFileError
from ._common import Nonfinite, warn

if TYPE_CHECKING:
    from ..sources import Source

#: ``--sensor`` of the commands that read samples.
sensor_option = click.option(
    "--sensor",
    metavar="ID",
    help="The compass of a flight log or bag (its id or device id, as 'magfit inspect FILE' lists them). Default: "
    "each compass of the log (plot: the only one).",
)


@dataclass(frozen=True, eq=False)
class Recording:
    """One magnetometer's samples as a command reads them.

    Attributes
    ----------
    name : str
        ``mag.csv``, or ``flight.bin (MAG/1)`` for a log's compass.
    samples : ndarray, shape (N, 3)
    columns : tuple
        The columns or fields they came from.
    n_rows, n_skipped : int
        Rows read and rows skipped (NaN or inf).
    column_note : str or None
        For a file without a header, why these columns.
    unit : str or None
        A log's own unit (``mG``, ``G``, ``uT``), None for a samples file.
    sensor : str or None
        The log's compass id.
    time_s : ndarray or None
        A log's time stamps, seconds on its time base.
    source : Source or None
        The log it was read from (opened once: its other streams are read from it when a method needs them).
    """

    name: str
    samples: NDArray[np.float64]
    columns: tuple[Any, ...]
    n_rows: int
    n_skipped: int = 0
    column_note: str | None = None
    unit: str | None = None
    sensor: str | None = None
    time_s: NDArray[np.float64] | None = None
    source: Source | None = None


def is_log(path: Path) -> bool:
    """True when ``path`` is a flight log or bag (by its first bytes)."""
    from ..sources import log_kind

    return log_kind(path) is not None


def read_recordings(
    path: Path,
    *,
    columns: list[str | int] | None,
    nonfinite: Nonfinite,
    sensor: str | None,
    every: bool = True,
) -> list[Recording]:
    """``path``'s magnetometers: a samples file's three columns, or a log's compass ``sensor`` names; without it
    every usable compass of a log (``every``) or the only one (several refused, naming them)."""
    if not is_log(path):
        from ..io import read_samples

        # --sensor picks one compass of a samples file that interleaves several (I=1); read_samples refuses it
        # on a file that does not, and refuses an interleaved file without it.
        table = read_samples(path, columns=columns, nonfinite=nonfinite, sensor=sensor)
        if table.n_skipped:
            warn(
                f"{path}: skipped {table.n_skipped} of {table.n_rows} rows with NaN or inf values, values beyond "
                "±1e150 or a last line cut short"
            )
        return [
            Recording(
                path.name,
                table.samples,
                tuple(table.columns),
                table.n_rows,
                table.n_skipped,
                table.column_note,
                unit=table.unit,  # as the column names (or their converter) state it
            )
        ]
    if columns is not None:
        raise click.UsageError("--columns chooses the columns of a samples file; a log's compass is chosen by --sensor")
    from ..sources import open_source

    source = open_source(path, everything=False)
    usable = [m.id for m in source.magnetometers if m.problem is None and m.n_samples > 0]
    chosen: list[str | None] = [sensor] if sensor is not None or not every or len(usable) < 2 else list(usable)
    recordings = []
    for note in source.notes:  # the whole log's (a last message cut short): once, not with each compass
        warn(f"{path}: {note}")
    for sensor_id in chosen:
        read = source.read(sensor_id)
        magnetometer = read.magnetometer
        for note in read.notes:
            warn(f"{path} ({magnetometer.id}): {note}")
        if len(read.samples) == 0:
            raise DataFileError(f"{path} ({magnetometer.id}): holds no finite samples")
        recordings.append(
            Recording(
                name=f"{path.name} ({magnetometer.id})",
                samples=read.samples,
                columns=read.columns,
                n_rows=len(read.samples),
                unit=magnetometer.unit or None,
                sensor=magnetometer.id,
                time_s=read.time_s,
                source=source,
            )
        )
    return recordings


def with_streams(
    recording: Recording,
    methods: tuple[str, ...],
    unit: str | None,
    *,
    path: Path | None = None,
    columns: list[str | int] | None = None,
    nonfinite: Nonfinite = "skip",
) -> tuple[NDArray[np.float64], dict[str, Any]]:
    """The samples and the log's streams for the methods that need them (vector, gyro), where the log has them;
    for a samples file (``path``), the streams its columns hold, found by name (docs/file-formats.md).

    All the methods are then compared on the samples those streams cover.
    """
    from ..pipeline.streams import method_streams, stream_names

    names = stream_names(methods)  # what they need, and the optional streams they take (the accelerometer)
    if not names.needed:
        return recording.samples, {}
    source, sensor, reference_ned = recording.source, recording.sensor, None
    if (source is None or sensor is None) and path is not None and recording.sensor is None:
        from ..pipeline.table import StreamSpec, samples_source

        wanted = ["attitude", "reference", "place", "gyro", "accel", "time"]
        read = samples_source(path, columns, StreamSpec(), wanted, None, nonfinite)
        source, sensor, reference_ned = read.source, "columns", read.reference_ned
    if source is None or sensor is None:
        return recording.samples, {}
    found = method_streams(
        source,
        sensor,
        names.needed,
        optional=[name for name in names.optional if name != "inclination_deg" or source.position is not None],
        unit=unit or recording.unit,
        available=True,
        reference_ned=reference_ned,
    )
    for note in found.notes:
        warn(note)
    return found.samples, found.options
