"""The joint equations of the vector fit with the accelerometer: (3) and (4) of :mod:`.method` in the 13 unknowns
``p = (M row 0, c₀, M row 1, c₁, M row 2, c₂, s)``, summed into normal equations over any subset of samples.

(3) is taken in the frame of ``r_k``: radial component ``r̂_k · (M raw_k − c) = |r_k|`` (free of the
attitude's error) and two tangential components (which carry it), weighted ``w = 1 / (σ² κ)`` each
(:func:`_vector_weights`, :func:`_inflation`: κ the batch means' excess over independent errors). The noise
in the regressors (the magnetometer's in ``raw``, the accelerometer's in ``d``) adds ``E[xxᵀ]`` terms to the
normal matrix that least squares would take as signal; they are taken off (adjusted least squares,
:meth:`_Equations.normal`), the noises from third differences of the samples: a third difference of white
noise has variance 20 σ² (:func:`_noise_sigma`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

#: Contiguous batches for the noise inflation of each kind of equation (the weights).
WEIGHT_BATCHES = 20


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
    radial component's own weight ``1 / (σ² κ)`` (module docstring)."""
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
