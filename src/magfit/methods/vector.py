"""``method="vector"``: calibration against a reference field, ``raw = G r + V`` (docs/methods.md, "vector").

``r`` is the field expected at each sample in the vehicle frame (the Earth's field rotated by the vehicle's
attitude); G is a general 3x3 matrix, the soft iron times the magnetometer's misalignment (a mirror for a
sensor with left-handed axes), V the hard iron. The calibration returned is ``frame="vehicle"``:
``matrix = G⁻¹`` (absolute: the corrected samples equal the reference, in its unit), ``offset = V``,
``field_strength`` the reference's median magnitude.

The estimator is linear least squares on the design ``[r, 1]``, one regression per axis of ``raw``
(Vasconcelos et al. 2011 and Kok & Schön 2016 fit the same model by maximum likelihood). The variants
measured on :func:`magfit.vehicle.simulate_vehicle` (3000 samples at 50 Hz, field 50, noise 0.3, soft iron
±8 %, mounting 20°, attitude error correlated over 5 s; RMS heading error over 6 seeds, flight / car / boat):

- least squares: 0.34 / 0.33 / 0.29° at 0.2° of attitude error, 0.85 / 0.82 / 0.71° at 0.5°, 1.7 / 1.7 /
  1.4° at 1°. The mean attitude error over the recording (0.16° and 0.79°) is the floor no estimator can
  pass: it is indistinguishable from a turned mounting.
- joint maximum likelihood with the errors-in-variables covariance ``σ_m² I + σ_a² G (|r|² I − r rᵀ) Gᵀ``
  (σ_m, σ_a estimated from the residuals): 10° and 18° on flight (σ_a is not separable from σ_m on so
  little tilt and the weights run away), 0.37-1.9° elsewhere. The shrinkage it corrects is σ_a² ≈ 3·10⁻⁴
  of the scale at 1°: nothing next to the error that the attitude's wandering leaves in G.
- two steps (magnitude-only ellipsoid, then the rotation by Procrustes between the calibrated samples and r):
  18° on a car, no ellipsoid at all on flight and boat (their directions do not determine it); on a tumble
  0.2-1.0°, the same as least squares.
- least squares plus the magnitude equations ``|G⁻¹ (raw − V)| = |r|`` (attitude-free), each weighted by its
  own residual: 1-5 % better (0.81 / 0.79 / 0.70° at 0.5°), but its weight is not something the data pin
  (3x: 12 % better on flight, 4 % worse on boat; 10x: 2.5x worse) and it costs an iterative solve in the
  lag search. Not kept.

Why least squares cannot do much better: an error in the attitude's roll or pitch turns the field's large
vertical part into the horizontal plane, so the recording's mean tilt error becomes a tilt of the fitted
mounting and costs ``tan δ`` times itself in heading (2x at δ = 64°). With the error on one axis at a time
(car, 1°, 15 000 samples, 5 seeds): yaw errors alone 0.25°, tilt errors alone 0.74°; the floor from the
mean errors ``√(ψ̄² + (tan δ θ̄)²)`` is 0.6°, least squares 0.77°.

A lag between the attitude and the magnetometer (``time_s`` given) is searched on a grid of one sample
period within ``±max_lag_s``, then refined by a bounded scalar minimisation of the residual sum of squares,
the reference interpolated in time; the lag joins the parameters of the uncertainty (the reference's rate
is its column of the design).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..calibration import Calibration
from ..diagnostics.reference import ADVICE, design_singularity, judge_reference_fit
from ..errors import CalibrationError, OptionError
from .registry import FitInput, register

__all__ = ["LagEstimate", "estimate_lag", "fit_vector"]

#: Fewest samples a vector fit takes: 12 parameters (13 with a lag), and the batch-means covariance needs 80.
MIN_SAMPLES = 80
#: Samples the lag search must keep inside the window where every candidate lag has a reference.
_MIN_WINDOW = 40
#: Rows the lag's grid search and jackknife read (a regular stride of a longer recording).
SEARCH_ROWS = 50_000
#: A step between samples over this many sample periods is a gap in the recording.
GAP_STEPS = 5.0
#: Contiguous blocks of the block jackknife that gives the lag's one-sigma.
LAG_BLOCKS = 8


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
    try:
        array = np.asarray(reference, dtype=np.float64)
    except (TypeError, ValueError):
        raise OptionError(
            f"reference= must be an (N, 3) array of numbers (the field expected at each sample), got "
            f"{type(reference).__name__}"
        ) from None
    if array.shape != (n, 3):
        raise OptionError(
            f"reference= must have one row (x, y, z) per sample, shape ({n}, 3); got shape {array.shape}"
            + ("; transpose it" if array.shape == (3, n) else "")
        )
    bad = ~np.all(np.isfinite(array), axis=1)
    if bad.any():
        raise OptionError(f"reference= has NaN or inf in row {int(np.argmax(bad))} (0-based); drop those samples")
    return array


def _time_array(time_s: Any, n: int) -> NDArray[np.float64]:
    try:
        array = np.asarray(time_s, dtype=np.float64)
    except (TypeError, ValueError):
        raise OptionError(f"time_s= must be an array of seconds, got {type(time_s).__name__}") from None
    if array.shape != (n,):
        raise OptionError(f"time_s= must have one time per sample, shape ({n},); got shape {array.shape}")
    if not np.all(np.isfinite(array)):
        raise OptionError(f"time_s= has NaN or inf in row {int(np.argmax(~np.isfinite(array)))} (0-based)")
    steps = np.diff(array)
    if np.any(steps <= 0):
        row = int(np.argmax(steps <= 0)) + 1
        raise OptionError(
            f"time_s= must increase strictly: row {row} (0-based) is {array[row]:g} s after {array[row - 1]:g} s; "
            "sort the samples by time and drop repeated ones"
        )
    return array


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
            "the window; record longer, give a smaller max_lag_s, or leave time_s out (no lag)"
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
    """
    raw = data.require_samples("vector")
    n = raw.shape[0]
    ref = _reference_array(reference, n)
    if not max_lag_s > 0:
        raise OptionError(f"max_lag_s must be a positive number of seconds, got {max_lag_s!r}")
    magnitudes = np.linalg.norm(ref, axis=1)
    field = float(np.median(magnitudes))
    if not field > 0:
        raise OptionError("reference= is zero at most samples: it must be the field expected at each sample")
    if np.any(magnitudes < 1e-6 * field):  # the Earth's field is never zero: a missing attitude written as 0
        row = int(np.argmax(magnitudes < 1e-6 * field))
        raise OptionError(f"reference= is zero in row {row} (0-based): drop the samples without an attitude")
    details: dict[str, Any] = {}
    rate = None
    lag_limit = None
    jackknife = 0.0
    used_raw, used_ref = raw, ref
    if time_s is None:
        details["lag_s"] = None
        details["lag_note"] = "no time_s given: the reference is taken as simultaneous with the samples (no lag fitted)"
    else:
        times = _time_array(time_s, n)
        found = estimate_lag(raw, ref, times, float(max_lag_s))
        used_raw, used_ref, rate = raw[found.keep], found.reference, found.rate
        details["lag_s"] = found.lag_s
        jackknife = found.lag_sigma_s
        if found.at_limit:
            lag_limit = found.lag_s
    singular = design_singularity(used_ref, field)
    if singular is not None:  # nothing to return even when forced: the least-squares solution is arbitrary
        raise CalibrationError(f"the samples do not support the vector calibration: {singular}; {ADVICE}")
    g, offset = _solve(used_raw, used_ref)
    if not abs(float(np.linalg.det(g))) > 1e-12 * float(np.max(np.abs(g))) ** 3:
        raise CalibrationError(
            "the samples do not support the vector calibration: the fitted matrix is singular (the samples do not "
            "change with the reference along some direction: a magnetometer axis that is dead or saturated?)"
        )
    report = judge_reference_fit(used_raw, used_ref, g, offset, rate=rate, lag_at_limit=lag_limit)
    if rate is not None:  # the larger of the jackknife's and the batch-means Gauss-Newton one-sigma
        details["lag_sigma_s"] = max(jackknife, float(np.sqrt(max(report.covariance[12, 12], 0.0))))
    details["residual_rms"] = report.residual_rms
    details["scale"] = report.scale
    details["support"] = report.support.to_dict()
    details["diagnostics"] = report.diagnostics(int(used_raw.shape[0])).to_dict()
    return Calibration(
        "vector", offset, np.linalg.inv(g), field, n_samples=int(used_raw.shape[0]), details=details, frame="vehicle"
    )
