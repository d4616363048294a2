"""``method="vector"``: calibration against a reference field, ``raw = G r + V`` (docs/methods.md, "vector").

``r`` is the field expected at each sample in the vehicle frame (the Earth's field rotated by the vehicle's
attitude); G is a general 3x3 matrix, the soft iron times the magnetometer's misalignment (a mirror for a
sensor with left-handed axes), V the hard iron. The calibration returned is ``frame="vehicle"``:
``matrix = G⁻¹`` (absolute: the corrected samples equal the reference, in its unit), ``offset = V``,
``field_strength`` the reference's median magnitude. The equations::

    raw_k = G r_k + V                                   (1)  the model
    raw(t) = G r(t + τ) + V                             (2)  with the attitude's lag τ (time_s given)
    M raw_k − c = r_k,        M = G⁻¹, c = M V          (3)  (1) solved for the field: the vector equations
    d_k · (M raw_k − c) = s,  d_k = −a_k / |a_k|        (4)  the gravity equations (accel given)

(4): where the accelerometer sees gravity alone (:func:`magfit.gravity.still_samples`), its down direction
``d_k`` and the calibrated field make the constant angle of the field's inclination, ``s = B sin δ``.

**Without accel**: linear least squares of (1) on the design ``[r, 1]``, one regression per axis of ``raw``
(Vasconcelos et al., IEEE TAES 47(2), 2011, and Kok & Schön, IEEE Sensors J. 16(14), 2016, fit the same model
by maximum likelihood). The attitude's error makes ``r`` noisy, an errors-in-variables problem whose shrinkage
of G is of order ``σ_a²``, negligible; what limits any estimator is that the error wanders: its mean over the
recording, ``σ_a √(2τ_c/T)`` per axis for a correlation time τ_c over a recording of length T, is
indistinguishable from a turned mounting. An error θ in roll or pitch turns the field's vertical part into the
horizontal plane, so that mean tilt costs ``tan δ · θ̄`` in heading: the floor is ``√(ψ̄² + (tan δ · θ̄)²)``.
(The variants tried against it, and why least squares is kept: docs/methods.md, "vector".)

**With accel**: the joint fit of (3) and (4) at the lag found from (2), linear in (M, c, s). (3) is taken in
the frame of ``r_k``: its radial component ``r̂_k · (M raw_k − c) = |r_k|`` is free of the attitude's error (a
small rotation of r changes its direction, not its length: the magnitude equation, linearised), its two
tangential components carry it. Each kind of equation is weighted by its own noise and time correlation,
``w = 1 / (σ² κ)``, σ² the residuals' scatter and κ how far their batch means exceed independent errors'
(:func:`_inflation`): first from the regression's residuals and the sensors' noise, then from the joint fit's
own residuals, with Huber weights on the gravity equations (accelerations the still-sample gate let through).
Both kinds have noise in their regressors (the magnetometer's in ``raw``, the accelerometer's in ``d``): least
squares would shrink M along what the motion leaves weak to fit it, so its expected contribution is taken off
the normal equations (adjusted least squares, :meth:`_Equations.normal`; the noises from third differences of
the samples, :func:`_noise_sigma`). The uncertainty is a block jackknife of the joint fit
(:data:`magfit.diagnostics.reference.BLOCKS` stretches, each refitted exactly), plus the accelerometer's
calibration prior (:func:`_tilt_prior`).

What each kind pins. The tangential components give the rotation about the vertical (the heading), with the
attitude's error. The gravity equations (4) see the calibrated field's component along gravity: they pin the
response of the vehicle's vertical output to the horizontal field (M's row z) through the horizontal field
turning under it as the vehicle holds still at different headings; the joint fit is made only when the still
samples' headings spread across both horizontal axes (:data:`MIN_HEADING_SPREAD`). Neither pins the response of
the horizontal outputs to the vertical field (M's column z): on a vehicle that tilts little the vertical field
hardly changes in the vehicle frame, so in (3) and (4) alike it is confounded with the offset. The radial
equations pin it: the field's length does change with the tilt, and they carry no attitude error.

What the gravity equations cannot check: they align the magnetometer to the accelerometer, biases included
(an offset b tilts its vertical by b / g; a frame mounted off the vehicle's by its angle). Three guards:

- without ``time_s`` and ``gyro`` the still-sample gate sees |a| alone, and a coordinated turn keeps |a| at g
  while it tilts the apparent vertical: the gravity equations are left out, said in the note;
- a vertical that disagrees with the reference's is refused (:func:`_vertical_disagreement`, a Hausman test
  against :data:`VERTICAL_CHI2`, and :data:`MAX_RESIDUAL_GROWTH`): the fit is the regression, and the verdict's
  weaknesses name the accelerometer;
- what no test can see (an offset that moves the vertical by no more than the attitude's error does) is in the
  stated one-sigma: ``accel_sigma`` propagated through the joint fit (:func:`_tilt_prior`).

**The lag** (``time_s`` given) is searched on a grid of one sample period within ``±max_lag_s``, then refined
by a bounded scalar minimisation of the residual sum of squares, the reference interpolated in time
(:func:`estimate_lag`); the lag joins the parameters of the uncertainty (the reference's rate is its column of
the design). A best lag at the edge of the grid is not an estimate: the search widens, doubling, up to
:data:`WIDEST_LAG` times ``max_lag_s`` (and a quarter of the recording), and a lag still at the edge is refused.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .._validation import check_rows, check_times
from ..calibration import Calibration
from ..diagnostics.reference import (
    ADVICE,
    BLOCKS,
    design_singularity,
    jackknife_covariance,
    judge_reference_fit,
    regression_covariance,
)
from ..errors import CalibrationError, OptionError, SampleError
from ..gravity import still_samples
from .registry import FitInput, register

__all__ = ["GravityFit", "LagEstimate", "estimate_lag", "fit_vector"]

#: Fewest samples a vector fit takes: 12 parameters (13 with a lag), and the batch-means covariance needs 80.
MIN_SAMPLES = 80
#: The lag search widens, doubling, to at most this many times max_lag_s when the best lag is at its edge.
WIDEST_LAG = 8.0
#: Samples the lag search must keep inside the window where every candidate lag has a reference.
_MIN_WINDOW = 40
#: Rows the lag's grid search and jackknife read (a regular stride of a longer recording).
SEARCH_ROWS = 50_000
#: A step between samples over this many sample periods is a gap in the recording.
GAP_STEPS = 5.0
#: Contiguous blocks of the block jackknife that gives the lag's one-sigma.
LAG_BLOCKS = 8
#: Fewest samples on which the accelerometer sees gravity alone for the gravity equations (4) to join the fit.
MIN_GRAVITY_ROWS = 50
#: Smallest in-plane eigenvalue of the scatter of the horizontal field's direction over the still samples
#: (a full circle of headings gives 0.5, headings within ±22° about 0.05, a boat's ±10° 0.01) for the joint
#: fit to be made: the gravity equations pin the tilt of the vertical through the horizontal field turning
#: under it; from one heading they pin one combination of the weak directions and move the others.
#: benchmarks/accuracy_vehicle.py, 8 trials each: the boat's spread 0.008-0.033 (its joint fit: rotation error
#: 1.88° → 3.48° at 1° of attitude error, 0.33° → 1.06° at 0.2°), flights' and cars' 0.058-0.48.
MIN_HEADING_SPREAD = 0.05
#: Huber's tuning constant (in robust standard deviations) for the gravity equations: residual accelerations
#: (a turn the gate missed, a lever arm) are down-weighted, not trusted.
HUBER = 1.345
#: Contiguous batches for the noise inflation of each kind of equation (the weights).
WEIGHT_BATCHES = 20
#: The two tests of an accelerometer whose vertical is not the reference's (an offset beyond ``accel_sigma``, a
#: frame tilted from the vehicle's): it drags the fit's vertical with it, the vector equations pay for it.
#: Either refuses the gravity equations. VERTICAL_CHI2: the χ² (2 components, its 1 % point) of the vertical's
#: move (M's row z) from the regression's, against the regression's covariance of it plus the accelerometer's
#: calibration prior (a Hausman test, :func:`_vertical_disagreement`). MAX_RESIDUAL_GROWTH: the vector
#: equations' residual RMS, the joint fit's over the regression's (what a wide covariance hides). Measured on
#: benchmarks/accuracy_vehicle.py's cases and tests/test_vector.py's 5-minute ones (flight and car, 0.2 / 0.5 /
#: 1° of attitude error; 90 fits with a right accelerometer, 36 per wrong one): a right one χ² 0.0-2.4,
#: growth 0.999-1.081 (none refused); 0.3 m/s² on x χ² 0.7-13.3, growth 1.001-1.60; tilted 2° χ² 0.0-18.4,
#: growth 1.001-1.82; 5° χ² 0.3-70, growth 1.001-3.5.
VERTICAL_CHI2 = 9.21
MAX_RESIDUAL_GROWTH = 1.10
#: Default one-sigma (m/s², each horizontal axis) of the accelerometer's calibration, the offset that the gravity
#: equations cannot see: it tilts their vertical by its ratio to g and goes into the calibration, so its cost
#: is added to the joint fit's covariance (:func:`_tilt_prior`). 0.1 m/s² (0.58°) is what neither test below
#: detects at 1° of attitude error (it costs 0.6-0.8° of heading there, docs/methods.md, "vector").
ACCEL_SIGMA = 0.1
#: Standard gravity (m/s²): ``accel_sigma`` over it is the tilt of the accelerometer's vertical (radians).
STANDARD_GRAVITY = 9.80665


@dataclass(frozen=True)
class LagEstimate:
    """The lag found by :func:`estimate_lag` and the samples it keeps (those with a reference at every lag).

    ``lag_sigma_s`` is the block jackknife's one-sigma; ``reference`` and ``rate`` are the reference and its
    time derivative at the kept samples' times plus the lag; ``at_limit`` is true when the best grid point
    was the search's edge.
    """

    lag_s: float
    lag_sigma_s: float
    keep: NDArray[np.bool_]
    reference: NDArray[np.float64]
    rate: NDArray[np.float64]
    at_limit: bool


def _reference_array(reference: Any, n: int) -> NDArray[np.float64]:
    if reference is None:
        raise OptionError(
            "method 'vector' needs reference=: the field expected at each sample in the vehicle frame, an (N, 3) "
            "array in the samples' unit (the Earth's field rotated by each sample's attitude)"
        )
    if isinstance(reference, str):  # what a refit finds recorded: the reference itself is not kept
        raise OptionError(
            "a vector calibration is refitted only with a new reference: call magfit.fit(samples, method='vector', "
            "reference=...) with the field expected at each new sample"
        )
    return check_rows(reference, "reference", n, "the field expected at each sample")


def _design(reference: NDArray[np.float64]) -> NDArray[np.float64]:
    return np.column_stack([reference, np.ones(reference.shape[0])])


def _solve(raw: NDArray[np.float64], reference: NDArray[np.float64]) -> tuple[NDArray[Any], NDArray[Any]]:
    """G and V of ``raw = G r + V`` by least squares (one regression per axis of raw)."""
    coefficients, *_ = np.linalg.lstsq(_design(reference), raw, rcond=None)
    return coefficients[:3].T, coefficients[3]


def _shifted(reference: NDArray[np.float64], time_s: NDArray[np.float64], at: NDArray[np.float64]) -> NDArray[Any]:
    """``reference`` linearly interpolated at the times ``at`` (inside ``time_s``): one search for the 3 axes."""
    index = np.clip(np.searchsorted(time_s, at) - 1, 0, time_s.size - 2)
    weight = ((at - time_s[index]) / (time_s[index + 1] - time_s[index]))[:, None]
    return reference[index] * (1.0 - weight) + reference[index + 1] * weight


def _lag_cost(raw: NDArray[np.float64], reference: NDArray[np.float64], time_s: NDArray[np.float64],
              at: NDArray[np.float64]) -> Any:  # fmt: skip
    """The residual sum of squares of ``raw = G r(at + τ) + V`` as a function of τ (G, V refitted for each)."""
    total = float(np.sum(raw**2))

    def cost(lag: float) -> float:
        design = _design(_shifted(reference, time_s, at + lag))
        cross = design.T @ raw
        try:
            coefficients = np.linalg.solve(design.T @ design, cross)
        except np.linalg.LinAlgError:
            return total
        return total - float(np.sum(coefficients * cross))

    return cost


def _refine(cost: Any, low: float, high: float, step: float) -> float:
    from scipy.optimize import minimize_scalar  # not needed to import magfit

    result = minimize_scalar(cost, bounds=(low, high), method="bounded", options={"xatol": step * 1e-3})
    return float(result.x)


def _inside_segments(time_s: NDArray[np.float64], margin: float) -> NDArray[np.bool_]:
    """The samples at least ``margin`` seconds from the ends of their contiguous stretch of the recording.

    A gap (a step over :data:`GAP_STEPS` sample periods: a log with dropouts, stretches cut out) is an end too:
    the reference interpolated across it at ``t + τ`` would be a straight line through a turn never seen.
    """
    steps = np.diff(time_s)
    gap = steps > GAP_STEPS * float(np.median(steps))
    segment = np.concatenate([[0], np.cumsum(gap)])
    starts = np.concatenate([[0], np.flatnonzero(gap) + 1])
    ends = np.concatenate([np.flatnonzero(gap), [time_s.size - 1]])
    return (time_s >= time_s[starts][segment] + margin) & (time_s <= time_s[ends][segment] - margin)


def estimate_lag(raw: NDArray[np.float64], reference: NDArray[np.float64], time_s: NDArray[np.float64],
                 max_lag_s: float) -> LagEstimate:  # fmt: skip
    """The lag τ (s) for which ``raw(t) = G r(t + τ) + V`` fits best: τ > 0 when the reference lags the samples.

    The residual sum of squares is compared over the same samples for every candidate (those whose
    ``t ± max_lag_s`` lies inside their stretch of the recording, :func:`_inside_segments`), on a grid of
    one sample period, then refined between the grid neighbours of the best point (scipy's bounded scalar
    minimisation). Its one-sigma is a block jackknife: the lag found again without each of
    :data:`LAG_BLOCKS` contiguous stretches. (The Gauss-Newton figure understates it: the reference's rate,
    the lag's column of the design, carries the attitude's jitter, and a slow vehicle's lag trades with the
    attitude's wandering error. simulate_vehicle, flight at 1° of attitude error, 5 min: the lag off by
    0.09 s where Gauss-Newton said ±0.009 s.)
    """
    span = float(time_s[-1] - time_s[0])
    limit = min(max_lag_s, span / 4)  # a lag over a quarter of the recording leaves too little to fit
    keep = _inside_segments(time_s, limit)
    if int(keep.sum()) < _MIN_WINDOW:
        raise CalibrationError(
            f"the recording is too short to search a lag of ±{limit:.3g} s: {int(keep.sum())} samples remain inside "
            "the window; record longer, give a smaller max_lag_s, or leave time_s out (no lag)",
            codes=("too_few_samples",),
        )
    kept_raw, kept_t = raw[keep], time_s[keep]
    # The grid and the jackknife read a regular stride of at most SEARCH_ROWS rows; the final refinement all
    # of them (400 000 samples at 50 Hz: the whole fit took 12.8 s with every row searched, 6.8 s so).
    stride = max(1, -(-kept_t.size // SEARCH_ROWS))
    search_raw, search_t = kept_raw[::stride], kept_t[::stride]
    search = _lag_cost(search_raw, reference, time_s, search_t)
    step = float(np.median(np.diff(time_s)))
    grid = np.arange(-limit, limit + 0.5 * step, step)
    costs = np.array([search(float(lag)) for lag in grid])
    best = int(np.argmin(costs))
    low, high = float(grid[max(best - 1, 0)]), float(grid[min(best + 1, grid.size - 1)])
    cost = _lag_cost(kept_raw, reference, time_s, kept_t)
    lag = _refine(cost, low, high, step)
    if cost(lag) > cost(float(grid[best])):
        lag = float(grid[best])
    # The jackknife's refits search near the full estimate (±5 sample periods, within the limit).
    edges = np.linspace(0, search_t.size, LAG_BLOCKS + 1).astype(np.int64)
    partial = []
    for block in range(LAG_BLOCKS):
        rows = np.ones(search_t.size, dtype=bool)
        rows[edges[block] : edges[block + 1]] = False
        partial_cost = _lag_cost(search_raw[rows], reference, time_s, search_t[rows])
        partial.append(_refine(partial_cost, max(lag - 5 * step, -limit), min(lag + 5 * step, limit), step))
    spread = np.asarray(partial)
    sigma = float(np.sqrt((LAG_BLOCKS - 1) / LAG_BLOCKS * np.sum((spread - spread.mean()) ** 2)))
    rate_full = np.gradient(reference, time_s, axis=0)
    at = kept_t + lag
    at_limit = best in (0, grid.size - 1)
    return LagEstimate(lag, sigma, keep, _shifted(reference, time_s, at), _shifted(rate_full, time_s, at), at_limit)


def _check_gyro_unit(reference: NDArray[np.float64], time_s: NDArray[np.float64], gyro: NDArray[np.float64]) -> None:
    """A gyro in degrees per second: refused with the fix (the still-sample gate would read every row as a turn).

    The reference, a fixed field seen from the turning vehicle, turns as ``ṙ = r × ω``; a gyro that predicts
    it far better divided by 57.3 is in degrees per second (the test of :func:`magfit.methods.gyro`'s
    ``_check_rate_unit``, on the reference instead of the samples). A vehicle that never turns fits both alike.
    """
    rate = np.gradient(reference, time_s, axis=0)
    predicted = np.cross(reference, gyro)
    rss = {unit: float(np.sum((rate - factor * predicted) ** 2)) for unit, factor in (("rad/s", 1.0),
           ("deg/s", math.pi / 180.0))}  # fmt: skip
    if rss["deg/s"] < 0.25 * rss["rad/s"]:
        raise OptionError(
            f"gyro= looks like degrees per second (the reference turns as it predicts "
            f"{rss['rad/s'] / max(rss['deg/s'], 1e-300):.0f} times better after dividing it by 57.3): give it in "
            "rad/s (numpy.radians(gyro))",
            codes=("gyro_unit",),
            remedy=(("gyro", "numpy.radians(gyro)"),),
        )


def _noise_sigma(values: NDArray[np.float64], across: int) -> float:
    """White noise per axis of a smooth signal from its third differences (robust: their median).

    A third difference of white noise has variance 20 σ²; a turning field or a rolling boat at 10 Hz leaves
    below a fiftieth of that. ``across`` axes carry the noise (3 for the magnetometer, 2 across a direction).
    """
    if values.shape[0] < 8:
        return 0.0
    third = np.diff(values, n=3, axis=0)
    median_chi2 = {2: 1.3863, 3: 2.3660}[across]  # the median of χ² with 2 or 3 degrees of freedom
    return float(np.sqrt(np.median(np.sum(third**2, axis=1)) / (20.0 * median_chi2)))


def _inflation(residuals: NDArray[np.float64], weights: NDArray[np.float64] | None = None) -> tuple[float, float]:
    """(σ², κ): the residuals' variance per component and how much their batch means exceed what independent
    errors give (κ = 1: white; the attitude's error, correlated over seconds, gives tens)."""
    e = residuals.reshape(residuals.shape[0], -1)
    if weights is not None:
        e = e * np.sqrt(weights)[:, None]
    e = e - e.mean(axis=0)
    variance = float(np.mean(e**2))
    batches = min(WEIGHT_BATCHES, e.shape[0] // 10)
    if batches < 4 or not variance > 0:
        return max(variance, 1e-300), 1.0
    edges = np.linspace(0, e.shape[0], batches + 1).astype(np.int64)
    means = np.add.reduceat(e, edges[:-1], axis=0) / np.diff(edges)[:, None]
    excess = float(np.mean(np.var(means, axis=0, ddof=1) * (e.shape[0] / batches))) / variance
    return variance, max(excess, 1.0)


@dataclass(frozen=True)
class _Equations:
    """The equations (3) and (4) in the 13 unknowns p = (M row 0, c₀, M row 1, c₁, M row 2, c₂, s), ready to be
    summed over any subset of the samples (the block jackknife refits without a stretch)."""

    design: NDArray[np.float64]  # (n, 4): x_k = (raw_k, −1)
    reference: NDArray[np.float64]  # (n, 3)
    rows: NDArray[np.int64]  # (m,): the gravity rows' samples (indices into design)
    down: NDArray[np.float64]  # (m, 3)
    mag_noise: float  # σ_m, raw units, per axis
    down_noise: float  # σ_a, radians, per axis across gravity

    def normal(self, w_vector: float, w_gravity: NDArray[np.float64], w_radial: float,
               select: NDArray[np.bool_] | None = None) -> tuple[NDArray[Any], NDArray[Any]]:  # fmt: skip
        """H and b of the weighted least squares, corrected for the noise in the regressors (see the module
        docstring): over the samples ``select`` (all when None). ``w_vector`` weighs the vector equations'
        tangential components, ``w_radial`` their radial one, ``w_gravity`` each gravity equation."""
        x, r = self.design, self.reference
        in_g = np.ones(self.rows.size, dtype=bool) if select is None else select[self.rows]
        if select is not None:
            x, r = x[select], r[select]
        noisy = np.diag([1.0, 1.0, 1.0, 0.0])  # the magnetometer's noise is in raw, not in the −1
        h = np.zeros((13, 13))
        b = np.zeros(13)
        # (3) row by row in the frame of r_k: radial (weight w_radial, target |r_k|) and tangential (w_vector,
        # target 0): Σ_k W_k ⊗ x_k x_kᵀ with W_k = w_vector (I − u uᵀ) + w_radial u uᵀ, u = r_k / |r_k|.
        size = np.linalg.norm(r, axis=1)
        u = r / size[:, None]
        radial = u[:, :, None] * u[:, None, :]
        mix = w_vector * (np.eye(3)[None] - radial) + w_radial * radial
        h[:12, :12] += np.einsum("kab,ki,kj->aibj", mix, x, x).reshape(12, 12)
        h[:12, :12] -= self.mag_noise**2 * np.kron(mix.sum(axis=0), noisy)  # the noise in raw, taken off
        b[:12] += (w_radial * size[:, None, None] * u[:, :, None] * x[:, None, :]).sum(axis=0).reshape(12)
        d, w = self.down[in_g], w_gravity[in_g]
        xg = self.design[self.rows[in_g]]
        a = np.concatenate([(d[:, :, None] * xg[:, None, :]).reshape(-1, 12), -np.ones((d.shape[0], 1))], axis=1)
        h += (a * w[:, None]).T @ a
        # The regressors d_i x_j carry the magnetometer's noise (d_i n_j) and the accelerometer's (ν_i x_j, ν
        # across d): their expected contributions to aᵀa, taken off (adjusted least squares).
        dd = np.einsum("k,ki,kj->ij", w, d, d)
        across = np.einsum("k,kab,ki,kj->aibj", w, np.eye(3)[None] - d[:, :, None] * d[:, None, :], xg, xg)
        h[:12, :12] -= self.mag_noise**2 * np.kron(dd, noisy) + self.down_noise**2 * across.reshape(12, 12)
        return h, b

    def residuals(self, p: NDArray[np.float64]) -> tuple[NDArray[Any], NDArray[Any]]:
        """(vector residuals (n, 3), gravity residuals (m,)) at p."""
        beta = p[:12].reshape(3, 4)
        body = self.design @ beta.T
        return body - self.reference, np.einsum("ki,ki->k", self.down, body[self.rows]) - p[12]


def _vector_weights(residuals: NDArray[np.float64], reference: NDArray[np.float64],
                    floor: float) -> tuple[float, float, float]:  # fmt: skip
    """The weights of the vector equations (3): (σ², κ) of their tangential components (per component) and the
    radial component's own weight ``1 / (σ² κ)`` (see the module docstring)."""
    u = reference / np.linalg.norm(reference, axis=1, keepdims=True)
    radial = np.einsum("ki,ki->k", residuals, u)
    tangential = residuals - radial[:, None] * u
    t_var, t_kappa = _inflation(tangential)
    r_var, r_kappa = _inflation(radial)
    # _inflation averages over the 3 axes; the tangential scatter lives in 2 of them.
    return max(1.5 * t_var, floor), t_kappa, 1.0 / (max(r_var, floor) * r_kappa)


def _solve_normal(h: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64] | None:
    """The solution, or None when the corrected normal matrix is not positive definite (the noise corrections
    exceed what the samples determine along some direction)."""
    if not h[12, 12] > 0:  # no gravity equation among these samples: s is not an unknown
        h = h.copy()
        h[12, 12] = 1.0
    # Scaled to a unit diagonal first: M is dimensionless and c in the samples' unit.
    diagonal = np.sqrt(np.abs(np.diag(h)))
    if not np.all(diagonal > 0):
        return None
    scaled = 0.5 * (h + h.T) / np.outer(diagonal, diagonal)
    try:
        lower = np.linalg.cholesky(scaled)
    except np.linalg.LinAlgError:
        return None
    if not float(np.min(np.diag(lower))) ** 2 > 1e-13:
        return None
    return np.asarray(np.linalg.solve(scaled, b / diagonal) / diagonal, dtype=np.float64)


def _vehicle_form(p: NDArray[np.float64]) -> tuple[NDArray[Any], NDArray[Any]]:
    """(G, V) of ``raw = G r + V`` from p = (M, c) of ``M raw − c = r``: G = M⁻¹, V = M⁻¹ c."""
    beta = p[:12].reshape(3, 4)
    g = np.linalg.inv(beta[:, :3])
    return g, g @ beta[:, 3]


@dataclass(frozen=True)
class GravityFit:
    """What the accelerometer added to a vector fit (:func:`fit_vector` with ``accel=``).

    ``g`` and ``offset`` are None when the gravity equations were not used: neither ``time_s`` nor ``gyro``
    given, too few samples where the accelerometer sees gravity alone, their headings too close together,
    a normal matrix not positive definite once corrected for the noise, or an accelerometer that disagrees
    with the reference (``caution`` then says so, for the verdict's weaknesses). ``covariance`` (of G
    row-major and V, block jackknife) is None also when one of the jackknife's refits had no solution: the
    verdict then computes the regression's covariance at the joint fit (the note says so). ``prior`` (12, 12)
    is the accelerometer's calibration cost (:func:`_tilt_prior`). ``facts`` go to ``details["gravity"]``,
    ``note`` to the diagnostics' notes.
    """

    g: NDArray[np.float64] | None
    offset: NDArray[np.float64] | None
    covariance: NDArray[np.float64] | None
    facts: dict[str, Any]
    note: str
    prior: NDArray[np.float64] | None = None
    caution: str | None = None


def _relative_rms(raw: NDArray[np.float64], reference: NDArray[np.float64], g: NDArray[np.float64],
                  offset: NDArray[np.float64]) -> float:  # fmt: skip
    """The RMS of ``raw − G r − V`` over the field in the samples' unit (as the verdict's residual_rms)."""
    residuals = raw - reference @ g.T - offset
    scale = abs(float(np.linalg.det(g))) ** (1.0 / 3.0)
    return float(np.sqrt(np.mean(np.sum(residuals**2, axis=1)))) / scale


def _vertical(g: NDArray[np.float64]) -> NDArray[np.float64]:
    """The unit row z of ``M = G⁻¹``: which direction of the samples the calibration reads as the vehicle's vertical."""
    row = np.linalg.inv(g)[2]
    return np.asarray(row / np.linalg.norm(row), dtype=np.float64)


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


def _gravity_fit(raw: NDArray[np.float64], kept: NDArray[np.int64], used_raw: NDArray[np.float64],
                 used_ref: NDArray[np.float64], accel: NDArray[np.float64], gyro: NDArray[np.float64] | None,
                 times: NDArray[np.float64] | None, g: NDArray[np.float64], offset: NDArray[np.float64],
                 accel_sigma: float) -> GravityFit:  # fmt: skip
    """The joint fit of equations (3) and (4) on the kept samples (module docstring), or the reason it is not made."""
    if gyro is None and times is None:
        # Then the gate checks |a| alone, and a coordinated turn keeps |a| at g while it tilts the apparent
        # vertical: benchmarks/accuracy_vehicle.py at 1° of attitude error, heading error 5.8-6.6° on a flight
        # and 4.1-16.1° on a car with such rows (0.29-0.65° with time_s, 0.38° on the car without accel).
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
            # With time_s the reference tells the unit (_check_gyro_unit); without it, only the size does: no
            # vehicle turns at a median 57°/s, a car's or a flight's median turn is 3-8°/s.
            note += " gyro= turns at a median rate over 1 rad/s: if it is in degrees per second, give it in rad/s."

        return GravityFit(None, None, None, {**facts, "note": note}, note)
    a = accel[kept][still]
    down = -a / np.linalg.norm(a, axis=1, keepdims=True)  # the specific force points up
    body = (used_raw[still] - offset) @ np.linalg.inv(g).T
    across = body - np.einsum("ki,ki->k", body, down)[:, None] * down
    across /= np.maximum(np.linalg.norm(across, axis=1, keepdims=True), 1e-300)
    spread = float(np.linalg.eigvalsh(across.T @ across / across.shape[0])[1])
    facts["heading_spread"] = spread
    if spread < MIN_HEADING_SPREAD:
        note = (
            f"The accelerometer sees gravity alone on {still.size} of {kept.size} samples, but at headings so close "
            f"together (spread {spread:.2g}, under {MIN_HEADING_SPREAD:g}; a full circle gives 0.5) that its "
            "equations cannot pin the tilt of the vertical: the fit is the regression on the reference alone; "
            "hold still (or drive straight) at headings across both horizontal axes to use them."
        )
        return GravityFit(None, None, None, {**facts, "note": note}, note)
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
    p = _solve_normal(*equations.normal(1.0 / (v_var * v_kappa), np.full(still.size, 1.0 / g_var), r_weight))
    huber = np.ones(still.size)
    g_kappa = 1.0
    outliers = 0
    if p is not None:
        # Pass 2: each kind weighted by its own residuals' scatter and correlation; the gravity equations'
        # outliers (accelerations the gate let through) down-weighted by Huber's weights.
        e_vector, e_gravity = equations.residuals(p)
        v_var, v_kappa, r_weight = _vector_weights(e_vector, used_ref, floor)
        scale = 1.4826 * float(np.median(np.abs(e_gravity - np.median(e_gravity))))
        if scale > 0:
            huber = np.minimum(1.0, HUBER * scale / np.maximum(np.abs(e_gravity), 1e-300))
            outliers = int(np.sum(np.abs(e_gravity) > 3.0 * scale))
            g_var, g_kappa = _inflation(e_gravity, huber)
            g_var = max(g_var / float(np.mean(huber)), floor)
        weights = (1.0 / (v_var * v_kappa), huber / (g_var * g_kappa), r_weight)
        whole_h, whole_b = equations.normal(*weights)
        p = _solve_normal(whole_h, whole_b)
    if p is None or not abs(np.linalg.det(p[:12].reshape(3, 4)[:, :3])) > 0:
        note = (
            "The accelerometer's gravity equations were not used: corrected for the sensors' noise, they and the "
            "reference do not determine the fit along some direction; the fit is the regression on the reference alone."
        )
        return GravityFit(None, None, None, {**facts, "note": note}, note)
    g_joint, offset_joint = _vehicle_form(p)
    # Floored: noise-free data leave rounding errors alone, whose ratio means nothing.
    tiny = 1e-9 * float(np.median(np.linalg.norm(used_ref, axis=1)))
    growth = max(_relative_rms(used_raw, used_ref, g_joint, offset_joint), tiny) / max(
        _relative_rms(used_raw, used_ref, g, offset), tiny
    )
    facts["residual_growth"] = growth
    estimate = np.concatenate([g_joint.ravel(), offset_joint])
    prior = _tilt_prior(equations, weights, estimate, accel_sigma / STANDARD_GRAVITY) if accel_sigma > 0 else None
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
        return GravityFit(None, None, None, {**facts, "note": note}, note, caution=caution)
    # The block jackknife: the joint fit again without each contiguous stretch (its gravity rows with it); the
    # normal equations are sums over the samples, so each refit takes its stretch's share off the whole's.
    edges = np.linspace(0, n, BLOCKS + 1).astype(np.int64)
    estimates: list[NDArray[np.float64]] = []
    for start, stop in itertools.pairwise(edges):
        select = np.zeros(n, dtype=bool)
        select[start:stop] = True
        block_h, block_b = equations.normal(*weights, select=select)
        partial = _solve_normal(whole_h - block_h, whole_b - block_b)
        if partial is None:
            estimates = []
            break
        g_part, v_part = _vehicle_form(partial)
        estimates.append(np.concatenate([g_part.ravel(), v_part]))
    covariance = jackknife_covariance(np.asarray(estimates)) if estimates else None
    facts.update(
        used=True,
        down_weighted=int(np.sum(huber < 1.0)),
        outliers=outliers,
        vertical_field=float(p[12]),
        vector_sigma=math.sqrt(v_var),
        vector_inflation=v_kappa,
        gravity_sigma=math.sqrt(g_var),
        gravity_inflation=g_kappa,
        magnetometer_noise=mag_noise,
        accelerometer_noise_deg=math.degrees(down_noise),
        accel_sigma=accel_sigma,
        jackknife=covariance is not None,
    )
    cost = ""
    if prior is not None:
        sigma = math.degrees(accel_sigma / STANDARD_GRAVITY)
        cost = f" (accel_sigma={accel_sigma:g} m/s², {sigma:.2g}° of tilt, is in the one-sigma)"
    else:
        cost = " (its cost is not in the one-sigma: accel_sigma=0 or a refit without a solution)"
    note = (
        f"The accelerometer's gravity equations joined the fit on {still.size} of {kept.size} samples, where it "
        f"sees gravity alone (dropped: {reasons}); {outliers} of them beyond 3 robust standard deviations (residual "
        "accelerations), down-weighted. They align the magnetometer to the accelerometer, whose offsets go into "
        f"the calibration{cost}: calibrate the accelerometer first."
    )
    if covariance is None:
        note += (
            " The block jackknife had no solution without one stretch of the recording: the one-sigma is the "
            "regression's (independent residuals, widened by its own jackknife) at the joint fit."
        )
    return GravityFit(g_joint, offset_joint, covariance, {**facts, "note": note}, note, prior=prior)


@register(
    "vector",
    min_samples=MIN_SAMPLES,
    data="samples",
    summary="soft iron × misalignment (a general matrix into the vehicle frame), hard iron and the attitude's lag, "
    "by least squares against a reference field",
    needs=("reference",),
)
def fit_vector(
    data: FitInput,
    *,
    reference: ArrayLike | None = None,
    time_s: ArrayLike | None = None,
    max_lag_s: float = 1.0,
    accel: ArrayLike | None = None,
    gyro: ArrayLike | None = None,
    accel_sigma: float = ACCEL_SIGMA,
) -> Calibration:
    """Fit ``raw = G r + V`` against the reference field ``r`` (see the module docstring).

    Parameters
    ----------
    reference : array_like, shape (N, 3)
        The field expected at each sample in the vehicle frame, in the samples' unit.
    time_s : array_like, shape (N,), optional
        Sample times in seconds (strictly increasing). Given, the lag between the reference and the samples
        is estimated within ``±max_lag_s`` and the fit made at it; not given, none is assumed.
    max_lag_s : float
        The largest lag searched, seconds.
    accel : array_like, shape (N, 3), optional
        The accelerometer's specific force at each sample in the reference's (vehicle) frame, any unit. Given,
        its gravity equations (4) join the fit where it sees gravity alone (:func:`magfit.gravity.still_samples`):
        ``details["gravity"]`` says on how many samples and why the others were left out.
    gyro : array_like, shape (N, 3), optional
        Body rates in rad/s in the same frame, for the still-sample gate (only with ``accel``; without it
        unused, said in ``details["gyro_note"]``). One that looks like degrees per second (the reference turns
        57 times slower than it says) is refused.
    accel_sigma : float
        The accelerometer's calibration one-sigma in m/s² (each axis): its cost in the calibration (the gravity
        equations take the accelerometer's vertical as the truth) is added to the stated uncertainty. 0 for none.
    """
    raw = data.require_samples("vector")
    n = raw.shape[0]
    ref = _reference_array(reference, n)
    if not max_lag_s > 0:
        raise OptionError(f"max_lag_s must be a positive number of seconds, got {max_lag_s!r}")
    if not (isinstance(accel_sigma, (int, float)) and 0 <= accel_sigma < STANDARD_GRAVITY):
        raise OptionError(f"accel_sigma must be the accelerometer's calibration one-sigma in m/s², got {accel_sigma!r}")
    frame = "in the reference's (vehicle) frame"
    acc = None if accel is None else check_rows(accel, "accel", n, f"the specific force, any unit, {frame}")
    rates = None if gyro is None else check_rows(gyro, "gyro", n, f"body rates in rad/s, {frame}")
    if acc is not None and np.any(np.all(acc == 0.0, axis=1)):
        row = int(np.argmax(np.all(acc == 0.0, axis=1)))
        raise OptionError(f"accel= is (0, 0, 0) in row {row} (0-based), which has no direction: drop that sample")
    magnitudes = np.linalg.norm(ref, axis=1)
    field = float(np.median(magnitudes))
    if not field > 0:
        raise OptionError("reference= is zero at most samples: it must be the field expected at each sample")
    if np.any(magnitudes < 1e-6 * field):  # the Earth's field is never zero: a missing attitude written as 0
        row = int(np.argmax(magnitudes < 1e-6 * field))
        raise OptionError(f"reference= is zero in row {row} (0-based): drop the samples without an attitude")
    details: dict[str, Any] = {}
    if rates is not None and acc is None:  # compare() and the pipeline pass every stream a method takes
        details["gyro_note"] = "gyro= is used only with accel= (to find where the accelerometer sees gravity alone)"
    rate = None
    lag_limit = None
    jackknife = 0.0
    used_raw, used_ref = raw, ref
    kept = np.arange(n)
    times = None
    if time_s is None:
        details["lag_s"] = None
        details["lag_note"] = "no time_s given: the reference is taken as simultaneous with the samples (no lag fitted)"
    else:
        times = check_times(time_s, "time_s", n)
        if rates is not None and acc is not None:
            _check_gyro_unit(ref, times, rates)
        # A lag at the edge of the search is not an estimate: the search widens (doubling, up to
        # WIDEST_LAG times max_lag_s and a quarter of the recording) until the best lag lies inside it.
        limit = float(max_lag_s)
        widest = min(WIDEST_LAG * limit, 0.25 * float(times[-1] - times[0]))
        found = estimate_lag(raw, ref, times, limit)
        while found.at_limit and limit < widest:
            limit = min(2.0 * limit, widest)
            found = estimate_lag(raw, ref, times, limit)
        if limit > max_lag_s:
            details["lag_search_s"] = limit
        used_raw, used_ref, rate = raw[found.keep], found.reference, found.rate
        kept = np.flatnonzero(found.keep)
        details["lag_s"] = found.lag_s
        jackknife = found.lag_sigma_s
        if found.at_limit:
            lag_limit = found.lag_s
            details["lag_search_s"] = limit
    singular = design_singularity(used_ref, field)
    if singular is not None:  # nothing to return even when forced: the least-squares solution is arbitrary
        raise CalibrationError(
            f"the samples do not support the vector calibration: {singular}; {ADVICE}",
            codes=("single_axis" if "hardly turned" in singular else "undetermined",),
        )
    g, offset = _solve(used_raw, used_ref)
    if not abs(float(np.linalg.det(g))) > 1e-12 * float(np.max(np.abs(g))) ** 3:
        raise CalibrationError(
            "the samples do not support the vector calibration: the fitted matrix is singular (the samples do not "
            "change with the reference along some direction: a magnetometer axis that is dead or saturated?)",
            codes=("undetermined",),
        )
    covariance = prior = None
    notes: tuple[str, ...] = ()
    cautions: tuple[str, ...] = ()
    if acc is not None:
        joint = _gravity_fit(raw, kept, used_raw, used_ref, acc, rates, times, g, offset, float(accel_sigma))
        details["gravity"] = joint.facts
        notes = (joint.note,)
        cautions = () if joint.caution is None else (joint.caution,)
        if joint.g is not None and joint.offset is not None:
            g, offset, covariance, prior = joint.g, joint.offset, joint.covariance, joint.prior
    report = judge_reference_fit(
        used_raw, used_ref, g, offset, rate=rate, lag_at_limit=lag_limit, covariance=covariance, prior=prior,
        notes=notes, cautions=cautions,
    )  # fmt: skip
    if rate is not None:  # the larger of the lag search's jackknife and the fit's covariance (when it has the lag)
        lag_variance = report.covariance[12, 12] if report.covariance.shape[0] > 12 else 0.0
        details["lag_sigma_s"] = max(jackknife, float(np.sqrt(max(lag_variance, 0.0))))
    details["alignment_sigma_deg"] = report.rotation_sigma_deg
    details["residual_rms"] = report.residual_rms
    details["scale"] = report.scale
    details["support"] = report.support.to_dict()
    details["diagnostics"] = report.diagnostics(int(used_raw.shape[0])).to_dict()
    return Calibration(
        "vector", offset, np.linalg.inv(g), field, n_samples=int(used_raw.shape[0]), details=details, frame="vehicle"
    )
