"""Stage 1: the kinematics (1) of :mod:`.method` integrated over windows, linear in the correction.

Over a window ``[a, b]`` (about :data:`WINDOW_S`), (1) integrates to::

    H (y_b − y_a) = −∫ (ω − β) × (H y − c) dt                                    (W1)

with the integrals as sums of trapezoids of ``ω yᵀ``, ``y`` and ``ω`` (:class:`_Windows`, each window a
difference of running sums). A difference of two samples (MAGYC's ``diff(m)/dt``) has the magnetometer noise
of two samples for one sample's turn; a window of L samples has it for L samples' turn. (W1) is linear and
homogeneous in ``θ = (H, c)``: its rows ``A θ = 0`` (:func:`_design`) are solved for the unit θ of least
residual, the eigenvector of the smallest eigenvalue of ``AᵀA`` with c eliminated (:func:`_constrained`),
for a general H or one restricted to ``P S`` (S symmetric, :func:`_symmetric`). The bias enters (W1) as
``β × (H ∫y − T c)``, linear once θ is held: Gauss-Newton on (θ on its unit sphere, β) from the bias-free
solution (:func:`_windowed_bias`). A window never spans a gap of the time stamps (:func:`_gaps`): the turn
across it was not measured.
"""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from ...rotations import skew

#: Window of the integrated kinematic residual (stage 1), seconds; at least ``_MIN_WINDOW`` samples.
WINDOW_S = 1.0
_MIN_WINDOW = 5
#: A step of the time stamps longer than this many of their median steps (and than GAP_MIN_S) is a gap: the
#: gyro's turn across it is unknown, so the stages do not integrate across it (a new stretch, no window).
GAP_STEPS = 5.0
GAP_MIN_S = 0.05


@dataclass(frozen=True)
class _Windows:
    """Per window ``[a, b]``: ``dy = y_b − y_a``, ``M = ∫ ω yᵀ dt``, ``Sy = ∫ y dt``, ``Sw = ∫ ω dt``, ``T``."""

    dy: NDArray[np.float64]
    M: NDArray[np.float64]
    Sy: NDArray[np.float64]
    Sw: NDArray[np.float64]
    T: NDArray[np.float64]


def _gaps(t: NDArray[np.float64]) -> NDArray[np.bool_]:
    """(n − 1,) True at the steps of ``t`` that are gaps (:data:`GAP_STEPS`): nothing is integrated across them.
    The last times' are kept (every stretch and window of a fit asks for them)."""
    with _LOCK:
        for times, kept in _GAPS:
            if times is t:
                return kept
    steps = np.diff(t)
    gaps = np.asarray(steps > max(GAP_STEPS * float(np.median(steps)), GAP_MIN_S), dtype=bool)
    with _LOCK:
        _GAPS[:] = [*_GAPS[-1:], (t, gaps)]
    return gaps


@dataclass(frozen=True)
class _Frame:
    """What the windows of one recording share whatever rates are read against it (the lag searched, the
    readings of the inputs tried): the trapezoids' half-steps, the samples cut into windows, ``∫ y dt``, ``dy``,
    ``T`` and the windows kept (none across a gap). :func:`_windows` is :meth:`windows` of this."""

    y: NDArray[np.float64]
    t: NDArray[np.float64]
    length: int
    left: NDArray[np.float64]
    yl: NDArray[np.float64]
    yr: NDArray[np.float64]
    whole: NDArray[np.bool_]
    dy: NDArray[np.float64]
    Sy: NDArray[np.float64]
    T: NDArray[np.float64]

    @property
    def used(self) -> int:
        return int(self.left.shape[0] * self.length)

    def integral(self, f: NDArray[np.float64]) -> NDArray[np.float64]:
        """``∫ f dt`` over every window (kept or not), (windows, k), trapezoid by trapezoid (each window's sum a
        row-by-column product: a strided sum over the middle axis takes ten times as long)."""
        used, shape = self.used, (self.left.shape[0], self.length, -1)
        ends = f[:used].reshape(shape) + f[1 : used + 1].reshape(shape)
        return np.asarray(np.matmul(self.left.transpose(0, 2, 1), ends)[:, 0], dtype=np.float64)

    def windows(self, w: NDArray[np.float64]) -> _Windows:
        """The integrals of (W1) with the rates ``w`` (n, 3): only ``M`` and ``Sw`` depend on them."""
        used, windows, length = self.used, self.left.shape[0], self.length
        wl = (w[:used] * self.left.reshape(-1, 1)).reshape(windows, length, 3)
        wr = (w[1 : used + 1] * self.left.reshape(-1, 1)).reshape(windows, length, 3)
        moment = np.matmul(wl.transpose(0, 2, 1), self.yl) + np.matmul(wr.transpose(0, 2, 1), self.yr)  # ∫ ω yᵀ dt
        turn = np.matmul(np.ones((1, length)), wl + wr)[:, 0]  # ∫ ω dt, from the same weighted rates
        return _Windows(self.dy, moment[self.whole], self.Sy, turn[self.whole], self.T)


def _frame(y: NDArray[np.float64], t: NDArray[np.float64], length: int) -> _Frame:
    """The :class:`_Frame` of ``y`` and ``t`` in windows of ``length`` samples (the last one kept while the
    same arrays are asked for again, until :func:`forget_frame`)."""
    with _LOCK:
        for last in _LAST:
            if last.y is y and last.t is t and last.length == length:
                return last
    dt = np.diff(t)
    starts = np.arange(0, len(y) - length, length)
    windows = starts.size
    used = windows * length  # the pieces k = 0 … used − 1 (every window's), samples 0 … used
    # ½ dt_k weighs sample k (the piece's left end) and sample k + 1 (its right end), window by window
    left = (0.5 * dt[:used]).reshape(windows, length, 1)
    yl, yr = y[:used].reshape(windows, length, 3), y[1 : used + 1].reshape(windows, length, 3)
    ends = starts + length
    crossed = np.concatenate([[0], np.cumsum(_gaps(t))])  # gaps among the steps before each sample
    whole = crossed[ends] == crossed[starts]  # a window across a gap would integrate a turn nobody measured
    frame = _Frame(y, t, length, left, yl, yr, whole, y[ends[whole]] - y[starts[whole]], np.zeros((0, 3)),
                   t[ends[whole]] - t[starts[whole]])  # fmt: skip
    frame = replace(frame, Sy=frame.integral(y)[whole])
    with _LOCK:
        _LAST[:] = [frame]
    return frame


#: The last frame, kept while a fit reads other rates against the same samples; emptied when a gyro fit ends.
_LAST: list[_Frame] = []
_LOCK = threading.Lock()


#: The last windows of one recording's rates, and the last biases fitted on windows: the lag search, the readings'
#: check, stage 1 and stage 3 ask for the same ones (the rates as given, with no delay).
_WINDOWS: list[tuple[NDArray[np.float64], _Windows]] = []
_GAPS: list[tuple[NDArray[np.float64], NDArray[np.bool_]]] = []
_BIASES: list[tuple[_Windows, tuple[NDArray[np.float64], NDArray[np.float64]]]] = []


def forget_frame() -> None:
    """Drop the kept frame, windows and biases (the frame's arrays are the size of the recording)."""
    with _LOCK:
        _LAST.clear()
        _WINDOWS.clear()
        _BIASES.clear()
        _GAPS.clear()


def _windows(y: NDArray[np.float64], w: NDArray[np.float64], t: NDArray[np.float64], length: int) -> _Windows:
    """The integrals of (W1) over consecutive windows of ``length`` samples, those across a gap left out.

    Trapezoids: over a window ``[s, s + L]``, ``∫ f dt = Σ_{k=s}^{s+L−1} ½ dt_k (f_k + f_{k+1})``, summed window
    by window (each sample weighted by the half-steps beside it), not as differences of running sums. What does
    not depend on the rates is computed once per samples and times (:func:`_frame`), and the windows of the
    last rates asked for are kept.
    """
    frame = _frame(y, t, length)
    with _LOCK:
        for rates, kept in _WINDOWS:
            if rates is w and _LAST and _LAST[0] is frame:
                return kept
    win = frame.windows(w)
    with _LOCK:
        _WINDOWS[:] = [(w, win)]
    return win


def _design(win: _Windows, beta: NDArray[np.float64]) -> NDArray[np.float64]:
    """Rows of the integrated (1) in θ = (H row by row, c): ``H dy + ∫ (ω−β) × (H y) − ∫(ω−β) × c``, (3m, 12)."""
    m = win.T.size
    moment = win.M - beta[None, :, None] * win.Sy[:, None, :]  # ∫ (ω − β) yᵀ
    turn = win.Sw - beta * win.T[:, None]  # ∫ (ω − β)
    design = np.zeros((m, 3, 12))
    for i in range(3):
        design[:, i, 3 * i : 3 * i + 3] = win.dy
    # (ω × H y)_i = ε_ijk ω_j H_kl y_l: [column l of the moment]× in H's row k, column l
    design[:, :, :9] += skew(moment.transpose(0, 2, 1)).transpose(0, 2, 3, 1).reshape(m, 3, 9)
    design[:, :, 9:] = -skew(turn)
    return design.reshape(3 * m, 12)


def _symmetric(left: NDArray[np.float64], right: NDArray[np.float64]) -> NDArray[np.float64]:
    """(9, 6): ``left @ S @ right`` row by row for S symmetric, over an orthonormal basis of S (unit |S|_F)."""
    basis = np.zeros((9, 6))
    pairs = [(0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2)]
    for column, (a, b) in enumerate(pairs):
        s = np.zeros((3, 3))
        s[a, b] = s[b, a] = 1.0 if a == b else math.sqrt(0.5)
        basis[:, column] = (left @ s @ right).ravel()
    return basis


def _constrained(
    design: NDArray[np.float64], basis: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64], float]:
    """H = basis @ h with |h| = 1 and the best c minimising the windowed residual: (H, c, residual²).

    c is eliminated (the Schur complement of the normal equations) and h is the eigenvector of the smallest
    eigenvalue of what is left, so the residuals of different models of H (general, or ``P S`` for each
    mapping) are on one scale (|H|_F = 1). Normal equations from one product of the tall design with itself,
    not an SVD or QR of it: LAPACK's threads on a shared machine made those most of a long recording's fit.
    """
    k = basis.shape[1]
    reduced = np.empty((design.shape[0], k + 3))
    np.matmul(design[:, :9], basis, out=reduced[:, :k])
    reduced[:, k:] = design[:, 9:]
    normal = reduced.T @ reduced
    n_hh, n_hc, n_cc = normal[:k, :k], normal[:k, k:], normal[k:, k:]
    eliminate = np.linalg.solve(n_cc, n_hc.T)  # c = −N_cc⁻¹ N_chᵀ h
    values, vectors = np.linalg.eigh(n_hh - n_hc @ eliminate)
    h = vectors[:, 0]
    return (basis @ h).reshape(3, 3), -eliminate @ h, float(max(values[0], 0.0))


def _windowed_bias(win: _Windows, iterations: int = 20) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Gauss-Newton on the windowed residual over θ = (H, c) (on its unit sphere: the scale is free) and β,
    from the bias-free total least-squares solution (the last few kept, by the windows they were fitted on: the
    readings' check and the handedness check both negate the given rates)."""
    with _LOCK:
        for kept, result in _BIASES:
            if iterations == 20 and (kept is win or (kept.dy is win.dy and kept.T is win.T and np.array_equal(
                    kept.M, win.M) and np.array_equal(kept.Sw, win.Sw))):  # fmt: skip
                return result
    result = _gauss_newton(win, iterations)
    if iterations == 20:
        with _LOCK:
            _BIASES[:] = [*_BIASES[-3:], (win, result)]
    return result


def _gauss_newton(win: _Windows, iterations: int) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """:func:`_windowed_bias`, computed. The design is linear in β: built once at β = 0 and once for each axis's
    part (the windows' β terms alone), then combined at each iterate."""
    zero = np.zeros(3)
    base = _design(win, zero)
    parts = [_design(_Windows(np.zeros_like(win.dy), -axis[None, :, None] * win.Sy[:, None, :], win.Sy,
                              -axis * win.T[:, None], win.T), zero) for axis in np.eye(3)]  # fmt: skip
    h, c, _ = _constrained(base, np.eye(9))
    theta = np.concatenate([h.ravel(), c])
    theta /= np.linalg.norm(theta)
    beta = np.zeros(3)
    m = win.T.size
    for _ in range(iterations):
        h, c = theta[:9].reshape(3, 3), theta[9:]
        jac_theta = base + beta[0] * parts[0] + beta[1] * parts[1] + beta[2] * parts[2]
        # H ∫y − T c: the residual is linear in β through −β × u
        u = np.einsum("ij,mj->mi", h, win.Sy) - win.T[:, None] * c
        q, _ = np.linalg.qr(np.column_stack([theta, np.eye(12)]))
        tangent = q[:, 1:12]
        # [J r], J in (θ's tangent, β): the normal equations and the gradient from one product with itself
        extended = np.empty((3 * m, 15))
        np.matmul(jac_theta, tangent, out=extended[:, :11])
        extended[:, 11:14] = skew(u).reshape(3 * m, 3)
        extended[:, 14] = jac_theta @ theta
        normal = extended.T @ extended
        step, *_ = np.linalg.lstsq(normal[:14, :14], -normal[:14, 14], rcond=None)
        theta = theta + tangent @ step[:11]
        theta = theta / np.linalg.norm(theta)
        beta = beta + step[11:]
        if np.linalg.norm(step) < 1e-10:
            break
    return theta, beta


def _turn_axes(win: _Windows, beta: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """How much the recording turned about each principal axis and those axes (columns), largest first.

    The scatter of the windows' turns ``∫ (ω − β) dt`` (a second each: the gyro's noise averages out of
    them, where the scatter of the rates themselves would count it as turning); the square roots of its
    eigenvalues, in degrees, in proportion to the turning about each axis.
    """
    turns = win.Sw - beta * win.T[:, None]
    values, vectors = np.linalg.eigh(turns.T @ turns)
    order = values.argsort()[::-1]
    return np.degrees(np.sqrt(np.clip(values[order], 0, None))), vectors[:, order]


def window_length(t: NDArray[np.float64]) -> int:
    """Samples per window of stage 1: :data:`WINDOW_S` at the median step, at least ``_MIN_WINDOW``."""
    return max(_MIN_WINDOW, round(WINDOW_S / float(np.median(np.diff(t)))))
