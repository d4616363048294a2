"""The body's rotation integrated from the gyro's rates: ``dR/dt = R [ω − β]×`` over each stretch.

Each step ``j`` (samples j to j + 1, ``dt_j`` apart) turns by the mean rate of its two samples,
``φ_j = ((ω_j + ω_{j+1}) / 2 − β) dt_j``, exactly as a rotation of ``|φ_j|`` about ``φ_j``::

    D_j = exp([φ_j]×),    q_j = (cos(|φ_j|/2), sin(|φ_j|/2) φ_j / |φ_j|)                (K1)

and the rotation from a stretch's first sample s to sample k is the ordered product::

    R_k = D_s D_{s+1} … D_{k−1},    so that  v_s = R_k v_k                                 (K2)

(K2) is an inclusive scan under the quaternion product, reset at each stretch's start. It is computed in
blocks of B steps: each block scanned in step order for all blocks at once, then the blocks' own totals
scanned the same way (recursively) and carried into the blocks they lead into. That is O(n) work in about
B log_B(n) vectorised steps, where a prefix doubling (Hillis-Steele) takes n log₂ n. The quaternion product
is associative, so only the rounding differs between orders (a few ulps per step).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

#: Rows per block of the scan: (a) takes this many vectorised steps per level, and there are log_B(n) levels.
_BLOCK = 32


def _quaternion_product(a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    """``a ⊗ b`` (..., 4), scalar first: the rotation ``b`` then ``a`` (``R(a ⊗ b) = R(a) R(b)``)."""
    w1, x1, y1, z1 = a[..., 0], a[..., 1], a[..., 2], a[..., 3]
    w2, x2, y2, z2 = b[..., 0], b[..., 1], b[..., 2], b[..., 3]
    return np.stack([
        w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
        w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
        w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
        w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
    ], axis=-1)  # fmt: skip


def _product(a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    """:func:`_quaternion_product` on components first, (4, ...): every term a contiguous array (the same
    arithmetic, term for term, so the same numbers to the last bit)."""
    w1, x1, y1, z1 = a
    w2, x2, y2, z2 = b
    out = np.empty((4, *np.broadcast_shapes(w1.shape, w2.shape)))
    out[0] = w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2
    out[1] = w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2
    out[2] = w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2
    out[3] = w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2
    return out


def _segmented_scan(q: NDArray[np.float64], start: NDArray[np.bool_]) -> NDArray[np.float64]:
    """Inclusive products ``q_s ⊗ … ⊗ q_k`` (n, 4) from the last ``start`` at or before each k (K2).

    ``start[0]`` is taken as True. See :func:`_scan`, which this runs on the components.
    """
    return _scan(np.ascontiguousarray(q.T), start).T


def _scan(q: NDArray[np.float64], start: NDArray[np.bool_]) -> NDArray[np.float64]:
    """:func:`_segmented_scan` on components first: ``q`` (4, n), the products (4, n).

    Blocks of :data:`_BLOCK` rows: (a) each block scanned in row order, all blocks at once; (b) the blocks' last
    rows, scanned the same way (recursively) with a reset where a block holds a start, give the product that
    runs into each block; (c) that product is put in front of each row whose chain reaches back to its block's
    first row. The blocks are laid out (4, row in block, block), so that each step of (a) reads and writes
    contiguous runs over the blocks.
    """
    n = q.shape[1]
    if n <= _BLOCK:
        out = q.copy()
        for k in range(1, n):
            if not start[k]:
                out[:, k] = _product(out[:, k - 1], out[:, k])
        return out
    blocks = -(-n // _BLOCK)
    padded = np.zeros((4, blocks * _BLOCK))
    padded[0] = 1.0
    padded[:, :n] = q
    flags = np.zeros(blocks * _BLOCK, dtype=bool)
    flags[:n] = start
    flags[0] = True
    rows = np.ascontiguousarray(padded.reshape(4, blocks, _BLOCK).transpose(0, 2, 1))  # (4, _BLOCK, blocks)
    resets = np.ascontiguousarray(flags.reshape(blocks, _BLOCK).T)  # (_BLOCK, blocks)
    for j in range(1, _BLOCK):  # (a)
        product = _product(rows[:, j - 1], rows[:, j])
        rows[:, j] = np.where(resets[j], rows[:, j], product) if resets[j].any() else product
    reaches = ~np.logical_or.accumulate(resets, axis=0)  # the row's chain runs back into the block before
    totals = _scan(rows[:, -1], ~reaches[-1])  # (b): the product up to each block's last row
    inbound = totals[:, None, :-1]
    rows[:, :, 1:] = np.where(reaches[None, :, 1:], _product(inbound, rows[:, :, 1:]), rows[:, :, 1:])  # (c)
    return rows.transpose(0, 2, 1).reshape(4, blocks * _BLOCK)[:, :n]


def _turns(w: NDArray[np.float64], t: NDArray[np.float64], beta: NDArray[np.float64],
           segment: NDArray[np.int64]) -> NDArray[np.float64]:  # fmt: skip
    """R_k (n, 3, 3): the body's rotation from its stretch's first sample to sample k (``v_start = R_k v_k``),
    (K1) and (K2)."""
    start = np.ones(t.size, dtype=bool)
    start[1:] = segment[1:] != segment[:-1]
    return _rotations(0.5 * (w[:-1] + w[1:]), np.diff(t), beta, start)


def _rotations(mean_rates: NDArray[np.float64], dt: NDArray[np.float64], beta: NDArray[np.float64],
               start: NDArray[np.bool_]) -> NDArray[np.float64]:  # fmt: skip
    """:func:`_turns` from the steps' mean rates (n − 1, 3) and lengths (n − 1,) and the stretches' first samples
    (n,): what a trajectory keeps, so that each new bias costs only the integration."""
    n = start.size
    return _rotation_entries(mean_rates, dt, beta, start).T.reshape(n, 3, 3)


def _rotation_entries(mean_rates: NDArray[np.float64], dt: NDArray[np.float64], beta: NDArray[np.float64],
                      start: NDArray[np.bool_]) -> NDArray[np.float64]:  # fmt: skip
    """:func:`_rotations` entry by entry, (9, n), each row contiguous over the samples (row-major R_k)."""
    return _entries(_rotation_quaternions(mean_rates, dt, beta, start))


def _rotation_quaternions(mean_rates: NDArray[np.float64], dt: NDArray[np.float64], beta: NDArray[np.float64],
                          start: NDArray[np.bool_]) -> NDArray[np.float64]:  # fmt: skip
    """The quaternions of :func:`_rotations`, (4, n) components first: (K1), then the scan (K2)."""
    # Component by component (contiguous runs over the steps; the same arithmetic as on the (n − 1, 3) rows).
    phi = (np.ascontiguousarray(mean_rates.T) - np.asarray(beta, dtype=np.float64)[:, None]) * dt
    angle = np.sqrt(phi[0] * phi[0] + phi[1] * phi[1] + phi[2] * phi[2])
    sinc = np.where(angle > 1e-12, np.sin(0.5 * angle) / np.maximum(angle, 1e-300), 0.5)
    n = start.size
    q = np.empty((4, n))
    q[:, 0] = (1.0, 0.0, 0.0, 0.0)
    q[0, 1:] = np.cos(0.5 * angle)
    np.multiply(phi, sinc, out=q[1:, 1:])
    q[:, start] = np.array([[1.0], [0.0], [0.0], [0.0]])  # a stretch starts from itself
    return _scan(q, start)


def _entries(q: NDArray[np.float64]) -> NDArray[np.float64]:
    """The rotation matrices of unit quaternions ``q`` (4, m), entry by entry (9, m) (row-major R)."""
    s, x, y, z = q
    n = q.shape[1]
    xx, yy, zz, xy, xz, yz, sx, sy, sz = x * x, y * y, z * z, x * y, x * z, y * z, s * x, s * y, s * z
    r = np.empty((9, n))
    r[0], r[1], r[2] = 1 - 2 * (yy + zz), 2 * (xy - sz), 2 * (xz + sy)
    r[3], r[4], r[5] = 2 * (xy + sz), 1 - 2 * (xx + zz), 2 * (yz - sx)
    r[6], r[7], r[8] = 2 * (xz - sy), 2 * (yz + sx), 1 - 2 * (xx + yy)
    return r


def _jacobian_steps(entries: NDArray[np.float64], mean_rates: NDArray[np.float64], dt: NDArray[np.float64],
                    beta: NDArray[np.float64]) -> NDArray[np.float64]:  # fmt: skip
    """``R_k J_r(φ_{k−1})`` entry by entry (9, n) (row-major; k = 0 carries R_0): the terms of the bias's exact
    Jacobian, ``δR_k = −[Σ_{j<k} dt_j R_{j+1} J_r(φ_j) δβ]× R_k``, with the right Jacobian of (K1)::

        exp([φ + δφ]×) = exp([φ]×) exp([J_r(φ) δφ]×),   J_r(φ) = I − a [φ]× + b [φ]×²,
        a = (1 − cos θ) / θ²,  b = (θ − sin θ) / θ³,  θ = |φ|                                     (K3)

    Row by row, ``r [φ]× = r × φ``.
    """
    phi = np.zeros((3, entries.shape[1]))
    phi[:, 1:] = (np.ascontiguousarray(mean_rates.T) - np.asarray(beta, dtype=np.float64)[:, None]) * dt
    theta2 = phi[0] * phi[0] + phi[1] * phi[1] + phi[2] * phi[2]
    theta = np.sqrt(theta2)
    small = theta < 1e-3  # the series, where the closed forms lose digits: a and b to θ⁴
    safe = np.where(small, 1.0, theta)
    a = np.where(small, 0.5 - theta2 / 24.0, (1.0 - np.cos(safe)) / (safe * safe))
    b = np.where(small, 1.0 / 6.0 - theta2 / 120.0, (safe - np.sin(safe)) / (safe * safe * safe))
    out = np.empty_like(entries)
    px, py, pz = phi
    for row in range(3):
        rx, ry, rz = entries[3 * row], entries[3 * row + 1], entries[3 * row + 2]
        cx, cy, cz = ry * pz - rz * py, rz * px - rx * pz, rx * py - ry * px  # r × φ
        dx, dy, dz = cy * pz - cz * py, cz * px - cx * pz, cx * py - cy * px  # (r × φ) × φ
        out[3 * row] = rx - a * cx + b * dx
        out[3 * row + 1] = ry - a * cy + b * dy
        out[3 * row + 2] = rz - a * cz + b * dz
    return out


def _unit(angles: NDArray[np.float64]) -> NDArray[np.float64]:
    """Unit vectors (m, 3) from (elevation, azimuth) pairs (m, 2), radians."""
    elevation, azimuth = angles[:, 0], angles[:, 1]
    return np.column_stack(
        [np.cos(elevation) * np.cos(azimuth), np.cos(elevation) * np.sin(azimuth), np.sin(elevation)]
    )
