"""The accelerometer's gravity equations (4) of :mod:`.method` joined to the vector equations (3).

Where the accelerometer sees gravity alone (:func:`_still_rows`), at headings spread across both horizontal
axes (:func:`_heading_spread`), the joint fit is made in two passes (:func:`_joint_fit`: first weighted by the
regression's residuals and the sensors' noise, then by its own residuals with Huber weights on the gravity
equations), and kept unless the accelerometer's vertical disagrees with the reference's
(:func:`_vertical_disagreement`, a Hausman test: the joint fit is the far more precise, so the difference has
the regression's covariance when both are right) or the vector equations' residual grows. Its uncertainty is
a block jackknife (:func:`_jackknife`; the normal equations are sums over samples, so each refit takes its
block's share off) plus the accelerometer's calibration prior (:func:`_tilt_prior`: the joint fit again with
the down directions turned by a small angle about x and y).
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..._scale import robust_scale
from ...diagnostics.reference import (
    BLOCKS,
    jackknife_covariance,
    regression_covariance,
)
from ...errors import OptionError, SampleError
from ...gravity import still_samples
from .equations import _Equations, _inflation, _noise_sigma, _solve_normal, _vector_weights, _vehicle_form
from .regression import _relative_rms, _vertical

#: Fewest samples on which the accelerometer sees gravity alone for the gravity equations (4) to join the fit.
MIN_GRAVITY_ROWS = 50
#: Smallest in-plane eigenvalue of the scatter of the horizontal field's direction over the still samples
#: (a full circle of headings gives 0.5, headings within ±22° about 0.05, a boat's ±10° 0.01) for the joint
#: fit to be made: the gravity equations pin the tilt of the vertical through the horizontal field turning
#: under it; from one heading they pin one combination of the weak directions and move the others (the
#: spreads of boats, flights and cars: docs/methods.md, "vector").
MIN_HEADING_SPREAD = 0.05
#: Huber's tuning constant (in robust standard deviations) for the gravity equations: residual accelerations
#: (a turn the gate missed, a lever arm) are down-weighted, not trusted.
HUBER = 1.345
#: The two tests of an accelerometer whose vertical is not the reference's (an offset beyond ``accel_sigma``, a
#: frame tilted from the vehicle's): it drags the fit's vertical with it, the vector equations pay for it.
#: Either refuses the gravity equations. VERTICAL_CHI2: the χ² (2 components, its 1 % point) of the vertical's
#: move (M's row z) from the regression's, against the regression's covariance of it plus the accelerometer's
#: calibration prior (a Hausman test, :func:`_vertical_disagreement`). MAX_RESIDUAL_GROWTH: the vector
#: equations' residual RMS, the joint fit's over the regression's (what a wide covariance hides). The values
#: of both on right and wrong accelerometers: docs/methods.md, "vector".
VERTICAL_CHI2 = 9.21
MAX_RESIDUAL_GROWTH = 1.10
#: Default one-sigma (m/s², each horizontal axis) of the accelerometer's calibration, the offset that the gravity
#: equations cannot see: it tilts their vertical by its ratio to g and goes into the calibration, so its cost
#: is added to the joint fit's covariance (:func:`_tilt_prior`): about what neither test detects at 1° of
#: attitude error (docs/methods.md, "vector").
ACCEL_SIGMA = 0.1
#: Standard gravity (m/s²): ``accel_sigma`` over it is the tilt of the accelerometer's vertical (radians).
STANDARD_GRAVITY = 9.80665


@dataclass(frozen=True)
class GravityFit:
    """What the accelerometer added to a vector fit (:func:`fit_vector` with ``accel=``).

    ``g`` and ``offset`` are None when the gravity equations were not used: neither ``time_s`` nor ``gyro``
    given, too few samples where the accelerometer sees gravity alone, their headings too close together,
    a normal matrix not positive definite once corrected for the noise, or an accelerometer that disagrees
    with the reference (``caution`` then says so, for the verdict's weaknesses). ``covariance`` (of G
    row-major and V, block jackknife) is None also when one of the jackknife's refits had no solution: the
    verdict then computes the regression's covariance at the joint fit (the note says so). ``prior`` (12, 12)
    is the accelerometer's calibration cost (:func:`_tilt_prior`). ``facts`` go to ``calibration.vector.gravity``,
    ``note`` to the diagnostics' notes.
    """

    g: NDArray[np.float64] | None
    offset: NDArray[np.float64] | None
    covariance: NDArray[np.float64] | None
    facts: dict[str, Any]
    note: str
    prior: NDArray[np.float64] | None = None
    caution: str | None = None


def _vertical_disagreement(raw: NDArray[np.float64], reference: NDArray[np.float64], g: NDArray[np.float64],
                           offset: NDArray[np.float64], g_joint: NDArray[np.float64],
                           prior: NDArray[np.float64] | None) -> tuple[float, float]:  # fmt: skip
    """(χ², degrees): how far the joint fit moved the vertical (:func:`_vertical`) from the regression's, against
    the regression's covariance of it plus the accelerometer's calibration ``prior`` (two components across
    it; a Hausman test: the joint fit is the far more precise of the two, so the difference has the regression's
    covariance when both are right, and the prior's when the accelerometer is off by its one-sigma)."""
    base = _vertical(g)
    across = np.linalg.svd(np.eye(3) - np.outer(base, base))[0][:, :2]
    step = 1e-6 * float(np.max(np.abs(g)))
    jac = np.zeros((2, 9))
    for p in range(9):
        moved = g.copy()
        moved[p // 3, p % 3] += step
        jac[:, p] = across.T @ (_vertical(moved) - base) / step
    covariance = regression_covariance(raw, reference, g, offset)[:9, :9]
    if prior is not None:
        covariance = covariance + prior[:9, :9]
    covariance = jac @ covariance @ jac.T + 1e-18 * np.eye(2)  # noise-free data: rounding is no disagreement
    shift = across.T @ (_vertical(g_joint) - base)
    try:
        chi2 = float(shift @ np.linalg.solve(covariance, shift))
    except np.linalg.LinAlgError:
        chi2 = 0.0  # the regression does not pin the vertical at all: nothing to disagree with
    return chi2, math.degrees(float(np.linalg.norm(shift)))


def _tilt_prior(equations: _Equations, weights: tuple[float, NDArray[np.float64], float],
                estimate: NDArray[np.float64], tilt_sigma: float) -> NDArray[np.float64] | None:  # fmt: skip
    """The covariance of (G row-major, V) that a tilt of the accelerometer's vertical with one-sigma
    ``tilt_sigma`` (radians, about the vehicle's x and y axes) causes: the joint fit again with the down
    directions turned by a small angle about each axis (finite differences; None when a refit has no solution)."""
    step = 1e-3
    jac = np.zeros((12, 2))
    for axis in (0, 1):
        turn = np.eye(3)
        i, j = (1, 2) if axis == 0 else (2, 0)  # the plane the rotation about x (or y) turns
        turn[i, i] = turn[j, j] = math.cos(step)
        turn[j, i], turn[i, j] = math.sin(step), -math.sin(step)
        tilted = replace(equations, down=equations.down @ turn.T)
        solution = _solve_normal(*tilted.normal(*weights))
        if solution is None or not abs(np.linalg.det(solution[:12].reshape(3, 4)[:, :3])) > 0:
            return None
        g_tilted, v_tilted = _vehicle_form(solution)
        jac[:, axis] = (np.concatenate([g_tilted.ravel(), v_tilted]) - estimate) / step
    return np.asarray(tilt_sigma**2 * jac @ jac.T, dtype=np.float64)


def _unused(facts: dict[str, Any], note: str, caution: str | None = None) -> GravityFit:
    """The gravity equations left out, with the reason (``note``, and ``caution`` for the verdict)."""
    return GravityFit(None, None, None, {**facts, "note": note}, note, caution=caution)


@dataclass(frozen=True)
class _Still:
    """The rows the accelerometer sees gravity alone on (:func:`_still_rows`): ``still`` indexes the kept
    samples, ``facts`` start ``calibration.vector.gravity``, ``reasons`` say what the gate dropped."""

    still: NDArray[np.int64]
    facts: dict[str, Any]
    reasons: str


def _still_rows(raw: NDArray[np.float64], kept: NDArray[np.int64], accel: NDArray[np.float64],
                gyro: NDArray[np.float64] | None, times: NDArray[np.float64] | None, g: NDArray[np.float64],
                offset: NDArray[np.float64]) -> _Still | GravityFit:  # fmt: skip
    """Where the accelerometer sees gravity alone among the kept samples (:func:`magfit.gravity.still_samples`,
    its rate of turn from the regression's field), or the reason the gravity equations are left out."""
    if gyro is None and times is None:
        # Then the gate checks |a| alone, and a coordinated turn keeps |a| at g while it tilts the apparent
        # vertical (docs/methods.md, "vector": the heading errors of such rows).
        note = (
            "The accelerometer's gravity equations were not used: without time_s= or gyro= the samples taken in a "
            "turn (|a| stays near g while the apparent vertical tilts) cannot be told from the still ones; give "
            "time_s= or gyro= to use them. The fit is the regression on the reference alone."
        )
        unused = {"used": False, "rows": 0, "of": int(kept.size), "dropped": {}, "notes": [], "note": note}
        return GravityFit(None, None, None, unused, note)
    corrected = (raw - offset) @ np.linalg.inv(g).T  # the field in the vehicle frame: the gate's rate of turn
    try:
        gate = still_samples(accel, mag=corrected, gyro=gyro, time_s=times)
    except SampleError as error:
        raise OptionError(f"accel=: {error}") from None
    dropped = {reason: count for reason, count in gate.dropped.items() if count}
    outside = int(np.sum(gate.keep)) - int(np.sum(gate.keep[kept]))
    if outside:
        dropped["outside the window of the lag search (the ends of the recording's stretches)"] = outside
    still = np.flatnonzero(gate.keep[kept])
    facts: dict[str, Any] = {"used": False, "rows": int(still.size), "of": int(kept.size), "dropped": dropped,
                             "notes": list(gate.notes)}  # fmt: skip
    reasons = "; ".join(f"{count} {reason}" for reason, count in dropped.items()) or "none"
    if still.size < MIN_GRAVITY_ROWS:
        note = (
            f"The accelerometer sees gravity alone on {still.size} of {kept.size} samples (dropped: {reasons}), "
            f"fewer than the {MIN_GRAVITY_ROWS} its equations need: the fit is the regression on the reference alone."
        )
        if gyro is not None and times is None and float(np.median(np.linalg.norm(gyro, axis=1))) > 1.0:
            # With time_s the reference tells the unit (reference._check_rate_units); without it, only the size does: no
            # vehicle turns at a median 1 rad/s (57°/s).
            note += " gyro= turns at a median rate over 1 rad/s: if it is in degrees per second, give it in rad/s."

        return _unused(facts, note)
    return _Still(still, facts, reasons)


def _heading_spread(down: NDArray[np.float64], body: NDArray[np.float64]) -> float:
    """The smaller in-plane eigenvalue of the scatter of the field's horizontal direction (across ``down``) over
    the still samples: 0.5 for a full circle of headings, 0 for one heading (:data:`MIN_HEADING_SPREAD`)."""
    across = body - np.einsum("ki,ki->k", body, down)[:, None] * down
    across /= np.maximum(np.linalg.norm(across, axis=1, keepdims=True), 1e-300)
    return float(np.linalg.eigvalsh(across.T @ across / across.shape[0])[1])


@dataclass(frozen=True)
class _Joint:
    """The joint fit of (3) and (4) (:func:`_joint_fit`): its solution ``p`` (None: no positive definite
    normal matrix), the weights and whole normal equations (the jackknife and the tilt prior refit with them),
    and the noise figures that go to ``calibration.vector.gravity``."""

    p: NDArray[np.float64] | None
    equations: _Equations
    weights: tuple[float, NDArray[np.float64], float]
    whole: tuple[NDArray[np.float64], NDArray[np.float64]]
    huber: NDArray[np.float64]
    outliers: int
    v_var: float
    v_kappa: float
    g_var: float
    g_kappa: float
    mag_noise: float
    down_noise: float


def _joint_fit(raw: NDArray[np.float64], used_raw: NDArray[np.float64], used_ref: NDArray[np.float64],
               accel: NDArray[np.float64], still: NDArray[np.int64], down: NDArray[np.float64],
               body: NDArray[np.float64], g: NDArray[np.float64], offset: NDArray[np.float64]) -> _Joint:  # fmt: skip
    """(3) and (4) by weighted, noise-corrected least squares in two passes (module docstring; the equations and
    their noise correction: :mod:`.equations`)."""
    mag_noise = _noise_sigma(raw, 3)
    down_noise = _noise_sigma(-accel / np.linalg.norm(accel, axis=1, keepdims=True), 2)
    n = used_raw.shape[0]
    equations = _Equations(np.column_stack([used_raw, -np.ones(n)]), used_ref, still, down, mag_noise, down_noise)
    # Pass 1: the vector equations weighted by their scatter and its correlation (from the regression's
    # residuals), the gravity equations by the noise the sensors predict for them (white).
    m0 = np.linalg.inv(g)
    # Noise-free data would give zero variances: floored far below any real sensor's noise.
    floor = (1e-9 * float(np.median(np.linalg.norm(used_ref, axis=1)))) ** 2
    v_var, v_kappa, r_weight = _vector_weights((used_raw - offset) @ m0.T - used_ref, used_ref, floor)
    g_var = mag_noise**2 * float(np.mean(np.sum((down @ m0) ** 2, axis=1)))
    g_var += down_noise**2 * float(np.mean(np.sum(np.cross(down, body) ** 2, axis=1)))
    g_var = max(g_var, floor)
    weights: tuple[float, NDArray[np.float64], float] = (1.0 / (v_var * v_kappa), np.full(still.size, 1.0 / g_var),
                                                         r_weight)  # fmt: skip
    whole = equations.normal(*weights)
    p = _solve_normal(*whole)
    huber = np.ones(still.size)
    g_kappa = 1.0
    outliers = 0
    if p is not None:
        # Pass 2: each kind weighted by its own residuals' scatter and correlation; the gravity equations'
        # outliers (accelerations the gate let through) down-weighted by Huber's weights.
        e_vector, e_gravity = equations.residuals(p)
        v_var, v_kappa, r_weight = _vector_weights(e_vector, used_ref, floor)
        scale = robust_scale(e_gravity)[1]
        if scale > 0:
            huber = np.minimum(1.0, HUBER * scale / np.maximum(np.abs(e_gravity), 1e-300))
            outliers = int(np.sum(np.abs(e_gravity) > 3.0 * scale))
            g_var, g_kappa = _inflation(e_gravity, huber)
            g_var = max(g_var / float(np.mean(huber)), floor)
        weights = (1.0 / (v_var * v_kappa), huber / (g_var * g_kappa), r_weight)
        whole = equations.normal(*weights)
        p = _solve_normal(*whole)
    return _Joint(p, equations, weights, whole, huber, outliers, v_var, v_kappa, g_var, g_kappa, mag_noise,
                  down_noise)  # fmt: skip


def _jackknife(joint: _Joint, n: int) -> NDArray[np.float64] | None:
    """The block jackknife of the joint fit: again without each contiguous stretch (its gravity rows with it).
    The normal equations are sums over the samples, so each refit takes its stretch's share off the whole's.
    None when a refit has no solution."""
    whole_h, whole_b = joint.whole
    edges = np.linspace(0, n, BLOCKS + 1).astype(np.int64)
    estimates: list[NDArray[np.float64]] = []
    for start, stop in itertools.pairwise(edges):
        select = np.zeros(n, dtype=bool)
        select[start:stop] = True
        block_h, block_b = joint.equations.normal(*joint.weights, select=select)
        partial = _solve_normal(whole_h - block_h, whole_b - block_b)
        if partial is None:
            return None
        g_part, v_part = _vehicle_form(partial)
        estimates.append(np.concatenate([g_part.ravel(), v_part]))
    return jackknife_covariance(np.asarray(estimates))


def _gravity_fit(raw: NDArray[np.float64], kept: NDArray[np.int64], used_raw: NDArray[np.float64],
                 used_ref: NDArray[np.float64], accel: NDArray[np.float64], gyro: NDArray[np.float64] | None,
                 times: NDArray[np.float64] | None, g: NDArray[np.float64], offset: NDArray[np.float64],
                 accel_sigma: float) -> GravityFit:  # fmt: skip
    """The joint fit of equations (3) and (4) on the kept samples (module docstring), or the reason it is not made."""
    rows = _still_rows(raw, kept, accel, gyro, times, g, offset)
    if isinstance(rows, GravityFit):
        return rows
    still, facts, reasons = rows.still, rows.facts, rows.reasons
    a = accel[kept][still]
    down = -a / np.linalg.norm(a, axis=1, keepdims=True)  # the specific force points up
    body = (used_raw[still] - offset) @ np.linalg.inv(g).T
    spread = _heading_spread(down, body)
    facts["heading_spread"] = spread
    if spread < MIN_HEADING_SPREAD:
        note = (
            f"The accelerometer sees gravity alone on {still.size} of {kept.size} samples, but at headings so close "
            f"together (spread {spread:.2g}, under {MIN_HEADING_SPREAD:g}; a full circle gives 0.5) that its "
            "equations cannot pin the tilt of the vertical: the fit is the regression on the reference alone; "
            "hold still (or drive straight) at headings across both horizontal axes to use them."
        )
        return _unused(facts, note)
    joint = _joint_fit(raw, used_raw, used_ref, accel, still, down, body, g, offset)
    p = joint.p
    if p is None or not abs(np.linalg.det(p[:12].reshape(3, 4)[:, :3])) > 0:
        note = (
            "The accelerometer's gravity equations were not used: corrected for the sensors' noise, they and the "
            "reference do not determine the fit along some direction; the fit is the regression on the reference alone."
        )
        return _unused(facts, note)
    g_joint, offset_joint = _vehicle_form(p)
    # Floored: noise-free data leave rounding errors alone, whose ratio means nothing.
    tiny = 1e-9 * float(np.median(np.linalg.norm(used_ref, axis=1)))
    growth = max(_relative_rms(used_raw, used_ref, g_joint, offset_joint), tiny) / max(
        _relative_rms(used_raw, used_ref, g, offset), tiny
    )
    facts["residual_growth"] = growth
    estimate = np.concatenate([g_joint.ravel(), offset_joint])
    prior = (
        _tilt_prior(joint.equations, joint.weights, estimate, accel_sigma / STANDARD_GRAVITY) if accel_sigma > 0
        else None
    )  # fmt: skip
    chi2, moved = _vertical_disagreement(used_raw, used_ref, g, offset, g_joint, prior)
    facts["vertical_chi2"] = chi2
    facts["vertical_moved_deg"] = moved
    if chi2 > VERTICAL_CHI2 or growth > MAX_RESIDUAL_GROWTH:
        how = (
            f"it moves the calibration's vertical by {moved:.2g}°, {math.sqrt(chi2):.1f} times the reference's "
            f"one-sigma of it, and the samples follow the reference {100 * (growth - 1):.0f} % worse (RMS)"
        )
        note = (
            f"The accelerometer's gravity equations were not used: {how}; its vertical is not the reference's. "
            "The fit is the regression on the reference alone."
        )
        caution = (
            f"the accelerometer disagrees with the reference ({how}), so its gravity equations were left out and "
            "the heading is the reference's alone: calibrate the accelerometer's offsets and check that accel= "
            "is in the reference's (vehicle) frame, mounted level with it"
        )
        return _unused(facts, note, caution)
    covariance = _jackknife(joint, used_raw.shape[0])
    facts.update(
        used=True,
        down_weighted=int(np.sum(joint.huber < 1.0)),
        outliers=joint.outliers,
        vertical_field=float(p[12]),
        vector_sigma=math.sqrt(joint.v_var),
        vector_inflation=joint.v_kappa,
        gravity_sigma=math.sqrt(joint.g_var),
        gravity_inflation=joint.g_kappa,
        magnetometer_noise=joint.mag_noise,
        accelerometer_noise_deg=math.degrees(joint.down_noise),
        accel_sigma=accel_sigma,
        jackknife=covariance is not None,
    )
    note = _used_note(still.size, kept.size, reasons, joint.outliers, accel_sigma, prior is not None,
                      covariance is not None)  # fmt: skip
    return GravityFit(g_joint, offset_joint, covariance, {**facts, "note": note}, note, prior=prior)


def _used_note(rows: int, of: int, reasons: str, outliers: int, accel_sigma: float, priced: bool,
               jackknifed: bool) -> str:  # fmt: skip
    """The diagnostics' note on a joint fit made: on how many rows, the outliers, the accelerometer's cost."""
    if priced:
        sigma = math.degrees(accel_sigma / STANDARD_GRAVITY)
        cost = f" (accel_sigma={accel_sigma:g} m/s², {sigma:.2g}° of tilt, is in the one-sigma)"
    else:
        cost = " (its cost is not in the one-sigma: accel_sigma=0 or a refit without a solution)"
    note = (
        f"The accelerometer's gravity equations joined the fit on {rows} of {of} samples, where it "
        f"sees gravity alone (dropped: {reasons}); {outliers} of them beyond 3 robust standard deviations (residual "
        "accelerations), down-weighted. They align the magnetometer to the accelerometer, whose offsets go into "
        f"the calibration{cost}: calibrate the accelerometer first."
    )
    if not jackknifed:
        note += (
            " The block jackknife had no solution without one stretch of the recording: the one-sigma is the "
            "regression's (independent residuals, widened by its own jackknife) at the joint fit."
        )
    return note
