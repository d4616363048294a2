"""The magnetometer's delay behind the gyroscope.

A magnetometer read at a lower rate and held, or filtered, reports the field late: (1) of :mod:`.method` then
pairs the field with the rate of a moment earlier. The delay τ minimises the windowed residual of stage 1
with the gyro read τ earlier (:func:`_delayed`, linear interpolation): a grid of ±:data:`MAX_LAG_S` in steps
of the sample interval (at least 5 ms) with the bias of no delay held, kept only when it lowers the
residual below :data:`LAG_GAIN` of no delay's (on a slowly turning vehicle the minimum is shallow and
biased), then refined by a bounded scalar minimisation with the bias fitted at each candidate (held at no
delay's, it pulls the minimum towards zero). The figures behind these choices: docs/methods.md, "gyro".
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from .windows import _constrained, _design, _frame, _windowed_bias, _Windows, _windows

#: The magnetometer's delay behind the gyroscope is searched within ± this (seconds).
MAX_LAG_S = 0.25
#: A window whose residual at no delay exceeds this many times the median window's is left out of the search.
OUTLIER_WINDOW = 50.0
#: ... and kept when it brings the windowed residual below this share of no delay's.
LAG_GAIN = 0.8


def _delayed(w: NDArray[np.float64], t: NDArray[np.float64], lag: float) -> NDArray[np.float64]:
    """The gyro read ``lag`` seconds earlier at each sample time (linear interpolation; the ends held)."""
    if lag == 0.0:
        return w
    at = t - lag
    out = np.empty_like(w)
    for axis in range(3):
        out[:, axis] = np.interp(at, t, w[:, axis])
    return out


def _ordinary(win: _Windows, theta: NDArray[np.float64], beta: NDArray[np.float64]) -> NDArray[np.bool_]:
    """The windows whose residual at no delay is within :data:`OUTLIER_WINDOW` times the median window's: a
    glitch (a sample from elsewhere, a jump) makes one window's residual thousands of times the others' and
    the lag's score then follows that window, not the turning."""
    per_window = np.sum((_design(win, beta) @ theta).reshape(-1, 3) ** 2, axis=1)
    return np.asarray(per_window <= OUTLIER_WINDOW * max(float(np.median(per_window)), 1e-300), dtype=bool)


def _subset(win: _Windows, kept: NDArray[np.bool_]) -> _Windows:
    """The windows ``kept`` of ``win``."""
    return _Windows(win.dy[kept], win.M[kept], win.Sy[kept], win.Sw[kept], win.T[kept])


def _search_lag(y: NDArray[np.float64], w: NDArray[np.float64], t: NDArray[np.float64], length: int) -> float:
    """The magnetometer's delay behind the gyroscope (s) that minimises the windowed residual of stage 1.

    A grid of ±MAX_LAG_S in steps of the sample interval (at least 5 ms), the bias of no delay held, scored
    at every other lag and then beside the best; kept only when it lowers the windowed residual by more than
    LAG_GAIN (module docstring), then refined.
    """
    step = max(float(np.median(np.diff(t))), 0.005)
    grid = np.arange(-MAX_LAG_S, MAX_LAG_S + step / 2, step)
    given = _windows(y, w, t, length)
    theta, beta = _windowed_bias(given)
    kept = _ordinary(given, theta, beta)
    frame = _frame(y, t, length)  # (the delayed rates' windows are not kept: each is asked for once)
    residual = np.full(grid.size, np.inf)

    def scored(indices: list[int]) -> None:
        for i in indices:
            if 0 <= i < grid.size and np.isinf(residual[i]):
                win = _subset(frame.windows(_delayed(w, t, float(grid[i]))), kept)
                residual[i] = _constrained(_design(win, beta), np.eye(9))[2]

    # Every other lag of the grid (with the ends and the one nearest zero), then the two beside the best: the
    # grid's own minimum wherever it is not a second valley within a step of the first.
    zero = int(np.argmin(np.abs(grid)))
    scored(sorted({*range(0, grid.size, 2), grid.size - 1, zero}))
    best = int(np.argmin(residual))
    scored([best - 1, best + 1])
    best = int(np.argmin(residual))
    if residual[best] > LAG_GAIN * residual[zero]:
        return 0.0
    if best in (0, grid.size - 1):
        return float(grid[best])
    # Refined with the bias fitted at each candidate: held at no delay's, it pulls the minimum towards zero.
    from scipy.optimize import minimize_scalar  # not needed to import magfit

    def refitted(lag: float) -> float:
        win = _subset(_windows(y, _delayed(w, t, lag), t, length), kept)
        return _constrained(_design(win, _windowed_bias(win)[1]), np.eye(9))[2]

    low, high = float(grid[best] - 2 * step), float(grid[best] + 2 * step)
    result = minimize_scalar(refitted, bounds=(low, high), method="bounded", options={"xatol": 1e-3 * step})
    return float(result.x)
