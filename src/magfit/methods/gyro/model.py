"""Stage 2: maximum likelihood on the samples over stretches of the recording, and its covariance.

Integrating (1) of :mod:`.method` over a stretch of ``segment_s`` seconds from its first sample::

    b_k = R_kᵀ b₀,    y_k = G R_kᵀ b₀ + V,    |b₀| = 1                            (M1)

with ``R_k`` the body's rotation from the stretch's start (:func:`.kinematics._turns`, from ``ω − β``) and G
carrying the field's magnitude. The unknowns ``p = (q, V, β, [δ,] (elevation, azimuth) of each b₀)``, G =
``basis @ q`` (general, or ``W Pᵀ`` with W symmetric for a standard mapping), are fitted by
Levenberg-Marquardt on the residuals ``G b_k + V − y_k`` (and, with the accelerometer, the gravity rows (2) of
:mod:`.gravity`). This uses that the field is one vector for many seconds, which the windows of stage 1
forget; longer stretches add fewer unknowns but let the gyro's noise walk the integrated rotation away.

The Jacobian in β follows from ``R_k = D_0 … D_{k−1}``: each step turns by ``J_r(φ_j) δφ_j`` more
(eq. K3 of :mod:`.kinematics`, ``δφ_j = −dt_j δβ``), which carried to the stretch's start is
``δR_k = −[C_k δβ]× R_k`` with ``C_k = Σ_{j<k} dt_j R_{j+1} J_r(φ_j)`` (a running sum over the stretch), so::

    ∂b_k/∂β = −R_kᵀ [b₀]× C_k                                                     (M2)

The gyro is integrated at one bias β̄ in one chain from the recording's first sample, ``Q_k``, and a stretch
from sample s reads ``R_k = Q_sᵀ Q_k`` and ``C_k = Q_sᵀ (Σ_k − Σ_s)`` with ``Σ_k`` the chain's running sum
(:class:`_Integration`): one integration serves every layout of stretches (the whole fit's, each half's).
A fit whose rows are :data:`LINEAR_STRIDE` or more samples apart carries each row's turn from the row before
it (or from its stretch's start), ``ΔR_i = R_aᵀ R_r``, to a nearby β by the same first-order rule over that
interval, with ``ΔC_i = R_aᵀ (C_r − C_a)``::

    ΔR_i(β) = exp([−ΔC_i (β − β̄)]×) ΔR_i(β̄) + O((|β − β̄| T_i)²),    R_r = R_a ΔR_i,
    C_r ≈ C_a + R_a ΔC_i(β̄)                                                                          (M4)

(the rows' chain a scan over the rows, reset at each stretch; T_i an interval's length). The gyro is
integrated again at β once ``|β − β̄| max T_i`` exceeds the fit's turn: :data:`LINEAR_TURN` for the screening
fits, whose small error only moves where the kept fit starts, and :data:`FINAL_TURN` for the fit kept and the
halves, whose rotations are then within about 1e-8 rad of the integration's (the error is second order in each
interval, summed down a stretch). An evaluation costs a scan over the rows instead of over every sample. C
enters the Jacobian only (the steps and the covariance, to first order in ``|β − β̄|``), not the residuals
nor so the minimum.

The covariance is the sandwich ``I⁻¹ (Σ_batches s sᵀ) I⁻¹`` of the score summed over contiguous batches of the
recording (the gyro's noise walks, so neighbouring residuals are correlated), never below the independent
residuals' ``σ² I⁻¹`` (:func:`_covariance`).
"""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass, replace
from functools import cached_property
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..._optimize import Evaluation, Solution, levenberg_marquardt
from ...rotations import skew
from .gravity import ACCEL_BIAS_PRIOR, _cos, _Gravity, _gravity_angle
from .kinematics import _entries, _jacobian_steps, _product, _rotation_quaternions, _scan, _unit
from .mapping import MAPPINGS
from .windows import _gaps, _symmetric

#: A MEMS gyroscope's scale error per axis, one-sigma, taken as unknown (:func:`_gyro_scale`): datasheets bound
#: the sensitivity after the factory trim by ±0.5-3 %; a bound taken as 3 one-sigmas (docs/methods.md, "gyro").
GYRO_SCALE_PRIOR = 0.005
#: ... and corrected for (:func:`_gyro_scale`) only where an axis's estimate exceeds this many of its one-sigmas.
SCALE_SIGMAS = 3.0

#: At most this many samples enter the maximum-likelihood residuals (a regular stride of the recording);
#: the gyro is integrated at every sample all the same.
MAX_RESIDUAL_SAMPLES = 20_000
#: Rows the candidate mappings are told apart on.
SCREEN_ROWS = 3_000
#: Iterations each candidate mapping gets from the general fit.
SCREEN_ITER = 40
#: At most this many stretches (each adds two unknowns); longer recordings get longer stretches.
MAX_SEGMENTS = 60
#: Fits whose rows are at least this many samples apart carry the rotations between rows to first order in the
#: bias (M4); closer rows integrate every sample (the saving would be small).
LINEAR_STRIDE = 3
#: ... integrating again when the bias has moved by more than this turn (radians) over the longest interval
#: between rows, in the screening fits: (M4)'s error is of its square, up to 1e-6 rad (docs/methods.md, "gyro").
LINEAR_TURN = 1e-3
#: ... carried this far on the way to the minimum, before the fit is finished with the turn above (an error of up
#: to 1e-4 rad moves the steps, not where they end).
LOOSE_TURN = 1e-2
#: ... and in the fit kept and the halves: an error of about 1e-8 rad at most (second order in each interval, summed
#: down a stretch), a few millionths of the noise of a magnetometer good to 0.5 % of the field (docs/methods.md,
#: "gyro"); their bias moves far less than this from where the screening integrated.
FINAL_TURN = 1e-4


@dataclass(frozen=True)
class _Trajectory:
    """What the maximum-likelihood residual needs: the recording, its stretches, the rows it is read at and
    the model of G (``G.ravel() = basis @ q``: general, or ``W Pᵀ`` with W symmetric for a standard mapping).

    The parameters are ``p = (q, V, β, [δ,] the stretches' (elevation, azimuth) of b₀)``, the inclination δ
    only with gravity rows. Each row has three magnetometer residuals ``G b_k + V − y_k`` and, with gravity, a
    fourth ``weight · (d_k · b_k − sin δ) / cos δ`` (zero where the accelerometer does not see gravity alone).
    """

    y: NDArray[np.float64]
    w: NDArray[np.float64]
    t: NDArray[np.float64]
    segment: NDArray[np.int64]
    rows: NDArray[np.int64]
    count: int
    basis: NDArray[np.float64]
    gravity: _Gravity | None = None
    linear: bool = False
    turn: float = LINEAR_TURN
    origin: tuple[NDArray[np.float64], NDArray[np.float64], int] | None = None  # (rates, times, first sample)

    @cached_property
    def steps(self) -> _Steps:
        """What every integration reuses: the steps' mean rates (n − 1, 3) and lengths (n − 1,), the stretches'
        first samples (n,), and the weight of R_k in the running sum C (``dt_{k−1}``, 0 at a stretch's start).
        Shared by the trajectories of one recording and its stretches (the fits of one recording ask for them)."""
        with _LOCK:
            for w, t, segment, kept in _STEPS:
                if w is self.w and t is self.t and (segment is self.segment or np.array_equal(segment, self.segment)):
                    return kept
        dt = np.diff(self.t)
        start = np.ones(self.t.size, dtype=bool)
        start[1:] = self.segment[1:] != self.segment[:-1]
        weights = np.concatenate([[0.0], dt])
        weights[start] = 0.0
        steps: _Steps = (0.5 * (self.w[:-1] + self.w[1:]), dt, start, weights)
        with _LOCK:
            _STEPS[:] = [*_STEPS[-1:], (self.w, self.t, self.segment, steps)]
        return steps

    @cached_property
    def first(self) -> NDArray[np.int64]:
        """Each sample's stretch start (n,) (stretches ascend)."""
        starts = np.flatnonzero(self.steps[2])
        return np.repeat(starts, np.diff(np.append(starts, self.t.size)))

    @cached_property
    def starts(self) -> NDArray[np.int64]:
        """Each stretch's first row among ``rows`` (count,) (rows ascend in stretch)."""
        return np.searchsorted(self.segment[self.rows], np.arange(self.count))

    @property
    def k(self) -> int:
        return int(self.basis.shape[1])

    @property
    def head(self) -> int:
        """Parameters every row may depend on: q, V, β (and δ with gravity); the stretches' angles follow."""
        return self.k + 6 + (self.gravity is not None)

    @property
    def components(self) -> int:
        """Residuals per row: the magnetometer's three, and the gravity row's."""
        return 3 + (self.gravity is not None)

    def n_residuals(self) -> int:
        """Residuals that carry data (the gravity rows of moving samples are zeros)."""
        gravity = 0 if self.gravity is None else int(np.sum(self.gravity.still[self.rows]))
        return 3 * self.rows.size + gravity

    def distortion(self, p: NDArray[np.float64]) -> NDArray[np.float64]:
        """G (3, 3) from the parameters."""
        return np.asarray(self.basis @ p[: self.k], dtype=np.float64).reshape(3, 3)

    def field(self, p: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """b_k = R_kᵀ b₀ at ``rows``, the (rows, 3, 3) rotations, and ∂b_k/∂β (rows, 3, 3).

        ``R_k = D_0 … D_{k−1}`` with ``D_j = exp([(ω̄_j − β) dt_j]×)``, so ``δR_k = −[C_k δβ]× R_k`` with
        ``C_k = Σ_{j<k} dt_j R_{j+1} J_r(φ_j)`` (a running sum over the stretch; module docstring), and
        ``∂b_k/∂β = −R_kᵀ [b₀]× C_k``.
        """
        if self.linear:
            turns, running = _linearized(self, p[self.k + 3 : self.k + 6])
        else:
            turns, running = _integrated_rows(self, p[self.k + 3 : self.k + 6])
        start = _unit(p[self.head :].reshape(self.count, 2))[self.segment[self.rows]]
        # (M2), R_kᵀ [b₀]× C_k: stacked 3×3 products (numpy's own loop, no threaded BLAS, far quicker than einsum)
        d_beta = -np.matmul(np.matmul(turns.transpose(0, 2, 1), skew(start)), running)
        return np.matmul(turns.transpose(0, 2, 1), start[:, :, None])[:, :, 0], turns, d_beta

    def _gravity_rows(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """d_k (rows, 3) and each row's weight (rows,): 0 where the accelerometer is not still."""
        assert self.gravity is not None
        down = self.gravity.down[self.rows]
        return down, self.gravity.weight * self.gravity.still[self.rows].astype(np.float64)

    def _residual_of(self, p: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
        magnetometer = b @ self.distortion(p).T + p[self.k : self.k + 3] - self.y[self.rows]
        if self.gravity is None:
            return magnetometer
        down, weight = self._gravity_rows()
        return np.column_stack([magnetometer, weight * _gravity_angle(down, b, p[self.k + 6])])

    def residual(self, p: NDArray[np.float64]) -> NDArray[np.float64]:
        """All residuals, (rows · components,): row by row, the magnetometer's three then the gravity row."""
        return self.blocks(p)[0].ravel()  # (the last evaluations' are kept)

    def magnetometer_residual(self, p: NDArray[np.float64]) -> NDArray[np.float64]:
        """The samples' own residuals ``G b_k + V − y_k``, (rows, 3), in the samples' unit."""
        return self.residual(p).reshape(-1, self.components)[:, :3]

    def blocks(self, p: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """The residual (rows, C), its Jacobian in (q, V, β[, s]) (rows, C, head), and in the row's own
        stretch's two angles (rows, C, 2): every other angle column of a row is zero. C = :attr:`components`.
        The last two are kept (the solver's last evaluation is the covariance's)."""
        key = p.tobytes()
        with _LOCK:
            for traj, at, kept in _BLOCKS:
                if traj is self and at == key:
                    return kept
        computed = self._blocks(p)
        with _LOCK:
            _BLOCKS[:] = [*_BLOCKS[-1:], (self, key, computed)]
        return computed

    def _blocks(self, p: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """:meth:`blocks`, computed."""
        k = self.k
        g = self.distortion(p)
        b, turns, d_beta = self.field(p)
        rows = self.rows.size
        residual = self._residual_of(p, b)
        dense = np.zeros((rows, self.components, self.head))
        for i in range(3):
            # ∂(G b)_i / ∂G_ij = b_j, through the basis
            dense[:, i, :k] = b @ self.basis[3 * i : 3 * i + 3]
        dense[:, :3, k : k + 3] = np.eye(3)
        dense[:, :3, k + 3 : k + 6] = np.matmul(g, d_beta)
        angles = p[self.head :].reshape(self.count, 2)  # ∂b₀ per stretch, then each row's stretch's
        elevation, azimuth = angles[:, 0], angles[:, 1]
        up, across = np.sin(elevation), np.cos(elevation)
        d_start = np.stack([
            np.column_stack([-up * np.cos(azimuth), -up * np.sin(azimuth), across]),
            np.column_stack([-across * np.sin(azimuth), across * np.cos(azimuth), np.zeros(self.count)]),
        ], axis=2)[self.segment[self.rows]]  # fmt: skip
        angular = np.zeros((rows, self.components, 2))
        turned = np.matmul(turns.transpose(0, 2, 1), d_start)  # R_kᵀ ∂b₀
        angular[:, :3] = np.matmul(g, turned)  # G R_kᵀ ∂b₀
        if self.gravity is not None:
            down, weight = self._gravity_rows()
            inclination = p[k + 6]
            across = weight / _cos(inclination)
            dense[:, 3, k + 3 : k + 6] = across[:, None] * np.einsum("ki,kim->km", down, d_beta)
            # ∂/∂δ of (x − sin δ) / cos δ = −1 + tan δ · (x − sin δ) / cos δ
            dense[:, 3, k + 6] = weight * (-1.0 + math.tan(inclination) * _gravity_angle(down, b, inclination))
            angular[:, 3] = across[:, None] * np.einsum("ki,kin->kn", down, turned)
        return residual, dense, angular

    def normal_equations(self, p: NDArray[np.float64]) -> Evaluation:
        """½ Σ r², JᵀJ and Jᵀr from the blocks: the angle columns of a stretch only meet its own rows.

        JᵀJ by :meth:`information`; the gradient by einsum (a matrix-vector product through BLAS was slower).
        """
        residual, dense, angular = self.blocks(p)
        gradient = np.concatenate([
            np.einsum("kip,ki->p", dense, residual),
            self._by_stretch(np.einsum("kin,ki->kn", angular, residual)).ravel(),
        ])  # fmt: skip
        return Evaluation(0.5 * float(np.sum(residual**2)), self.information(dense, angular), gradient)

    def _by_stretch(self, values: NDArray[np.float64]) -> NDArray[np.float64]:
        """Sums of ``values`` (rows, ...) over each stretch's rows (count, ...); zero for a stretch with none."""
        counts = np.diff(np.append(self.starts, self.rows.size))
        out = np.zeros((self.count, *values.shape[1:]))
        held = counts > 0
        out[held] = np.add.reduceat(values, self.starts[held], axis=0)
        return out

    def information(self, dense: NDArray[np.float64], angular: NDArray[np.float64]) -> NDArray[np.float64]:
        """JᵀJ (p.size, p.size) from the blocks of :meth:`blocks`: a stretch's angles meet only its own rows.

        The head block is one product of the (rows · C, head) Jacobian with itself, and each stretch's columns
        one product of its own rows: matrix products on few columns, a tenth of einsum's time even on shared
        cores (einsum adds the rows in another order: the sums agree to rounding, not bit for bit).
        """
        head = self.head
        size = head + 2 * self.count
        normal = np.zeros((size, size))
        flat = dense.reshape(-1, head)
        normal[:head, :head] = flat.T @ flat
        angles = angular.reshape(-1, 2)
        bounds = self.components * np.append(self.starts, self.rows.size)
        for s in range(self.count):
            rows = slice(bounds[s], bounds[s + 1])
            columns = slice(head + 2 * s, head + 2 * s + 2)
            cross = flat[rows].T @ angles[rows]  # (head, 2); zeros for a stretch with no rows
            normal[:head, columns] = cross
            normal[columns, :head] = cross.T
            normal[columns, columns] = angles[rows].T @ angles[rows]
        return normal

    def score(self, dense: NDArray[np.float64], angular: NDArray[np.float64],
              residual: NDArray[np.float64]) -> NDArray[np.float64]:  # fmt: skip
        """Each row's ``Jᵀ r`` (rows, p.size): the gradient's terms, which the sandwich sums by batch."""
        rows = self.rows.size
        terms = np.zeros((rows, self.head + 2 * self.count))
        terms[:, : self.head] = np.einsum("kip,ki->kp", dense, residual)
        columns = self.head + 2 * self.segment[self.rows]
        own = np.einsum("kin,ki->kn", angular, residual)
        for shift in range(2):
            terms[np.arange(rows), columns + shift] = own[:, shift]
        return terms

    def times(self, dense: NDArray[np.float64], angular: NDArray[np.float64],
              other: NDArray[np.float64]) -> NDArray[np.float64]:  # fmt: skip
        """``Jᵀ X`` (p.size, m) for X (rows, C, m) from the blocks of :meth:`blocks`."""
        angles = self._by_stretch(np.matmul(angular.transpose(0, 2, 1), other))  # (count, 2, m)
        return np.concatenate([np.einsum("kip,kiq->pq", dense, other), angles.reshape(-1, other.shape[2])])


@dataclass(frozen=True)
class _Integration:
    """One recording integrated at one bias in one chain from its first sample, across its stretches: the
    quaternions of ``Q_k = D_0 … D_{k−1}`` (4, n), ``Q_k`` entry by entry (9, n) and the running sums
    ``Σ_{j<k} dt_j Q_{j+1} J_r(φ_j)`` (n, 3, 3). A stretch from sample s has ``R_k = Q_sᵀ Q_k`` and
    ``C_k = Q_sᵀ (Σ_k − Σ_s)`` (K2 and M2 with the chain's common start left out), so one integration serves
    every layout of stretches over the recording, the halves' too (their samples from ``offset`` on)."""

    w: NDArray[np.float64]
    t: NDArray[np.float64]
    beta: NDArray[np.float64]
    quaternions: NDArray[np.float64]
    entries: NDArray[np.float64]
    running: NDArray[np.float64]

    def offset(self, traj: _Trajectory) -> int | None:
        """Where ``traj``'s samples start in this recording (0 for the recording itself), or None."""
        if self.w is traj.w and self.t is traj.t:
            return 0
        if traj.origin is not None and self.w is traj.origin[0] and self.t is traj.origin[1]:
            return traj.origin[2]
        return None

    def at_rows(self, traj: _Trajectory, rows: NDArray[np.int64],
                offset: int) -> tuple[NDArray[np.float64], NDArray[np.float64]]:  # fmt: skip
        """R_k and C_k (k in ``rows`` of ``traj``) from their stretches' first samples, (rows, 3, 3) each."""
        first = traj.first[rows] + offset
        at = rows + offset
        start = self.entries[:, first].T.reshape(-1, 3, 3).transpose(0, 2, 1)  # Q_sᵀ
        turns = np.matmul(start, self.entries[:, at].T.reshape(-1, 3, 3))
        return turns, np.matmul(start, self.running[at] - self.running[first])


#: The last integration of each recording (the rates as given and, for the handedness check, negated), at most
#: :data:`_KEEP_INTEGRATIONS`: reused while a fit evaluates at the same bias (the candidate mappings start from
#: the general fit, the covariance at the solution the fit last integrated) and as the point a linearization
#: (M4) carries from. Emptied when a gyro fit ends (:func:`forget_integration`).
_LAST: list[_Integration] = []
_KEEP_INTEGRATIONS = 2
_LOCK = threading.Lock()
#: The last two recordings' steps (:attr:`_Trajectory.steps`): (rates, times, stretches, steps).
_Steps = tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.bool_], NDArray[np.float64]]
_STEPS: list[tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.int64], _Steps]] = []
#: The last rows' rotations carried by (M4) (:func:`_linearized`): (trajectory, bias's bytes, R_k and C_k).
_CARRIED: list[tuple[_Trajectory, bytes, tuple[NDArray[np.float64], NDArray[np.float64]]]] = []
#: The last two evaluations' blocks (:meth:`_Trajectory.blocks`): (trajectory, parameters' bytes, blocks).
_BLOCKS: list[tuple[_Trajectory, bytes, tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]]] = []


def _integration(traj: _Trajectory, beta: NDArray[np.float64]) -> tuple[_Integration, int]:
    """``traj``'s recording integrated at bias ``beta`` (:class:`_Integration`), or the kept one at that bias, and
    where ``traj``'s samples start in it."""
    beta = np.asarray(beta, dtype=np.float64)
    with _LOCK:
        for last in _LAST:
            offset = last.offset(traj)
            if offset is not None and np.array_equal(last.beta, beta):
                return last, offset
    mean_rates, dt, _, _ = traj.steps
    n = traj.t.size
    chain = np.zeros(n, dtype=bool)
    chain[0] = True  # one chain: a stretch's rotations are its quotients
    quaternions = _rotation_quaternions(mean_rates, dt, beta, chain)
    entries = _entries(quaternions)  # (9, n): each entry's run over the samples
    # Σ dt_j Q_{j+1} J_r(φ_j), summed along each entry's contiguous run: a third of the time of the same sums
    # over the (n, 3, 3) view.
    running = _jacobian_steps(entries, mean_rates, dt, beta)
    running[:, 0] = 0.0
    running[:, 1:] *= dt
    np.cumsum(running, axis=1, out=running)
    found = _Integration(traj.w, traj.t, beta.copy(), quaternions, entries, running.T.reshape(n, 3, 3))
    with _LOCK:  # one per recording (its rates' array), the newest last
        _LAST[:] = [*(kept for kept in _LAST if kept.w is not traj.w), found][-_KEEP_INTEGRATIONS:]
    return found, 0


def _integrated(traj: _Trajectory, beta: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """R_k and C_k of every sample of ``traj`` from its stretch's first sample (n, 3, 3) each, at bias ``beta``
    (:class:`_Integration`), integrated or reused."""
    found, offset = _integration(traj, beta)
    return found.at_rows(traj, np.arange(traj.t.size), offset)


def _integrated_rows(traj: _Trajectory, beta: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """R_k and C_k at ``traj``'s rows, every sample integrated."""
    found, offset = _integration(traj, beta)
    return found.at_rows(traj, traj.rows, offset)


def forget_rates(w: NDArray[np.float64]) -> None:
    """Drop what is kept for the rates ``w`` (a reading of them done with: the negated rates' check), so that
    the recording's own integration is the only one of its size left."""
    with _LOCK:
        _LAST[:] = [kept for kept in _LAST if kept.w is not w]
        _LINEAR[:] = [kept for kept in _LINEAR if kept.w is not w]
        _STEPS[:] = [kept for kept in _STEPS if kept[0] is not w]


def forget_integration() -> None:
    """Drop the kept integrations (their arrays are the size of the recording)."""
    with _LOCK:
        _LAST.clear()
        _LINEAR.clear()
        _BLOCKS.clear()
        _STEPS.clear()
        _CARRIED.clear()


@dataclass(frozen=True)
class _Linearization:
    """(M4) of one recording's rows at the bias ``beta``: each row's turn from its anchor (the row before in its
    stretch, or the stretch's first sample) as a quaternion ``local`` (4, m), ``ΔC_i`` (m, 3, 3), the rows that
    start a stretch's chain ``restart`` (m,), and the longest interval ``reach`` (s)."""

    w: NDArray[np.float64]
    t: NDArray[np.float64]
    segment: NDArray[np.int64]
    rows: NDArray[np.int64]
    beta: NDArray[np.float64]
    local: NDArray[np.float64]
    sums: NDArray[np.float64]
    restart: NDArray[np.bool_]
    reach: float

    def holds(self, traj: _Trajectory, beta: NDArray[np.float64]) -> bool:
        """True for ``traj``'s recording and rows, with ``beta`` within its turn (``traj.turn``) of its own."""
        return (self.w is traj.w and self.t is traj.t and np.array_equal(self.segment, traj.segment)
                and np.array_equal(self.rows, traj.rows)
                and float(np.max(np.abs(beta - self.beta))) * self.reach <= traj.turn)  # fmt: skip


#: The screening fits' linearizations (the general fit's, the negated rates' of :mod:`.rates`, the candidates'
#: and the kept fit's), the last :data:`_KEEP_LINEAR`: each is the size of its rows.
_LINEAR: list[_Linearization] = []
_KEEP_LINEAR = 6


def _reach(traj: _Trajectory) -> tuple[NDArray[np.bool_], NDArray[np.int64], float]:
    """The rows that restart a chain (m,), each row's anchor (m,) and the longest interval between them (s)."""
    rows = traj.rows
    restart = np.ones(rows.size, dtype=bool)
    restart[1:] = traj.segment[rows[1:]] != traj.segment[rows[:-1]]
    anchor = np.where(restart, traj.first[rows], np.concatenate([[0], rows[:-1]]))
    return restart, anchor, float(np.max(traj.t[rows] - traj.t[anchor]))


def _linearization(traj: _Trajectory, beta: NDArray[np.float64]) -> _Linearization:
    """(M4)'s terms at ``beta`` from one integration over every sample: a kept one of the same recording when its
    bias is within ``traj.turn`` of ``beta`` over these rows' longest interval (then (M4) is taken from there),
    else a new one at ``beta``."""
    restart, anchor, reach = _reach(traj)
    with _LOCK:
        near = [(kept, kept.offset(traj)) for kept in _LAST if kept.offset(traj) is not None
                and float(np.max(np.abs(beta - kept.beta))) * reach <= traj.turn]  # fmt: skip
    found, offset = near[-1] if near else _integration(traj, beta)
    assert offset is not None
    q, entries, running = found.quaternions, found.entries, found.running
    rows, anchor = traj.rows + offset, anchor + offset  # (the anchor is in its row's stretch: Q_aᵀ Q_r = R_aᵀ R_r)
    conjugate = q[:, anchor] * np.array([[1.0], [-1.0], [-1.0], [-1.0]])
    local = _product(conjugate, q[:, rows])  # ΔR_i = R_aᵀ R_r
    turned = entries[:, anchor].T.reshape(-1, 3, 3)
    sums = np.matmul(turned.transpose(0, 2, 1), running[rows] - running[anchor])  # ΔC_i = R_aᵀ (C_r − C_a)
    return _Linearization(traj.w, traj.t, traj.segment, traj.rows, found.beta, local, sums, restart, reach)


def _linearized(traj: _Trajectory, beta: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """R_k and ``C_k`` at ``traj``'s rows (rows, 3, 3) at bias ``beta`` by (M4), from the linearization that holds
    (or a new one); the last is kept (a fit's start and its first evaluation ask for the same)."""
    key = np.asarray(beta, dtype=np.float64).tobytes()
    with _LOCK:
        for kept_traj, at, carried in _CARRIED:
            if kept_traj is traj and at == key:
                return carried
    with _LOCK:
        found = next((kept for kept in _LINEAR if kept.holds(traj, beta)), None)
    if found is None:
        found = _linearization(traj, beta)
        with _LOCK:
            _LINEAR[:] = [*_LINEAR[1 - _KEEP_LINEAR :], found]
    v = -np.matmul(found.sums, beta - found.beta)  # (rows, 3): exp([v]×) carries ΔR_i to β
    angle = np.sqrt(np.einsum("ki,ki->k", v, v))
    sinc = np.where(angle > 1e-12, np.sin(0.5 * angle) / np.maximum(angle, 1e-300), 0.5)
    correction = np.concatenate([np.cos(0.5 * angle)[None], (v * sinc[:, None]).T])
    chained = _scan(_product(correction, found.local), found.restart)  # R_r = R_a ΔR_i along each stretch
    m = traj.rows.size
    turns = _entries(chained).T.reshape(m, 3, 3)
    before = np.empty_like(turns)  # R_a: the row before's, or I at a stretch's first row
    before[1:] = turns[:-1]
    before[found.restart] = np.eye(3)
    steps = np.matmul(before, found.sums)  # R_a ΔC_i
    total = np.cumsum(steps, axis=0)
    first = traj.starts[traj.segment[traj.rows]]  # each row's stretch's first row
    carried = (turns, total - total[first] + steps[first])
    with _LOCK:
        _CARRIED[:] = [(traj, key, carried)]
    return carried


def _trajectory(y: NDArray[np.float64], w: NDArray[np.float64], t: NDArray[np.float64], segment_s: float,
                basis: NDArray[np.float64], max_rows: int = MAX_RESIDUAL_SAMPLES,
                gravity: _Gravity | None = None, linear: bool = False, turn: float = LINEAR_TURN,
                origin: tuple[NDArray[np.float64], NDArray[np.float64], int] | None = None) -> _Trajectory:  # fmt: skip
    span = float(t[-1] - t[0])
    length = max(segment_s, span / MAX_SEGMENTS)
    segment = np.minimum(((t - t[0]) // length).astype(np.int64), max(int(span // length) - 1, 0))
    # a gap in the time stamps starts a new stretch too: the gyro's turn across it is unknown
    segment = np.concatenate([[0], np.cumsum((np.diff(segment) != 0) | _gaps(t))]).astype(np.int64)
    stride = max(1, math.ceil(y.shape[0] / max_rows))
    rows = np.arange(0, y.shape[0], stride)
    linear = linear and stride >= LINEAR_STRIDE
    return _Trajectory(y, w, t, segment, rows, int(segment.max()) + 1, basis, gravity, linear, turn, origin)


def _start(traj: _Trajectory, g: NDArray[np.float64], offset: NDArray[np.float64],
           beta: NDArray[np.float64]) -> NDArray[np.float64]:  # fmt: skip
    """Parameters for ``traj`` from G (any scale: |b₀| = 1 rescales it), V and β; each stretch's b₀ the mean of
    ``R_k H (y_k − V)`` over its rows (b₀ = R_k b_k, (M1)), which the first evaluation's rotations give, and
    (with gravity) δ read off the samples."""
    h = np.linalg.inv(g)
    field = (traj.y[traj.rows] - offset) @ h.T
    radius = float(np.median(np.linalg.norm(field, axis=1)))
    turns = (_linearized(traj, beta) if traj.linear else _integrated_rows(traj, beta))[0]
    first = traj._by_stretch(np.matmul(turns, field[:, :, None])[:, :, 0])
    length = np.linalg.norm(first, axis=1)
    if not np.all(length > 0):  # a stretch without rows: its first sample's direction (it carries no residual)
        lone = np.array([(traj.y[np.argmax(traj.segment == s)] - offset) @ h.T for s in range(traj.count)])
        first[length == 0] = lone[length == 0]
        length = np.linalg.norm(first, axis=1)
    first /= np.maximum(length, 1e-300)[:, None]
    angles = np.column_stack([np.arcsin(np.clip(first[:, 2], -1, 1)), np.arctan2(first[:, 1], first[:, 0])])
    q, *_ = np.linalg.lstsq(traj.basis, (g * radius).ravel(), rcond=None)
    head = [q, offset, beta]
    if traj.gravity is not None:
        still = traj.gravity.still
        seen = (traj.y[still] - offset) @ h.T
        unit = seen / np.linalg.norm(seen, axis=1)[:, None]
        dots = np.einsum("ki,ki->k", traj.gravity.down[still], unit)
        head.append(np.array([math.asin(float(np.clip(np.median(dots), -0.99, 0.99)))]))
    return np.concatenate([*head, angles.ravel()])


def _maximum_likelihood(traj: _Trajectory, start: NDArray[np.float64], iterations: int = 60,
                        tolerance: float = 1e-3) -> Solution:
    """Levenberg-Marquardt on the samples' residuals (the project's solver: normal equations, k ≤ 135), stopped
    at a step shorter than ``tolerance`` standard errors (the solver's own 1e-3, unless said)."""

    def evaluate(p: NDArray[np.float64], warm: Any) -> Evaluation:
        return traj.normal_equations(p)

    def solve(matrix: NDArray[np.float64], rhs: NDArray[np.float64]) -> NDArray[np.float64]:
        return _solve_arrow(matrix, rhs, traj.head)

    return levenberg_marquardt(evaluate, start, n_residuals=traj.n_residuals(), max_iterations=iterations,
                               solve=solve, skip_small_steps=tolerance)  # fmt: skip


#: The head's Schur complement (eq. M3) is inverted only below this condition number; above it the pseudo-inverse
#: of the whole matrix is taken (which truncates what the data do not determine, as before).
_ARROW_CONDITION = 1e10


def _arrow_blocks(matrix: NDArray[np.float64], head: int) -> tuple[NDArray[np.float64], ...] | None:
    """The 2×2 diagonal blocks of an arrow matrix's tail, as (d00, d01, d10, d11, det), or None if one is singular."""
    count = (matrix.shape[0] - head) // 2
    index = head + 2 * np.arange(count)
    d00, d01 = matrix[index, index], matrix[index, index + 1]
    d10, d11 = matrix[index + 1, index], matrix[index + 1, index + 1]
    det = d00 * d11 - d01 * d10
    if not np.all(np.isfinite(det)) or np.any(det == 0.0):
        return None
    return d00, d01, d10, d11, det


def _block_solve(blocks: tuple[NDArray[np.float64], ...], v: NDArray[np.float64]) -> NDArray[np.float64]:
    """D⁻¹ v for v (2·count, ...), D block-diagonal with the 2×2 ``blocks`` of :func:`_arrow_blocks`."""
    d00, d01, d10, d11, det = (x.reshape((-1,) + (1,) * (v.ndim - 1)) for x in blocks)
    first, second = v[0::2], v[1::2]
    out = np.empty_like(v)
    out[0::2] = (d11 * first - d01 * second) / det
    out[1::2] = (d00 * second - d10 * first) / det
    return out


def _inverse_arrow(matrix: NDArray[np.float64], head: int) -> NDArray[np.float64] | None:
    """The inverse of a symmetric arrow matrix (the information of (M1)) by its blocks (eq. M3)::

        [[A, B], [Bᵀ, D]]⁻¹ = [[S⁻¹, −S⁻¹ Eᵀ], [−E S⁻¹, D⁻¹ + E S⁻¹ Eᵀ]],   E = D⁻¹ Bᵀ,  S = A − B E

    or None when a block is singular or S is ill-conditioned (:data:`_ARROW_CONDITION`). Products by einsum:
    a threaded matrix product of this size costs more than its arithmetic on a shared machine.
    """
    blocks = _arrow_blocks(matrix, head)
    if blocks is None:
        return None
    b = matrix[:head, head:]
    e = _block_solve(blocks, np.ascontiguousarray(b.T))  # (2·count, head)
    schur = matrix[:head, :head] - np.einsum("ij,jk->ik", b, e)
    if not np.linalg.cond(schur) < _ARROW_CONDITION:
        return None
    s_inv = np.linalg.inv(schur)
    es = np.einsum("ij,jk->ik", e, s_inv)
    size = matrix.shape[0]
    inverse = np.zeros((size, size))
    inverse[:head, :head] = s_inv
    inverse[head:, :head] = -es
    inverse[:head, head:] = -es.T
    inverse[head:, head:] = np.einsum("ij,kj->ik", es, e)
    index = 2 * np.arange((size - head) // 2)
    d00, d01, d10, d11, det = blocks
    tail = inverse[head:, head:]
    tail[index, index] += d11 / det
    tail[index, index + 1] -= d01 / det
    tail[index + 1, index] -= d10 / det
    tail[index + 1, index + 1] += d00 / det
    return inverse


def _solve_arrow(matrix: NDArray[np.float64], rhs: NDArray[np.float64], head: int) -> NDArray[np.float64]:
    """``matrix⁻¹ rhs`` for the normal matrix of (M1): dense in its first ``head`` parameters, and 2×2 blocks on
    the diagonal for each stretch's two angles (a stretch's angles meet only its own rows).

    With ``matrix = [[A, B], [C, D]]`` and D block-diagonal, the Schur complement::

        (A − B D⁻¹ C) x_h = r_h − B D⁻¹ r_a,    x_a = D⁻¹ (r_a − C x_h)                  (M3)

    leaves one head × head system: no LAPACK call on the whole matrix, whose threads cost far more than the
    arithmetic when the machine's cores are shared. Raises ``LinAlgError`` when a block or the complement is
    singular, as a dense solve would.
    """
    a, b, c = matrix[:head, :head], matrix[:head, head:], matrix[head:, :head]
    blocks = _arrow_blocks(matrix, head)
    if blocks is None:
        raise np.linalg.LinAlgError("a stretch's angle block is singular")
    r_h, r_a = rhs[:head], rhs[head:]
    x_h = np.linalg.solve(a - b @ _block_solve(blocks, c), r_h - b @ _block_solve(blocks, r_a))
    return np.asarray(np.concatenate([x_h, _block_solve(blocks, r_a - c @ x_h)]), dtype=np.float64)


def _covariance(traj: _Trajectory, p: NDArray[np.float64]) -> NDArray[np.float64]:
    """The sandwich covariance of p: batch sums of the score over 20-40 contiguous stretches of the recording."""
    rows, components = traj.rows.size, traj.components
    residual, dense, angular = traj.blocks(p)
    information = traj.information(dense, angular)
    structured = _inverse_arrow(information, traj.head)
    # ill-conditioned: the pseudo-inverse leaves out what the data do not determine
    inverse = np.asarray(np.linalg.pinv(information) if structured is None else structured, dtype=np.float64)
    dof = max(traj.n_residuals() - p.size, 1)
    independent = inverse * float(np.sum(residual**2)) / dof
    score = traj.score(dense, angular, residual)
    batches = max(2, min(40, rows // 50))
    sums = np.array([s.sum(axis=0) for s in np.array_split(score, batches)])
    # Products by einsum: BLAS's threads on matrices of this size cost more than the arithmetic on shared cores.
    # I⁻¹ (Σ s sᵀ) I⁻¹ = (I⁻¹ S)(I⁻¹ S)ᵀ with S the batches' sums (p, batches): a fortieth of p³ each.
    turned = np.einsum("ij,bj->ib", inverse, sums)
    sandwich = np.einsum("ib,jb->ij", turned, turned) * batches / (batches - 1)
    # Never below the independent-noise covariance (a few batches can understate it by chance).
    covariance = _larger(sandwich, independent)
    if traj.gravity is not None:
        # An accelerometer tilted by θ (its bias over g, or its mounting against the gyro) moves every d_k by
        # θ × d_k, which the fit absorbs: p moves by −(JᵀJ)⁻¹ Jᵀ ∂r/∂θ, added for θ of ACCEL_BIAS_PRIOR / g.
        b = traj.field(p)[0]
        down, weight = traj._gravity_rows()
        tilt = np.zeros((rows, components, 3))
        tilt[:, 3] = (weight / _cos(float(p[traj.k + 6])))[:, None] * np.cross(down, b)  # ∂(d·b)/∂θ = d × b
        shift = -np.einsum("ij,jk->ik", inverse, traj.times(dense, angular, tilt))
        covariance = covariance + (ACCEL_BIAS_PRIOR / 9.81) ** 2 * np.einsum("ik,jk->ij", shift, shift)
    return covariance


def _scale_jacobian(traj: _Trajectory, p: NDArray[np.float64]) -> NDArray[np.float64]:
    """``K = ∂r/∂s`` (rows, C, 3): the residuals' change with the gyro's scale per axis, ``ω̄ → (1 + s) ω̄``.

    Each step then turns by ``δφ_j = dt_j ω̄_{j,m} δs_m e_m`` more, so, as (M2) for the bias (``δφ_j = −dt_j δβ``),
    ``δR_k = [S_k δs]× R_k`` with ``S_k = Σ_{j<k} dt_j R_{j+1} J_r(φ_j) diag(ω̄_j)`` and ``∂b_k/∂s = R_kᵀ [b₀]× S_k``:
    the bias's running sum with each column weighted by its axis's rate, from the recording's integration
    (:class:`_Integration`, stretch by stretch as there; the kept one, at the fit's bias or near it).
    """
    k = traj.k
    with _LOCK:  # the recording's kept integration, at the fit's bias or the linearization's (M4) beside it
        kept = [(last, where) for last in _LAST if (where := last.offset(traj)) is not None]
    found, offset = kept[-1] if kept else _integration(traj, p[k + 3 : k + 6])
    mean_rates, dt, _, _ = traj.steps
    weighted = _jacobian_steps(found.entries, mean_rates, dt, found.beta)
    weighted[:, 0] = 0.0
    for row in range(3):
        weighted[3 * row : 3 * row + 3, 1:] *= (mean_rates * dt[:, None]).T
    np.cumsum(weighted, axis=1, out=weighted)
    sums = weighted.T.reshape(-1, 3, 3)
    first, at = traj.first[traj.rows] + offset, traj.rows + offset
    start = found.entries[:, first].T.reshape(-1, 3, 3).transpose(0, 2, 1)  # Q_sᵀ
    turns = np.matmul(start, found.entries[:, at].T.reshape(-1, 3, 3))
    running = np.matmul(start, sums[at] - sums[first])
    del weighted, sums
    field = _unit(p[traj.head :].reshape(traj.count, 2))[traj.segment[traj.rows]]
    d_scale = np.matmul(np.matmul(turns.transpose(0, 2, 1), skew(field)), running)  # R_kᵀ [b₀]× S_k
    change = np.zeros((traj.rows.size, traj.components, 3))
    change[:, :3] = np.matmul(traj.distortion(p), d_scale)
    if traj.gravity is not None:
        down, weight = traj._gravity_rows()
        across = weight / _cos(float(p[k + 6]))
        change[:, 3] = across[:, None] * np.einsum("ki,kim->km", down, d_scale)
    return change


def _gyro_scale(
    traj: _Trajectory, p: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """The gyroscope's scale error per axis ``s`` estimated from the fit, its one-sigma, and what it does to p:
    ``(p corrected, covariance to add, s, its covariance)``.

    A rate read ``(1 + s_i)`` times too large about axis i turns every ``R_k`` too far, which a fit at s = 0
    absorbs into G, V and the stretches' fields. Linearised at the fit, ``r ≈ r₀ + J δp + K s``
    (:func:`_scale_jacobian`); p re-optimised for a given s moves by ``δp = −(JᵀJ)⁻¹ JᵀK s``
    and leaves the projected ``K̃ = (I − J (JᵀJ)⁻¹ Jᵀ) K``. With s taken as unknown within
    :data:`GYRO_SCALE_PRIOR` (a prior ``N(0, σ_s² I)``) and the residuals' variance σ²::

        ŝ = −(K̃ᵀK̃ / σ² + I / σ_s²)⁻¹ K̃ᵀ r₀ / σ²,    Σ_s = (K̃ᵀK̃ / σ² + I / σ_s²)⁻¹               (S1)

    so a recording that determines the scale corrects for it (p moves by ``δp(ŝ)``) and adds little, and
    one that does not adds the prior's worth, ``(∂p/∂s) Σ_s (∂p/∂s)ᵀ``, to the covariance.
    """
    residual, dense, angular = traj.blocks(p)
    information = traj.information(dense, angular)
    structured = _inverse_arrow(information, traj.head)
    inverse = np.asarray(np.linalg.pinv(information) if structured is None else structured, dtype=np.float64)
    change = _scale_jacobian(traj, p)
    crossed = traj.times(dense, angular, change)  # JᵀK, (p, 3)
    moved = -np.einsum("ij,jk->ik", inverse, crossed)  # ∂p/∂s
    projected = np.einsum("kim,kin->mn", change, change) + np.einsum("pm,pn->mn", crossed, moved)  # K̃ᵀK̃
    dof = max(traj.n_residuals() - p.size, 1)
    variance = max(float(np.sum(residual**2)) / dof, 1e-300)
    posterior = np.linalg.inv(projected / variance + np.eye(3) / GYRO_SCALE_PRIOR**2)
    estimate = -posterior @ np.einsum("kim,ki->m", change, residual) / variance
    added = np.einsum("pm,mn,qn->pq", moved, posterior, moved)
    if not np.any(np.abs(estimate) > SCALE_SIGMAS * np.sqrt(np.diag(posterior))):
        return p, np.asarray(added, dtype=np.float64), np.zeros(3), posterior
    return p + moved @ estimate, np.asarray(added, dtype=np.float64), estimate, posterior


def _larger(a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    """``b`` plus the positive part of ``a − b``: the larger of two covariances."""
    values, vectors = _eigh_serial(a - b)
    positive = values > 0  # (the others add nothing)
    kept = vectors[:, positive]
    return b + np.einsum("ik,jk->ij", kept * values[positive], kept)


@dataclass(frozen=True)
class _Model:
    """One model of G fitted by maximum likelihood: ``"general"`` or a :data:`MAPPINGS` name."""

    name: str
    traj: _Trajectory
    solution: Solution

    @property
    def rss(self) -> float:
        return 2.0 * self.solution.evaluation.cost


def _fit_model(y: NDArray[np.float64], w: NDArray[np.float64], t: NDArray[np.float64], segment_s: float,
               name: str, g: NDArray[np.float64], offset: NDArray[np.float64], beta: NDArray[np.float64],
               max_rows: int = MAX_RESIDUAL_SAMPLES, iterations: int = 60,
               gravity: _Gravity | None = None, linear: bool = True, turn: float = FINAL_TURN,
               loose: bool = False, origin: tuple[NDArray[np.float64], NDArray[np.float64], int] | None = None,
               tolerance: float = 1e-3) -> _Model:  # fmt: skip
    """One model of G fitted from G, V and β; ``linear``: its rotations between rows at least
    :data:`LINEAR_STRIDE` samples apart follow the bias by (M4) while it stays within ``turn`` (the screening's
    :data:`LINEAR_TURN`, or :data:`FINAL_TURN` for the fit kept and the halves), else every sample is
    integrated at every bias. ``loose``: first carried :data:`LOOSE_TURN` far (a fit whose bias moves far).
    ``origin``: the recording these samples are a stretch of (its rates, times, and where they start), whose
    integration they may carry from (the halves). ``tolerance``: the step, in standard errors, below which the
    fit stops (:func:`_maximum_likelihood`)."""
    basis = np.eye(9) if name == "general" else _symmetric(np.eye(3), MAPPINGS[name].T)  # G = W Pᵀ = (P S)⁻¹
    traj = _trajectory(y, w, t, segment_s, basis, max_rows, gravity, linear, turn, origin)
    start = _start(traj, g, offset, beta)
    if traj.linear and loose and turn < LOOSE_TURN:
        # First towards the minimum with the rows' rotations carried LOOSE_TURN far (a fit whose bias moves far,
        # as the negated rates' does, then integrates once on the way instead of every LINEAR_TURN), then on
        # from there with the turn asked for.
        start = _maximum_likelihood(replace(traj, turn=LOOSE_TURN), start, iterations).params
    return _Model(name, traj, _maximum_likelihood(traj, start, iterations, tolerance))


def _parts(model: _Model) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """G, V and β of a fitted model."""
    params, k = model.solution.params, model.traj.k
    return model.traj.distortion(params), params[k : k + 3], params[k + 3 : k + 6]


def _effective_variance(residual: NDArray[np.float64], times: NDArray[np.float64], unknowns: int) -> float:
    """The variance per component of ``residual`` (rows, m), times the correlation excess of the residuals in
    time.

    Neighbouring residuals share the gyro's integrated noise (a random walk over each stretch) and the
    magnetometer's filtering: the variance of means over five-second blocks of rows, times the block length,
    over the plain variance (at least 1).
    """
    variance = float(np.sum(residual**2)) / max(residual.size - unknowns, 1)
    step = float(np.median(np.diff(times))) if times.size > 1 else 1.0
    block = max(1, round(5.0 / step))
    blocks = residual.shape[0] // block
    if blocks < 10:
        return variance
    means = residual[: blocks * block].reshape(blocks, block, residual.shape[1]).mean(axis=1)
    excess = block * float(np.mean(means**2)) / max(float(np.mean(residual**2)), 1e-300)
    return variance * max(1.0, excess)


def _noise_variance(model: _Model) -> float:
    """The magnetometer residuals' variance per component, times their correlation excess in time."""
    traj = model.traj
    residual = traj.magnetometer_residual(model.solution.params)
    return _effective_variance(residual, traj.t[traj.rows], model.solution.params.size)


def _eigh_serial(matrix: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Eigenvalues and orthonormal eigenvectors (columns) of a symmetric matrix without threaded BLAS.

    Householder reflections ``H_k = I − 2 v_k v_kᵀ`` bring it to tridiagonal form ``T = Qᵀ A Q`` (each a rank-two
    update ``A − v wᵀ − w vᵀ`` with ``w = 2 A v − 2 (vᵀ A v) v``), LAPACK's tridiagonal solver (which calls no
    level-3 BLAS) gives ``T = Z Λ Zᵀ``, and the eigenvectors are ``Q Z``, the reflections applied in reverse.
    Normwise backward stable as LAPACK's own; on a 2-core machine shared with other work it takes tens of
    milliseconds on the 136×136 matrices here where ``numpy.linalg.eigh``'s threads wait for hundreds.
    """
    from scipy.linalg import eigh_tridiagonal  # not needed to import magfit

    a = np.array(matrix, dtype=np.float64, copy=True)
    n = a.shape[0]
    if n < 3:
        values, vectors = np.linalg.eigh(a)
        return np.asarray(values, dtype=np.float64), np.asarray(vectors, dtype=np.float64)
    reflectors: list[NDArray[np.float64] | None] = []
    for k in range(n - 2):
        x = a[k + 1 :, k]
        norm = math.sqrt(float(np.einsum("i,i->", x, x)))
        if norm == 0.0:
            reflectors.append(None)
            continue
        alpha = -math.copysign(norm, float(x[0]))
        v = x.copy()
        v[0] -= alpha
        v /= math.sqrt(float(np.einsum("i,i->", v, v)))
        sub = a[k + 1 :, k + 1 :]
        p = np.einsum("ij,j->i", sub, v)
        w = 2.0 * p - 2.0 * float(np.einsum("i,i->", v, p)) * v
        sub -= v[:, None] * w[None, :] + w[:, None] * v[None, :]
        a[k + 1, k] = a[k, k + 1] = alpha
        a[k + 2 :, k] = 0.0
        a[k, k + 2 :] = 0.0
        reflectors.append(v)
    values, z = eigh_tridiagonal(np.diag(a).copy(), np.diag(a, 1).copy())
    for k in range(n - 3, -1, -1):
        v = reflectors[k]
        if v is not None:
            block = z[k + 1 :]
            block -= 2.0 * v[:, None] * np.einsum("i,ij->j", v, block)[None, :]
    return np.asarray(values, dtype=np.float64), np.asarray(z, dtype=np.float64)
