"""The gyro's rates and times, their units, and the other readings of them the kinematics prefer.

(1) of :mod:`.method` fixes how fast the field turns per unit of ``ω dt``, so a gyro in degrees per second or
times in milliseconds scale the turn by 57.3 or 1000, a lag between the clocks shifts it, and a gyro whose
axes are of the other handedness than the magnetometer's (two swapped, or one sign-flipped: ω is a
pseudovector, ``S ω`` for an improper S is ``−(−S) ω``) turns the field backwards, which no G absorbs. Each
reading (:func:`_readings`, :func:`_lagged_readings`) is scored by the windowed residual of stage 1 over the
turning it explains, ``|r|² / Σ |H dy|²``, a correction that no soft iron gives (an axis squeezed
:data:`MIN_SINGULAR_RATIO`) not counted; one far better than the given reading is refused with its own code
and remedy. Where the windows cannot tell (a slow vehicle) and the fit leaves a large residual, stage 2's
general fit decides (:func:`_check_readings_by_fit`, :func:`_check_handedness`). The handedness is the windows'
to tell only by a factor of :data:`AXES_WINDOWS_GAIN`: turning mostly about one axis, a mirrored gyro turns
the field alike, and where neither the windows nor the fit tell it the recording is refused as such
(``handedness_undetermined``, exit 1), not as the wrong axes.

A gyroscope logged at its own rate is averaged over each magnetometer sample's interval from its running
integral (:func:`_own_rate`): the mean rate over the interval is what turns the field between two samples,
where a rate interpolated at the stamps aliases a fast gyro's vibration.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..._validation import check_rows, check_times
from ...errors import CalibrationError, OptionError
from ...timeunits import time_readings
from .lag import MAX_LAG_S, _delayed
from .model import LINEAR_TURN, SCREEN_ROWS, _fit_model, _Model, _noise_variance, forget_rates
from .windows import (
    GAP_MIN_S,
    GAP_STEPS,
    _constrained,
    _design,
    _windowed_bias,
    _Windows,
    _windows,
    window_length,
)

#: No soft iron squeezes an axis this much (the smallest singular value of H over its largest): a correction
#: that does only fits samples moving in a plane while it ignores the rates.
MIN_SINGULAR_RATIO = 0.05
#: Another reading of the inputs (degrees per second, milliseconds, the other handedness, a lag beyond
#: MAX_LAG_S) is named when its windowed residual is below this share of the given one's.
READING_GAIN = 0.25
#: ... and when it leaves at most this share of the turning unexplained (on a flight the windows' noise leaves
#: the right reading and its mirror image close: docs/methods.md, "gyro").
DECISIVE_SHARE = 0.05
#: Noise variances by which the rates negated (the gyro's axes of the other handedness) must fit better than as
#: given to be refused (the wrong sense fits worse by thousands on simulated vehicles: docs/methods.md, "gyro").
HANDEDNESS_RATIO = 500.0
#: ... when the negated fit's residual sum of squares is within this factor of the samples' white noise.
HANDEDNESS_FLOOR = 1.5
#: The windows alone refuse the other handedness only when its windowed residual is below this share of the given
#: reading's: a tumble's mirror image leaves 1e-3 to 1e-4 of it, a car's 0.02-0.06, but on a boat or a flight
#: (turning mostly about one axis, about which a mirrored gyro turns the field alike) the right reading and its
#: mirror image are within a few times of each other, either way (docs/methods.md, "gyro").
AXES_WINDOWS_GAIN = 0.01
#: Share of the rows repeating the one before exactly above which the compass is taken as held (:func:`_held`).
HELD_SHARE = 0.2
#: Lags beyond MAX_LAG_S are tried, on a grid of WIDE_LAG_STEP_S to MAX_WIDE_LAG_S, when the given reading's
#: windowed residual is over WIDE_LAG_SHARE of the turning it explains (the gyro explains little of it).
WIDE_LAG_STEP_S = 0.25
MAX_WIDE_LAG_S = 10.0
WIDE_LAG_SHARE = 0.1


def _motion(
    gyro: ArrayLike | None, time_s: ArrayLike | None, n: int
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The gyro rates (n, 3) and times (n,), checked; one-line :class:`OptionError` naming what is wrong."""
    if gyro is None:
        raise OptionError(
            "method 'gyro' needs gyro=: the body rates in rad/s, shape (N, 3), one row per magnetometer sample"
        )
    if time_s is None:
        raise OptionError("method 'gyro' needs time_s=: the sample times in seconds, shape (N,)")
    w = check_rows(gyro, "gyro", n, "body rates in rad/s, one row per magnetometer sample")
    return w, check_times(time_s, "time_s", n)


def _held(y: NDArray[np.float64]) -> tuple[NDArray[np.bool_], str] | None:
    """The fresh samples (True where a row differs from the one before) and a note, when at least
    :data:`HELD_SHARE` of the rows repeat the one before exactly: a compass read more slowly than the rows are
    logged (10 Hz in a 50 Hz log), its last reading held. The held rows are the same field at later times: the
    kinematics (1) of :mod:`.method` read them as a field that stopped turning and then jumped. None otherwise
    (noise makes two readings of a turning field differ)."""
    if y.shape[0] < 2:
        return None
    repeated = np.all(y[1:] == y[:-1], axis=1)
    share = float(np.mean(repeated))
    if share < HELD_SHARE:
        return None
    fresh = np.concatenate([[True], ~repeated])
    note = (f"{100 * share:.0f} % of the samples repeat the one before exactly (the compass read more slowly than "
            f"the rows were logged, its reading held): the {int(fresh.sum())} fresh samples are fitted at their own "
            "times, with the gyro's mean rate over each one's interval")  # fmt: skip
    return fresh, note


def _own_rate(gyro: ArrayLike | None, gyro_time_s: ArrayLike,
              t: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.bool_], list[str]]:  # fmt: skip
    """A gyroscope logged at its own rate (M, 3) at ``gyro_time_s`` (M,): its mean rate over each magnetometer
    sample's interval (the midpoints to its neighbours), (n, 3), from the running integral of its own samples.

    Read at the magnetometer's stamps instead (interpolated), a fast gyro's vibration aliases into the slow
    rate: the mean over the interval is what turns the field between two samples. The stages downstream then
    take it as one rate per sample, as they take a gyro logged beside the magnetometer.

    Also returns which samples' intervals overlap a gap of the gyro (a step longer than :data:`GAP_STEPS` of
    its median, and than :data:`GAP_MIN_S`), which the caller drops, and a note per gap: across a gap the
    running integral is a straight line, a turn the gyro never saw.
    """
    if gyro is None:
        raise OptionError("gyro_time_s= was given without gyro=: the body rates in rad/s, shape (M, 3), at those times")
    try:
        w = np.asarray(gyro, dtype=np.float64)
        tg = np.asarray(gyro_time_s, dtype=np.float64)
    except (TypeError, ValueError):
        raise OptionError("gyro= and gyro_time_s= must be numeric arrays") from None
    if tg.ndim != 1 or tg.size < 2 or w.shape != (tg.size, 3):
        raise OptionError(
            f"with gyro_time_s= of shape {tg.shape}, gyro= must have shape (M, 3) with M = len(gyro_time_s) ≥ 2, got "
            f"shape {w.shape}; rows are samples, it is never transposed"
        )
    if not (np.all(np.isfinite(w)) and np.all(np.isfinite(tg))):
        raise OptionError("gyro= and gyro_time_s= must be finite (no NaN or inf): drop or fill those rows first")
    steps = np.diff(tg)
    if np.any(steps <= 0):
        at = int(np.argmax(steps <= 0)) + 1
        raise OptionError(
            f"gyro_time_s= must increase strictly; row {at} ({tg[at]:g} s) does not: sort or de-duplicate"
        )
    span, own_span = float(t[-1] - t[0]), float(tg[-1] - tg[0])
    if not 0.1 * span <= own_span <= 10.0 * span:
        # A span far from the magnetometer's is a unit (milliseconds, microseconds), not a longer log: with
        # gyro_time_s= in ms every interval would read the first fraction of a second of the gyro.
        raise OptionError(
            f"gyro_time_s= spans {own_span:g} units where the magnetometer's time_s= spans {span:g} s "
            f"({own_span / max(span, 1e-300):.3g} times as long): one of them is not in seconds (milliseconds? "
            "divide by 1000; microseconds? by 1e6); give both in seconds on one clock, the gyro trimmed to the "
            "magnetometer's span"
        )
    if t[0] < tg[0] or t[-1] > tg[-1]:
        raise OptionError(
            f"gyro_time_s= spans {tg[0]:g}-{tg[-1]:g} s, the magnetometer's time_s= {t[0]:g}-{t[-1]:g} s: the gyro "
            "must cover every sample (same clock, same unit); trim the samples to the gyro's span"
        )
    turned = np.concatenate([np.zeros((1, 3)), np.cumsum(0.5 * (w[:-1] + w[1:]) * steps[:, None], axis=0)])
    edges = np.concatenate([[t[0] - 0.5 * (t[1] - t[0])], 0.5 * (t[:-1] + t[1:]), [t[-1] + 0.5 * (t[-1] - t[-2])]])
    edges = np.clip(edges, tg[0], tg[-1])
    at_edges = np.column_stack([np.interp(edges, tg, turned[:, axis]) for axis in range(3)])
    rates = np.asarray(np.diff(at_edges, axis=0) / np.diff(edges)[:, None], dtype=np.float64)
    gaps = np.nonzero(steps > max(GAP_STEPS * float(np.median(steps)), GAP_MIN_S))[0]
    dropped = np.zeros(t.size, dtype=bool)
    notes = []
    for gap in gaps:
        # the samples whose interval [edge_k, edge_k+1] overlaps the gap (tg[gap], tg[gap + 1])
        overlap = (edges[1:] > tg[gap]) & (edges[:-1] < tg[gap + 1])
        dropped |= overlap
        if np.any(overlap):
            notes.append(
                f"the gyro has no sample from {tg[gap]:g} s to {tg[gap + 1]:g} s ({steps[gap]:.3g} s, "
                f"{steps[gap] / float(np.median(steps)):.0f} of its steps): the {int(overlap.sum())} magnetometer "
                "samples there were dropped and the integration restarts after it"
            )
    return rates, dropped, notes


def _check_gyro(w: NDArray[np.float64], y: NDArray[np.float64]) -> None:
    """A gyro that never changes while the samples do: not a gyroscope's reading (a stream not logged)."""
    if np.ptp(w, axis=0).max() > 0 or np.ptp(y, axis=0).max() == 0:
        return
    what = "(0, 0, 0)" if not np.any(w) else f"the same rate {tuple(float(v) for v in w[0])}"
    raise CalibrationError(
        f"the samples do not support the gyro calibration: gyro= reads {what} on every row while the samples "
        "change: a gyroscope not logged or not running; give its body rates in rad/s",
        codes=("gyro",),
    )


@dataclass(frozen=True)
class _Reading:
    """One reading of the inputs (module docstring): the rates and times as the
    kinematics would take them, and what the user must change to give them so (code, words, remedy)."""

    code: str
    w: NDArray[np.float64]
    t: NDArray[np.float64]
    words: str = ""
    remedy: tuple[tuple[str, str], ...] = ()
    scale: float | None = None  # the given rates times this (on the given times): their windows are the given's scaled


def _readings(w: NDArray[np.float64], t: NDArray[np.float64]) -> list[_Reading]:
    """The readings compared with the one given: degrees per second, the gyro's axes of the other handedness,
    and time in milliseconds or microseconds where the steps are long enough to be."""
    step = float(np.median(np.diff(t)))
    found = [
        _Reading("gyro_unit", w * (math.pi / 180.0), t,
                 "gyro= looks like degrees per second: give it in rad/s (numpy.radians(gyro))",
                 (("gyro", "numpy.radians(gyro)"),), math.pi / 180.0),
        _Reading("gyro_axes", -w, t,
                 "gyro= turns the field the wrong way round: the gyro's axes are of the other handedness than the "
                 "magnetometer's (two of them swapped, or one with its sign flipped); give them in the order and "
                 "signs of the sensor's datasheet or the firmware's board rotation, right-handed",
                 (("gyro", "the rates about right-handed axes"),), -1.0),
    ]  # fmt: skip
    for reading in time_readings(t):  # the one rule of magfit.timeunits, vector's too
        divisor = reading.divisor
        found.append(_Reading(
            "time_unit", w, t * reading.factor,
            f"time_s= looks like {reading.unit}: its steps are a median {step:.3g} units apart, and the gyro explains "
            f"the samples' turning only with them divided by {divisor}; give it in seconds (time_s / {divisor})",
            (("time_s", f"time_s / {divisor}"),)))  # fmt: skip
    return found


def _lagged_readings(w: NDArray[np.float64], t: NDArray[np.float64]) -> list[_Reading]:
    """The gyro read earlier or later than :data:`MAX_LAG_S` allows: a grid of :data:`WIDE_LAG_STEP_S` out to
    :data:`MAX_WIDE_LAG_S` (at most a quarter of the recording)."""
    reach = min(MAX_WIDE_LAG_S, 0.25 * float(t[-1] - t[0]))
    grid = np.arange(WIDE_LAG_STEP_S, reach + 1e-9, WIDE_LAG_STEP_S)
    return [
        _Reading("lag_at_edge", _delayed(w, t, lag), t,
                 f"the magnetometer and the gyroscope fit only {lag:+.2f} s apart, beyond the ±{MAX_LAG_S:g} s "
                 f"searched: their time stamps are not on one clock; align them, or give lag_s={lag:.2f}",
                 (("lag_s", f"{lag:.2f}"),))
        for lag in (float(sign * value) for value in grid[grid > MAX_LAG_S] for sign in (1.0, -1.0))
    ]  # fmt: skip


def _windowed_share(y: NDArray[np.float64], reading: _Reading, bias: bool = True,
                    given: _Windows | None = None) -> float:  # fmt: skip
    """The windowed residual of stage 1 (the bias fitted, unless ``bias`` is False) over the turning it explains,
    ``|r|² / Σ |H dy|²``; inf when only a correction that no soft iron gives fits (an axis squeezed
    :data:`MIN_SINGULAR_RATIO`: samples that move in a plane are also fitted by a rank-one H that ignores the
    rates). ``given``: the given rates' windows, which a reading with a ``scale`` scales (they are linear in ω)."""
    if given is not None and reading.scale is not None:
        win = _Windows(given.dy, reading.scale * given.M, given.Sy, reading.scale * given.Sw, given.T)
    else:
        win = _windows(y, reading.w, reading.t, window_length(reading.t))
    return _share(win, bias)


def _share(win: _Windows, bias: bool = True) -> float:
    """:func:`_windowed_share` on the windows ``win``."""
    if win.T.size < 20:
        return math.inf
    try:
        beta = _windowed_bias(win)[1] if bias else np.zeros(3)
        h, _, rss = _constrained(_design(win, beta), np.eye(9))
    except np.linalg.LinAlgError:
        return math.inf
    singular = np.linalg.svd(h, compute_uv=False)
    turning = float(np.sum((win.dy @ h.T) ** 2))
    if not (singular[-1] >= MIN_SINGULAR_RATIO * singular[0] and turning > 0):
        return math.inf
    return rss / turning


def _refuse_reading(best: _Reading, how: str) -> None:
    """The one-line error for a reading of the inputs that the samples prefer to the one given."""
    error = CalibrationError if best.code == "lag_at_edge" else OptionError
    raise error(f"{best.words}; {how}", codes=(best.code,), remedy=best.remedy)


def _check_readings(y: NDArray[np.float64], w: NDArray[np.float64], t: NDArray[np.float64],
                    lag_given: bool = False) -> list[_Reading]:  # fmt: skip
    """Refuses inputs that the kinematics read far better another way (stage 1's windows): in degrees per
    second, in milliseconds, of the other handedness, or beyond the lag searched. Returns the candidates the
    windows left open, best first (what :func:`_check_readings_by_fit` tries when the fit is poor)."""
    windows = _windows(y, w, t, window_length(t))
    given = _windowed_share(y, _Reading("given", w, t))
    scored = [(_windowed_share(y, reading, given=windows), reading) for reading in _readings(w, t)]
    if not lag_given and not given < WIDE_LAG_SHARE and min(share for share, _ in scored) >= DECISIVE_SHARE:
        # The gyro explains little of the turning, read any other way too: is it late or early? The lags are
        # ranked without the bias (a tenth of the cost), the best one scored with it.
        lagged = _lagged_readings(w, t)
        shares = [_windowed_share(y, reading, bias=False) for reading in lagged]
        if lagged and min(shares) < math.inf:
            best_lag = lagged[int(np.argmin(shares))]
            scored.append((_windowed_share(y, best_lag), best_lag))
    scored.sort(key=lambda pair: pair[0])
    # The other handedness only where the windows are overwhelming: elsewhere the fit of stage 2 decides
    # (:func:`_check_handedness`).
    told_apart = [(share, reading) for share, reading in scored
                  if reading.code != "gyro_axes" or share < AXES_WINDOWS_GAIN * given]  # fmt: skip
    share, best = told_apart[0] if told_apart else scored[0]
    if share < min(READING_GAIN * given, DECISIVE_SHARE):
        told = (
            "only read so do the kinematics fit with a soft iron" if math.isinf(given)
            else f"read so, the kinematics fit {given / max(share, 1e-300):.0f} times better"
        )  # fmt: skip
        _refuse_reading(best, told)
    return [reading for _, reading in scored]


def _check_readings_by_fit(y: NDArray[np.float64], t: NDArray[np.float64], readings: list[_Reading],
                           segment_s: float, residual_rms: float) -> None:  # fmt: skip
    """The general fit of stage 2 on each open reading (:func:`_check_readings`): one that leaves a third of
    the given reading's residual or less is named (a slow vehicle's windows cannot tell the unit)."""
    for reading in readings:
        length = window_length(reading.t)
        try:
            win = _windows(y, reading.w, reading.t, length)
            _, beta = _windowed_bias(win)
            h, c, _ = _constrained(_design(win, beta), np.eye(9))
            offset = np.asarray(np.linalg.lstsq(h, c, rcond=None)[0], dtype=np.float64)
            start = np.asarray(np.linalg.inv(h), dtype=np.float64)
            model = _fit_model(y, reading.w, reading.t, segment_s, "general", start, offset, beta, SCREEN_ROWS,
                               turn=LINEAR_TURN, loose=True)  # fmt: skip
        except np.linalg.LinAlgError:
            continue
        g = model.traj.distortion(model.solution.params)
        singular = np.linalg.svd(g, compute_uv=False)
        if not singular[-1] >= MIN_SINGULAR_RATIO * singular[0]:
            continue
        strength = abs(float(np.linalg.det(g))) ** (1.0 / 3.0)
        rms = math.sqrt(model.rss / model.traj.rows.size) / strength
        if rms < residual_rms / 3.0:
            how = f"the samples leave {100 * residual_rms:.0f} % of the field off the turning the gyro predicts"
            if reading.code == "gyro_axes":  # the other handedness only where _check_handedness found it
                _cannot_tell(f"{how} as given, {100 * rms:.1f} % with the rates negated, short of what tells it: "
                             f"{HANDEDNESS_RATIO:.0f} noise variances, the negated fit at the samples' noise")
            _refuse_reading(reading, f"{how} as given, {100 * rms:.1f} % read so")


def _check_handedness(y: NDArray[np.float64], w: NDArray[np.float64], t: NDArray[np.float64], win: _Windows,
                      segment_s: float, general: _Model) -> None:  # fmt: skip
    """The general fit of stage 2 with the rates negated (the gyro's axes of the other handedness, module
    docstring): far better by :data:`HANDEDNESS_RATIO` noise variances is refused. Where the windows cannot
    tell (a boat's roll, a flight), this fit can (docs/methods.md, "gyro"); where they tell the rates as given
    :data:`AXES_WINDOWS_GAIN` apart from the negated ones (a tumble), it is not run. Where the windows prefer the
    negated rates (:data:`READING_GAIN`) and this fit does not prefer the given ones as far, the recording
    cannot tell the handedness: refused so, with what would tell it."""
    negated = _Windows(win.dy, -win.M, win.Sy, -win.Sw, win.T)
    given_share, negated_share = _share(win), _share(negated)
    if given_share < DECISIVE_SHARE and AXES_WINDOWS_GAIN * negated_share > given_share:
        return  # the windows tell it, as they tell the other handedness (:data:`AXES_WINDOWS_GAIN`): as given
    suspected = negated_share < min(READING_GAIN * given_share, DECISIVE_SHARE)
    try:
        _, beta = _windowed_bias(negated)
        h, c, _ = _constrained(_design(negated, beta), np.eye(9))
        offset = np.asarray(np.linalg.lstsq(h, c, rcond=None)[0], dtype=np.float64)
        start = np.asarray(np.linalg.inv(h), dtype=np.float64)
        negated_rates = -w
        try:
            mirrored = _fit_model(y, negated_rates, t, segment_s, "general", start, offset, beta, SCREEN_ROWS,
                                  turn=LINEAR_TURN, loose=True)  # fmt: skip
        finally:
            forget_rates(negated_rates)  # (its integration is the recording's size)
    except np.linalg.LinAlgError:
        return
    g = mirrored.traj.distortion(mirrored.solution.params)
    singular = np.linalg.svd(g, compute_uv=False)
    if not singular[-1] >= MIN_SINGULAR_RATIO * singular[0]:
        return
    ratio = (general.rss - mirrored.rss) / max(_noise_variance(mirrored), 1e-300)
    # ... and the negated fit must follow the samples to about their own white noise (third differences): a
    # given fit that is poor for another reason (a flight that hardly turned, a lag) is not beaten by a
    # negated one that is merely less poor.
    third = np.diff(y, n=3, axis=0)
    floor = 3 * mirrored.traj.rows.size * float(np.median(np.sum(third**2, axis=1))) / (20.0 * 2.3660)
    if ratio > HANDEDNESS_RATIO and mirrored.rss < HANDEDNESS_FLOOR * floor:
        reading = next(r for r in _readings(w, t) if r.code == "gyro_axes")
        _refuse_reading(reading, f"with the rates negated, the samples follow the turning {ratio:.0f} noise "
                                 "variances better")  # fmt: skip
    told = (mirrored.rss - general.rss) / max(_noise_variance(general), 1e-300)
    if suspected and not (told > HANDEDNESS_RATIO and general.rss < HANDEDNESS_FLOOR * floor):
        _cannot_tell(f"the windows fit the rates negated {given_share / max(negated_share, 1e-300):.1f} times better, "
                     f"the fit of every sample the rates as given {told:.0f} noise variances better, where "
                     f"{HANDEDNESS_RATIO:.0f} would tell")  # fmt: skip


def _cannot_tell(evidence: str) -> None:
    """The refusal of a recording that does not tell the gyro's handedness (``evidence``: what was seen)."""
    raise CalibrationError(
        "the samples do not support the gyro calibration: they do not tell the gyroscope's handedness against the "
        f"magnetometer's ({evidence}): turning mostly about one axis, as a boat rolls or an aircraft turns, a "
        "mirrored gyroscope turns the field alike; record a few tilts about a second axis (rolls and pitches), or "
        "calibrate with the logged attitude and the known field (method vector or align), and check the gyro's axes "
        "and signs against the sensor's datasheet",
        codes=("handedness_undetermined",), remedy=(("method", "vector"),),
    )
