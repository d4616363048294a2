"""The residuals shared by the diagnostics, the robust fit and the model choice.

Every calibration maps a raw sample x onto the unit sphere through the symmetric square root L of the
ellipsoid matrix A of eq. (2) (``A = LᵀL = L²``, ``Calibration.ellipsoid_matrix``). Two residuals:

    r(x) = |L (x − V)| − 1                    (corrected-space residual, the paper's section V metric)
    d(x) = r(x) / |L u|,  u = L(x − V) / |L(x − V)|     (first-order distance to the ellipsoid)

r is the signed distance of the corrected sample to the unit sphere (``magfit.sphere_distances``): what a
heading sees, and what the robust fit and the observability analysis use. d is r divided by the norm of
its gradient (Sampson's first-order distance): it measures in the sample space, where the sensor noise is
isotropic, so it is the residual of the maximum-likelihood fit, of the model choice (BIC) and of the
parameter covariance, and it cannot be made small by stretching the ellipsoid along a direction the
samples do not cover.

Three nested models share them, each a parameter vector p in an affine normalised frame
``z = T (x − c)`` (:class:`Frame`: the data centred and scaled, or a calibration's corrected frame):

- ``"sphere"``: p = (v₁, v₂, v₃, l), L = l I                     (paper section III, 4 parameters)
- ``"diag"``:   p = (v₁, v₂, v₃, l₁₁, l₂₂, l₃₃), L diagonal       (offset + axis-aligned scales, 6)
- ``"full"``:   p = (v₁, v₂, v₃, l₁₁, l₂₂, l₃₃, l₁₂, l₁₃, l₂₃)     (paper section II, 9)

L is kept symmetric: that fixes the rotation W·Q that the data cannot see (see ``Calibration``), so
the Jacobian has full rank whenever the data determine the ellipsoid.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from ..calibration import Calibration
from ..errors import CalibrationError
from ..rotations import axis_words as axis_words  # one copy (rotations.py); imported from here by diagnostics

Kind = Literal["sphere", "diag", "full"]
KINDS: tuple[Kind, ...] = ("sphere", "diag", "full")
N_PARAMETERS: dict[str, int] = {"sphere": 4, "diag": 6, "full": 9}
#: Names of the entries of p, for messages and for the covariance layout in ``details``.
PARAMETER_NAMES: dict[str, tuple[str, ...]] = {
    "sphere": ("offset_x", "offset_y", "offset_z", "scale"),
    "diag": ("offset_x", "offset_y", "offset_z", "scale_x", "scale_y", "scale_z"),
    "full": (
        "offset_x",
        "offset_y",
        "offset_z",
        "scale_x",
        "scale_y",
        "scale_z",
        "shear_xy",
        "shear_xz",
        "shear_yz",
    ),
}
_OFF_DIAGONAL = ((0, 1), (0, 2), (1, 2))


@dataclass(frozen=True)
class Frame:
    """An affine normalised frame ``z = T (x − centre)`` (centre in input units, T in 1 / input units).

    :meth:`of` centres and scales the data (``T = I / s``); :meth:`corrected` is the frame in which a
    calibration maps its samples onto the unit sphere (``T = L``): there its own parameters are
    ``v = 0, L = I`` and a perturbation of p reads directly in fractions of the field strength.
    """

    centre: NDArray[np.float64]
    transform: NDArray[np.float64]

    @classmethod
    def of(cls, samples: NDArray[np.float64]) -> Frame:
        centre = samples.mean(axis=0)
        scale = float(np.sqrt(np.mean(np.sum((samples - centre) ** 2, axis=1))))
        return cls(centre, np.eye(3) / (scale if scale > 0 else 1.0))

    @classmethod
    def corrected(cls, calibration: Calibration) -> Frame:
        return cls(np.array(calibration.offset), symmetric_unit_map(calibration))

    def normalise(self, samples: NDArray[np.float64]) -> NDArray[np.float64]:
        return rows_times(np.asarray(samples, dtype=np.float64) - self.centre, self.transform.T)


def rows_times(rows: NDArray[np.float64], matrix: NDArray[np.float64]) -> NDArray[np.float64]:
    """``rows @ matrix`` for rows (N, 3) and a (3, 3) matrix, column by column, shape (N, 3).

    The same numbers as the matrix product, without BLAS: its threads split a product of three columns
    into pieces too small to pay for waking them, and where other processes hold the cores each call
    can wait for a time slice (200 000 rows: 0.2 s instead of 1 ms, measured on a busy 2-core machine).
    """
    rows = np.asarray(rows, dtype=np.float64)
    columns = rows.T
    out = np.empty((3, rows.shape[0]))
    for j in range(3):
        np.multiply(columns[0], matrix[0, j], out=out[j])
        out[j] += columns[1] * matrix[1, j]
        out[j] += columns[2] * matrix[2, j]
    return out.T


def symmetric_unit_map(calibration: Calibration) -> NDArray[np.float64]:
    """L = A^½, the symmetric square root of ``calibration.ellipsoid_matrix`` (input units⁻¹)."""
    return _sqrtm(calibration.ellipsoid_matrix)


def _sqrtm(matrix: NDArray[np.float64]) -> NDArray[np.float64]:
    eigenvalues, eigenvectors = np.linalg.eigh(0.5 * (matrix + matrix.T))
    return np.asarray((eigenvectors * np.sqrt(np.clip(eigenvalues, 0.0, None))) @ eigenvectors.T, dtype=np.float64)


def unit_map(p: NDArray[np.float64], kind: str) -> NDArray[np.float64]:
    """L of the parameter vector p (normalised frame)."""
    if kind == "sphere":
        return np.eye(3) * p[3]
    lmat = np.diag(p[3:6])
    if kind == "full":
        for value, (j, k) in zip(p[6:9], _OFF_DIAGONAL, strict=True):
            lmat[j, k] = lmat[k, j] = value
    return lmat


def parameters(calibration: Calibration, kind: str, frame: Frame) -> NDArray[np.float64]:
    """p of ``calibration`` in ``frame``, projected onto ``kind`` (for a model that is not of that kind,
    the nearest one: the geometric-mean scale for a sphere, the diagonal for ``diag``)."""
    inverse = np.linalg.inv(frame.transform)
    lmat = _sqrtm(inverse.T @ calibration.ellipsoid_matrix @ inverse)  # A_z = T⁻ᵀ A T⁻¹, L_z = A_z^½
    v = frame.transform @ (calibration.offset - frame.centre)
    if kind == "sphere":
        return np.concatenate([v, [float(np.linalg.det(lmat)) ** (1.0 / 3.0)]])
    diagonal = np.diag(lmat)
    if kind == "diag":
        return np.concatenate([v, diagonal])
    return np.concatenate([v, diagonal, [lmat[j, k] for j, k in _OFF_DIAGONAL]])


def _row_norms(vectors: NDArray[np.float64]) -> NDArray[np.float64]:
    """|row| of an (N, 3) array (3x faster than ``np.linalg.norm(axis=1)``, which reduces along strides)."""
    return np.sqrt(np.einsum("ij,ij->i", vectors, vectors))


def residuals(p: NDArray[np.float64], z: NDArray[np.float64], kind: str) -> NDArray[np.float64]:
    """r = |L (z − v)| − 1 for every normalised sample, shape (N,)."""
    return _row_norms(rows_times(z - p[:3], unit_map(p, kind))) - 1.0


def distances(p: NDArray[np.float64], z: NDArray[np.float64], kind: str) -> NDArray[np.float64]:
    """First-order distance of each normalised sample to the ellipsoid, in the units of z, shape (N,).

    ``r / |L u|`` (Sampson's approximation: the residual over the norm of its gradient in z, with
    u = L y / |L y|): unlike r it measures in the sample space, where the noise is isotropic, so it is the
    residual of the maximum-likelihood fit and cannot shrink by stretching the ellipsoid along a direction
    the samples do not cover.
    """
    lmat = unit_map(p, kind)
    w = rows_times(z - p[:3], lmat)
    norm = _row_norms(w)
    return (norm * norm - norm) / _row_norms(rows_times(w, lmat))  # (n − 1) / |L u|, u = w / n


def distances_and_jacobian(
    p: NDArray[np.float64], z: NDArray[np.float64], kind: str
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """:func:`distances` and their Jacobian ∂d/∂p, shape (N, k), from one set of intermediates.

    With y = z − v, w = L y, n = |w| and q = L w = L² y, ``d = (n² − n) / |q|``, so
    ``∂d = ((2n − 1) ∂n − d ∂|q|) / |q|``, where (u = w / n, q̂ = q / |q|):

    - ∂n = ∂r: −L u along the offset, ``u_j y_k + u_k y_j`` along an entry l_jk of L (``u_j y_j`` on the
      diagonal, ``u · y`` for the sphere's single scale);
    - ``∂|q| = q̂ · ∂q``: −L² q̂ along the offset, ``q̂ · (E w + L E y)`` along l_jk (E = e_j e_kᵀ,
      symmetrised), ``2 l |y|`` for the sphere.

    Every column is written in place into one (N, k) array.
    """
    lmat = unit_map(p, kind)
    y = z - p[:3]
    w = rows_times(y, lmat)  # L symmetric: row i is (L y_i)ᵀ
    n = _row_norms(w)
    q = rows_times(w, lmat)
    q_norm = _row_norms(q)
    u = w / np.where(n > 0, n, 1.0)[:, None]
    q_hat = q / np.where(q_norm > 0, q_norm, 1.0)[:, None]
    q_l = rows_times(q_hat, lmat)  # (q̂ᵀ L) per row
    d = (n * n - n) / q_norm
    along_n = (2.0 * n - 1.0) / q_norm  # weight of ∂n in ∂d
    along_q = d / q_norm  # weight of ∂|q| in ∂d (with a minus sign)
    jacobian_matrix = np.empty((z.shape[0], N_PARAMETERS[kind]))
    jacobian_matrix[:, :3] = rows_times(along_q[:, None] * q_l - along_n[:, None] * u, lmat)
    if kind == "sphere":
        jacobian_matrix[:, 3] = along_n * np.einsum("ij,ij->i", u, y) - along_q * 2.0 * p[3] * _row_norms(y)
        return d, jacobian_matrix
    jacobian_matrix[:, 3:6] = along_n[:, None] * (u * y) - along_q[:, None] * (q_hat * w + q_l * y)
    if kind == "full":
        for column, (j, k) in enumerate(_OFF_DIAGONAL, start=6):
            d_n = u[:, j] * y[:, k] + u[:, k] * y[:, j]
            d_q = q_hat[:, j] * w[:, k] + q_hat[:, k] * w[:, j] + q_l[:, j] * y[:, k] + q_l[:, k] * y[:, j]
            jacobian_matrix[:, column] = along_n * d_n - along_q * d_q
    return d, jacobian_matrix


def distance_jacobian(p: NDArray[np.float64], z: NDArray[np.float64], kind: str) -> NDArray[np.float64]:
    """∂d/∂p of :func:`distances`, shape (N, k) (see :func:`distances_and_jacobian`)."""
    return distances_and_jacobian(p, z, kind)[1]


def jacobian(p: NDArray[np.float64], z: NDArray[np.float64], kind: str) -> NDArray[np.float64]:
    """∂r/∂p, shape (N, k): ∂r/∂v = −L u, ∂r/∂l_jk = u_j y_k + u_k y_j (u = L y / |L y|, y = z − v)."""
    lmat = unit_map(p, kind)
    y = z - p[:3]
    w = rows_times(y, lmat)  # L symmetric: row i is (L y_i)ᵀ
    norm = _row_norms(w)
    u = w / np.where(norm > 0, norm, 1.0)[:, None]
    jacobian_matrix = np.empty((z.shape[0], N_PARAMETERS[kind]))
    jacobian_matrix[:, :3] = -rows_times(u, lmat)
    if kind == "sphere":
        jacobian_matrix[:, 3] = np.einsum("ij,ij->i", u, y)
        return jacobian_matrix
    jacobian_matrix[:, 3:6] = u * y
    if kind == "full":
        for column, (j, k) in enumerate(_OFF_DIAGONAL, start=6):
            jacobian_matrix[:, column] = u[:, j] * y[:, k] + u[:, k] * y[:, j]
    return jacobian_matrix


def maximum_likelihood(
    z: NDArray[np.float64],
    model: str,
    starts: list[NDArray[np.float64]],
    *,
    cost_tolerance: float = 1e-6,
    max_iterations: int | None = None,
) -> tuple[float, NDArray[np.float64]]:
    """Minimum of Σ d² (d: first-order distance to the ellipsoid) over ``model``'s parameters, and its p.

    Levenberg–Marquardt (:mod:`magfit._optimize`) from each start, for at most 20 iterations per
    parameter (or ``max_iterations``), until the cost changes by less than ``cost_tolerance`` (relative);
    the best result, never worse than the best start.
    """
    from .._optimize import Evaluation, levenberg_marquardt

    def evaluate(p: NDArray[np.float64], _: object) -> Evaluation:
        with np.errstate(all="ignore"):  # a degenerate trial may overflow; its non-finite cost is refused
            residual, jacobian_matrix = distances_and_jacobian(p, z, model)
        # Σ d² by einsum, not a BLAS dot: OpenBLAS threads a dot of 10⁴ values, and on a busy machine each call
        # waits for the woken thread (median 14 ms on 20 000 rows against 0.02 ms, measured on 2 shared cores).
        return Evaluation(
            0.5 * float(np.einsum("n,n->", residual, residual)),
            jacobian_matrix.T @ jacobian_matrix,
            jacobian_matrix.T @ residual,
        )

    best: tuple[float, NDArray[np.float64]] | None = None
    for start in starts:
        # The reference fits need the cost to a part in a million (BIC, consistency), not to round-off: the
        # looser stop ends the long crawls of a model that cannot describe the data (a sphere on steel).
        solution = levenberg_marquardt(
            evaluate,
            start,
            n_residuals=z.shape[0],
            max_iterations=max_iterations or 20 * start.size,
            cost_tolerance=cost_tolerance,
        )
        for candidate in (solution.params, start):
            with np.errstate(all="ignore"):
                value = float(np.sum(distances(candidate, z, model) ** 2))
            if np.isfinite(value) and (best is None or value < best[0]):
                best = (value, np.asarray(candidate, dtype=np.float64))
    if best is None:
        raise CalibrationError(f"the {model} model has no finite distances to these samples")
    return best


def calibration_from_parameters(
    p: NDArray[np.float64],
    kind: str,
    frame: Frame,
    method: str,
    *,
    n_samples: int | None = None,
    details: Mapping[str, Any] | None = None,
) -> Calibration:
    """The calibration of p: offset ``c + T⁻¹ v``, ellipsoid matrix ``Tᵀ L² T``, ``det(matrix) = 1``."""
    from .quadric import calibration_from_ellipsoid

    lmat = unit_map(p, kind)
    eigenvalues = np.linalg.eigvalsh(lmat)
    if not eigenvalues[0] > 1e-9 * abs(eigenvalues[-1]):
        raise CalibrationError(
            f"the {kind} model degenerated during the fit (a scale went to zero or below): the samples do "
            "not outline an ellipsoid; rotate the sensor through more attitudes"
        )
    offset = frame.centre + np.linalg.solve(frame.transform, p[:3])
    shape = frame.transform.T @ lmat @ lmat @ frame.transform  # A_x = Tᵀ L² T
    return calibration_from_ellipsoid(method, offset, shape, n_samples=n_samples, details=details)


def describe_parameter_direction(vector: NDArray[np.float64], kind: str) -> str:
    """Name the combination of parameters an eigenvector of the information matrix moves.

    E.g. ``"the offset along z together with the scale along z"``: the parameters whose share of the
    (unit) vector is at least 20 %, largest first.
    """
    names = PARAMETER_NAMES[kind]
    weights = vector**2 / float(np.sum(vector**2))
    order = [int(i) for i in np.argsort(weights)[::-1] if weights[i] >= 0.2] or [int(np.argmax(weights))]
    return " together with ".join(_parameter_words(names[i]) for i in order)


def _parameter_words(name: str) -> str:
    if name == "scale":
        return "the field strength (overall scale)"
    family, axis = name.split("_")
    if family == "offset":
        return f"the offset along {axis}"
    if family == "scale":
        return f"the scale along {axis}"
    return f"the {axis[0]}-{axis[1]} cross-coupling of the soft-iron matrix"
