"""A recording to calibrations: :func:`calibrate_file`, what ``magfit calibrate`` runs (see the package docstring)."""

from __future__ import annotations

import datetime
import importlib.util
import math
import os
from collections.abc import Callable, Mapping, Sequence
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

import numpy as np

from ..calibration import Calibration
from ..errors import CalibrationError, DataFileError, MagfitError, OptionError
from ..evaluate import evaluate
from ..facts import LogCompass, SampleSource
from ..findings import Reason
from ..fit import fit
from ..methods import get_method
from ..outliers import kept_statistics
from ..remedy import option
from ..sources import Magnetometer, Source, log_kind, open_source
from ..units import field_unit_reason, get_unit
from .advice import RefusedWithAdvice, StreamsMissing, level_only, looks_like_vehicle, turned, vehicle_advice
from .results import CompassCalibration, CompassFailure, FileCalibration, ModelField
from .streaming import (
    Nonfinite,
    Progress,
    SamplesFileFit,
    fit_samples_file,
    log_read_limit,
    log_subsample,
    no_progress,
    samples_for_fit,
)
from .table import StreamSpec
from .vehicle import VEHICLE_METHODS, attempt_all, best, held_by_samples_file, refusal, rescue_note, with_rescue

if TYPE_CHECKING:
    pass  # (imported when used: the wmm extra)

__all__ = ["FROM_LOG", "calibrate_file"]

#: ``location="log"``: the World Magnetic Model at the recording's own GNSS fixes.
FROM_LOG: Literal["log"] = "log"


def calibrate_file(
    path: str | os.PathLike[str],
    method: str | None = None,
    *,
    sensor: str | None = None,
    columns: Sequence[str | int] | None = None,
    unit: str | None = None,
    field_strength: float | Literal["wmm"] | None = None,
    location: tuple[float, float, float] | Literal["log"] | None = None,
    date: datetime.date | str | None = None,
    force: bool = False,
    nonfinite: Nonfinite = "skip",
    even: bool = False,
    max_samples: int | None = None,
    options: Mapping[str, Any] | None = None,
    progress: Progress = no_progress,
    notify: Callable[[str], None] | None = None,
    attitude: Sequence[str | int] | None = None,
    reference: Sequence[str | int] | None = None,
    gyro: Sequence[str | int] | None = None,
    accel: Sequence[str | int] | None = None,
    time: Sequence[str | int] | None = None,
    attitude_convention: Literal["ned", "enu"] = "ned",
    angle_unit: Literal["auto", "deg", "rad"] = "auto",
    gyro_unit: Literal["rad/s", "deg/s"] = "rad/s",
    motor: str = "auto",
) -> FileCalibration:
    """Fit a recording: a samples file (text, npy, npz), a PX4 ULog, an ArduPilot DataFlash log or a ROS bag.

    Parameters
    ----------
    path : str or path-like
        The recording (compressed files and ``"-"`` for standard input as :func:`magfit.io.read_samples`).
    method : str or None
        A name in :data:`magfit.METHODS`. None (the default, ``magfit calibrate`` without ``--method``):
        ``auto``, and when it refuses the recording and the recording holds a vehicle's streams, the methods
        that use them (``vector``: attitude with the reference field; ``gyro``: gyroscope and time), the
        best-determined of those that fit returned, a note saying which and why
        (:mod:`magfit.pipeline.vehicle`); their refusals added to auto's when none fits. A name, ``"auto"``
        included, is that method alone.
    sensor : str or None
        A log's compass (its id or device id, as :func:`magfit.sources.open_source` lists them). None fits
        every compass of a log that holds several (each one's failure in ``failures``), or the only one.
    columns : sequence or None
        A samples file's three magnetometer columns (names or 0-based indices); None detects them.
    unit : str or None
        The samples' unit (``"uT"``, ``"G"``, ``"counts"`` ...); a log's own unit when None.
    field_strength : float, ``"wmm"`` or None
        The known field strength in the samples' unit, or ``"wmm"``: the World Magnetic Model's at
        ``location`` (or at the log's own GNSS fixes); the fit scales the corrected field to it.
    location : (lat, lon) or (lat, lon, alt_km), ``"log"`` or None
        Where the recording was made (degrees, degrees, km above sea level; 0 km when left out), for the
        model's field (checked against the fitted one); ``"log"``: the log's own GNSS fixes (the median of its
        3-D fixes).
    date : date, str or None
        When, for the model; None is the date of the log's first fix with a time, else today.
    force : bool
        Return a calibration the samples do not support, marked so (``allow_undetermined``).
    nonfinite : {"skip", "error"}
        A samples file's rows holding NaN or inf: skipped (counted) or refused.
    even : bool
        Fit an even subsample over directions (a long stay in one attitude does not pull the fit).
    max_samples : int or None
        Most samples an iterative method holds in memory (a larger samples file is fitted on an even
        subsample; a log's compass with more records, by any method, on a regular stride of them);
        None: :func:`magfit.pipeline.streaming.memory_sample_limit`.
    options : mapping or None
        The method's other keyword options, passed to :func:`magfit.fit`.
    progress : Progress
        Shows the passes over a big samples file (the command line's bar); default: nothing shown.
    notify : callable or None
        Called with each note about the recording as soon as it is known (``"x.bin (MAG/0): ..."``), before
        a fit that may fail; the notes are in the result too.
    attitude, reference, gyro, accel, time : sequence or None
        A samples file's other streams for ``vector`` and ``gyro`` (docs/file-formats.md): the attitude's
        columns (roll, pitch, yaw, or a quaternion w, x, y, z), the reference field's N, E, D columns (in the
        samples' unit; without them, the World Magnetic Model at ``location`` or at the file's latitude and
        longitude columns), the gyroscope's (rad/s), the accelerometer's and the time column (seconds). Names
        or 0-based numbers, as ``columns``; None finds each by its name.
    attitude_convention : {"ned", "enu"}
        ``"ned"``: aerospace 3-2-1 Euler angles (yaw, pitch, roll) or a quaternion from the body's
        forward-right-down axes into North-East-Down; ``"enu"``: ROS's, forward-left-up into East-North-Up
        (the reference columns then E, N, U).
    angle_unit : {"auto", "deg", "rad"}
        The Euler angles' unit; ``"auto"`` decides from the values and refuses a file they leave ambiguous.
    gyro_unit : {"rad/s", "deg/s"}
        The gyroscope columns' unit (the methods refuse rates that look like degrees per second as rad/s).
    motor : {"auto", "current", "throttle", "none"}
        The motors' field in a flight log (:mod:`magfit.pipeline.motor`): ``"auto"`` fits it with the
        calibration when the log's current or throttle determines it and it matters, a name fits that one
        whenever it is determined, ``"none"`` never. Said in the notes either way; ignored for samples files.

    Returns
    -------
    FileCalibration
        One :class:`CompassCalibration` per compass fitted.

    Raises
    ------
    CalibrationError
        The samples cannot support the fit (of one compass: several fitted together report theirs in
        ``failures``).
    DataFileError
        The file cannot be read, holds no samples, or ``sensor`` names no compass of it.
    OptionError
        Unknown method or option; ``field_strength="wmm"`` without a place or without a physical unit.
    """
    path = Path(path)
    by_default = method is None  # auto, then the vehicle methods on the recording's own streams
    method = "auto" if method is None else method
    get_method(method)  # an unknown method, before the file is read
    if motor not in ("auto", "none"):  # the default needs no check, nor the motors' modules imported for it
        from .motor import check_motor

        check_motor(motor)
    if motor not in ("auto", "none") and path.is_file() and log_kind(path) is None:
        raise OptionError(
            f"{path}: {option('motor', motor)} fits the motors' field from a flight log's own {motor} (DataFlash, "
            f"ULog, tlog); a samples file's is not read for it: calibrate the log, or drop {option('motor', motor)}"
        )
    location = _checked_location(location)
    options = dict(options or {})
    if force:  # fit's own keyword, passed with the method's options
        options["allow_undetermined"] = True
    if date is not None and location is None and field_strength != "wmm" and not get_method(method).needs:
        raise OptionError(
            f"{option('date', 'YYYY-MM-DD')} goes with {option('location', 'LAT,LON[,ALT]')} or "
            f"{option('field_strength', 'wmm')}: the World Magnetic Model needs the place too"
        )
    say = notify or (lambda note: None)
    given = [name for name, value in (("attitude", attitude), ("reference", reference), ("gyro", gyro),
                                      ("accel", accel), ("time", time)) if value is not None]  # fmt: skip
    if given and (not get_method(method).needs or log_kind(path) is not None):
        what = (
            "a flight log's streams are its own" if log_kind(path) is not None else f"{method} takes the samples alone"
        )
        raise OptionError(
            f"{path}: {', '.join(option(name, '...') for name in given)} names a samples file's columns for the "
            f"methods that read them (vector, gyro); {what}"
        )
    from ..io.instances import head_sensors

    kind = log_kind(path)
    # A samples file that interleaves compasses (mavlogdump's I, device_id) is read one at a time, as a log is.
    ids = head_sensors(path) if kind is None else ()
    if kind is None and not (ids and (sensor is not None or len(ids) > 1)):
        if sensor is not None:
            raise DataFileError(
                f"{path}: {option('sensor', 'ID')} chooses a compass of a flight log or bag (ULog, DataFlash, ROS)"
            )
        needs = get_method(method).needs
        spec = StreamSpec(attitude, reference, gyro, accel, time, attitude_convention, angle_unit, gyro_unit)
        model = _model(path, None, location, date)  # (no log: "wmm" without a place is refused below)
        if needs and not all(need in options for need in needs):
            if field_strength is not None:
                raise OptionError(
                    f"{path}: {option('field_strength', '...')} goes with a magnitude-only method, not {method}"
                )
            if even:
                raise OptionError(
                    f"{path}: {option('even', True)} subsamples by direction; the {method} method needs every sample "
                    "in time order"
                )
            where = location if location is not None and location != FROM_LOG else None
            compass = _calibrate_samples_streams(
                path, method, columns, spec, unit, where, date, options, say, nonfinite
            )
            return FileCalibration(path, (_with_model_field(compass, model),), model_field=model)
        if field_strength == "wmm":
            options["field_strength"] = _model_strength(model, unit or _file_unit(path, columns, nonfinite))
        elif field_strength is not None:
            options["field_strength"] = field_strength
        try:
            compass = _calibrate_samples(path, method, columns, nonfinite, unit, even, max_samples, options, progress)
        except CalibrationError as error:
            refused = _with_vehicle_advice(path, error, columns, unit, method, nonfinite)
            placed = location not in (None, FROM_LOG)
            held = held_by_samples_file(path, given, placed) if by_default and not force else ()
            if not held:
                raise refused from None
            where = location if location is not None and location != FROM_LOG else None

            def fit_one(name: str, note: Callable[[str], None]) -> CompassCalibration:
                return _calibrate_samples_streams(path, name, columns, spec, unit, where, date, {}, note, nonfinite)

            compass = _rescued(str(path), refused, attempt_all(held, fit_one), say)
            return FileCalibration(path, (_with_model_field(compass, model),), model_field=model)
        compass = _vehicle_weak(compass, columns, nonfinite, unit, method)
        return FileCalibration(path, (_with_model_field(compass, model),), model_field=model)
    if columns is not None:
        raise OptionError(
            f"{path}: {option('columns', '...')} chooses the columns of a samples file; a log's compass by "
            f"{option('sensor', 'ID')}"
        )
    source = open_source(path, everything=False)  # the magnetometers (and the GNSS): what a fit needs
    place: tuple[float, float, float] | Literal["log"] | None = location
    if place is None and field_strength == "wmm":
        place = FROM_LOG
    elif place is None and importlib.util.find_spec("pygeomag") is not None and source.position is not None:
        place = FROM_LOG  # a log that knows where it was: the fitted field is checked against the model's there
    model = _model(path, source, place, date)
    fitted_source = _placed(source, location)  # the vector method's reference field: the place given, without fixes
    chosen = [sensor] if sensor is not None else _usable(source)
    compasses: list[CompassCalibration] = []
    failures: list[CompassFailure] = []
    for sensor_id in chosen:
        magnetometer = source.magnetometer(sensor_id)
        compass_options = dict(options)
        if field_strength == "wmm":
            compass_options["field_strength"] = _model_strength(model, unit or magnetometer.unit or None)
        elif field_strength is not None:
            compass_options["field_strength"] = field_strength
        try:
            try:
                compass = _calibrate_compass(
                    fitted_source,
                    magnetometer,
                    method,
                    compass_options,
                    unit,
                    even,
                    say,
                    date,
                    motor,
                    max_samples=max_samples,
                )
            except RefusedWithAdvice as error:  # a compass that turned: the log's own streams may determine it
                if not by_default or force:
                    raise
                compass = _log_rescue(fitted_source, magnetometer, error, unit, say, date, motor, max_samples)
        except (CalibrationError, DataFileError) as error:
            if len(chosen) == 1:
                raise
            notes = _notes(source, magnetometer)
            if isinstance(error, RefusedWithAdvice):  # the refusal's words; the remedies as data
                failures.append(CompassFailure(magnetometer.id, error.text, notes, error.advice, error.codes))
            else:
                failures.append(CompassFailure(magnetometer.id, str(error), notes, codes=error.codes))
            continue
        compasses.append(_with_model_field(compass, model))
    tried = tuple(compass.sensor or "" for compass in compasses) + tuple(f.sensor for f in failures)
    order = [m.id for m in source.magnetometers]
    sensors = tuple(sorted(tried, key=lambda sensor_id: order.index(sensor_id) if sensor_id in order else len(order)))
    return FileCalibration(path, tuple(compasses), tuple(failures), model, sensors, source.position, source.identity)


def _rescued(
    where: str, refused: CalibrationError, attempts: Sequence[Any], say: Callable[[str], None]
) -> CompassCalibration:
    """The best-determined fit of the vehicle methods tried after the default's refusal, its notes told and
    the rescue's note first (:mod:`magfit.pipeline.vehicle`); the refusal with what each found when none fits."""
    chosen = best(attempts)
    if chosen is None or chosen.compass is None:
        raise refusal(refused, attempts) from None
    note = rescue_note(where, refused, attempts, chosen)
    for said in (*chosen.notes, note):
        say(said)
    return with_rescue(chosen.compass, note)


def _log_rescue(
    source: Source,
    magnetometer: Magnetometer,
    refused: CalibrationError,
    unit: str | None,
    say: Callable[[str], None],
    date: datetime.date | str | None,
    motor: str,
    max_samples: int | None,
) -> CompassCalibration:
    """A log's compass the default refused: the vehicle methods on the log's own streams (:func:`_rescued`),
    with their own options only (auto's, a field strength among them, are not theirs)."""

    def fit_one(name: str, note: Callable[[str], None]) -> CompassCalibration:
        return _calibrate_compass(
            source, magnetometer, name, {}, unit, False, note, date, motor, max_samples=max_samples
        )

    return _rescued(f"{source.path} ({magnetometer.id})", refused, attempt_all(VEHICLE_METHODS, fit_one), say)


def _placed(source: Source, location: tuple[float, float, float] | Literal["log"] | None) -> Source:
    """``source`` with the place given as its position when the log holds no 3-D GNSS fix of its own: the
    World Magnetic Model's field there is the reference of the methods that need one (``vector``). A log's own
    fixes are kept (they follow the vehicle; the place given is checked against them by the model's field)."""
    if location is None or location == FROM_LOG or source.position is not None:
        return source
    from ..sources.position import Position

    lat, lon, alt_km = location
    return replace(source, position=Position(lat, lon, alt_km, float("nan"), 0))


def _with_model_field(compass: CompassCalibration, model: ModelField | None) -> CompassCalibration:
    """``compass`` with the model's field, compared with the fitted one (:attr:`ModelField.mismatch`)."""
    if model is None:
        return replace(compass, model_field=None)
    from ..geomag import compare_fitted

    calibration, mismatch = compass.calibration, None
    if calibration.unit and get_unit(calibration.unit).is_physical:
        known = calibration.known_field
        fitted = known.fitted if known is not None and known.fitted is not None else calibration.field_strength
        text = compare_fitted(fitted, calibration.unit, model.field)
        mismatch = Reason(text, "field_mismatch") if text is not None else None
    return replace(compass, model_field=replace(model, mismatch=mismatch))


def _usable(source: Source) -> list[str | None]:
    """The compasses to fit when none is chosen: every usable one of a log that holds several, else the one
    :meth:`Source.magnetometer` picks (which names the problem when there is none)."""
    usable = [m.id for m in source.magnetometers if m.problem is None and m.n_samples > 0]
    return list(usable) if len(usable) > 1 else [None]


def _notes(source: Source, magnetometer: Magnetometer) -> tuple[str, ...]:
    """What the log says about a compass, each note naming the file and the compass."""
    return tuple(f"{source.path} ({magnetometer.id}): {note}" for note in (*source.notes, *magnetometer.notes))


def _calibrate_compass(
    source: Source,
    magnetometer: Magnetometer,
    method: str,
    options: Mapping[str, Any],
    unit: str | None,
    even: bool,
    say: Callable[[str], None],
    date: datetime.date | str | None = None,
    motor: str = "none",
    *,
    max_samples: int | None = None,
) -> CompassCalibration:
    """Fit one magnetometer of a flight log or bag (docs/file-formats.md): its raw field, read by magfit.sources.

    A method that needs more than the samples (``vector``, ``gyro``) gets the log's streams on the compass's
    stamps (:func:`magfit.pipeline.streams.method_streams`; ``date`` for the model's field, else the log's).
    """
    path = source.path
    where = f"{path} ({magnetometer.id}, {magnetometer.description})"
    try:
        read = source.read(magnetometer.id, max_samples=log_read_limit(max_samples))
    except DataFileError:
        for note in source.notes:
            say(f"{path} ({magnetometer.id}): {note}")
        raise
    subsample = log_subsample(magnetometer.n_samples, read.every, max_samples, even)
    # Told before a refusal too: they often say why (a compass logged at 1 Hz, a calibration undone).
    notes = tuple(f"{path} ({magnetometer.id}): {note}" for note in (*source.notes, *read.notes))
    for note in notes:
        say(note)
    if len(read.samples) == 0:
        raise DataFileError(f"{where}: holds no finite samples")
    needs = get_method(method).needs
    fitted, frame_details = read.samples, {}
    if needs:  # vector, gyro: the log's attitude, gyroscope and time on the compass's stamps (docs/file-formats.md)
        from .streams import method_streams, stream_names

        names = stream_names([method])
        streams = method_streams(
            source, magnetometer.id, names.needed, optional=names.optional, unit=unit, date=date,
            gyro_own_rate="gyro_time_s" in get_method(method).options,
        )  # fmt: skip
        for note in streams.notes:
            say(note)
        notes += streams.notes
        fitted, frame_details = streams.samples, streams.sensor_details
        options = {**options, **streams.options}
        if motor != "none" and "regressor" in get_method(method).options:  # tilt fits the motors' field itself
            from .motor import method_regressor

            options = {**options, **method_regressor(source, motor, where)}
    elif even:
        fitted = samples_for_fit(read.samples, even)
    several = len([m for m in source.magnetometers if m.problem is None and m.n_samples > 0]) > 1
    streams_held = ("attitude", "place", "gyro", "time")  # a log's: vector and gyro read them (or say why not)
    label = unit or magnetometer.unit
    from .motor import MotorOutcome, motor_stage  # the motors' field: the method again on raw − k c when kept

    def stage(calibration: Calibration) -> MotorOutcome:
        return motor_stage(
            source, read, calibration, motor=motor, where=where, refit_samples=fitted if needs else read.samples,
            refit_time_s=options.get("time_s") if needs else read.time_s,
            refit=lambda s: _labelled(
                fit(s if needs or not even else samples_for_fit(s, even), method=method, **options), label
            ),
        )  # fmt: skip

    try:
        outcome = stage(_labelled(fit(fitted, method=method, **options), label))
    except CalibrationError as error:
        # The motors' field may be what the magnitude-only fit cannot describe: the term is fitted from the
        # forced calibration, and the method judged again on raw − k c (refused again: the first refusal stands).
        rescued = _with_motor_term(stage, fitted, method, options, label) if motor != "none" else None
        if rescued is None:
            advice = "".join(f"; {note}" for note in magnetometer.notes if "logged at only" in note or "only " in note)
            chosen = magnetometer.id if several else None
            works = vehicle_advice(path, is_log=True, streams=streams_held, unit=unit, method=method, sensor=chosen)
            if not turned(fitted):  # a compass never turned: only recording again helps
                raise CalibrationError(f"{where}: {error}{advice}", codes=error.codes, remedy=error.remedy) from None
            said = error.without_general_advice() if works else str(error)  # the log's own advice replaces it
            raise RefusedWithAdvice(path, f"{where}: {said}{advice}", works, codes=error.codes) from None
        outcome = rescued
    for note in outcome.notes:
        say(note)
    notes += outcome.notes
    calibration = outcome.calibration
    rotation = frame_details.get("applied_rotation")  # the firmware's mounting, applied before logging
    sensor = LogCompass(
        magnetometer.id, magnetometer.slot, magnetometer.device_id,
        None if rotation is None else tuple(tuple(map(float, row)) for row in rotation),
        magnetometer.calibration_in_use,  # the exports refuse to write a residual in its place
    )  # fmt: skip
    verdict = calibration.support.verdict if calibration.support is not None else None
    vehicle: tuple[Reason, ...] = ()
    if verdict in ("weak", "refused") and turned(fitted):  # a flight log is a vehicle's: what works for it
        chosen = magnetometer.id if several else None
        vehicle = vehicle_advice(path, is_log=True, streams=streams_held, unit=unit, method=method, sensor=chosen)
    calibration = replace(calibration, sensor=sensor, source=SampleSource(path.name, calibration.unit))
    evaluation = evaluate(replace(calibration, motor=None), outcome.evaluation_samples)
    calibration = _stated_uncertainty(calibration, evaluation.std)
    times = read.time_s[np.isfinite(read.time_s)]
    span = f"{magnetometer.span_s:.1f} s" if np.isfinite(magnetometer.span_s) else "no time stamps"
    return CompassCalibration(
        path=path,
        calibration=calibration,
        evaluation=evaluation,
        columns=read.columns,
        n_rows=len(read.samples),
        n_skipped=0,
        skipped_lines=(),
        file_format=f"{source.format}; {magnetometer.id}: {magnetometer.description}, {span}",
        streamed=False,
        subsample=subsample,
        magnetometer=magnetometer,
        start_s=float(times.min()) if times.size else float("nan"),
        end_s=float(times.max()) if times.size else float("nan"),
        time_base=source.time_base,
        notes=notes,
        warnings=_unit_warnings(calibration.field_strength, label or None),
        advice=vehicle,
        statistics=kept_statistics(calibration, read.samples),
    )


def _stated_uncertainty(calibration: Calibration, residual_sigma: float) -> Calibration:
    """``calibration`` with the one-sigma its method states in its own facts (the gyro method's level heading
    one-sigma, :class:`magfit.facts.GyroFacts`: RMS over eight level headings, the field dipping 60°) in
    ``diagnostics.uncertainty`` too, where every reader of a calibration looks for it; unchanged otherwise."""
    diagnostics, gyro = calibration.diagnostics, calibration.gyro
    if diagnostics is None or diagnostics.uncertainty is not None or gyro is None or gyro.heading_sigma_deg is None:
        return calibration
    from ..findings import Uncertainty

    stated = Uncertainty(
        offset_sigma=None, scale_sigma=None, field_strength_sigma=None, heading_sigma_deg=gyro.heading_sigma_deg,
        heading_sigma_max_deg=None, inclination_deg=60.0, residual_sigma=float(residual_sigma),
        n_samples=int(calibration.n_samples or diagnostics.n_samples),
    )  # fmt: skip
    details = {**calibration.details, "diagnostics": replace(diagnostics, uncertainty=stated).to_dict()}
    return replace(calibration, details=details)


def _unit_warnings(field_strength: float, unit: str | None) -> tuple[Reason, ...]:
    """The unit check's warning (``unit_mismatch``): a field strength no place on Earth has in the unit declared
    (:func:`magfit.units.field_unit_reason`)."""
    if not math.isfinite(field_strength):
        return ()
    reason = field_unit_reason(float(field_strength), unit)
    return () if reason is None else (reason,)


def _samples_file_advice(
    path: Path, columns: Sequence[str | int] | None, nonfinite: Nonfinite, unit: str | None, method: str
) -> tuple[Reason, ...]:
    """The methods that work for a vehicle, when a samples file's samples look like a vehicle's (one pass over
    the file for their covariance, in chunks: read only when a fit is refused or weak); none otherwise."""
    from ..io import iter_sample_chunks
    from ..io.layout import sniff
    from ..io.streams import find_stream_columns

    try:
        count, total, outer = 0, np.zeros(3), np.zeros((3, 3))
        for chunk in iter_sample_chunks(path, columns=columns, nonfinite=nonfinite):
            count += len(chunk)
            total += chunk.sum(axis=0)
            outer += chunk.T @ chunk
        header = sniff(path).header
    except MagfitError:
        return ()
    if count < 10:
        return ()
    mean = total / count
    covariance = outer / count - np.outer(mean, mean)
    if not looks_like_vehicle(covariance, float(np.trace(outer)) / count):
        return ()
    streams = tuple(find_stream_columns(header)) if header is not None else ()
    level = level_only(covariance)  # level turns: the pinned sphere has two solutions and is not advised
    return vehicle_advice(path, is_log=False, streams=streams, unit=unit, method=method, level=level)


def _with_vehicle_advice(
    path: Path,
    error: CalibrationError,
    columns: Sequence[str | int] | None,
    unit: str | None,
    method: str,
    nonfinite: Nonfinite = "skip",
) -> CalibrationError:
    """A samples file's refusal, with the methods that work for a vehicle when the samples look like one's."""
    advice = _samples_file_advice(path, columns, nonfinite, unit, method)
    if not advice:
        return error
    # The file's own advice (its columns named) replaces the method's words for vehicles in general.
    return RefusedWithAdvice(path, error.without_general_advice(), advice, codes=error.codes)


def _vehicle_weak(
    compass: CompassCalibration,
    columns: Sequence[str | int] | None,
    nonfinite: Nonfinite,
    unit: str | None,
    method: str,
) -> CompassCalibration:
    """A weak fit of a vehicle's samples gets the methods that work for a vehicle (``advice``)."""
    support = compass.calibration.support
    if support is None or support.verdict not in ("weak", "refused"):
        return compass
    source = compass.calibration.source
    chosen = columns if columns is not None or source is None else source.column_indices
    return replace(compass, advice=_samples_file_advice(compass.path, chosen, nonfinite, unit, method))


def _calibrate_samples_streams(
    path: Path,
    method: str,
    columns: Sequence[str | int] | None,
    spec: StreamSpec,
    unit: str | None,
    location: tuple[float, float, float] | None,
    date: datetime.date | str | None,
    options: Mapping[str, Any],
    say: Callable[[str], None],
    nonfinite: Nonfinite = "skip",
) -> CompassCalibration:
    """Fit a samples file with ``vector`` or ``gyro``: its attitude, reference, gyroscope, accelerometer and
    time columns through the logs' path (:func:`magfit.pipeline.streams.method_streams`)."""
    from .streams import method_streams, stream_names
    from .table import samples_source

    names = stream_names([method])
    wanted = ["attitude", "reference", "place"] if "reference" in names.needed else []
    wanted += [s for s in ("gyro", "accel") if s in (*names.needed, *names.optional)]
    wanted += ["time"] if "time_s" in (*names.needed, *names.optional) else []
    read = samples_source(path, columns, spec, wanted, location, nonfinite)
    source, reference_ned, notes = read.source, read.reference_ned, read.notes
    motion = source.read_motion("columns")
    label = unit or motion.unit or None
    # The call as the user made it (the remedy adds what is missing): method, unit, columns, place, date.
    base = [("method", method)] + ([("unit", label)] if label else [])
    if columns is not None:
        base.append(("columns", ",".join(map(str, columns))))
    for name, value in (("attitude", spec.attitude), ("reference", spec.reference), ("gyro", spec.gyro),
                        ("accel", spec.accel), ("time", spec.time)):  # fmt: skip
        if value is not None:
            base.append((name, ",".join(map(str, value))))
    if location is not None:
        base.append(("location", ",".join(f"{v:g}" for v in location)))
    if date is not None:
        base.append(("date", str(date)))
    found = {
        "attitude": motion.attitude is not None,
        "reference": reference_ned is not None or motion.position is not None,
    }
    listing = f"the columns are: {_columns_of(path)}" + "".join(f"; {hint}" for hint in read.hints)
    if "reference" in names.needed:
        if motion.attitude is None:
            raise StreamsMissing(
                path,
                f"{path}: the vector method needs the vehicle's attitude beside the samples, and no attitude columns "
                f"were found (roll, pitch, yaw or qw, qx, qy, qz; {listing}): name them",
                (*base, ("attitude", "ROLL,PITCH,YAW"), *(() if found["reference"] else (("reference", "N,E,D"),))),
            )
        if reference_ned is None and motion.position is None:
            raise StreamsMissing(
                path,
                f"{path}: the vector method needs the reference field at each sample: no N/E/D columns were found "
                f"(ref_n, ref_e, ref_d; {listing}) and no place for the World Magnetic Model (no latitude and "
                "longitude columns, no location): name the reference columns, or give the place",
                (*base, ("reference", "N,E,D")),
            )
    if "gyro" in names.needed and (motion.gyro is None or "time" not in source.time_base):
        missing = [
            what
            for what, ok in (("gyroscope", motion.gyro is not None), ("time", "time" in source.time_base))
            if not ok
        ]
        raise StreamsMissing(
            path,
            f"{path}: the gyro method needs the gyroscope's rates (rad/s) and the time of each sample; no "
            f"{' or '.join(missing)} columns were found (gx, gy, gz; time; {listing}): name them",
            (*base, *((("gyro", "GX,GY,GZ"),) if motion.gyro is None else ()),
             *((("time", "TIME"),) if "time" not in source.time_base else ())),
        )  # fmt: skip
    for note in notes[1:]:  # (the first names the magnetometer's columns: the summary shows them)
        say(note)
    streams = method_streams(
        source, "columns", names.needed,
        optional=[o for o in names.optional if o != "inclination_deg" or motion.position],
        unit=label, date=date, reference_ned=reference_ned,
    )  # fmt: skip
    for note in streams.notes:
        say(note)
    fitted_options = {**options, **streams.options}
    if "time" not in source.time_base:
        fitted_options.pop("time_s", None)  # row numbers are no time: no lag searched
    try:
        calibration = fit(streams.samples, method=method, **fitted_options)
    except OptionError as error:  # (the gyroscope's or the time's unit: said where its columns are)
        if "time_unit" in error.codes and "time" in source.time_base:
            time_column = next((note.split(": time ", 1)[1] for note in notes if ": time " in note), "time")
            raise OptionError(
                f"{path}: {error} (the file's time column {time_column}: if it counts milliseconds, name it time_ms; "
                "microseconds, time_us)",
                codes=error.codes,
            ) from None
        if "gyro" not in fitted_options or spec.gyro_unit != "rad/s" or "gyro_unit" not in error.codes:
            raise
        gyro_columns = next((note.split(": gyro ", 1)[1] for note in notes if ": gyro " in note), "gyro")
        raise OptionError(
            f"{path}: {error} (the file's gyroscope columns {gyro_columns}; if they hold degrees per second, say so "
            f"with {option('gyro_unit', 'deg/s')})",
            codes=error.codes,
        ) from None
    except CalibrationError as error:
        used = f"columns {source.magnetometers[0].description}"
        refusal = CalibrationError(f"{path} ({used}): {error}", codes=error.codes)
        raise _with_vehicle_advice(path, refusal, columns, label, method, nonfinite) from None
    calibration = calibration.with_unit(label) if label else calibration
    chosen = source.magnetometers[0]
    fitted_on = SampleSource(
        path.name, calibration.unit, tuple(map(str, read.columns)), tuple(map(int, read.column_indices)),
        read.header, read.n_columns, tuple(note.split(": ", 1)[1] for note in notes[1:]),
    )  # fmt: skip
    calibration = replace(calibration, source=fitted_on)
    evaluation = evaluate(calibration, streams.samples)
    calibration = _stated_uncertainty(calibration, evaluation.std)
    return CompassCalibration(
        path=path,
        calibration=calibration,
        evaluation=evaluation,
        columns=tuple(chosen.description.split(", ")),
        n_rows=read.n_rows,
        n_skipped=read.n_dropped,
        skipped_lines=(),
        file_format=source.format,
        streamed=False,
        notes=notes + streams.notes,
        warnings=_unit_warnings(calibration.field_strength, label),
    )


def _columns_of(path: Path) -> str:
    from ..io.layout import sniff

    fmt = sniff(path)
    return ", ".join(fmt.column_label(i) for i in range(fmt.n_columns))


def _labelled(calibration: Calibration, label: str | None) -> Calibration:
    return calibration.with_unit(label) if label else calibration


def _with_motor_term(
    stage: Callable[[Calibration], Any], fitted: Any, method: str, options: Mapping[str, Any], label: str | None
) -> Any:
    """The motors' stage from the method's forced fit, when it keeps a term and the method then accepts the
    samples with the term taken off; None otherwise (the refusal stands)."""
    if options.get("allow_undetermined"):
        return None
    try:
        start = _labelled(fit(fitted, method=method, **{**options, "allow_undetermined": True}), label)
        outcome = stage(start)
    except CalibrationError:
        return None
    kept = outcome.calibration
    refused = kept.support is not None and bool(kept.support.refusals)  # a method that fits the term itself, forced
    return outcome if kept.motor is not None and not refused else None


def _calibrate_samples(
    path: Path,
    method: str,
    columns: Sequence[str | int] | None,
    nonfinite: Nonfinite,
    unit: str | None,
    even: bool,
    max_samples: int | None,
    options: Mapping[str, Any],
    progress: Progress,
) -> CompassCalibration:
    """Fit a samples file (text, npy, npz) within bounded memory (:func:`.streaming.fit_samples_file`)."""
    from ..io import ChunkReader, SampleTable
    from .streaming import how_read

    # The columns first (cheap: the file's head): every message, a refusal too, says which were used.
    chosen = ChunkReader(path, columns=columns, nonfinite=nonfinite)  # not iterated: layout and columns only
    try:
        fitted = fit_samples_file(
            SamplesFileFit(path, method, columns, nonfinite, options, even, max_samples, progress)
        )
    except CalibrationError as error:
        used = "columns " + ", ".join(str(c) for c in chosen.columns)
        used += f"; {chosen.column_note}" if chosen.column_note else ""
        named = CalibrationError(f"{path} ({used}): {error}", codes=error.codes, remedy=error.remedy)
        named.general_advice = error.general_advice
        raise named from None
    calibration = fitted.calibration
    unit = unit if unit is not None else chosen.unit  # the file's own when its column names say it (mag_x_uT)
    if unit is not None:
        calibration = calibration.with_unit(unit)
    # Where the samples came from, so that `magfit apply` reads the same columns (Calibration.source).
    source = SampleSource(
        path.name, unit if unit is not None else calibration.unit, tuple(map(str, chosen.columns)),
        tuple(map(int, chosen.column_indices)), chosen.format.header is not None, chosen.format.n_columns,
    )  # fmt: skip
    calibration = replace(calibration, source=source)
    read = fitted.read
    return CompassCalibration(
        path=path,
        calibration=calibration,
        evaluation=fitted.evaluation,
        columns=tuple(read.columns),
        n_rows=int(read.n_rows),
        n_skipped=int(read.n_skipped),
        skipped_lines=tuple(int(line) for line in read.skipped_lines),
        file_format=how_read(path) + read.format.describe(),
        streamed=fitted.streamed,
        subsample=fitted.subsample,
        column_note=chosen.column_note,
        warnings=_unit_warnings(calibration.field_strength, unit),
        statistics=kept_statistics(calibration, read.samples) if isinstance(read, SampleTable) else fitted.statistics,
    )


def _checked_location(location: Any) -> tuple[float, float, float] | Literal["log"] | None:
    """``location`` as (lat, lon, alt_km), ``"log"`` or None; anything else refused in one line."""
    if location is None or (isinstance(location, str) and location == FROM_LOG):
        return location
    try:
        values = [float(value) for value in location]
    except (TypeError, ValueError):
        values = []
    if len(values) not in (2, 3) or not all(map(math.isfinite, values)):
        raise OptionError(
            f"location={location!r} is no place: give (latitude, longitude) in degrees, optionally with the altitude "
            f"in km, e.g. {option('location', '52.1,4.3,0.1')}, or {FROM_LOG!r} for a log's own GNSS fixes"
        )
    lat, lon, alt_km = (*values, 0.0) if len(values) == 2 else values
    return (lat, lon, alt_km)  # (their ranges: magfit.geomag.field_at)


def _model(
    path: Path,
    source: Source | None,
    location: tuple[float, float, float] | Literal["log"] | None,
    date: datetime.date | str | None,
) -> ModelField | None:
    """The World Magnetic Model's field at ``location`` (or the log's fixes), None when no place is asked for.

    The field is needed for ``field_strength="wmm"`` too: without a place then, the log's fixes are used.
    """
    from ..geomag import field_at

    if location is None:
        return None
    if location != FROM_LOG:
        lat, lon, alt_km = location
        return ModelField(field_at(lat, lon, alt_km, date=date), "the location given")
    position = source.position if source is not None else None
    if position is None:
        what = "this file is no flight log or bag" if source is None else "this log holds no 3-D GNSS fix"
        raise OptionError(
            f"{path}: the World Magnetic Model needs the place of the recording and {what}: give "
            f"{option('location', 'LAT,LON[,ALT]')}",
            codes=("no_location",),
        )
    when = ""
    if math.isfinite(position.time_s):
        first = datetime.datetime.fromtimestamp(position.time_s, tz=datetime.timezone.utc)
        when = first.strftime(", first at %Y-%m-%d %H:%M UTC")
        date = date or first.date()
    origin = f"the log's GNSS fixes (median of {position.n_fixes} 3-D fixes{when})"
    return ModelField(field_at(position.lat_deg, position.lon_deg, position.alt_km, date=date), origin)


def _file_unit(path: Path, columns: Sequence[str | int] | None, nonfinite: Nonfinite) -> str | None:
    """The unit a samples file states for its magnetometer (its columns' names, ``mag_x_uT``; a converter's
    file), read from its head; None when it states none."""
    from ..io import ChunkReader

    return ChunkReader(path, columns=columns, nonfinite=nonfinite).unit  # not iterated: the head only


def _model_strength(model: ModelField | None, unit: str | None) -> float:
    """The model's field strength in ``unit`` for ``field_strength="wmm"``; refuses a missing place or unit."""
    if model is None:
        raise OptionError(
            f"{option('field_strength', 'wmm')} needs {option('location', 'LAT,LON[,ALT]')} (where the recording was "
            "made), or a flight log or bag with its own GNSS fixes",
            codes=("no_location",),
        )
    if unit is None or not get_unit(unit).is_physical:
        raise OptionError(
            f"{option('field_strength', 'wmm')} needs the samples' physical unit ({option('unit', 'uT')}, G, mG ...): "
            "the model gives the field in tesla units, and raw counts have no known scale"
        )
    return model.field.total_in(unit)
