"""``method="tilt"``: calibration against the reference field with the logged roll and pitch only, the yaw free
(docs/methods.md, "tilt").

A vehicle's logged yaw is the estimator's, and on most vehicles the estimator steers its yaw by the compass that
is being calibrated: a compass with a wrong offset turns the logged heading with it, and a fit against the whole
attitude (``vector``) learns that error back. Roll and pitch come from the accelerometer and the gyroscope and do
not depend on the compass. In the level frame (the vertical ``d_k``, from roll and pitch, in the vehicle frame) the
reference field has a known horizontal strength ``h`` and a known vertical component ``z``, whatever the heading::

    c_k = S (raw_k − V − k x_k)                         (T1)  the corrected field, vehicle frame
    z_k(c) = d_k · c_k,   h_k(c) = |c_k − z_k d_k|       (T2)  its vertical and horizontal parts
    e_k = (h_k(c) − h,  z_k(c) − z)                      (T3)  the residuals, two per sample

and ``Σ_k |e_k|²`` is minimised over the symmetric matrix S (6: the soft iron and the scale into the reference's
unit, as ArduPilot's DIA/ODI and SCALE hold them), the offset V (3) and, with a regressor ``x`` (the battery current
or the throttle), the motors' field k (3; eq. M1). (T3) is the distance from ``c_k`` to the circle of headings the
reference allows at that roll and pitch: the heading profiled out (it is pymavlink's ``magfit_WMM.py`` objective).

**What it cannot see.** A rotation of the compass about the vehicle's vertical moves no ``h_k`` and, level, no
``z_k``: the mounting's yaw is not fitted (S symmetric: no rotation at all; a mounting tilted about x or y is
absorbed in S's off-diagonal terms). The heading stated is relative to the compass's declared orientation; ``vector``
or ``magfit align`` measure the yaw where the logged heading can be trusted.

**What it needs.** (T2) pins the offset and S's horizontal block through the headings the horizontal field turns
through (the corrected field's, not the log's), and S's response to the vertical field and V's z component through
the tilts: level, the vertical field is constant and ``S_zz`` trades with ``V_z``. The Gauss-Newton covariance of
(S, V, k) is widened by a block jackknife over :data:`~magfit.diagnostics.reference.BLOCKS` stretches of the
recording (the attitude's error and the field's drift are correlated over seconds) and carried to the heading at 36
level headings and at :data:`~magfit.diagnostics.reference.TILT_DEG` of tilt; beyond
:data:`~magfit.diagnostics.reference.HEADING_LIMIT_DEG` the fit is refused with what the recording lacked. The two
halves of the recording are fitted apart as ``vector``'s are; their heading difference beyond its noise widens the
one-sigma stated (:data:`~magfit.diagnostics.reference.HALVES_SIGMAS`).

**The motors' field.** k is told from V only by the regressor's variation and from S only where the regressor does
not follow the attitude: ρ of eq. (M4) is computed on (T3)'s Jacobian, and the term is kept as
:func:`magfit.motor.fit_motor` keeps it (determined, significant, above :data:`magfit.motor.MIN_PERCENT` of the
field for ``motor="auto"``); otherwise the fit is made without it and the verdict says why. With
``regressor_time_s`` its lag is searched on a grid within ``±max_lag_s``.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..._validation import check_rows, check_times
from ...calibration import Calibration
from ...diagnostics.coverage import coverage
from ...diagnostics.reference import (
    BLOCKS,
    HALVES_SIGMAS,
    HEADING_LIMIT_DEG,
    TILT_DEG,
    jackknife_covariance,
    widened,
)
from ...diagnostics.verdict import LARGE_RESIDUAL_RMS, NO_ELLIPSOID_RMS, USELESS_BOUND_DEG
from ...errors import CalibrationError, OptionError, SampleError
from ...findings import Diagnostics, Observability, Reason, ReasonList, Support, Uncertainty
from ...motor import (
    CHI2_3_999,
    MAX_LAG_S,
    MIN_INDEPENDENCE,
    MIN_PERCENT,
    MOTOR_CHOICES,
    WEAK_INDEPENDENCE,
    regressor_at,
)
from ...motorterm import REGRESSORS, MotorTerm
from ...outliers import DEFAULT_THRESHOLD, robust_scale
from ..registry import FitInput, fit_input, register
from .reference import _field, _reference_array

#: Fewest samples: 12 parameters with the motors' term, and the block jackknife needs 20 a block.
MIN_SAMPLES = 200
#: Rows the fit reads at most (a regular stride of a longer recording).
FIT_ROWS = 20_000
#: The smallest residual (a fraction of the field, either component) that makes a sample an outlier: a log's
#: stretch on the ground has residuals of a few tenths of a percent, its flight of a few percent (the attitude's
#: error, vibration): the robust scale of the whole would cut the flight away.
OUTLIER_FLOOR = 2.0 * LARGE_RESIDUAL_RMS
#: Roll and pitch spread (RMS about their mean, degrees) below which S's response to the vertical field and V's
#: z component are not told apart (a level flight): refused whatever the linearised one-sigma says.
MIN_TILT_DEG = 3.0
#: Largest ratio of S's eigenvalues for a fitted soft iron (real ones stay within 1.5).
MAX_AXIS_RATIO = 3.0
#: Relative eigenvalue of the scaled information below which a direction is not determined at all, and the
#: variance (normalised units) it is given then.
SINGULAR_INFORMATION = 1e-10
UNDETERMINED_VARIANCE = 1e6
#: The share of samples left out as outliers beyond which the verdict names it.
MAX_REJECTED = 0.05
#: The heading one-sigma beyond which a weak direction is named (half the refusal's limit).
WEAK_HEADING_DEG = HEADING_LIMIT_DEG / 2.0
ADVICE = (
    "record while the vehicle turns through every heading and also rolls and pitches (15° or more, both ways), or "
    "calibrate the magnetometer first with a tumble (method auto)"
)
#: The symmetric matrix's entries as (row, column) pairs, in parameter order.
_ENTRIES = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))


def _matrix(p: NDArray[np.float64]) -> NDArray[np.float64]:
    s = np.empty((3, 3))
    for value, (a, b) in zip(p[:6], _ENTRIES, strict=True):
        s[a, b] = s[b, a] = value
    return s


def _parts(p: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """(S, V, k) from p (k zero when p holds 9 parameters)."""
    return _matrix(p), p[6:9], (p[9:12] if p.size > 9 else np.zeros(3))


@dataclass(frozen=True)
class _Data:
    """The fit's inputs in normalised units: samples and targets over the field, the regressor over its spread."""

    x: NDArray[np.float64]  # (n, 3) raw / B
    down: NDArray[np.float64]  # (n, 3) unit vertical in the vehicle frame
    h: NDArray[np.float64]  # (n,) horizontal strength / B
    z: NDArray[np.float64]  # (n,) vertical component / B
    c: NDArray[np.float64] | None  # (n,) regressor / its spread

    def take(self, rows: Any) -> _Data:
        return _Data(
            self.x[rows], self.down[rows], self.h[rows], self.z[rows], None if self.c is None else self.c[rows]
        )


def _residuals(p: NDArray[np.float64], data: _Data) -> NDArray[np.float64]:
    """(T3), shape (n, 2)."""
    s, v, k = _parts(p)
    y = data.x - v if data.c is None or p.size <= 9 else data.x - v - np.outer(data.c, k)
    c = y @ s  # S symmetric: (S y)ᵀ = yᵀ S
    zc = np.einsum("ki,ki->k", c, data.down)
    hc = np.linalg.norm(c - zc[:, None] * data.down, axis=1)
    return np.column_stack([hc - data.h, zc - data.z])


def _jacobian(p: NDArray[np.float64], data: _Data) -> NDArray[np.float64]:
    """∂e/∂p of (T3), shape (n, 2, P): ∂z/∂S_ab = d_a y_b + d_b y_a (a ≠ b), ∂z/∂V = −Sd, ∂z/∂k = −x Sd; the same
    for h with the horizontal unit vector ĥ in place of d."""
    s, v, k = _parts(p)
    current = data.c if data.c is not None and p.size > 9 else None
    y = data.x - v if current is None else data.x - v - np.outer(current, k)
    c = y @ s
    zc = np.einsum("ki,ki->k", c, data.down)
    horizontal = c - zc[:, None] * data.down
    hat = horizontal / np.maximum(np.linalg.norm(horizontal, axis=1, keepdims=True), 1e-12)
    jac = np.zeros((data.x.shape[0], 2, p.size))
    for row, u in ((0, hat), (1, data.down)):
        for j, (a, b) in enumerate(_ENTRIES):
            jac[:, row, j] = u[:, a] * y[:, b] + (u[:, b] * y[:, a] if a != b else 0.0)
        su = u @ s
        jac[:, row, 6:9] = -su
        if current is not None:
            jac[:, row, 9:12] = -current[:, None] * su
    return jac


def _solve(data: _Data, start: NDArray[np.float64]) -> tuple[NDArray[np.float64], float]:
    """Least squares of (T3) from ``start``; (p, cost = mean squared residual)."""
    from scipy.optimize import least_squares  # not needed to import magfit

    result = least_squares(
        lambda q: _residuals(q, data).ravel(), start, jac=lambda q: _jacobian(q, data).reshape(-1, q.size),
        method="lm", xtol=1e-12, ftol=1e-12, max_nfev=200 * start.size,
    )  # fmt: skip
    p = np.asarray(result.x, dtype=np.float64)
    if not np.all(np.isfinite(p)):
        raise SampleError("the tilt fit did not converge")
    return p, float(np.mean(_residuals(p, data) ** 2))


def _starts(data: _Data, reference: NDArray[np.float64]) -> list[NDArray[np.float64]]:
    """Starting points: the offset as the samples' mean less the reference's (exact when the logged yaw is), and
    the centre of the samples' best sphere (any yaw) when the samples determine one; S the identity."""
    identity = np.array([1.0, 0, 0, 1.0, 0, 1.0])
    starts = [np.concatenate([identity, data.x.mean(axis=0) - reference.mean(axis=0)])]
    design = np.column_stack([2 * data.x, np.ones(data.x.shape[0])])
    solution, *_ = np.linalg.lstsq(design, np.sum(data.x**2, axis=1), rcond=None)
    centre = solution[:3]
    radius2 = solution[3] + float(centre @ centre)
    if radius2 > 0 and 0.5 < math.sqrt(radius2) < 2.0:
        starts.append(np.concatenate([identity / math.sqrt(radius2), centre]))
    return starts


def _best(data: _Data, starts: list[NDArray[np.float64]]) -> tuple[NDArray[np.float64], float]:
    best: tuple[NDArray[np.float64], float] | None = None
    for start in starts:
        try:
            found = _solve(data, start)
        except SampleError:
            continue
        if best is None or found[1] < best[1]:
            best = found
    if best is None:
        raise CalibrationError("the tilt fit did not converge from any start", codes=("solver",))
    return best


def _covariance(p: NDArray[np.float64], data: _Data) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """(independent, widened): Gauss-Newton ``σ² H⁻¹`` and the same widened by the block jackknife (each block's
    refit one Gauss-Newton step, ``Δp_b = (H − H_b)⁻¹ s_b``)."""
    jac = _jacobian(p, data)
    res = _residuals(p, data)
    n, _, count = jac.shape
    hessian = np.einsum("kap,kaq->pq", jac, jac)
    variance = float(np.sum(res**2)) / max(2 * n - count, 1)
    independent = variance * _inverse(hessian)
    blocks = min(BLOCKS, n // 20)
    if blocks < 4:
        return independent, independent
    scores = np.einsum("kap,ka->kp", jac, res)
    edges = np.linspace(0, n, blocks + 1).astype(np.int64)
    moves = []
    for start, stop in itertools.pairwise(edges):
        rest = hessian - np.einsum("kap,kaq->pq", jac[start:stop], jac[start:stop])
        try:
            moves.append(np.linalg.solve(rest, scores[start:stop].sum(axis=0)))
        except np.linalg.LinAlgError:
            return independent, independent * 1e12
    return independent, widened(independent, jackknife_covariance(np.asarray(moves)))


def _inverse(hessian: NDArray[np.float64]) -> NDArray[np.float64]:
    """H⁻¹, with a direction the samples do not determine (an eigenvalue of the scaled H below
    :data:`SINGULAR_INFORMATION` of the largest) given :data:`UNDETERMINED_VARIANCE` instead of the zero a
    pseudo-inverse would give it."""
    norms = np.sqrt(np.maximum(np.diag(hessian), 1e-300))
    values, vectors = np.linalg.eigh(hessian / np.outer(norms, norms))
    floor = SINGULAR_INFORMATION * max(float(values[-1]), 1e-300)
    inverse_values = np.where(values > floor, 1.0 / np.maximum(values, floor), UNDETERMINED_VARIANCE)
    return np.asarray((vectors * inverse_values) @ vectors.T / np.outer(norms, norms), dtype=np.float64)


def _body_fields(inclination_deg: float, tilt_deg: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The unit Earth field in the vehicle frame at 36 headings rolled by ``tilt_deg``, (36, 3), and the vertical."""
    delta = math.radians(inclination_deg)
    psi = np.radians(np.arange(0.0, 360.0, 10.0))
    level = np.column_stack([math.cos(delta) * np.cos(psi), -math.cos(delta) * np.sin(psi),
                             np.full(psi.size, math.sin(delta))])  # fmt: skip
    roll = math.radians(tilt_deg)
    rx = np.array([[1, 0, 0], [0, math.cos(roll), math.sin(roll)], [0, -math.sin(roll), math.cos(roll)]])
    return level @ rx.T, rx @ np.array([0.0, 0.0, 1.0])


def _heading_sigmas(p: NDArray[np.float64], covariance: NDArray[np.float64], inclination_deg: float,
                    regressor: float, tilt_deg: float = 0.0) -> tuple[float, float]:  # fmt: skip
    """RMS and worst heading one-sigma (degrees) over 36 headings, level or rolled by ``tilt_deg``: the raw samples
    the fitted model gives there, read back through p moved along each parameter (finite differences)."""
    s, v, k = _parts(p)
    body, down = _body_fields(inclination_deg, tilt_deg)
    raw = body @ np.linalg.inv(s).T + v + regressor * k

    def heading(q: NDArray[np.float64]) -> NDArray[np.float64]:
        sq, vq, kq = _parts(q)
        c = (raw - vq - regressor * kq) @ sq
        level = c - np.outer(c @ down, down)  # the tilt taken off with the true roll: its horizontal part
        east = np.cross(down, np.array([1.0, 0.0, 0.0]))
        east /= np.linalg.norm(east)
        north = np.cross(east, down)
        return np.asarray(np.arctan2(-(level @ east), level @ north))

    base = heading(p)
    jac = np.zeros((36, p.size))
    for i in range(p.size):
        step = 1e-6 * max(1.0, abs(float(p[i])))
        moved = p.copy()
        moved[i] += step
        jac[:, i] = np.angle(np.exp(1j * (heading(moved) - base))) / step
    variances = np.einsum("hp,pq,hq->h", jac, covariance, jac)
    sigmas = np.degrees(np.sqrt(np.maximum(variances, 0.0)))
    return float(np.sqrt(np.mean(sigmas**2))), float(np.max(sigmas))


def _spreads(data: _Data, p: NDArray[np.float64]) -> tuple[float, float]:
    """(tilt, heading) spreads in degrees: the RMS angle of the vertical from its mean direction in the vehicle
    frame, and the circular spread of the corrected horizontal field's direction (the fit's own headings)."""
    mean = data.down.mean(axis=0)
    mean /= np.linalg.norm(mean)
    tilt = math.degrees(math.sqrt(float(np.mean(np.arccos(np.clip(data.down @ mean, -1.0, 1.0)) ** 2))))
    s, v, k = _parts(p)
    y = data.x - v if data.c is None or p.size <= 9 else data.x - v - np.outer(data.c, k)
    c = y @ s
    horizontal = c - np.einsum("ki,ki->k", c, data.down)[:, None] * data.down
    angle = np.arctan2(horizontal[:, 1], horizontal[:, 0])
    resultant = float(np.abs(np.mean(np.exp(1j * angle))))
    heading = math.degrees(math.sqrt(max(-2.0 * math.log(max(resultant, 1e-12)), 0.0)))
    return tilt, heading


@dataclass(frozen=True)
class _Motor:
    """The motors' term tried: kept or not, why, and its figures."""

    kept: bool
    p: NDArray[np.float64]  # the fit with the term (12) or without (9) that is returned
    lag_s: float
    facts: dict[str, Any]
    reasons: tuple[Reason, ...] = ()


def _independence(jac: NDArray[np.float64]) -> float:
    """ρ of (M4) on (T3)'s Jacobian: the share of k's information the other parameters leave."""
    flat = jac.reshape(-1, jac.shape[2])
    info = flat.T @ flat
    norms = np.sqrt(np.maximum(np.diag(info), 1e-300))
    scaled = info / np.outer(norms, norms)
    rest, kk = slice(0, 9), slice(9, 12)
    schur = scaled[kk, kk] - scaled[kk, rest] @ np.linalg.lstsq(scaled[rest, rest], scaled[rest, kk], rcond=1e-12)[0]
    inv_root = np.linalg.inv(np.linalg.cholesky(scaled[kk, kk]))
    return max(float(np.min(np.linalg.eigvalsh(inv_root @ schur @ inv_root.T))), 0.0)


def _motor(data_at: Any, lags: NDArray[np.float64], without: NDArray[np.float64], kind: str, motor: str,
           field: float, c_scale: float, full_scale: float) -> _Motor:  # fmt: skip
    """The joint fit with the term at the best lag, and whether it is kept (module docstring)."""
    costs = []
    fits = []
    for lag in lags:
        data = data_at(float(lag))
        p, cost = _best(data, [np.concatenate([without, np.zeros(3)])])
        costs.append(cost)
        fits.append(p)
    best = int(np.argmin(costs))
    lag, p = float(lags[best]), fits[best]
    data = data_at(lag)
    rho = _independence(_jacobian(p, data))
    _, covariance = _covariance(p, data)
    k = p[9:12] * field / c_scale
    k_cov = covariance[9:12, 9:12] * (field / c_scale) ** 2
    size = float(np.linalg.norm(k))
    percent = 100.0 * size * full_scale / field
    direction = k / size if size > 0 else np.zeros(3)
    percent_sigma = 100.0 * full_scale / field * math.sqrt(max(float(direction @ k_cov @ direction), 0.0))
    significance = float(k @ np.linalg.pinv(k_cov) @ k) if size > 0 else 0.0
    facts: dict[str, Any] = {
        "regressor": kind, "percent": percent, "percent_sigma": percent_sigma, "independence": rho,
        "significance": significance, "lag_s": lag, "coefficients": k.tolist(),
        "at_lag_edge": bool(lags.size > 1 and best in (0, lags.size - 1)),
    }  # fmt: skip
    reasons = ReasonList()
    at = f"full current ({full_scale:.3g} A)" if kind == "current" else "full throttle"
    if motor == "none":
        reasons.add("motor_negligible", "motor='none': estimated, not fitted")
    elif rho < MIN_INDEPENDENCE:
        heading = math.degrees(math.atan(percent / 100.0))
        code = "motor_undetermined"
        text = (
            f"the {kind} does not vary independently of the attitude and the offset (ρ = {rho:.3f}, below "
            f"{MIN_INDEPENDENCE}): its field cannot be told from the calibration, so no term is fitted"
        )
        if percent - 2.0 * percent_sigma > MIN_PERCENT:
            text += (
                f"; a fit would put it at {percent:.0f} % ± {percent_sigma:.0f} % of the field at {at}, which turns "
                f"the heading by about {heading:.0f}° where the field is horizontal, beyond the uncertainty stated"
            )
        reasons.add(code, text + "; record a flight that turns and tilts at low and at high throttle")
    elif motor == "auto" and (percent + 3 * percent_sigma < MIN_PERCENT or percent < MIN_PERCENT
                              or significance < CHI2_3_999):  # fmt: skip
        reasons.add("motor_negligible", f"{percent:.1f} % ± {percent_sigma:.1f} % of the field at {at}, below "
                    f"{MIN_PERCENT:g} % or within the noise: no term is invented")  # fmt: skip
    kept = not reasons
    return _Motor(kept, p if kept else without, lag, facts, tuple(reasons))


def _inputs(raw: NDArray[np.float64], reference: ArrayLike | None, down: ArrayLike | None) -> tuple[NDArray[Any],
            NDArray[Any], float]:  # fmt: skip
    n = raw.shape[0]
    ref = _reference_array(reference, n)
    if down is None:
        raise OptionError(
            "method 'tilt' needs down=: the vertical (down) direction at each sample in the vehicle frame, an (N, 3) "
            "array from the logged roll and pitch (row 3 of each body-to-NED attitude matrix)"
        )
    vertical = check_rows(down, "down", n, "the vertical (down) direction in the vehicle frame")
    size = np.linalg.norm(vertical, axis=1)
    if np.any(~(size > 0.5)) or np.any(size > 2.0):
        row = int(np.argmax(~((size > 0.5) & (size < 2.0))))
        raise OptionError(f"down= is not a unit vector in row {row} (0-based, length {size[row]:.3g}): give the "
                          "vertical direction from roll and pitch, or drop that sample")  # fmt: skip
    return ref, vertical / size[:, None], _field(ref)


def _regressor(n: int, regressor: ArrayLike | None, kind: str, time_s: ArrayLike | None,
               regressor_time_s: ArrayLike | None, max_lag_s: float) -> tuple[Any, NDArray[np.float64]]:  # fmt: skip
    """(values at a lag, the lags searched); (None, [0]) without a regressor."""
    if regressor is None:
        if regressor_time_s is not None:
            raise OptionError("regressor_time_s= is given without regressor=")
        return None, np.array([0.0])
    if kind not in REGRESSORS:
        raise OptionError(f"regressor_kind must be one of {', '.join(REGRESSORS)}; got {kind!r}")
    values = np.asarray(regressor, dtype=np.float64)
    if regressor_time_s is None:
        if values.shape != (n,):
            raise OptionError(f"regressor= must be one value per sample, shape ({n},), got shape {values.shape}; or "
                              "give regressor_time_s= (its own clock) and time_s=")  # fmt: skip
        return (lambda lag: values), np.array([0.0])
    if time_s is None:
        raise OptionError("regressor_time_s= needs time_s=, the samples' stamps on the same clock")
    stamps = check_times(time_s, "time_s", n)
    own = np.asarray(regressor_time_s, dtype=np.float64)
    if own.shape != values.shape or own.ndim != 1 or own.size < 2:
        raise OptionError("regressor_time_s= must hold one stamp per regressor value (at least two)")
    if not max_lag_s >= 0:
        raise OptionError(f"max_lag_s must be a number of seconds >= 0, got {max_lag_s!r}")
    order = np.argsort(own, kind="stable")
    own, values = own[order], values[order]
    steps = math.floor(max_lag_s / 0.01 + 1e-9)
    lags = np.asarray(0.01 * np.arange(-steps, steps + 1), dtype=np.float64)
    return (lambda lag: regressor_at(stamps, own, values, lag)), lags


@register(
    "tilt",
    min_samples=MIN_SAMPLES,
    data="samples",
    summary="soft iron (symmetric, with the scale), hard iron and the motors' field against the reference field's "
    "horizontal strength and vertical component, with the logged roll and pitch only (the yaw free)",
    needs=("reference", "down"),
    fit_rows=FIT_ROWS,
)
def fit_tilt(
    data: FitInput,
    *,
    reference: ArrayLike | None = None,
    down: ArrayLike | None = None,
    regressor: ArrayLike | None = None,
    regressor_kind: str = "current",
    regressor_time_s: ArrayLike | None = None,
    time_s: ArrayLike | None = None,
    max_lag_s: float = MAX_LAG_S,
    motor: str = "auto",
) -> Calibration:
    """Fit (T1)-(T3) of the module docstring.

    Parameters
    ----------
    reference : array_like, shape (N, 3)
        The field expected at each sample in the vehicle frame, in the samples' unit (its yaw is not used: only
        its horizontal strength and vertical component about ``down``).
    down : array_like, shape (N, 3)
        The vertical (down) at each sample in the vehicle frame, from the logged roll and pitch.
    regressor : array_like, optional
        The battery current (A) or the throttle (0-1): one value per sample, or on its own clock
        ``regressor_time_s`` (``time_s`` then gives the samples' stamps, and the lag is searched within
        ``±max_lag_s``). Given, the motors' field is fitted with the calibration (module docstring).
    regressor_kind : {"current", "throttle"}
    motor : {"auto", "current", "throttle", "none"}
        ``"auto"``: keep the term when it is determined and matters; a name: whenever it is determined; ``"none"``:
        estimate it, never keep it.
    """
    raw = fit_input(data, "tilt").require_samples("tilt")
    ref, vertical, field = _inputs(raw, reference, down)
    if motor not in MOTOR_CHOICES:
        raise OptionError(f"motor must be one of {', '.join(MOTOR_CHOICES)}; got {motor!r}")
    values_at, lags = _regressor(raw.shape[0], regressor, regressor_kind, time_s, regressor_time_s, max_lag_s)
    n = raw.shape[0]
    stride = max(1, -(-n // FIT_ROWS))
    z = np.einsum("ki,ki->k", ref, vertical)
    h = np.linalg.norm(ref - z[:, None] * vertical, axis=1)
    rows = np.arange(0, n, stride)
    first = _fit_rows(rows, raw, ref, vertical, h, z, field, values_at, lags, regressor_kind, motor)
    # Samples whose residual lies beyond DEFAULT_THRESHOLD robust standard deviations and OUTLIER_FLOOR (a crash,
    # the vehicle on its back with the motors stalled, a magnet) are left out and the fit made again without them.
    residuals = _residuals(first.p, first.data)
    outside = np.zeros(rows.size, dtype=bool)
    for component in residuals.T:
        centre, sigma = robust_scale(component)
        outside |= np.abs(component - centre) > max(DEFAULT_THRESHOLD * sigma, OUTLIER_FLOOR)
    fitted = first
    if np.any(outside) and rows.size - np.count_nonzero(outside) >= MIN_SAMPLES:
        fitted = _fit_rows(rows[~outside], raw, ref, vertical, h, z, field, values_at, lags, regressor_kind, motor)
    details = fitted.details
    details["rejected"] = int(np.count_nonzero(outside)) if fitted is not first else 0
    return _judged(fitted.p, fitted.data, field, fitted.term, fitted.motor, details, n, stride, rows.size)


@dataclass(frozen=True)
class _Fitted:
    p: NDArray[np.float64]
    data: _Data
    term: MotorTerm | None
    motor: _Motor | None
    details: dict[str, Any]


def _fit_rows(rows: NDArray[np.intp], raw: NDArray[np.float64], ref: NDArray[np.float64],
              vertical: NDArray[np.float64], h: NDArray[np.float64], z: NDArray[np.float64], field: float,
              values_at: Any, lags: NDArray[np.float64], kind: str, motor: str) -> _Fitted:  # fmt: skip
    """(T3) on the samples ``rows``, with the motors' term tried when a regressor is given."""
    base = _Data(raw[rows] / field, vertical[rows], h[rows] / field, z[rows] / field, None)
    p9, _ = _best(base, _starts(base, ref[rows] / field))
    details: dict[str, Any] = {}
    if values_at is None:
        return _Fitted(p9, base, None, None, details)
    c0 = values_at(0.0)[rows]
    finite = np.isfinite(c0)
    spread = float(np.nanpercentile(c0, 95) - np.nanpercentile(c0, 5)) if np.any(finite) else 0.0
    full_scale = 1.0 if kind == "throttle" else float(np.nanmax(np.abs(c0))) if np.any(finite) else 0.0
    term = None
    data_final = base
    if np.count_nonzero(finite) < MIN_SAMPLES or not spread > 0 or not full_scale > 0:
        motor_fit = _Motor(False, p9, 0.0, {"regressor": kind}, (Reason(
            f"the {kind} does not vary over the samples (5-95 % spread {spread:.3g}): its field cannot be told from "
            "the offset; record a flight whose throttle changes", "motor_undetermined"),))  # fmt: skip
    else:

        def data_at(lag: float) -> _Data:
            c = values_at(lag)[rows]
            good = np.isfinite(c)
            c[~good] = np.interp(np.flatnonzero(~good), np.flatnonzero(good), c[good])  # beyond its span: its ends
            return _Data(base.x, base.down, base.h, base.z, c / spread)

        motor_fit = _motor(data_at, lags, p9, kind, motor, field, spread, full_scale)
        if motor_fit.kept:
            data_final = data_at(motor_fit.lag_s)
            term = MotorTerm(kind, np.asarray(motor_fit.facts["coefficients"]), lag_s=motor_fit.lag_s,
                             full_scale=full_scale)  # fmt: skip
    details["motor"] = {**motor_fit.facts, "kept": motor_fit.kept,
                        "reasons": [Reason.to_dict(r) for r in motor_fit.reasons]}  # fmt: skip
    return _Fitted(motor_fit.p, data_final, term, motor_fit, details)


def _halves(p: NDArray[np.float64], data: _Data, inclination: float, regressor: float) -> tuple[float, float] | None:
    """(RMS heading difference, combined one-sigma) of the fits of the two halves of the recording, degrees."""
    n = data.x.shape[0]
    if n < 2 * MIN_SAMPLES:
        return None
    body, _ = _body_fields(inclination, 0.0)
    s, v, k = _parts(p)
    raw = body @ np.linalg.inv(s).T + v + regressor * k
    headings, variances = [], []
    for half in (slice(0, n // 2), slice(n // 2, n)):
        part = data.take(half)
        try:
            q, _ = _best(part, [p])
        except CalibrationError:
            return None
        sq, vq, kq = _parts(q)
        c = (raw - vq - regressor * kq) @ sq
        headings.append(np.arctan2(-c[:, 1], c[:, 0]))
        variances.append(_heading_sigmas(q, _covariance(q, part)[1], inclination, regressor)[0] ** 2)
    difference = np.angle(np.exp(1j * (headings[0] - headings[1])))
    return math.degrees(float(np.sqrt(np.mean(difference**2)))), math.sqrt(sum(variances))


def _judged(p: NDArray[np.float64], data: _Data, field: float, term: MotorTerm | None, motor_fit: _Motor | None,
            details: dict[str, Any], n: int, stride: int, read: int) -> Calibration:  # fmt: skip
    """The calibration with its verdict (module docstring)."""
    scale = field  # the normalised unit
    independent, covariance = _covariance(p, data)
    residuals = _residuals(p, data)
    residual_rms = float(np.sqrt(np.mean(np.sum(residuals**2, axis=1))))  # over the field (normalised)
    inclination = math.degrees(math.atan2(float(np.median(data.z)), float(np.median(data.h))))
    regressor = float(np.sqrt(np.mean(data.c**2))) if data.c is not None and p.size > 9 else 0.0
    heading, heading_max = _heading_sigmas(p, covariance, inclination, regressor)
    tilted, tilted_max = _heading_sigmas(p, covariance, inclination, regressor, TILT_DEG)
    independent_heading, _ = _heading_sigmas(p, independent, inclination, regressor)
    tilt_spread, heading_spread = _spreads(data, p)
    refusals, weaknesses = ReasonList(), ReasonList()
    effect = (
        f"the heading one-sigma that follows is ±{heading:.2g}° at level and ±{tilted:.2g}° at {TILT_DEG:.0f}° of tilt"
    )
    if residual_rms > NO_ELLIPSOID_RMS:
        refusals.add("reference",
            f"the samples do not follow the reference's horizontal strength and vertical component: after the best "
            f"fit they still differ by {100 * residual_rms:.0f} % of the field (RMS); the roll and pitch or the "
            "reference field are wrong (the attitude of another frame, another place or unit), or the field changed "
            "(motors, a magnet)")  # fmt: skip
    elif residual_rms > LARGE_RESIDUAL_RMS:
        weaknesses.add("large_residual",
            f"the residuals are large: {100 * residual_rms:.1f} % of the field (RMS): the roll and pitch err by "
            "degrees, or the field changed while recording; expect heading errors of a few degrees")  # fmt: skip
    lacking = []
    if heading_spread < 90.0:
        lacking.append(f"the horizontal field turned through only {heading_spread:.0f}° of headings (circular spread)")
    if tilt_spread < 8.0:
        lacking.append(f"roll and pitch varied by only {tilt_spread:.1f}° (RMS about their mean), so the response to "
                       "the vertical field trades with the vertical offset")  # fmt: skip
    why = "; ".join(lacking) if lacking else "the attitudes recorded do not pin the calibration"
    axes = np.linalg.eigvalsh(_matrix(p))
    ratio = float(axes[-1] / axes[0]) if axes[0] > 0 else float("inf")
    if tilt_spread < MIN_TILT_DEG and not refusals:
        refusals.add("undetermined",
            f"roll and pitch varied by only {tilt_spread:.2g}° (RMS about their mean): the response to the vertical "
            "field trades with the vertical offset, which a fit through level attitudes cannot tell apart (the "
            f"linearised one-sigma, {effect}, does not hold so far from the samples)")  # fmt: skip
    elif not ratio < MAX_AXIS_RATIO and not refusals:
        refusals.add(
            "undetermined",
            f"the fitted soft iron stretches one axis {ratio:.2g} times another (more than {MAX_AXIS_RATIO:g}): no "
            f"compass's soft iron does; the attitudes recorded leave a direction free and the fit ran along it: {why}",
        )
    if max(heading, tilted) > HEADING_LIMIT_DEG and not refusals:
        refusals.add("undetermined", f"the roll and pitch recorded do not determine the calibration: {why}; {effect}")
    elif max(heading, tilted) > WEAK_HEADING_DEG:
        weaknesses.add(
            "weakly_determined",
            f"the calibration is weakly determined: {why}; {effect}: it holds near the attitudes recorded",
        )
    sigmas = np.sqrt(np.maximum(np.diag(covariance), 0.0))
    if motor_fit is not None:
        for reason in motor_fit.reasons:
            if reason.code == "motor_undetermined" and "beyond the uncertainty" in reason:
                weaknesses.add(reason.code, str(reason))
        if motor_fit.kept and motor_fit.facts["independence"] < WEAK_INDEPENDENCE:
            weaknesses.add("motor_weak",
                f"the motors' term kept is weakly told from the attitude (ρ = {motor_fit.facts['independence']:.3f}): "
                f"its size, {motor_fit.facts['percent']:.1f} % ± {motor_fit.facts['percent_sigma']:.1f} % of the field "
                "at full scale, may be off by more than its one-sigma says; confirm it on a flight that turns and "
                "tilts at low and at high throttle")  # fmt: skip
    stated, stated_max = heading, max(heading_max, tilted_max)
    halves = _halves(p, data, inclination, regressor) if not refusals else None
    if halves is not None and halves[0] > HALVES_SIGMAS * halves[1]:
        stated = max(stated, halves[0] / 2.0)
        stated_max = max(stated_max, stated)
        apart = (
            f"the two halves of the recording give headings {halves[0]:.2g}° apart (RMS over level headings), "
            f"{halves[0] / max(halves[1], 1e-12):.1f} times their combined one-sigma (±{halves[1]:.2g}°): the field, "
            f"the motors' field or the roll and pitch changed between them; the heading one-sigma stated holds half "
            f"their difference, ±{stated:.2g}°"
        )
        if stated > USELESS_BOUND_DEG:
            refusals.add("inconsistent_halves", f"{apart}: beyond {USELESS_BOUND_DEG:g}°, a bound that wide is no "
                         "calibration")  # fmt: skip
        else:
            weaknesses.add("inconsistent_halves", apart)
    rejected = int(details.get("rejected", 0))
    if rejected > MAX_REJECTED * read:
        weaknesses.add("large_residual",
            f"{rejected} of {read} samples ({100 * rejected / read:.0f} %) lie far from the fit and were left out: the "
            "roll and pitch, the field or the motors' field changed over part of the recording")  # fmt: skip
    support = Support.judged(refusals, weaknesses, ADVICE)
    s, v, _ = _parts(p)
    offset_sigma = tuple(float(sigmas[6 + i] * scale) for i in range(3))
    scale_sigma = tuple(float(sigmas[(0, 3, 5)[i]] / max(abs(s[i, i]), 1e-12)) for i in range(3))
    count = int(data.x.shape[0])
    effective = count * (independent_heading / heading) ** 2 if heading > 0 else float(count)
    uncertainty = Uncertainty(
        offset_sigma=(offset_sigma[0], offset_sigma[1], offset_sigma[2]),
        scale_sigma=(scale_sigma[0], scale_sigma[1], scale_sigma[2]),
        field_strength_sigma=None,
        heading_sigma_deg=stated,
        heading_sigma_max_deg=stated_max,
        inclination_deg=inclination,
        residual_sigma=residual_rms,
        n_samples=count,
        effective_samples=float(min(effective, count)),
    )
    information = np.linalg.eigvalsh(np.linalg.pinv(covariance[:9, :9]))
    condition = float(information[-1] / information[0]) if information[0] > 0 else None  # (JSON holds no inf)
    observability = Observability(model="vector", condition=condition, weak=(), turn_axis=None)  # (named in words)
    centred = data.x - v
    reached = coverage(centred / np.linalg.norm(centred, axis=1, keepdims=True))
    notes = (
        "Judged against the reference field's horizontal strength and vertical component at the logged roll and "
        "pitch (the yaw free): the residuals and the uncertainty with a block jackknife over the recording; the "
        "mounting's rotation about the vertical is not fitted (the heading is relative to the declared orientation).",
        f"Roll and pitch spread {tilt_spread:.1f}° (RMS about their mean); the corrected horizontal field turned "
        f"through {heading_spread:.0f}° (circular spread).",
        *((f"{rejected} of {read} samples left out: their residual lay beyond {DEFAULT_THRESHOLD:g} robust standard "
           f"deviations and {100 * OUTLIER_FLOOR:g} % of the field (a crash, a magnet, the attitude lost).",)
          if rejected else ()),
    )  # fmt: skip
    diagnostics = Diagnostics(
        n_samples=count, n_used=count, coverage=None, observability=observability, uncertainty=uncertainty,
        goodness=None, warnings=support.warnings, notes=notes, support=support,
    )  # fmt: skip
    details.update(residual_rms=residual_rms, tilt_spread_deg=tilt_spread, heading_spread_deg=heading_spread,
                   cells_reached=reached.cells_reached, diagnostics=diagnostics.to_dict())  # fmt: skip
    if stride > 1:
        details["fit_stride"] = stride
    return Calibration(
        "tilt", v * scale, s, field, n_samples=n, details=details, frame="vehicle", support=support, motor=term,
    )  # fmt: skip
