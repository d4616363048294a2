"""The motors' field fitted jointly with the hard and soft iron, from the samples' magnitude: :func:`fit_motor`.

The model (docs/methods.md, "The motors' field"). A current ``c`` in the power wires adds a field ``k c``
that is fixed in the vehicle (it turns with the compass), so it is a hard-iron offset that changes with the
current::

    raw(t) = W R(t) B e + V + k c(t − τ)                                    (M1)
    |L (raw(t) − V − k c(t − τ))| = 1,  A = Lᵀ L                            (M2)

(M2) is the ellipsoid of the paper's eq. (2) whose centre moves with the current: it holds for every attitude
``R(t)``, so the fit needs **no attitude and no heading**: an EKF yaw that the bad compass itself drove
(the fault pymavlink's ``magfit_WMM.py`` works around by taking only roll and pitch from the log) cannot bias
it. Only what the samples' magnitude determines is fitted: L (upper triangular, 6), V (3), k (3).

**Determined or not.** The residual's Jacobian rows are::

    ∂r/∂V = −uᵀ L,   ∂r/∂k = −c uᵀ L,   ∂r/∂L_ab = u_a d_b,   d = raw − V − k c,  u = L d / |L d|   (M3)

so ``k`` is told from ``V`` only by the current's variation, and from the soft iron only when the current
does not follow the direction of the field in the sensor (a vehicle that draws its peak current at one
heading or tilt only). With the information matrix ``I = JᵀJ`` split into the k block and the rest, the
share of k's information the other parameters leave (the Schur complement over ``I_kk``)::

    ρ = λ_min( I_kk^{-1/2} (I_kk − I_kr I_rr⁻¹ I_rk) I_kk^{-1/2} ) = 1 − R²_max                       (M4)

is 1 when the current varies independently of the attitude and the offset, 0 when it does not at all.
Below :data:`MIN_INDEPENDENCE` the term is **not** fitted (reason ``motor_undetermined``): a fit would absorb
attitude into the coefficients. The covariance of k is ``σ² S⁻¹`` (S the Schur complement).

**Does it matter.** The interference at full current in % of the field, ``100 |k| c_max / B`` (what
ArduPilot's compassmot reports), with its standard error. With ``motor="auto"`` the term is kept when it is
determined, above :data:`MIN_PERCENT` of the field and distinguishable from noise (``kᵀ Cov⁻¹ k`` above the
99.9 % point of χ²₃); otherwise no term is invented (``motor_negligible``). A term asked for by name is kept
whenever it is determined.

**The lag.** The regressor on its own clock is interpolated at ``t − τ`` for τ on a grid within
``±max_lag_s`` (PX4's ``mag_compensation_flight.py`` searches ±80 ms); the τ of least residual is kept.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .calibration import Calibration
from .errors import OptionError, SampleError
from .findings import Reason, ReasonList
from .motorterm import REGRESSORS, MotorTerm

__all__ = ["MIN_INDEPENDENCE", "MIN_PERCENT", "MOTOR_CHOICES", "MotorFit", "fit_motor", "regressor_at", "with_motor"]

#: The library's and the command line's choices: fit when determined and it matters, one by name, or none.
MOTOR_CHOICES = ("auto", "current", "throttle", "none")
#: ρ of (M4) below which k is not told from the attitude and the offset.
MIN_INDEPENDENCE = 0.02
#: ρ below which a kept term is said to be weakly told from the attitude (its bias from any misfit grows as ρ^-½).
WEAK_INDEPENDENCE = 0.05
#: The interference at full current (% of the field) below which "auto" fits no term.
MIN_PERCENT = 2.0
#: χ²₃ at 99.9 %: a term whose k is not this far from zero (in its covariance) is noise.
CHI2_3_999 = 16.27
#: The default lag search: ±80 ms (PX4's mag_compensation_flight.py).
MAX_LAG_S = 0.08
#: Samples the joint fit uses at most (an even stride over the recording), and the lag search.
MAX_FIT_SAMPLES = 20_000
MAX_SEARCH_SAMPLES = 3_000


@dataclass(frozen=True, eq=False)
class MotorFit:
    """What :func:`fit_motor` found.

    Attributes
    ----------
    calibration : Calibration
        The joint fit with the term (``motor`` set) when it was fitted; else the calibration given, unchanged.
    fitted : bool
        Whether the term was kept.
    term : MotorTerm or None
        The term estimated (kept or not); None when it could not be estimated at all.
    percent : float
        The interference at full scale in % of the field (NaN when not estimated).
    percent_sigma : float
        Its one-sigma.
    independence : float
        ρ of (M4): 1 when the regressor varies independently of the attitude and the offset, 0 when not.
    residual_rms : tuple of float
        The magnitude residual (input units, RMS) without and with the term.
    reasons : tuple of Reason
        Why it was not fitted (codes ``motor_undetermined``, ``motor_negligible``, ``motor_no_regressor``).
    """

    calibration: Calibration
    fitted: bool
    term: MotorTerm | None
    percent: float = float("nan")
    percent_sigma: float = float("nan")
    independence: float = float("nan")
    residual_rms: tuple[float, float] = (float("nan"), float("nan"))
    reasons: tuple[Reason, ...] = ()
    at_lag_edge: bool = False

    def summary(self) -> str:
        """In words: ``the motors' field: 4.2 mG per A, 31 % of the field at full current (45 A), fitted``."""
        if self.term is None:
            return "the motors' field: not estimated: " + "; ".join(self.reasons)
        unit = self.calibration.unit or "units"
        per = "A" if self.term.regressor == "current" else "full throttle"
        at = f"full current ({self.term.full_scale:.3g} A)" if self.term.regressor == "current" else "full throttle"
        size = float(np.linalg.norm(self.term.coefficients))
        text = (
            f"the motors' field ({self.term.regressor}): {size:.3g} {unit} per {per}, {self.percent:.1f} % "
            f"± {self.percent_sigma:.1f} % of the field at {at}, lag {1000 * self.term.lag_s:.0f} ms"
        )
        if np.isfinite(self.independence) and self.independence < WEAK_INDEPENDENCE:
            text += f", weakly told from the attitude (ρ = {self.independence:.2f})"
        if self.at_lag_edge:
            text += " (the lag at the edge of its search)"
        if self.fitted:
            return text + ", fitted"
        return text + ", not fitted: " + "; ".join(self.reasons)


def regressor_at(
    time_s: ArrayLike, regressor_time_s: ArrayLike, regressor_values: ArrayLike, lag_s: float = 0.0
) -> NDArray[np.float64]:
    """The regressor at ``time_s − lag_s`` (linear interpolation; NaN outside its span)."""
    at = np.asarray(time_s, dtype=np.float64) - lag_s
    rt = np.asarray(regressor_time_s, dtype=np.float64)
    rv = np.asarray(regressor_values, dtype=np.float64)
    values = np.interp(at, rt, rv)
    values[(at < rt[0]) | (at > rt[-1])] = np.nan
    return values


def _unpack(p: NDArray[np.float64]) -> tuple[NDArray[np.float64], float, NDArray[np.float64], NDArray[np.float64]]:
    """(M, R, V, k): M upper triangular with det M = 1 (M22 = 1 / (M00 M11)), the radius R."""
    m = np.zeros((3, 3))
    m[0, 0], m[0, 1], m[0, 2], m[1, 1], m[1, 2] = p[:5]
    m[2, 2] = 1.0 / (p[0] * p[3])
    return m, float(p[5]), p[6:9], p[9:12]


def _residuals(p: NDArray[np.float64], x: NDArray[np.float64], c: NDArray[np.float64]) -> NDArray[np.float64]:
    """``|M d| − R`` (M2 with L = M / R): a distance in the samples' (normalised) unit, not an algebraic one."""
    m, radius, offset, k = _unpack(p)
    y = (x - offset - np.outer(c, k)) @ m.T
    return np.asarray(np.linalg.norm(y, axis=1) - radius)


def _jacobian(p: NDArray[np.float64], x: NDArray[np.float64], c: NDArray[np.float64]) -> NDArray[np.float64]:
    """(M3) for ``|M d| − R``; columns: M00, M01, M02, M11, M12, R, V, k."""
    m, _, offset, k = _unpack(p)
    d = x - offset - np.outer(c, k)
    y = d @ m.T
    u = y / np.linalg.norm(y, axis=1, keepdims=True)
    last = u[:, 2] * d[:, 2] * m[2, 2]
    columns = [
        u[:, 0] * d[:, 0] - last / m[0, 0],
        u[:, 0] * d[:, 1],
        u[:, 0] * d[:, 2],
        u[:, 1] * d[:, 1] - last / m[1, 1],
        u[:, 1] * d[:, 2],
        -np.ones(len(d)),
    ]
    j_v = -(u @ m)
    return np.asarray(np.column_stack([*columns, j_v, j_v * c[:, None]]))


#: The soft-iron entries each model frees (indices into the parameter vector M00, M01, M02, M11, M12).
_MODEL_ENTRIES = {"sphere": (), "diag": (0, 3), "full": (0, 1, 2, 3, 4)}


def _model(calibration: Calibration) -> str:
    """The soft-iron model the method chose: the joint fit frees no more than the samples determined."""
    off = calibration.matrix - np.diag(np.diag(calibration.matrix))
    if np.allclose(calibration.matrix, np.eye(3), atol=1e-9):
        return "sphere"
    if np.allclose(off, 0.0, atol=1e-9):
        return "diag"
    return "full"


def _free(model: str, with_k: bool) -> NDArray[np.intp]:
    return np.array([*_MODEL_ENTRIES[model], 5, 6, 7, 8, *((9, 10, 11) if with_k else ())], dtype=np.intp)


def _solve(
    x: NDArray[np.float64], c: NDArray[np.float64], start: NDArray[np.float64], free: NDArray[np.intp]
) -> tuple[NDArray[np.float64], float]:
    from scipy.optimize import least_squares

    def full(q: NDArray[np.float64]) -> NDArray[np.float64]:
        p = start.copy()
        p[free] = q
        return p

    def res(q: NDArray[np.float64]) -> NDArray[np.float64]:
        return _residuals(full(q), x, c)

    def jac(q: NDArray[np.float64]) -> NDArray[np.float64]:
        return _jacobian(full(q), x, c)[:, free]

    result = least_squares(res, start[free], jac=jac, method="lm")
    p = full(result.x)
    if not np.all(np.isfinite(p)) or p[0] * p[3] <= 0 or p[5] <= 0:
        raise SampleError("the joint fit of the motors' field did not converge")
    return p, float(np.sqrt(np.mean(_residuals(p, x, c) ** 2)))


def _start(calibration: Calibration, scale: float) -> NDArray[np.float64]:
    """The calibration given as (M, R, V, k = 0) in the normalised units (samples / scale)."""
    a = calibration.ellipsoid_matrix * scale**2
    upper = np.linalg.cholesky(a).T  # A = Lᵀ L, L upper triangular
    det = float(np.prod(np.diag(upper)))
    m = upper / det ** (1.0 / 3.0)
    radius = 1.0 / det ** (1.0 / 3.0)
    return np.array([m[0, 0], m[0, 1], m[0, 2], m[1, 1], m[1, 2], radius, *(calibration.offset / scale), 0, 0, 0])


def _independence(jac: NDArray[np.float64]) -> tuple[float, NDArray[np.float64]]:
    """ρ of (M4) and the Schur complement S of the k block (the last three columns; k's covariance σ² S⁻¹)."""
    info = jac.T @ jac
    n = info.shape[0]
    norms = np.sqrt(np.maximum(np.diag(info), 1e-300))
    scaled = info / np.outer(norms, norms)
    rest, kk = slice(0, n - 3), slice(n - 3, n)  # (M, R, V) and k
    schur = scaled[kk, kk] - scaled[kk, rest] @ np.linalg.lstsq(scaled[rest, rest], scaled[rest, kk], rcond=1e-12)[0]
    root = np.linalg.cholesky(scaled[kk, kk])
    inv_root = np.linalg.inv(root)
    rho = float(np.min(np.linalg.eigvalsh(inv_root @ schur @ inv_root.T)))
    schur_unscaled = schur * np.outer(norms[kk], norms[kk])
    return max(rho, 0.0), schur_unscaled


def fit_motor(
    samples: ArrayLike,
    calibration: Calibration,
    regressor: ArrayLike,
    *,
    kind: str = "current",
    motor: str = "auto",
    time_s: ArrayLike | None = None,
    regressor_time_s: ArrayLike | None = None,
    max_lag_s: float = MAX_LAG_S,
    lag_step_s: float = 0.01,
    min_percent: float = MIN_PERCENT,
    full_model: bool = True,
) -> MotorFit:
    """Fit the motors' field jointly with the hard and soft iron, from the samples' magnitude (M2).

    Parameters
    ----------
    samples : array_like, shape (N, 3)
        The raw samples (the firmware's calibration and motor compensation undone), input units.
    calibration : Calibration
        A fit of the same samples without the term: the start, and what is returned when no term is fitted.
    regressor : array_like
        The regressor: shape (N,), at the samples (no lag search), or shape (M,) on its own clock
        ``regressor_time_s`` (the lag is then searched within ``±max_lag_s``; ``time_s`` required).
    kind : {"current", "throttle"}
        What the regressor is (amperes, or the throttle from 0 to 1).
    motor : {"auto", "current", "throttle", "none"}
        ``"auto"``: keep the term when it is determined and matters (module docstring); a name: keep it
        whenever it is determined; ``"none"``: estimate it, report it, never keep it.
    full_model : bool
        Fit the general ellipsoid with the term (default): a sphere or axis-aligned model chosen on samples
        the motors distorted would push its own misfit into k. False: the calibration's own model.

    Returns
    -------
    MotorFit
        With the term kept, ``calibration`` is the joint fit (M2) in the sensor frame (the symmetric root);
        :func:`with_motor` redoes a method's own fit (a vehicle-frame ``vector`` fit too) on ``raw − k c``.
    """
    if motor not in MOTOR_CHOICES:
        raise OptionError(f"motor must be one of {', '.join(MOTOR_CHOICES)}; got {motor!r}")
    if kind not in REGRESSORS:
        raise OptionError(f"the regressor's kind must be one of {', '.join(REGRESSORS)}; got {kind!r}")
    x_all = np.asarray(samples, dtype=np.float64)
    if x_all.ndim != 2 or x_all.shape[1] != 3:
        raise SampleError(f"fit_motor() takes samples of shape (N, 3), got {x_all.shape}")
    values = np.asarray(regressor, dtype=np.float64)
    if regressor_time_s is None:
        if values.shape != (len(x_all),):
            raise SampleError(f"the regressor must have shape ({len(x_all)},) (one per sample), got {values.shape}")

        def at(lag: float) -> NDArray[np.float64]:
            return values

        lags = np.array([0.0])
    else:
        if time_s is None:
            raise OptionError("regressor_time_s needs time_s, the samples' stamps on the same clock")
        stamps = np.asarray(time_s, dtype=np.float64)
        r_time = np.asarray(regressor_time_s, dtype=np.float64)
        if stamps.shape != (len(x_all),) or r_time.shape != values.shape or len(r_time) < 2:
            raise SampleError("time_s must be one stamp per sample and regressor_time_s one per regressor value")
        order = np.argsort(r_time, kind="stable")
        r_time, r_values = r_time[order], values[order]

        def at(lag: float) -> NDArray[np.float64]:
            return regressor_at(stamps, r_time, r_values, lag)

        steps = int(np.floor(max_lag_s / lag_step_s + 1e-9))
        lags = lag_step_s * np.arange(-steps, steps + 1)
    reasons = ReasonList()
    stride = max(1, int(np.ceil(len(x_all) / MAX_FIT_SAMPLES)))
    scale = calibration.field_strength
    c_at_zero = at(0.0)
    finite = np.isfinite(c_at_zero)
    spread = float(np.nanpercentile(c_at_zero, 95) - np.nanpercentile(c_at_zero, 5)) if np.any(finite) else 0.0
    full_scale = 1.0 if kind == "throttle" else float(np.nanmax(np.abs(c_at_zero))) if np.any(finite) else 0.0
    if np.count_nonzero(finite) < 50 or not spread > 0 or not full_scale > 0:
        reasons.add(
            "motor_no_regressor" if np.count_nonzero(finite) < 50 else "motor_undetermined",
            f"the {kind} does not vary over the samples (5-95 % spread {spread:.3g}): its field cannot be told from "
            "the hard-iron offset; record a flight whose throttle changes",
        )
        return MotorFit(calibration, False, None, reasons=tuple(reasons))
    c_scale = spread

    start = _start(calibration, scale)

    def subset(lag: float, every: int) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        c = at(lag)
        keep = np.isfinite(c)
        keep[np.arange(len(keep)) % every != 0] = False
        return x_all[keep] / scale, c[keep] / c_scale

    def joint(model: str) -> tuple[float, float, NDArray[np.float64]]:
        """The lag on an even subset (warm-started along the grid), then the fit on all at that lag."""
        free = _free(model, True)
        lag = float(lags[0])
        if len(lags) > 1:
            search_stride = max(stride, int(np.ceil(len(x_all) / MAX_SEARCH_SAMPLES)))
            costs, warm = [], start
            for candidate in lags:
                xs, cs = subset(float(candidate), search_stride)
                try:
                    warm, cost = _solve(xs, cs, warm, free)
                except SampleError:
                    warm, cost = start, np.inf
                costs.append(cost)
            lag = float(lags[int(np.argmin(costs))])
        xs, cs = subset(lag, stride)
        p, rms = _solve(xs, cs, start, free)
        return rms, lag, p

    def plausible(p: NDArray[np.float64]) -> bool:
        """The joint fit stays near the calibration given: its radius within 1/1.5-1.5x, its centre within one
        radius. A sphere grown a hundredfold to fit a band of directions is a degenerate solution, not a fit."""
        _, radius, offset, _ = _unpack(p)
        return 1 / 1.5 < radius / start[5] < 1.5 and float(np.linalg.norm(offset - start[6:9])) < start[5]

    # The calibration's own model, then the general ellipsoid (a sphere or axis-aligned model chosen on samples the
    # motors distorted would push its own misfit into k); the general one is kept when it stays plausible.
    models = [_model(calibration)] + (["full"] if full_model and _model(calibration) != "full" else [])
    fits = []
    for model in models:
        try:
            fits.append((model, *joint(model)))
        except SampleError:
            continue
    fits = [f for f in fits if plausible(f[3])]
    if not fits:
        reasons.add(
            "motor_undetermined",
            f"the joint fit with the {kind} does not stay near the calibration (its sphere grows or its centre runs "
            "away): the samples do not determine the motors' field; record a flight that turns and tilts more",
        )
        return MotorFit(calibration, False, None, reasons=tuple(reasons))
    model, rms_with, lag, p = fits[-1]
    free = _free(model, True)
    x, cn = subset(lag, stride)
    _, rms_without = _solve(x, cn, start, _free(model, False))
    # (M4) against the full soft iron whatever the model: k must not stand in for an attitude-dependent error.
    rho, _ = _independence(_jacobian(p, x, cn)[:, _free("full", True)])
    _, schur = _independence(_jacobian(p, x, cn)[:, free])
    dof = max(len(x) - len(_free(model, True)), 1)
    upper, radius_n, offset_n, k_n = _unpack(p)
    sigma2 = float(np.sum(_residuals(p, x, cn) ** 2) / dof)
    covariance = sigma2 * np.linalg.pinv(schur)  # of k_n (normalised units per normalised regressor)
    field = scale * radius_n  # the sphere's radius after the joint fit
    k = k_n * scale / c_scale
    k_cov = covariance * (scale / c_scale) ** 2
    size = float(np.linalg.norm(k))
    percent = 100.0 * size * full_scale / field
    direction = k / size if size > 0 else np.zeros(3)
    percent_sigma = 100.0 * full_scale / field * float(np.sqrt(max(float(direction @ k_cov @ direction), 0.0)))
    significance = float(k @ np.linalg.pinv(k_cov) @ k) if size > 0 else 0.0
    term = MotorTerm(kind, k, lag_s=lag, full_scale=full_scale)
    facts: dict[str, Any] = {
        "percent": percent, "percent_sigma": percent_sigma, "independence": rho,
        "residual_rms": [rms_without * scale, rms_with * scale], "significance": significance, "model": model,
    }  # fmt: skip
    if motor == "none":
        reasons.add("motor_negligible", "motor='none': not fitted")
    elif percent + 3 * percent_sigma < min_percent and motor == "auto":
        reasons.add(
            "motor_negligible",
            f"{percent:.1f} % ± {percent_sigma:.1f} % of the field at full scale, below {min_percent:g} %: no term "
            "is invented",
        )
    elif rho < MIN_INDEPENDENCE:
        reasons.add(
            "motor_undetermined",
            f"the {kind} does not vary independently of the attitude and the offset (ρ = {rho:.3f}, below "
            f"{MIN_INDEPENDENCE}): its field cannot be told from the calibration, so no term is fitted; record a "
            "flight that turns and tilts at low and at high throttle",
        )
    elif motor == "auto" and (percent < min_percent or significance < CHI2_3_999):
        reasons.add(
            "motor_negligible",
            f"{percent:.1f} % ± {percent_sigma:.1f} % of the field at full scale, below {min_percent:g} % or within "
            "the noise: no term is invented",
        )
    fitted = not reasons
    result = calibration
    if fitted:
        eigenvalues, eigenvectors = np.linalg.eigh(upper.T @ upper)
        matrix = (eigenvectors * np.sqrt(eigenvalues)) @ eigenvectors.T  # the symmetric root, det 1
        details = {**dict(calibration.details), "motor": {**facts, "start_method": calibration.method}}
        result = Calibration(
            calibration.method, offset_n * scale, matrix, field, unit=calibration.unit,
            n_samples=calibration.n_samples, details=details, frame="sensor", motor=term,
        )  # fmt: skip
    edge = len(lags) > 1 and abs(lag) >= float(np.max(np.abs(lags))) - 1e-12
    return MotorFit(
        result,
        fitted,
        term,
        percent,
        percent_sigma,
        rho,
        (rms_without * scale, rms_with * scale),
        tuple(reasons),
        edge,
    )


def with_motor(
    fitted: MotorFit,
    samples: NDArray[np.float64],
    regressor: NDArray[np.float64],
    refit: Callable[[NDArray[np.float64]], Calibration],
) -> Calibration:
    """The method's own fit redone on the samples with the motors' field removed, holding the term.

    The joint fit (M2) determines k; the method (its model, verdict and diagnostics) then runs on
    ``raw − k c`` as on any samples, so its verdict speaks of the calibration that is returned.
    """
    if not fitted.fitted or fitted.term is None:
        return fitted.calibration
    cleaned = samples - fitted.term.field(regressor)
    calibration = refit(cleaned)
    details = {**dict(calibration.details), "motor": dict(fitted.calibration.details.get("motor", {}))}
    return replace(calibration, motor=fitted.term, details=details)
