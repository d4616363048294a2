"""The motors' field in the log pipeline: :func:`motor_stage`, called once per compass by ``calibrate_file``.

After the method's fit, the log's current and throttle (:mod:`magfit.sources.power`) are tried as regressors
of the joint fit (:func:`magfit.motor.fit_motor`, docs/methods.md eq. M1-M4). When a term is kept, the method
runs again on ``raw − k c`` (:func:`magfit.motor.with_motor`), so that its verdict and diagnostics speak of the
calibration returned, and the calibration holds the term. Either way the user is told, in words.
"""

from __future__ import annotations

import functools
import os
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..calibration import Calibration
from ..errors import CalibrationError, DataFileError, OptionError
from ..findings import Reason
from ..motor import MOTOR_CHOICES, MotorFit, fit_motor, with_motor
from ..sources import LogSamples, Source
from ..sources.power import Power, Signal, read_power

__all__ = ["MotorOutcome", "motor_stage"]


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
                "give motor='auto' or 'none'",
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
        return MotorOutcome(replace(calibration, details=details), read.samples, notes, tried[0][0])
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
    final = replace(final, details=details)
    cleaned = read.samples - result.term.field(_clamped(times, signal, result.term.lag_s))
    return MotorOutcome(final, cleaned, notes, result)


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
