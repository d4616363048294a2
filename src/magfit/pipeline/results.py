"""What :func:`magfit.calibrate_file` returns: per compass, the calibration and what was read to fit it."""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ..calibration import Calibration
from ..errors import MagfitError
from ..evaluate import Evaluation
from ..findings import Reason
from ..sources import Magnetometer, Position
from ..statistics import Statistics

if TYPE_CHECKING:
    from ..geomag import Field  # (imported when used: the wmm extra)

__all__ = ["CompassCalibration", "CompassFailure", "FileCalibration", "ModelField"]


@dataclass(frozen=True)
class ModelField:
    """The World Magnetic Model's field where and when the recording was made.

    Attributes
    ----------
    field : Field
        The model's field (components in nT; :meth:`Field.total_in` converts).
    origin : str
        Where the place came from, in words: ``"the location given"`` or ``"the log's GNSS fixes (median of
        12 3-D fixes, first at 2026-01-01 10:00 UTC)"``.
    mismatch : Reason or None
        On a compass's result: the fitted field strength (the samples' own, when a known one was given)
        differs from the model's by more than :data:`magfit.geomag.MODEL_TOLERANCE` (code ``field_mismatch``),
        with the likely causes; None when they agree or the samples' unit is not physical.
    """

    field: Field
    origin: str
    mismatch: Reason | None = None


@dataclass(frozen=True, eq=False)
class CompassCalibration:
    """One compass's calibration and what was read to fit it.

    Attributes
    ----------
    path : Path
        The recording.
    calibration : Calibration
        The fit, labelled with the samples' unit; ``calibration.source`` says what it was fitted on (the
        file; a samples file's columns, for ``magfit apply``) and, for a log, ``calibration.sensor`` is the
        compass (:class:`magfit.facts.LogCompass`: id, slot, device id) an export writes it for.
    evaluation : Evaluation
        The paper's sphere-distance metric over every sample read (dimensionless).
    columns : tuple
        The three columns or fields used (names, or 0-based indices for files without a header).
    n_rows, n_skipped : int
        Rows (samples) read, and rows skipped because a value was NaN or infinite.
    skipped_lines : tuple of int
        Line numbers (1-based) of skipped rows, as reported by the reader (possibly only the first few).
    file_format : str
        The layout or log format in words.
    streamed : bool
        True when the file was read in chunks (a method that needs only the statistics).
    subsample : str or None
        None when the fit used every sample; else why it used an even subsample (``even=True``, or a file
        too large for memory), ``calibration.n_samples`` being how many.
    column_note : str or None
        For a file without a header, why these columns (``column 1 is monotonic: time or a counter``).
    magnetometer : Magnetometer or None
        For a flight log or a bag, the compass (id, device id, calibration slot, unit); None for a samples file.
    start_s, end_s : float
        First and last time stamp of the samples fitted, in seconds on the log's time base (``time_base``);
        NaN for a samples file.
    time_base : str
        What the time stamps count (``seconds since boot (TimeUS)``, ``seconds since the epoch ...``).
    notes : tuple of str
        What the user must know about these samples, in words (a compass logged too slowly, the firmware's
        calibration undone with the log's parameters, damaged data skipped).
    model_field : ModelField or None
        The World Magnetic Model's field at the recording, when asked for.
    warnings : tuple of Reason
        What a user must be warned of about the result (a field strength no place on Earth has in the unit
        declared: ``unit_mismatch``), each with its code.
    advice : tuple of Reason
        For a vehicle's recording fitted weakly: the methods that work for it, each with its remedy
        (:func:`magfit.pipeline.advice.vehicle_advice`).
    statistics : Statistics or None
        The sufficient statistics of the samples read, less those a robust fit rejected: what recordings of
        one compass merge by (:func:`magfit.fleet`), without reading them again. None for a samples file
        fitted on a subsample of a file too large for memory, or by ``vector`` or ``gyro``.
    """

    path: Path
    calibration: Calibration
    evaluation: Evaluation
    columns: tuple[Any, ...]
    n_rows: int
    n_skipped: int
    skipped_lines: tuple[int, ...]
    file_format: str
    streamed: bool
    subsample: str | None = None
    column_note: str | None = None
    magnetometer: Magnetometer | None = None
    start_s: float = float("nan")
    end_s: float = float("nan")
    time_base: str = ""
    notes: tuple[str, ...] = ()
    model_field: ModelField | None = None
    warnings: tuple[Reason, ...] = ()
    advice: tuple[Reason, ...] = ()
    statistics: Statistics | None = None

    @property
    def sensor(self) -> str | None:
        """The compass's id (``MAG/1``, ``sensor_mag/0``, a topic), None for a samples file."""
        return self.magnetometer.id if self.magnetometer is not None else None

    @property
    def span_s(self) -> float:
        """Seconds between the first and the last sample fitted (NaN without time stamps)."""
        return self.end_s - self.start_s

    @property
    def rate_hz(self) -> float:
        """Mean sample rate over the span (NaN without time stamps); a log read on a stride: the log's."""
        if self.magnetometer is not None and self.subsample is not None and "stride:" in self.subsample:
            return self.magnetometer.rate_hz
        span = self.span_s
        return (self.n_rows - 1) / span if self.n_rows > 1 and math.isfinite(span) and span > 0 else float("nan")

    @property
    def coverage(self) -> float | None:
        """The share of the sphere of field directions the samples reach (0 to 1), None when not diagnosed."""
        diagnostics = self.calibration.diagnostics
        if diagnostics is None or diagnostics.coverage is None:
            return None
        return float(diagnostics.coverage.share)


@dataclass(frozen=True)
class CompassFailure:
    """A compass of a log that could not be fitted: which, and why (the fit's refusal or the read's error);
    ``advice``: the methods that work for a vehicle, each a :class:`~magfit.findings.Reason` with its remedy."""

    sensor: str
    reason: str
    notes: tuple[str, ...] = ()
    advice: tuple[Reason, ...] = ()
    codes: tuple[str, ...] = ()  # the refusal's reason codes (magfit.REASON_CODES); empty for a read error


@dataclass(frozen=True, eq=False)
class FileCalibration:
    """What :func:`calibrate_file` returns: one :class:`CompassCalibration` per compass fitted.

    Attributes
    ----------
    path : Path
        The recording.
    compasses : tuple of CompassCalibration
        One per compass fitted, in the log's order (one for a samples file).
    failures : tuple of CompassFailure
        The compasses of a log fitted together that could not be fitted, with the reason (a single fit raises
        instead); ``compasses`` may then be empty.
    model_field : ModelField or None
        The World Magnetic Model's field at the recording, when asked for.
    sensors : tuple of str
        The ids of the compasses tried, in the log's order (empty for a samples file).
    position, identity : Position or None, str or None
        A log's GNSS position (with the time of its first fix) and the vehicle's own identity
        (:attr:`magfit.sources.Source.identity`), read in the same pass; None for a samples file.
    """

    path: Path
    compasses: tuple[CompassCalibration, ...]
    failures: tuple[CompassFailure, ...] = ()
    model_field: ModelField | None = None
    sensors: tuple[str, ...] = ()
    position: Position | None = None
    identity: str | None = None

    @property
    def calibration(self) -> Calibration:
        """The calibration, when one compass was fitted.

        Raises
        ------
        MagfitError
            Several compasses were fitted (read ``compasses``) or none was.
        """
        if len(self.compasses) != 1:
            ids = ", ".join(compass.sensor or "?" for compass in self.compasses) or "none"
            raise MagfitError(
                f"{self.path}: {len(self.compasses)} compasses were fitted ({ids}); read .compasses, or choose one "
                "with sensor='ID'"
            )
        return self.compasses[0].calibration

    def __iter__(self) -> Iterator[CompassCalibration]:
        """The compasses fitted, in the log's order: ``for compass in calibrate_file(...)``."""
        return iter(self.compasses)
