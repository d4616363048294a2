"""The types a recording's reader fills: its magnetometers, their samples, its position, the Source.

Every reader (``ulog``, ``dataflash``, ``tlog``, ``rosbag``, ``mavlogdump``, ``motion``) imports these from here,
and :mod:`magfit.sources` re-exports them; so the package's ``__init__`` (which dispatches to the readers) is
imported by no reader, and the data flow one way.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from ..errors import DataFileError, OptionError
from ..remedy import option
from .position import Position, median_position

if TYPE_CHECKING:
    from .motion import Motion

__all__ = ["SLOW_RATE_HZ", "LogSamples", "Magnetometer", "Position", "Source", "median_position", "strided"]


#: Below this rate a magnetometer is flagged as logged too slowly for a fit (a tumble lasts about a minute:
#: at 1 Hz that is 60 samples, too few to tell the directions apart).
SLOW_RATE_HZ = 5.0


@dataclass(frozen=True)
class Magnetometer:
    """One magnetometer stream in a recording.

    Attributes
    ----------
    id : str
        What ``--sensor`` takes: ``sensor_mag/0`` (ULog topic/instance), ``MAG/1`` (DataFlash compass index,
        0-based), ``columns`` for a samples file.
    description : str
        What it is, in words (``raw sensor_mag, device_id 592905``).
    unit : str
        The unit of its samples (``G``, ``mG``, or empty for an unknown unit).
    n_samples : int
        Samples in the recording.
    start_s, end_s : float
        First and last time stamp, in seconds on the recording's time base (NaN when it has none).
    device_id : int or None
        The firmware's device id, which the exported calibration must be written for.
    raw : bool
        True when the samples are the sensor's raw field as logged; False when :meth:`Source.read` undoes
        the firmware's calibration with the log's parameters (``notes`` says with which).
    notes : tuple of str
        What a user must know about this stream (too slow, calibration undone, motor compensation ...).
    problem : str or None
        Why the stream cannot be fitted (a calibration that cannot be undone), or None.
    slot : int or None
        The firmware's calibration slot its calibration is written to, 0-based: ArduPilot's compass index
        (``COMPASS_OFS_*`` is 0, ``COMPASS_OFS2_*`` is 1), PX4's ``CAL_MAGn`` index (the one whose
        ``CAL_MAGn_ID`` is this device, else the first free one). None when unknown (a samples file).
    calibration_in_use : str or None
        Set when the samples carry the firmware's calibration and the log does not say which (a telemetry log
        without the parameters): why, in words. A fit on them is a residual correction on top of that
        calibration, which no firmware export may write in its place.
    """

    id: str
    description: str
    unit: str
    n_samples: int
    start_s: float = float("nan")
    end_s: float = float("nan")
    device_id: int | None = None
    raw: bool = True
    notes: tuple[str, ...] = ()
    problem: str | None = None
    slot: int | None = None
    calibration_in_use: str | None = None

    @property
    def span_s(self) -> float:
        """Seconds between the first and the last sample (NaN without time stamps)."""
        return self.end_s - self.start_s

    @property
    def rate_hz(self) -> float:
        """Mean sample rate over the span (NaN without time stamps or with fewer than two samples)."""
        span = self.span_s
        if self.n_samples < 2 or not np.isfinite(span) or span <= 0:
            return float("nan")
        return (self.n_samples - 1) / span


@dataclass(frozen=True)
class LogSamples:
    """The samples of one magnetometer, read from a recording.

    Attributes
    ----------
    magnetometer : Magnetometer
        Which stream they are.
    samples : ndarray, shape (N, 3)
        The sensor's field, in ``magnetometer.unit`` (the firmware's calibration undone when it was applied).
    time_s : ndarray, shape (N,)
        Their time stamps in seconds (the recording's time base).
    columns : tuple of str
        The fields the samples came from (``x, y, z`` or ``MagX, MagY, MagZ``).
    notes : tuple of str
        What was done to them (the calibration undone, and with which parameters).
    every : int
        One record in every ``every`` of the stream was read (``max_samples``, or a reader's own bound on
        a long log; the notes say which); 1 when every record was.
    """

    magnetometer: Magnetometer
    samples: NDArray[np.float64]
    time_s: NDArray[np.float64]
    columns: tuple[str, ...]
    notes: tuple[str, ...] = ()
    every: int = 1


@dataclass(frozen=True)
class Source:
    """What a recording holds: its format, magnetometers and other logged streams.

    Attributes
    ----------
    path : Path
        The file, as the user named it.
    kind : str
        ``"ulog"``, ``"dataflash"``, ``"tlog"`` or ``"samples"`` (text, npy, npz: read by :mod:`magfit.io`).
    format : str
        The format in words (``PX4 ULog, PX4 v1.14.0``).
    time_base : str
        What the time stamps count (``microseconds since boot``).
    magnetometers : tuple of Magnetometer
        Every magnetometer stream, fit-able or not (see ``Magnetometer.problem``).
    other : tuple of str
        The other streams logged, with their sample counts (``vehicle_attitude (2 310)``).
    notes : tuple of str
        What a user must know about the whole file (bytes skipped as damaged ...).
    position : Position or None
        Where and when, from the log's own 3-D GNSS fixes (flight logs), or None.
    identity : str or None
        The vehicle's own identity, read in the same pass: the flight controller's board and unique id
        (:mod:`magfit.sources.identity`); None when the log does not say (a tlog, a bag, a samples file).

    :meth:`read` gives a magnetometer's samples; :meth:`read_motion` gives them with the attitude, gyroscope
    and accelerometer at their time stamps (:class:`magfit.sources.motion.Motion`).
    """

    path: Path
    kind: str
    format: str
    time_base: str
    magnetometers: tuple[Magnetometer, ...]
    other: tuple[str, ...] = ()
    notes: tuple[str, ...] = ()
    position: Position | None = None
    identity: str | None = None
    _reader: Callable[[Magnetometer], LogSamples] | None = field(default=None, repr=False, compare=False)
    _motion: Callable[[Magnetometer], Motion] | None = field(default=None, repr=False, compare=False)
    #: A reader that reads only a regular stride of a long stream's records (``max_samples``), when the
    #: format can (DataFlash, ULog); other sources are read whole and thinned after.
    _bounded_reader: Callable[[Magnetometer, int | None], LogSamples] | None = field(
        default=None, repr=False, compare=False
    )

    def magnetometer(self, sensor: str | None) -> Magnetometer:
        """The magnetometer ``sensor`` names (its id, or its device id), or the only usable one when None.

        Raises
        ------
        DataFileError
            No such sensor (the ids listed); several usable and none chosen (``--sensor`` asked for); none
            usable (each one's reason).
        """
        listing = "; ".join(f"{m.id} ({m.description})" for m in self.magnetometers)
        if sensor is not None:
            for candidate in self.magnetometers:
                if sensor == candidate.id or (candidate.device_id is not None and sensor == str(candidate.device_id)):
                    return candidate
            raise DataFileError(f"{self.path}: holds no magnetometer {sensor!r}; it holds: {listing or 'none'}")
        usable = [m for m in self.magnetometers if m.problem is None and m.n_samples > 0]
        if len(usable) == 1:
            return usable[0]
        if not usable:
            if not self.magnetometers:
                raise DataFileError(f"{self.path}: this {self.format} holds no magnetometer data")
            reasons = "; ".join(f"{m.id}: {m.problem or 'no samples'}" for m in self.magnetometers)
            raise DataFileError(f"{self.path}: no magnetometer in this {self.format} can be fitted ({reasons})")
        ids = ", ".join(m.id for m in usable)
        raise DataFileError(
            f"{self.path}: holds {len(usable)} magnetometers that can be fitted ({listing}); choose one with "
            f"{option('sensor', 'ID')} (one of {ids})"
        )

    def read(self, sensor: str | None = None, *, max_samples: int | None = None) -> LogSamples:
        """The samples of the magnetometer ``sensor`` names (see :meth:`magnetometer`).

        ``max_samples``: at most this many, a regular stride over the whole recording (every k-th record, k
        the least that keeps within it; the notes say so); None reads every one. A DataFlash log or a ULog
        reads only those records, so the memory grows with ``max_samples``, not with the log.

        Raises
        ------
        DataFileError
            As :meth:`magnetometer`, or the stream's ``problem`` (a calibration that cannot be undone).
        OptionError
            ``max_samples`` below 1.
        """
        chosen = self.magnetometer(sensor)
        if chosen.problem is not None:
            raise DataFileError(f"{self.path}: {chosen.id} cannot be fitted: {chosen.problem}")
        if max_samples is not None and max_samples < 1:
            raise OptionError(f"max_samples must be a positive number of samples, not {max_samples}")
        if self._bounded_reader is not None:
            return self._bounded_reader(chosen, max_samples)
        if self._reader is None:
            raise DataFileError(f"{self.path}: is a samples file; read it with magfit.io.read_samples")
        return strided(self._reader(chosen), max_samples)

    def read_motion(self, sensor: str | None = None) -> Motion:
        """The samples of magnetometer ``sensor`` with the vehicle's attitude, gyroscope and accelerometer at
        their time stamps, each with its frame (see :mod:`magfit.sources.motion`).

        Raises
        ------
        DataFileError
            As :meth:`read`; a samples file (it holds no other streams).
        """
        chosen = self.magnetometer(sensor)
        if chosen.problem is not None:
            raise DataFileError(f"{self.path}: {chosen.id} cannot be fitted: {chosen.problem}")
        if self._motion is None:
            raise DataFileError(
                f"{self.path}: is a samples file, which holds no attitude, gyroscope or accelerometer stream beside "
                "the magnetometer; give a flight log or a bag"
            )
        return self._motion(chosen)


def strided(read: LogSamples, max_samples: int | None) -> LogSamples:
    """``read`` thinned to a regular stride of at most ``max_samples`` samples (every k-th), said in its notes;
    ``read`` itself when it holds no more."""
    n = len(read.samples)
    if max_samples is None or n <= max_samples:
        return read
    every = -(-n // max_samples)
    note = (
        f"one sample in every {every} kept ({len(range(0, n, every))} of {n}): the stream holds more than "
        f"{option('max_samples', max_samples)}, so a regular stride over the whole recording is fitted"
    )
    return LogSamples(
        read.magnetometer,
        read.samples[::every],
        read.time_s[::every],
        read.columns,
        (*read.notes, note),
        every=read.every * every,
    )
