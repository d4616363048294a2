"""The attitude's lag behind the samples, (2) of :mod:`.method`: ``raw(t) = G r(t + τ) + V``.

The residual sum of squares of (1) refitted at each candidate τ, the reference linearly interpolated at
``t + τ`` (:func:`_lag_cost`, over the same samples for every candidate: those whose ``t ± max_lag_s`` lies
inside their stretch of the recording), on a grid of one sample period, then refined by a bounded scalar
minimisation; its one-sigma by a block jackknife (:func:`estimate_lag`). A best lag at the edge of the grid
is not an estimate: the search widens, doubling (:func:`_lag`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..._validation import check_times
from ...errors import CalibrationError
from .reference import _check_rate_units, _design, _shifted

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
    attitude's wandering error: docs/methods.md, "vector".)
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
    # of them (a long recording's search costs a stride's, docs/methods.md, "vector").
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


@dataclass(frozen=True)
class _Lagged:
    """The samples the fit reads once the lag is found (:func:`_lag`): ``raw`` and ``reference`` at the kept
    samples (``kept`` indexes the recording), the reference's ``rate`` (None without time_s), the ``times``,
    the lag when it stayed at the widest search's edge (``lag_limit``) and its jackknife one-sigma."""

    raw: NDArray[np.float64]
    reference: NDArray[np.float64]
    kept: NDArray[np.int64]
    rate: NDArray[np.float64] | None = None
    times: NDArray[np.float64] | None = None
    lag_limit: float | None = None
    jackknife: float = 0.0
    lag_s: float | None = None  # the lag found (None: no time stamps, no lag fitted)


def _lag(raw: NDArray[np.float64], ref: NDArray[np.float64], time_s: ArrayLike | None, max_lag_s: float,
         acc: NDArray[np.float64] | None, rates: NDArray[np.float64] | None,
         details: dict[str, Any]) -> _Lagged:  # fmt: skip
    """Eq. (2): the lag searched within ``±max_lag_s``, widened while it lies at the edge (module docstring); its
    facts go to ``details``. Without time_s no lag is fitted."""
    n = raw.shape[0]
    if time_s is None:
        details["lag_note"] = "no time_s given: the reference is taken as simultaneous with the samples (no lag fitted)"
        return _Lagged(raw, ref, np.arange(n))
    times = check_times(time_s, "time_s", n)
    if rates is not None and acc is not None:
        _check_rate_units(ref, times, rates)
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
    lag_limit = None
    if found.at_limit:
        lag_limit = found.lag_s
        details["lag_search_s"] = limit
    return _Lagged(raw[found.keep], found.reference, np.flatnonzero(found.keep), found.rate, times, lag_limit,
                   found.lag_sigma_s, found.lag_s)  # fmt: skip
