"""The motors' field in the log pipeline: :func:`motor_stage`, called once per compass by ``calibrate_file``.

After the method's fit, the log's current and throttle (:mod:`magfit.sources.power`) are tried as regressors
of the joint fit (:func:`magfit.motor.fit_motor`, docs/methods.md eq. M1-M4). When a term is kept, the method
runs again on ``raw − k c`` (:func:`magfit.motor.with_motor`), so that its verdict and diagnostics speak of the
calibration returned, and the calibration holds the term. Either way the user is told, in words.

A term that is estimated large but cannot be fitted (``motor_undetermined``: the regressor follows the attitude)
is left in the samples, and the calibration's verdict says so as a weakness with its size and the heading it can
turn (:func:`left_in`): the method's own uncertainty does not include it, and on a held-out stretch at another
current the calibration is off by about that much (benchmarks/results/motor_real.md).
"""

from __future__ import annotations

import functools
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from ..calibration import Calibration
from ..errors import CalibrationError, DataFileError, OptionError
from ..findings import Reason
from ..motor import MIN_PERCENT, MOTOR_CHOICES, WEAK_INDEPENDENCE, MotorFit, fit_motor, with_motor
from ..motorterm import MotorTerm
from ..remedy import option
from ..sources import LogSamples, Source
from ..sources.power import Power, Signal, read_power

__all__ = [
    "REGRESSOR_COLUMNS",
    "MotorOutcome",
    "column_regressor",
    "left_in",
    "log_regressor",
    "method_regressor",
    "motor_stage",
]

#: One-sigmas below its estimate the motors' field must still exceed MIN_PERCENT to be said as left in.
LEFT_IN_SIGMAS = 2.0

#: The column names (normalised: lower case, units dropped) that hold each regressor in a samples file.
REGRESSOR_COLUMNS = {
    "current": ("current", "curr", "current_a", "amps", "amp", "ibat", "i_bat", "battery_current", "bat_curr",
                "batt_curr", "bat_current", "batt_current"),
    "throttle": ("throttle", "thr", "tho", "thr_out", "throttle_out", "thrust"),
}  # fmt: skip


@dataclass(frozen=True)
class MotorOutcome:
    """The calibration (with the term when fitted), the samples to evaluate it on (the term removed, for the
    calibration without it), and what to tell the user."""

    calibration: Calibration
    evaluation_samples: NDArray[np.float64]
    notes: tuple[str, ...] = ()
    fit: MotorFit | None = None


def _clamped(time_s: NDArray[np.float64], signal: Signal, lag_s: float) -> NDArray[np.float64]:
    """The regressor at ``time_s − lag_s``, its first or last value beyond its span (for the refit only)."""
    return np.asarray(np.interp(time_s - lag_s, signal.time_s, signal.values), dtype=np.float64)


#: What each regressor is read from, in words (sources/power.py).
_WANTED = {
    "current": "BAT.Curr, battery_status.current_a or SYS_STATUS.current_battery",
    "throttle": "CTUN.ThO, vehicle_thrust_setpoint or VFR_HUD.throttle",
}


def log_regressor(
    path: str | os.PathLike[str], term: MotorTerm, time_s: NDArray[np.float64], *, held_by: str, cost: str
) -> tuple[NDArray[np.float64], str]:
    """The regressor ``term`` needs at the samples' stamps ``time_s`` (the log's time base), taken at the
    term's lag (its first or last value beyond its span, as the fit took it), and the stream it came from.

    Raises
    ------
    DataFileError
        The log holds no such stream (code ``motor_no_regressor``); ``held_by`` names the calibration in the
        message and ``cost`` says what leaving the term out costs.
    """
    power = read_power(path)
    signal = power.get(term.regressor)
    if signal is None:
        raise DataFileError(
            f"{held_by} holds the motors' field ({_per(term)}) and {path} logs no {term.regressor} magfit reads "
            f"({_WANTED[term.regressor]}); apply it to a log that does, or leave the term out "
            f"(--no-motor: {cost})",
            codes=("motor_no_regressor",),
        )
    return _clamped(np.asarray(time_s, dtype=np.float64), signal, term.lag_s), signal.name


def column_regressor(
    path: str | os.PathLike[str],
    term: MotorTerm,
    column: str | int | None,
    *,
    held_by: str,
    cost: str,
    magnetometer: Sequence[int] = (),
) -> tuple[NDArray[np.float64], str]:
    """The regressor ``term`` needs from a samples file's column (named or 0-based, or found by its name in
    :data:`REGRESSOR_COLUMNS`), one value per data row in the file's order (NaN where a cell is empty), and
    where it came from in words. The current in amperes, the throttle from 0 to 1 (a column above 1.5 is
    refused: a percentage). With a time column (found by its name, as ``calibrate`` finds it) the value is
    taken at the term's lag, as the fit took it; without one the row's own value is used (and said).

    Raises
    ------
    DataFileError
        No such column, none found by name (code ``motor_no_regressor``), or a throttle column in percent.
    """
    from ..io import sniff
    from ..io.selection import _match_name
    from ..io.streams import find_stream_columns, read_stream_columns

    file = Path(path)
    fmt = sniff(file)
    labels = [fmt.column_label(i) for i in range(fmt.n_columns)]
    if column is None:
        names = REGRESSOR_COLUMNS[term.regressor]
        found = [i for i, label in enumerate(labels) if fmt.header is not None and _key(label) in names]
        if len(found) != 1:
            what = "several columns" if found else "no column"
            raise DataFileError(
                f"{held_by} holds the motors' field ({_per(term)}) and {path} has {what} named like the "
                f"{term.regressor} ({', '.join(names[:4])} ...): name it with --regressor COLUMN, or leave the "
                f"term out (--no-motor: {cost})",
                codes=("motor_no_regressor",),
            )
        index = found[0]
    elif isinstance(column, int):
        if not 0 <= column < fmt.n_columns:
            raise DataFileError(f"{path}: regressor column {column} is out of range: 0 to {fmt.n_columns - 1}")
        index = column
    else:
        index = _match_name(file, column, labels, fmt.header is not None)
    time = find_stream_columns(fmt.header).get("time") if fmt.header is not None else None
    is_time = time is not None and index in time.indices
    taken = "one of the magnetometer's" if index in magnetometer else "the time" if is_time else ""
    if taken:  # the field or the clock taken for the current: a calibration silently wrong
        raise DataFileError(
            f"{path}: the {term.regressor} column {labels[index]!r} is {taken} column: name the {term.regressor}'s "
            f"own column with --regressor COLUMN, or leave the term out (--no-motor: {cost})",
            codes=("motor_no_regressor",),
        )
    wanted = {"regressor": [index], **({"time": list(time.indices)} if time is not None else {})}
    read = read_stream_columns(file, fmt, wanted)
    values = read["regressor"][:, 0]
    finite = values[np.isfinite(values)]
    if term.regressor == "throttle" and finite.size and float(np.max(np.abs(finite))) > 1.5:
        raise DataFileError(
            f"{path}: column {labels[index]!r} reaches {float(np.max(np.abs(finite))):.4g}: the throttle of this "
            "calibration is a fraction of full (0 to 1); divide a percentage by 100"
        )
    where = f"column {labels[index]!r}"
    if term.lag_s == 0.0:
        return values, where
    if time is None:
        return values, f"{where}, each row's own value (no time column for the {1000 * term.lag_s:.0f} ms lag)"
    stamps = read["time"][:, 0] * time.scale
    good = np.isfinite(stamps) & np.isfinite(values)
    if np.count_nonzero(good) < 2 or np.any(np.diff(stamps[good]) < 0):
        return values, f"{where}, each row's own value (column {time.labels[0]!r} is not increasing: no lag)"
    lagged = np.full(len(values), np.nan)
    signal = Signal(term.regressor, where, stamps[good], values[good])
    lagged[np.isfinite(stamps)] = _clamped(stamps[np.isfinite(stamps)], signal, term.lag_s)
    return lagged, f"{where} at {1000 * term.lag_s:.0f} ms lag (time column {time.labels[0]!r})"


def _key(label: str) -> str:
    from ..io.columns import normalise_name

    return normalise_name(label).strip("_ ")


def _per(term: MotorTerm) -> str:
    return "per ampere of battery current" if term.regressor == "current" else "per unit of throttle"


def _stamp(path: Any) -> tuple[int, int]:
    try:
        status = os.stat(path)
    except OSError:
        return (0, 0)
    return (status.st_mtime_ns, status.st_size)


@functools.lru_cache(maxsize=4)
def _power_of(path: str, mtime_ns: int, size: int) -> Power:
    """The log's current and throttle, read once for all its compasses (keyed by the file's time and size)."""
    return read_power(path)


def check_motor(motor: str) -> None:
    if motor not in MOTOR_CHOICES:
        raise OptionError(f"motor must be one of {', '.join(MOTOR_CHOICES)}; got {motor!r}")


def motor_stage(
    source: Source,
    read: LogSamples,
    calibration: Calibration,
    *,
    motor: str,
    refit: Callable[[NDArray[np.float64]], Calibration],
    refit_time_s: NDArray[np.float64] | None,
    refit_samples: NDArray[np.float64],
    where: str,
    power: Power | None = None,
) -> MotorOutcome:
    """Try the motors' field on one compass of a log (see the module docstring).

    ``refit`` fits the method on samples like ``refit_samples`` (whose stamps are ``refit_time_s``; None: the
    method's samples have no stamps the regressor can be put on, and no term is fitted).
    """
    check_motor(motor)
    unchanged = MotorOutcome(calibration, read.samples)
    if motor == "none" or len(read.samples) == 0:
        return unchanged
    if calibration.options.get("regressor") is not None:  # the method fitted the term with the calibration (tilt)
        return _method_term(source, read, calibration, where)
    try:
        power = power if power is not None else _power_of(str(source.path), *_stamp(source.path))
    except DataFileError as error:
        return replace(unchanged, notes=(f"{where}: the motors' field not tried: {error}",))
    kinds = ("current", "throttle") if motor == "auto" else (motor,)
    signals = [s for s in (power.get(kind) for kind in kinds) if s is not None]
    if not signals:
        if motor != "auto":
            raise OptionError(
                f"{where}: motor={motor!r}, but the log holds no {motor} magfit reads ({_WANTED[motor]}); "
                f"give {option('motor', 'auto')} or {option('motor', 'none')}",
                codes=("motor_no_regressor",),
            )
        return unchanged
    times = np.asarray(read.time_s, dtype=np.float64)
    if not np.all(np.isfinite(times)):
        return replace(unchanged, notes=(f"{where}: the motors' field not tried: the samples have no time stamps",))
    best: tuple[MotorFit, Signal] | None = None
    tried: list[tuple[MotorFit, Signal]] = []
    for signal in signals:
        result = fit_motor(
            read.samples, calibration, signal.values, kind=signal.kind, motor=motor,
            time_s=times, regressor_time_s=signal.time_s,
        )  # fmt: skip
        tried.append((result, signal))
        if result.fitted and (best is None or result.residual_rms[1] < best[0].residual_rms[1]):
            best = (result, signal)
    notes = tuple(f"{where}: {result.summary()} (from {signal.name})" for result, signal in tried)
    if best is None:
        codes = sorted({reason.code for result, _ in tried for reason in result.reasons})
        details = {**dict(calibration.details), "motor": _facts(tried, None, codes)}
        kept = _weakened(replace(calibration, details=details), left_in([result for result, _ in tried]))
        return MotorOutcome(kept, read.samples, notes, tried[0][0])
    result, signal = best
    assert result.term is not None
    if refit_time_s is None:
        return replace(unchanged, notes=(*notes, f"{where}: the method's samples carry no stamps: term not applied"))
    lagged = _clamped(np.asarray(refit_time_s, dtype=np.float64), signal, result.term.lag_s)
    outside = int(np.count_nonzero((times < signal.time_s[0]) | (times > signal.time_s[-1])))
    if outside:
        notes += (
            f"{where}: {outside} of {len(times)} samples lie outside {signal.name}'s span: corrected with its first "
            "or last value",
        )
    try:
        final = with_motor(result, refit_samples, lagged, refit)
    except CalibrationError as error:
        return replace(
            unchanged, notes=(*notes, f"{where}: with the motors' field removed the method refused: {error}")
        )
    details = {**dict(final.details), "motor": _facts(tried, signal.name, [])}
    final = _weakened(replace(final, details=details), weakly_told(result))
    cleaned = read.samples - result.term.field(_clamped(times, signal, result.term.lag_s))
    return MotorOutcome(final, cleaned, notes, result)


def method_regressor(source: Source, motor: str, where: str) -> dict[str, Any]:
    """The options of a method that fits the motors' field itself (``regressor``, its kind, its own clock and
    ``motor``): the log's current (or throttle: ``motor="throttle"``, or ``"auto"`` without a current); none
    when the log holds neither and ``motor="auto"``."""
    check_motor(motor)
    power = _power_of(str(source.path), *_stamp(source.path))
    kinds = ("current", "throttle") if motor == "auto" else (motor,)
    signal = next((s for s in (power.get(kind) for kind in kinds) if s is not None), None)
    if signal is None:
        if motor != "auto":
            raise OptionError(
                f"{where}: motor={motor!r}, but the log holds no {motor} magfit reads ({_WANTED[motor]}); "
                f"give {option('motor', 'auto')} or {option('motor', 'none')}",
                codes=("motor_no_regressor",),
            )
        return {}
    return {"regressor": signal.values, "regressor_kind": signal.kind, "regressor_time_s": signal.time_s,
            "motor": motor}  # fmt: skip


def _method_term(source: Source, read: LogSamples, calibration: Calibration, where: str) -> MotorOutcome:
    """A calibration whose method fitted the motors' field itself: the samples with its term removed (to evaluate
    it), the words, and ``details["motor"]`` in the form the summary reads (:func:`_facts`)."""
    facts = dict(calibration.details.get("motor") or {})
    term = calibration.motor
    kind = str(facts.get("regressor", "current"))
    signal = _power_of(str(source.path), *_stamp(source.path)).get(term.regressor if term is not None else kind)
    name = signal.name if signal is not None else kind
    reasons = [r for r in facts.get("reasons", []) if isinstance(r, dict)]
    if term is None or signal is None:
        said = "; ".join(str(r.get("text", "")) for r in reasons) or "not estimated"
        summary = f"the motors' field ({kind}): not fitted with the calibration: {said}"
        details = {**dict(calibration.details), "motor": _method_facts(facts, name, None, summary, reasons)}
        return MotorOutcome(replace(calibration, details=details), read.samples, (f"{where}: {summary}",))
    times = np.asarray(read.time_s, dtype=np.float64)
    cleaned = read.samples - term.field(_clamped(times, signal, term.lag_s))
    percent = float(facts.get("percent", float("nan")))
    sigma = float(facts.get("percent_sigma", float("nan")))
    rho = float(facts.get("independence", float("nan")))
    at = f"full current ({term.full_scale:.3g} A)" if term.regressor == "current" else "full throttle"
    edge = " (the lag at the edge of its search)" if facts.get("at_lag_edge") else ""
    weak = f", weakly told from the attitude (ρ = {rho:.2f})" if rho < WEAK_INDEPENDENCE else ""
    summary = (
        f"the motors' field ({term.regressor}): {np.linalg.norm(term.coefficients):.3g} {calibration.unit or 'units'} "
        f"per {'A' if term.regressor == 'current' else 'full throttle'}, {percent:.1f} % ± {sigma:.1f} % of the field "
        f"at {at}, lag {1000 * term.lag_s:.0f} ms{edge}{weak}, fitted with the calibration"
    )
    details = {**dict(calibration.details), "motor": _method_facts(facts, name, name, summary, reasons)}
    return MotorOutcome(replace(calibration, details=details), cleaned, (f"{where}: {summary} (from {name})",))


def _method_facts(facts: dict[str, Any], source: str, chosen: str | None, summary: str,
                  reasons: list[dict[str, Any]]) -> dict[str, Any]:  # fmt: skip
    """The method's own motor facts with the pipeline's keys (:func:`_facts`): what was tried, and the one kept."""
    percent, rho = facts.get("percent"), facts.get("independence")
    tried = {"regressor": facts.get("regressor"), "source": source, "summary": summary, "percent": percent,
             "independence": rho, "reasons": reasons}  # fmt: skip
    return {**facts, "chosen": chosen, "codes": sorted({str(r.get("code")) for r in reasons}), "tried": [tried]}


def _weakened(calibration: Calibration, weakness: Reason | None) -> Calibration:
    """The calibration with ``weakness`` added to its verdict (supported becomes weak; refused stays refused)."""
    support = calibration.support
    if weakness is None or support is None:
        return calibration
    verdict: Literal["weak", "refused"] = "refused" if support.refusals else "weak"
    details = dict(calibration.details)
    diagnostics = details.get("diagnostics")
    if isinstance(diagnostics, dict):  # the warnings the command line prints with the verdict's count
        details["diagnostics"] = {**diagnostics, "warnings": [*(diagnostics.get("warnings") or []), str(weakness)]}
    support = replace(support, verdict=verdict, weaknesses=(*support.weaknesses, weakness))
    return replace(calibration, support=support, details=details)


def weakly_told(fit: MotorFit) -> Reason | None:
    """The weakness of a kept term weakly told from the attitude (ρ of eq. M4 below
    :data:`~magfit.motor.WEAK_INDEPENDENCE`): its one-sigma assumes the model exact, and a misfit the attitude
    explains moves it by ρ^-½ times more; None for a term well told from the attitude."""
    if not fit.fitted or fit.term is None or not fit.independence < WEAK_INDEPENDENCE:
        return None
    return Reason(
        f"the motors' term kept is weakly told from the attitude (ρ = {fit.independence:.3f}): its size, "
        f"{fit.percent:.1f} % ± {fit.percent_sigma:.1f} % of the field at full scale, may be off by more than its "
        "one-sigma says (a misfit the attitude explains moves it); confirm it on a flight that turns and tilts at "
        "low and at high throttle, or with compassmot",
        "motor_weak",
    )


def left_in(tried: Sequence[MotorFit]) -> Reason | None:
    """The weakness of a calibration that leaves the motors' field in: the term estimated (of the regressor whose
    term leaves the smaller residual) and not fitted because it is not told from the attitude
    (``motor_undetermined``), whose interference at full scale exceeds :data:`~magfit.motor.MIN_PERCENT` by
    :data:`LEFT_IN_SIGMAS` one-sigmas; None when there is none.

    The heading it can turn is ``atan(p / 100)`` where the field is horizontal (``p`` the interference in % of the
    field): an error of that size perpendicular to the horizontal field; more where the field dips.
    """
    undetermined = [
        fit for fit in tried
        if fit.term is not None and not fit.fitted and any(r.code == "motor_undetermined" for r in fit.reasons)
        and np.isfinite(fit.percent) and fit.percent - LEFT_IN_SIGMAS * fit.percent_sigma > MIN_PERCENT
    ]  # fmt: skip
    if not undetermined:
        return None
    fit = min(undetermined, key=lambda f: f.residual_rms[1])  # the regressor that explains the field best
    assert fit.term is not None
    kind = fit.term.regressor
    at = f"full current ({fit.term.full_scale:.3g} A)" if kind == "current" else "full throttle"
    heading = float(np.degrees(np.arctan(fit.percent / 100.0)))
    return Reason(
        f"the motors' field is left in: the {kind} does not vary independently of the attitude (ρ = "
        f"{fit.independence:.3f}), so its field cannot be fitted; a fit would put it at {fit.percent:.0f} % ± "
        f"{fit.percent_sigma:.0f} % of the field at {at}, a figure the attitude explains as well; a field that size "
        f"turns the heading by about {heading:.0f}° where the field is horizontal, more where it dips, beyond the "
        "uncertainty stated; record a flight that turns and tilts at low and at high throttle, or calibrate with "
        "the motors off",
        "motor_undetermined",
    )


def _facts(tried: list[tuple[MotorFit, Signal]], chosen: str | None, codes: list[str]) -> dict[str, Any]:
    """What ``details["motor"]`` records: each regressor tried, in words and figures, and the one kept."""
    return {
        "chosen": chosen,
        "codes": codes,
        "tried": [
            {
                "regressor": signal.kind,
                "source": signal.name,
                "summary": result.summary(),
                "percent": result.percent if np.isfinite(result.percent) else None,
                "independence": result.independence if np.isfinite(result.independence) else None,
                "reasons": [Reason.to_dict(reason) for reason in result.reasons],
            }
            for result, signal in tried
        ],
    }
