"""Gyro-aided calibration (``method="gyro"``): hard and soft iron (and the axes) from the rotation kinematics,
without a tumble.

The Earth's field is constant in the world, so in the gyroscope's (body) frame the field ``b`` turns against
the body rate ``ω``: ``db/dt = −ω × b`` (Poisson's equation). The magnetometer reads ``y = G b + V`` (the
paper's eq. (1) with ``G = W Mᵀ``: soft iron W times the rotation Mᵀ from the gyroscope's axes into the
magnetometer's), so with ``H = G⁻¹`` and ``c = H V``::

    H dy/dt = −ω × (H y − c)                                      (1)

linear in (H, c) and homogeneous (the overall scale, and the sign, are free): the equation of MAGYC
(Rodríguez et al., "MAGYC: magnetometer and gyroscope calibration", IEEE J. Oceanic Eng. / arXiv:2410.13827,
2024), which there takes H symmetric (gyro and magnetometer axes assumed the same), differentiates the
samples and adds the gyro's bias β in ``ω = ω_measured − β``. TWOSTEP (Alonso & Shuster, J. Astronaut. Sci.
50(4), 2002) uses the field's magnitude only; Huang, Hendeby & Skog ("Joint magnetometer-IMU calibration via
maximum a posteriori estimation", arXiv:2505.16662, 2025) estimate the calibration with the orientation
trajectory as unknowns, which stage 2 does in a reduced form. Three stages, one module each:

1. :mod:`.windows`: (1) integrated over windows of about a second, solved by total least squares, then the
   gyro bias by Gauss-Newton on the same residual.
2. :mod:`.model`: maximum likelihood on the samples, ``y_k = G R_kᵀ b₀ + V`` over stretches (R_k from
   :mod:`.kinematics`), with the accelerometer's gravity rows (2) of :mod:`.gravity` when given.
3. :mod:`.mapping`, :mod:`.choice`: the standard axis mappings ``G = W Pᵀ`` against the general G, by their
   likelihood ratio.

Before them the inputs are checked and read (:mod:`.rates`: units, handedness, clocks; :mod:`.lag`: the
magnetometer's delay); after them :mod:`.judge` says what the motion determines. :func:`fit_gyro` runs these
steps in that order. The choices' measured figures: docs/methods.md, "gyro".
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..._validation import check_inclination
from ...calibration import Calibration
from ...diagnostics.verdict import USELESS_BOUND_DEG
from ...errors import CalibrationError, OptionError
from ...facts import GyroFacts, SolverStatus
from ...findings import Reason, Support
from ...rotations import angle_between_deg, axis_words, polar_decomposition
from ..registry import FitInput, fit_input, register
from .choice import LIKELIHOOD_RATIO, _choose
from .gravity import _accel, _gravity
from .inclination import _dip, _field_sense, _gravity_residual, _inclination_disagreement
from .judge import _ADVICE, HALVES_SIGMAS, LARGE_RESIDUAL, SINGLE_AXIS, _halves, _heading_sigma, _support
from .lag import _delayed, _search_lag
from .mapping import MAPPINGS, mapping_name
from .model import _covariance, _gyro_scale, _Model, forget_integration
from .rates import _check_gyro, _check_readings, _check_readings_by_fit, _held, _motion, _own_rate, _Reading
from .windows import WINDOW_S, _turn_axes, _windowed_bias, _Windows, _windows, forget_frame, window_length


@register(
    "gyro",
    min_samples=50,
    data="samples",
    summary="gyro-aided: hard iron, soft iron and the axes from the rotation kinematics (no tumble needed)",
    needs=("gyro", "time_s"),
)
def fit_gyro(
    data: FitInput,
    *,
    gyro: ArrayLike | None = None,
    time_s: ArrayLike | None = None,
    mapping: str = "search",
    segment_s: float = 10.0,
    lag_s: float | str = "search",
    accel: ArrayLike | None = None,
    gyro_time_s: ArrayLike | None = None,
    inclination_deg: float | None = None,
) -> Calibration:
    """Hard iron, soft iron and the magnetometer's axes in the gyroscope's, from the rotation kinematics.

    Parameters
    ----------
    data : FitInput
        The magnetometer samples (N, 3), any unit, in recording order.
    gyro : array_like, shape (N, 3)
        Body rates in rad/s, one row per sample (same clock), or (M, 3) at ``gyro_time_s``. Its constant bias
        is estimated.
    time_s : array_like, shape (N,)
        Sample times in seconds, strictly increasing.
    mapping : str
        ``"search"`` (the standard axis mappings tried, the general matrix kept when none fits),
        ``"general"`` (any rotation, no search), or a name of :data:`MAPPINGS` (``"+x+y+z"``: the axes
        coincide, MAGYC's model).
    segment_s : float
        Length of the stretches over which the gyro is integrated (:mod:`.model`, stage 2).
    lag_s : float or "search"
        The magnetometer's delay behind the gyroscope, seconds: searched within ±0.25 s on the windowed
        residual by default (``calibration.gyro.lag_s``), or given.
    gyro_time_s : array_like, shape (M,), optional
        The gyroscope's own times (seconds, the magnetometer's clock) when it is logged at its own rate: then
        ``gyro`` is (M, 3) and is averaged over each magnetometer sample's interval, not interpolated.
    accel : array_like, shape (N, 3), optional
        The accelerometer's specific force in the gyroscope's axes, any unit, one row per sample, on the
        gyroscope's clock: adds the gravity rows (2) where it sees gravity alone (:mod:`.gravity`).
    inclination_deg : float, optional
        The local field's inclination (the World Magnetic Model's), degrees: with ``accel``, a fitted dip that
        differs from it by more than :data:`INCLINATION_SIGMAS` times its one-sigma and
        :data:`INCLINATION_MODEL_DEG` combined (signs aside: the accelerometer's sign is free) means the
        accelerometer's calibration or alignment is off: its rows are dropped, the fit is the one without
        them, and the verdict is at most weak, saying so. Without it that is not checked (a weakness where
        the gravity rows carry the fit).

    Returns
    -------
    Calibration
        ``frame="vehicle"``: ``matrix`` turns into the gyroscope's axes (a proper rotation: a mirrored
        magnetometer cannot be told from a proper one by the kinematics), ``|det| = 1``; ``field_strength``
        the fitted magnitude. ``details``: the gyro bias and its one-sigma (rad/s), the mapping and the
        likelihood ratios that chose it, the rotation and its angle from the nearest standard mapping, the
        offset's one-sigma, ``sensor_matrix`` (the symmetric, magnitude-only root), and the verdict
        (``support``). With ``accel``: ``gravity`` (``used``, ``still_samples``, ``dropped``, ``notes``, and
        when used ``weight``, ``residual_rms_deg``, ``inclination_deg`` with ``inclination_sigma_deg``; when
        not, the ``reason``; ``inclination_given_deg`` when checked). With ``gyro_time_s``: ``gyro_gaps``, a
        line per gap of the gyro whose samples were dropped (``n_samples`` counts those kept).

    Raises
    ------
    OptionError
        gyro= or time_s= missing, of the wrong shape, not finite, not increasing, or in degrees per second;
        gyro_time_s= likewise, not covering the samples, or spanning more than 10 times or less than a tenth
        of time_s= (another unit); accel= of the wrong shape, not finite, or a row of zeros; inclination_deg
        ±90 or beyond. With accel=, a field that comes out pointing up against the accelerometer's down (or
        against the sign of inclination_deg= when given): a magnetometer left-handed against the gyroscope,
        which the kinematics calibrate with the field reversed (``mag_handedness``, naming the axis to negate
        or the two to swap; :func:`.inclination._field_sense`).
    CalibrationError
        Too short a recording, or one that turned about one axis only (named).
    """
    try:
        return _fit_gyro(data, gyro=gyro, time_s=time_s, mapping=mapping, segment_s=segment_s, lag_s=lag_s,
                         accel=accel, gyro_time_s=gyro_time_s, inclination_deg=inclination_deg)  # fmt: skip
    except np.linalg.LinAlgError:  # degenerate inputs the checks above let through (rates of 1e-300 rad/s)
        raise CalibrationError(
            "the samples do not support the gyro calibration: with these rates and samples the kinematics are "
            f"singular (no turning the gyro and the samples agree on); {_ADVICE}",
            codes=("gyro",),
        ) from None
    finally:
        forget_integration()
        forget_frame()


def _fit_gyro(data: FitInput, *, gyro: ArrayLike | None, time_s: ArrayLike | None, mapping: str, segment_s: float,
              lag_s: float | str, accel: ArrayLike | None, gyro_time_s: ArrayLike | None,
              inclination_deg: float | None) -> Calibration:  # fmt: skip
    """:func:`fit_gyro`'s work (its docstring), step by step (module docstring)."""
    inputs = _inputs(data, gyro, time_s, accel, gyro_time_s, mapping, segment_s, inclination_deg)
    aligned = _aligned(inputs, lag_s)
    beta, turns_deg = _turning(aligned.win)
    fitted = _fitted(aligned, beta, mapping, segment_s, inputs.inclination)
    return _calibration(inputs, aligned, fitted, turns_deg, mapping, segment_s, lag_s)


@dataclass(frozen=True)
class _Inputs:
    """The checked inputs: samples ``y``, rates ``w``, times ``t``, accelerometer ``a`` (those in the gyro's gaps
    dropped, noted in ``gap_notes``), the given inclination, and the note on a held compass's repeats (only its
    fresh samples kept, :func:`.rates._held`)."""

    y: NDArray[np.float64]
    w: NDArray[np.float64]
    t: NDArray[np.float64]
    a: NDArray[np.float64] | None
    gap_notes: list[str]
    inclination: float | None
    held: str | None = None


def _inputs(data: FitInput, gyro: ArrayLike | None, time_s: ArrayLike | None, accel: ArrayLike | None,
            gyro_time_s: ArrayLike | None, mapping: str, segment_s: float,
            inclination_deg: float | None) -> _Inputs:  # fmt: skip
    """The samples, rates, times and accelerometer checked (:mod:`.rates`, :mod:`.gravity`), and the options."""
    y = fit_input(data, "gyro").require_samples("gyro")
    n = y.shape[0]
    gap_notes: list[str] = []
    kept = np.ones(n, dtype=bool)
    if gyro_time_s is not None:
        _, t = _motion(np.zeros((n, 3)), time_s, n)  # the magnetometer's times checked first
        gyro, dropped, gap_notes = _own_rate(gyro, gyro_time_s, t)
        kept = ~dropped
    w, t = _motion(gyro, time_s, n)
    a = None if accel is None else _accel(accel, n)
    held = _held(y) if gyro_time_s is None else None
    note = None
    if held is not None:  # the fresh samples at their own times, the gyro (logged on every row) at its own
        fresh, note = held
        w, dropped, gap_notes = _own_rate(w, t, t[fresh])
        y, t, a = y[fresh], t[fresh], None if a is None else a[fresh]
        kept = ~dropped
    if not kept.all():  # samples the gyro never saw turning: dropped, the stretches restart after them
        y, w, t = y[kept], w[kept], t[kept]
        a = None if a is None else a[kept]
        if y.shape[0] < 50:
            raise CalibrationError(
                f"the samples do not support the gyro calibration: {y.shape[0]} samples are left once those in the "
                f"gyro's gaps (or repeating the one before) are dropped; {_ADVICE}",
                codes=("too_few_samples",),
            )
    if mapping not in ("search", "general") and mapping not in MAPPINGS:
        raise OptionError(
            f"mapping={mapping!r} is not valid; choose 'search', 'general' or one of: {', '.join(MAPPINGS)}"
        )
    if not segment_s > 0:
        raise OptionError(f"segment_s must be positive, got {segment_s!r}")
    if inclination_deg is not None:
        inclination_deg = check_inclination(inclination_deg)
    return _Inputs(y, w, t, a, gap_notes, inclination_deg, note)


@dataclass(frozen=True)
class _Aligned:
    """The inputs on one clock: the gyro read ``lag`` seconds earlier, the samples it has no reading for dropped
    (the accelerometer's with them, read late by :func:`_fitted`), the windows of stage 1 of ``length`` samples,
    and the readings the windows left open."""

    y: NDArray[np.float64]
    w: NDArray[np.float64]
    t: NDArray[np.float64]
    a: NDArray[np.float64] | None
    lag: float
    length: int
    win: _Windows
    open_readings: list[_Reading]


def _aligned(inputs: _Inputs, lag_s: float | str) -> _Aligned:
    """The lag found or given (:mod:`.lag`), the readings of the inputs checked (:mod:`.rates`), the windows."""
    y, w, t, a = inputs.y, inputs.w, inputs.t, inputs.a
    length = window_length(t)
    win = _windows(y, w, t, length)
    if win.T.size < 20:
        raise CalibrationError(
            f"the samples do not support the gyro calibration: the recording is too short, {win.T.size} windows "
            f"of {length} samples where 20 are needed (about {20 * WINDOW_S:.0f} s); {_ADVICE}",
            codes=("too_few_samples",),
        )
    _check_gyro(w, y)
    if lag_s == "search":
        open_readings = _check_readings(y, w, t)
        lag = _search_lag(y, w, t, length)
    elif isinstance(lag_s, (int, float)) and math.isfinite(lag_s):
        lag = float(lag_s)
        open_readings = _check_readings(y, _delayed(w, t, lag), t, lag_given=True)
    else:
        raise OptionError(f"lag_s must be 'search' or a number of seconds, got {lag_s!r}")
    w = _delayed(w, t, lag)
    inside = (t - lag >= t[0]) & (t - lag <= t[-1])
    if not inside.all():  # the gyro read before its first sample or after its last: held, not measured
        y, w, t = y[inside], w[inside], t[inside]
        a = None if a is None else a[inside]
    win = _windows(y, w, t, length)
    if win.T.size < 20:
        raise CalibrationError(
            f"the samples do not support the gyro calibration: {y.shape[0]} samples are left where the gyro, "
            f"{lag:+.3g} s apart, has a reading; {_ADVICE}",
            codes=("too_few_samples",),
        )
    return _Aligned(y, w, t, a, lag, length, win, open_readings)


def _turning(win: _Windows) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Stage 1's gyro bias and the turning about each principal axis (degrees); turning about one axis only is
    refused (:mod:`.judge`)."""
    beta = _windowed_bias(win)[1]
    turns_deg, axes = _turn_axes(win, beta)
    if turns_deg[1] < SINGLE_AXIS * turns_deg[0]:
        raise CalibrationError(
            "the samples do not support the gyro calibration: the vehicle turned about "
            f"{axis_words(axes[:, 0], 'gyro')} only (its turning about any other axis is "
            f"{100 * turns_deg[1] / turns_deg[0]:.1f} % of that): the kinematics then fix the offset across that "
            "axis and the distortion of the plane perpendicular to it, but the offset and the scale along it move "
            f"with the field's component along it, which never changes, so they are fixed by nothing; {_ADVICE}",
            codes=("single_axis",),
        )
    return beta, turns_deg


@dataclass(frozen=True)
class _Fitted:
    """The model kept (:mod:`.choice`), the candidates' likelihood ratios, the mappings not told apart, the
    accelerometer's disagreement with the given inclination, and ``calibration.gyro.gravity``."""

    model: _Model
    excess: dict[str, float]
    ambiguous: tuple[str, str, float] | None
    disagreement: str | None
    gravity_facts: dict[str, Any]


def _fitted(aligned: _Aligned, beta: NDArray[np.float64], mapping: str, segment_s: float,
            inclination_deg: float | None) -> _Fitted:  # fmt: skip
    """Stages 2 and 3, with the gravity rows when the accelerometer sees gravity alone and agrees with the given
    inclination (:mod:`.inclination`), else without them."""
    y, w, t, a, win = aligned.y, aligned.w, aligned.t, aligned.a, aligned.win
    # The accelerometer on the gyroscope's clock; its still samples gated on the rates with stage 1's bias taken
    # off (a rolling boat has no steady stretch for gravity.still_samples to take it from, and a bias of a
    # degree per second then reads as turning on every sample).
    gravity, gravity_facts = (None, {}) if a is None else _gravity(_delayed(a, t, aligned.lag), y, w - beta, t)
    model, excess, ambiguous = _choose(y, w, t, win, mapping, segment_s, gravity)
    disagreement = None
    if model.traj.gravity is not None and inclination_deg is not None:
        disagreement = _inclination_disagreement(model, inclination_deg)
        gravity_facts["inclination_given_deg"] = float(inclination_deg)
        if disagreement is not None:
            gravity_facts.update({"used": False, "reason": disagreement, **_dip(model)})
            model, excess, ambiguous = _choose(y, w, t, win, mapping, segment_s, None)
    return _Fitted(model, excess, ambiguous, disagreement, gravity_facts)


def _calibration(inputs: _Inputs, aligned: _Aligned, fitted: _Fitted, turns_deg: NDArray[np.float64],
                 mapping: str, segment_s: float, lag_s: float | str) -> Calibration:  # fmt: skip
    """The correction with its verdict (:func:`_verdict`) and its facts in ``details``."""
    y, lag, length, gap_notes = aligned.y, aligned.lag, aligned.length, inputs.gap_notes
    model, excess, gravity_facts = fitted.model, fitted.excess, fitted.gravity_facts
    traj, solution = model.traj, model.solution
    k = traj.k
    g, offset, beta, covariance, strength, matrix, scale_facts = _correction(model, gravity_facts)
    if aligned.a is not None:  # the field's sense, which the kinematics leave free, from the accelerometer
        reversed_field = _field_sense(y, _delayed(aligned.a, aligned.t, lag), offset, matrix, inputs.inclination)
        if reversed_field is not None and inputs.inclination is None:  # a mirror, or the southern hemisphere
            raise CalibrationError(f"the gyro calibration is refused: {reversed_field}",
                                   codes=("handedness_undetermined",))  # fmt: skip
        if reversed_field is not None:  # against the inclination given: the magnetometer's axes are mirrored
            raise OptionError(f"the gyro calibration is refused: {reversed_field}", codes=("mag_handedness",))
    rotation, symmetric = polar_decomposition(matrix)
    nearest = mapping_name(rotation)
    angle = angle_between_deg(MAPPINGS[nearest], rotation)
    support, residual_rms, heading_sigma = _verdict(inputs, aligned, fitted, turns_deg, g, offset, covariance,
                                                    matrix, strength, mapping, segment_s, lag_s)  # fmt: skip
    diagonal = np.sqrt(np.clip(np.diag(covariance), 0, None))
    facts = GyroFacts(
        mapping="general" if model.name == "general" else nearest,
        nearest_mapping=nearest,
        angle_from_nearest_deg=angle,
        rotation=_rows(rotation),
        sensor_matrix=_rows(symmetric),
        bias=tuple(float(v) for v in beta),
        bias_sigma=tuple(float(v) for v in diagonal[k + 3 : k + 6]),
        heading_sigma_deg=heading_sigma,
        lag_s=lag,
        gravity=gravity_facts or None,
    )
    solver = SolverStatus(iterations=solution.iterations, message=solution.message)
    details: dict[str, Any] = {  # free-form figures no other code reads
        "mapping_likelihood_ratios": excess,
        "mirror": "not determined by the kinematics: the magnetometer is taken to be right-handed (checked against "
        "the accelerometer's down when given)",
        "offset_sigma": diagonal[k : k + 3].tolist(),
        "residual_rms": residual_rms,
        "turns_deg": turns_deg.tolist(),
        "segments": traj.count,
        "window_samples": length,
        "solver_status": solution.status,
        **scale_facts,
    }
    if gap_notes:
        details["gyro_gaps"] = gap_notes
    if inputs.held is not None:
        details["held_samples"] = inputs.held
    return Calibration(
        "gyro", offset, matrix, strength, n_samples=int(y.shape[0]), details=details, frame="vehicle",
        support=support, solver=solver, gyro=facts,
    )  # fmt: skip


def _rows(matrix: NDArray[np.float64]) -> tuple[tuple[float, ...], ...]:
    return tuple(tuple(float(v) for v in row) for row in matrix)


_Correction = tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], float,
                    NDArray[np.float64], dict[str, list[float]]]  # fmt: skip


def _correction(model: _Model, gravity_facts: dict[str, Any]) -> _Correction:
    """G, V, β, the covariance of p, the field's magnitude ``|det G|^⅓``, the proper correction
    ``matrix = ±G⁻¹ |det G|^⅓`` and the gyro's scale (:func:`.model._gyro_scale`: p corrected for a scale error
    the recording determines, the covariance widened by what it leaves unknown); the gravity rows' fit goes to
    ``gravity_facts``."""
    traj, solution = model.traj, model.solution
    k = traj.k
    covariance = _covariance(traj, solution.params)
    p, added, scale, scale_covariance = _gyro_scale(traj, solution.params)
    covariance = covariance + added
    scale_facts = {"gyro_scale_correction": scale.tolist(),
                   "gyro_scale_sigma": np.sqrt(np.clip(np.diag(scale_covariance), 0, None)).tolist()}  # fmt: skip
    g = traj.distortion(p)
    offset, beta = p[k : k + 3], p[k + 3 : k + 6]

    strength = abs(float(np.linalg.det(g))) ** (1.0 / 3.0)
    matrix = np.linalg.inv(g) * strength
    if np.linalg.det(matrix) < 0:  # −H fits alike (a field and its negative turn alike): take the proper one
        matrix = -matrix
    if traj.gravity is not None:
        gravity_residual, _ = _gravity_residual(model, traj.gravity)
        gravity_facts.update({
            "weight": traj.gravity.weight,
            "residual_rms_deg": math.degrees(float(np.sqrt(np.mean(gravity_residual**2)))),
            **_dip(model, covariance),
        })  # fmt: skip
    return g, offset, beta, covariance, strength, matrix, scale_facts


def _verdict(inputs: _Inputs, aligned: _Aligned, fitted: _Fitted, turns_deg: NDArray[np.float64],
             g: NDArray[np.float64], offset: NDArray[np.float64], covariance: NDArray[np.float64],
             matrix: NDArray[np.float64], strength: float, mapping: str, segment_s: float,
             lag_s: float | str) -> tuple[Support, float, float]:  # fmt: skip
    """The verdict (:mod:`.judge`), the residual RMS (fraction of the field) and the heading one-sigma (degrees).
    A large residual first has the other readings of the inputs tried by the fit (:mod:`.rates`)."""
    y, t, a, lag, open_readings = aligned.y, aligned.t, aligned.a, aligned.lag, aligned.open_readings
    model, excess, ambiguous, disagreement = fitted.model, fitted.excess, fitted.ambiguous, fitted.disagreement
    gravity_facts, inclination_deg = fitted.gravity_facts, inputs.inclination
    traj, p, k = model.traj, model.solution.params, model.traj.k
    residual = traj.magnetometer_residual(p)
    residual_rms = float(np.sqrt(np.mean(np.sum(residual**2, axis=1)))) / strength
    if residual_rms > LARGE_RESIDUAL:  # the windows cannot tell the readings apart on a slow vehicle: the fit can
        _check_readings_by_fit(y, t, open_readings, segment_s, residual_rms)
    values, vectors = np.linalg.eigh(covariance[k : k + 3, k : k + 3])
    offset_sigma = np.sqrt(np.clip(values, 0, None)) / strength
    heading_sigma = _heading_sigma(g, offset, covariance, traj)
    field = np.einsum("ij,kj->ki", matrix, y - offset)
    directions = field / np.linalg.norm(field, axis=1)[:, None]
    mean = directions.mean(axis=0)
    spread = np.arccos(np.clip(np.einsum("kj,j->k", directions, mean / max(float(np.linalg.norm(mean)), 1e-12)), -1, 1))
    span_deg = 2.0 * float(np.degrees(spread.max()))
    unused = None if a is None or traj.gravity is not None else str(gravity_facts.get("reason", ""))
    support = _support(ambiguous, offset_sigma, vectors, heading_sigma, residual_rms, span_deg, lag, turns_deg,
                       gravity=traj.gravity is not None, accel_unused=unused,
                       inclination_checked=inclination_deg is not None, disagreement=disagreement,
                       lag_searched=lag_s == "search")  # fmt: skip
    halves = _halves(model, segment_s) if support.verdict != "refused" else None
    if halves is not None and halves[0] > HALVES_SIGMAS * halves[1]:
        # Two halves apart by d beyond their noise: the whole lies between them, up to d/2 from either, and the
        # one-sigma stated must hold that (the model's own, from the scatter, does not); beyond the useless bound
        # it is no calibration.
        heading_sigma = max(heading_sigma, halves[0] / 2.0)
        apart = Reason(
            f"the two halves of the recording give headings {halves[0]:.2g}° apart (RMS over level headings), "
            f"{halves[0] / max(halves[1], 1e-12):.1f} times their combined one-sigma (±{halves[1]:.2g}°): the field, "
            "the gyro's bias or the clocks changed between them; the heading one-sigma stated holds half their "
            f"difference, ±{heading_sigma:.2g}°", "inconsistent_halves")  # fmt: skip
        if heading_sigma > USELESS_BOUND_DEG:
            support = replace(support, verdict="refused", refusals=(*support.refusals, Reason(
                f"{apart}: beyond {USELESS_BOUND_DEG:g}°, a bound that wide is no calibration; record a flight whose "
                "field and gyro stay steady (no magnet, payload or power change between its halves)",
                "inconsistent_halves")))  # fmt: skip
        else:
            support = replace(support, verdict="weak", weaknesses=(*support.weaknesses, apart))
    if mapping in MAPPINGS and excess.get(mapping, 0.0) > LIKELIHOOD_RATIO:
        support = replace(support, verdict="weak" if support.verdict == "supported" else support.verdict,
                          weaknesses=(*support.weaknesses, Reason(
                                      f"the mapping given ({mapping}) fits {excess[mapping]:.0f} noise variances worse "
                                      "than a general rotation of the axes: the mounting is likely turned from it "
                                      "(mapping='search' reports by how much)", "gyro")))  # fmt: skip
    return support, residual_rms, heading_sigma
