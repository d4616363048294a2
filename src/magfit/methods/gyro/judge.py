"""What the motion determines: the verdict of a gyro-aided fit.

Turning about one axis ``a`` only, ``b``'s component along ``a`` stays constant, so ``G a`` and V along the
plane's normal are confounded: the kinematics fix the offset across ``a`` and the distortion of the plane
perpendicular to ``a`` (even from part of a turn: the gyroscope says how far it turned), never the offset
along the normal nor the scale along ``a``. A second rotation axis, even a little bank, makes everything
determined in principle; how well is the covariance of stage 2 (:func:`.model._covariance`): an offset
one-sigma above :data:`UNDETERMINED_OFFSET` of the field is a refusal, above :data:`WEAK_OFFSET` a weakness,
each with the heading error it causes. The heading one-sigma (:func:`_heading_sigma`) is the RMS over eight
level headings, the field dipping 60°, of::

    σ_ψ² = ∇ψᵀ Σ_(q,V) ∇ψ,    ψ = atan2(−b_y, b_x),  b = G⁻¹ (y − V)                   (J1)

with ∇ψ by finite differences in G's parameters and V. The model fitted again on each half of the
recording (:func:`_halves`) must agree within :data:`HALVES_SIGMAS` of their combined heading one-sigmas,
or the disagreement is named.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ...diagnostics.reference import HALVES_SIGMAS as HALVES_SIGMAS  # (the same bound as vector's)
from ...findings import ReasonList, Support
from ...rotations import axis_words
from .choice import LIKELIHOOD_RATIO
from .gravity import ACCEL_BIAS_PRIOR, MIN_GRAVITY_SAMPLES
from .lag import MAX_LAG_S
from .model import _covariance, _fit_model, _Model, _parts, _Trajectory
from .windows import WINDOW_S

#: The samples' residual RMS (fraction of the field) beyond which the fit is weak, and the other readings of
#: the inputs are tried by the fit.
LARGE_RESIDUAL = 0.05
#: Offset one-sigmas (fraction of the field) above which the offset is not determined / weakly determined.
UNDETERMINED_OFFSET = 0.05
WEAK_OFFSET = 0.01
#: The halves' fits stop at a step shorter than this many standard errors: their headings are then within about
#: this share of their one-sigma of their own minimum, and judged against HALVES_SIGMAS of them (docs/methods.md,
#: "gyro": the differences and one-sigmas measured against the solver's own 1e-3).
HALVES_STEP = 0.05
#: Turning about the second principal axis below this share of the first: turned about one axis only.
SINGLE_AXIS = 0.02
#: Largest turn (degrees) of the field seen in the samples' frame below which the sensor hardly turned.
MIN_TURN_DEG = 30.0
#: Without the accelerometer, turning about the third principal axis below this share of the first with a field
#: direction spanning less than NARROW_TURN_DEG is weak: a boat rolling on one heading, whose one-sigma then
#: understates its heading error (docs/methods.md, "gyro", for the figures that set both limits).
NARROW_THIRD_AXIS = 0.2
NARROW_TURN_DEG = 60.0
_ADVICE = (
    "record while the vehicle turns about at least two of its axes (turns with banks, a few rolls and pitches, "
    "or a tumble), with the gyroscope logged at the magnetometer's rate on the same clock"
)


def _heading_sigma(g: NDArray[np.float64], offset: NDArray[np.float64], covariance: NDArray[np.float64],
                   traj: _Trajectory) -> float:  # fmt: skip
    """RMS over eight level headings of the heading one-sigma (degrees) that the covariance of (q, V) gives.

    The field dips 60° (the diagnostics' default inclination); the heading of the corrected body field,
    ``atan2(−b_y, b_x)``, is differentiated numerically in the parameters of G and V.
    """
    k = traj.k
    if np.linalg.det(g) < 0:
        # (−G, V, antipodal b₀) fits alike; the level fields below are G's own, so take the proper sign with
        # its covariance (q's correlation with V turns): unturned, the one-sigma of a fit that converged to −G
        # would be that of another model.
        g = -g
        turn = np.concatenate([-np.ones(k), np.ones(covariance.shape[0] - k)])
        covariance = covariance * np.outer(turn, turn)
    dip = math.radians(60.0)
    headings = np.radians(np.arange(0, 360, 45))
    body = np.column_stack(
        [math.cos(dip) * np.cos(headings), -math.cos(dip) * np.sin(headings), np.full(8, math.sin(dip))]
    )
    raw = body @ g.T + offset
    q, *_ = np.linalg.lstsq(traj.basis, g.ravel(), rcond=None)
    base = np.concatenate([q, offset])

    def heading(params: NDArray[np.float64]) -> NDArray[np.float64]:
        corrected = (raw - params[k:]) @ np.linalg.inv((traj.basis @ params[:k]).reshape(3, 3)).T
        return np.asarray(np.arctan2(-corrected[:, 1], corrected[:, 0]), dtype=np.float64)

    reference = heading(base)
    gradient = np.zeros((8, k + 3))
    scale = np.concatenate([np.full(k, float(np.abs(g).max())), np.full(3, float(np.abs(g).max()))]) * 1e-6
    for i in range(k + 3):
        moved = base.copy()
        moved[i] += scale[i]
        change = np.angle(np.exp(1j * (heading(moved) - reference)))
        gradient[:, i] = change / scale[i]
    block = covariance[: k + 3, : k + 3]
    variances = np.einsum("hi,ij,hj->h", gradient, block, gradient)
    return float(np.degrees(np.sqrt(np.mean(np.clip(variances, 0, None)))))


def _level_headings(g: NDArray[np.float64], raw: NDArray[np.float64], offset: NDArray[np.float64]) -> NDArray[Any]:
    """The headings (radians) of ``raw`` corrected by (G, V), as :func:`_heading_sigma` reads them."""
    corrected = (raw - offset) @ np.linalg.inv(g).T
    return np.asarray(np.arctan2(-corrected[:, 1], corrected[:, 0]), dtype=np.float64)


def _halves(model: _Model, segment_s: float) -> tuple[float, float] | None:
    """(RMS heading difference, combined one-sigma), degrees, of the model fitted again on each half of the
    recording (the same mapping, from the whole fit), at the eight level headings of :func:`_heading_sigma`;
    None when a half is too short to fit."""
    traj, p = model.traj, model.solution.params
    g, offset = traj.distortion(p), p[traj.k : traj.k + 3]
    g = g * np.sign(np.linalg.det(g))  # (−G, V, antipodal b₀) fits alike: the level fields below are G's own
    dip = math.radians(60.0)
    headings_deg = np.radians(np.arange(0, 360, 45))
    body = np.column_stack(
        [math.cos(dip) * np.cos(headings_deg), -math.cos(dip) * np.sin(headings_deg), np.full(8, math.sin(dip))]
    )
    raw = body @ g.T + offset
    n = traj.t.size
    headings, variances = [], []
    for half in (slice(0, n // 2), slice(n // 2, n)):
        t = traj.t[half]
        if float(t[-1] - t[0]) < 20 * WINDOW_S:
            return None
        gravity = traj.gravity
        if gravity is not None:  # a half whose accelerometer never sees gravity alone is fitted without it
            gravity = replace(gravity, down=gravity.down[half], still=gravity.still[half])
            gravity = gravity if int(np.sum(gravity.still)) >= MIN_GRAVITY_SAMPLES else None
        try:
            fitted = _fit_model(traj.y[half], traj.w[half], t, segment_s, model.name, *_parts(model), gravity=gravity,
                                origin=(traj.w, traj.t, half.start), tolerance=HALVES_STEP)  # fmt: skip
            g_half = fitted.traj.distortion(fitted.solution.params)
            offset_half = fitted.solution.params[fitted.traj.k : fitted.traj.k + 3]
            covariance = _covariance(fitted.traj, fitted.solution.params)
        except np.linalg.LinAlgError:
            return None
        g_half = g_half * np.sign(np.linalg.det(g_half))
        headings.append(_level_headings(g_half, raw, offset_half))
        variances.append(_heading_sigma(g_half, offset_half, covariance, fitted.traj) ** 2)
    difference = np.angle(np.exp(1j * (headings[0] - headings[1])))
    return math.degrees(float(np.sqrt(np.mean(difference**2)))), math.sqrt(sum(variances))


def _support(
    ambiguous: tuple[str, str, float] | None,
    offset_sigma: NDArray[np.float64],
    offset_axes: NDArray[np.float64],
    heading_sigma: float,
    residual_rms: float,
    span_deg: float,
    lag: float = 0.0,
    turns_deg: NDArray[np.float64] | None = None,
    gravity: bool = False,
    accel_unused: str | None = None,
    inclination_checked: bool = False,
    disagreement: str | None = None,
    lag_searched: bool = True,
) -> Support:
    """The verdict on what the rotations determine (module docstring)."""
    refusals = ReasonList()
    weak = ReasonList()
    if span_deg < MIN_TURN_DEG:
        refusals.add("single_axis",
            f"the sensor hardly turned: the field's direction in its frame spans {span_deg:.0f}°, where the "
            f"kinematics need turns of {MIN_TURN_DEG:.0f}° or more"
        )
    if ambiguous is not None:
        first, second, separation = ambiguous
        refusals.add("gyro",
            f"the rotations do not tell the axis mapping {first} from {second} (the samples fit both within "
            f"{separation:.1f} noise variances, where {LIKELIHOOD_RATIO:.0f} would tell them apart): the "
            "magnetometer's alignment to the gyroscope is not determined; turn about a second axis, or give "
            "mapping= if the mounting is known"
        )
    worst = int(np.argmax(offset_sigma))
    where = axis_words(offset_axes[:, worst], "magnetometer")
    if offset_sigma[worst] > UNDETERMINED_OFFSET:
        refusals.add("undetermined",
            f"the samples do not determine the offset along {where} (one-sigma {100 * offset_sigma[worst]:.0f} % of "
            "the field): that number would be noise"
        )
    elif offset_sigma[worst] > WEAK_OFFSET:
        weak.add("weakly_determined",
            f"the offset along {where} is weakly determined (one-sigma {100 * offset_sigma[worst]:.1f} % of the "
            f"field); the heading uncertainty that follows is ±{heading_sigma:.2g}°"
        )
    elif heading_sigma > 1.0:
        weak.add(
            "weakly_determined",
            f"the heading uncertainty the fit leaves is ±{heading_sigma:.2g}° (one-sigma, level, 60° dip)",
        )
    planar = turns_deg is not None and turns_deg[2] < NARROW_THIRD_AXIS * turns_deg[0]
    narrow = planar and MIN_TURN_DEG <= span_deg < NARROW_TURN_DEG
    if not gravity and narrow:
        fix = (
            "give accel= (the accelerometer, in the gyroscope's axes) to pin it with gravity" if accel_unused is None
            else f"accel= was given but {accel_unused}"
        )  # fmt: skip
        weak.add("accelerometer",
            f"the field's direction spans only {span_deg:.0f}° in the magnetometer's frame, turning mostly about one "
            "axis (as a boat rolling on one heading): the axes' rotation about that axis rests on the little turning "
            f"about the others and its one-sigma understates it; {fix}"
        )
    elif gravity and narrow:
        # The dip sees the accelerometer's tilt about the magnetic east-west axis only (∂(d·b)/∂θ = d × b): a
        # tilt about north-south is absorbed by the axes' rotation, which is what the gravity rows pin here.
        checked = (
            "its tilt about the field's horizontal direction is not checked by the dip (its tilt across it agreed "
            "with inclination_deg=)" if inclination_checked
            else "its bias and alignment to the gyroscope are not checked; give inclination_deg= (the World "
            "Magnetic Model's) to check them across the field's horizontal direction"
        )  # fmt: skip
        weak.add("accelerometer",
            f"the field's direction spans only {span_deg:.0f}° in the magnetometer's frame, turning mostly about one "
            "axis: the axes' rotation about it rests on the accelerometer's gravity, taken true within "
            f"{ACCEL_BIAS_PRIOR:g} m/s² in the one-sigma (a 1° tilt or a 0.3 m/s² bias left up to 1.8° or 3.4° of "
            f"heading error on simulated boats); {checked}"
        )
    if disagreement is not None and not narrow:  # the calibration may be what is off: the user must know
        weak.add("inclination", disagreement)
    if residual_rms > LARGE_RESIDUAL:
        weak.add("large_residual",
            f"the samples leave {100 * residual_rms:.1f} % of the field (RMS) off the turning field the gyroscope "
            "predicts: the gyro and magnetometer are not on one clock, or the field changed while recording (motors, "
            "a magnet); expect heading errors of a few degrees"
        )
    if lag_searched and abs(lag) >= MAX_LAG_S - 1e-9:
        weak.add("lag_at_edge",
            f"the magnetometer and the gyroscope fit best {lag:+.2f} s apart, the end of the range searched: their "
            "time stamps are not on one clock; check them (or give lag_s=)"
        )
    return Support.judged(refusals, weak, _ADVICE)
