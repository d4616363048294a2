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


def _segmented_scan(q: NDArray[np.float64], start: NDArray[np.bool_]) -> NDArray[np.float64]:
    """Inclusive products ``q_s ⊗ … ⊗ q_k`` (n, 4) from the last ``start`` at or before each k (K2).

    ``start[0]`` is taken as True. Blocks of :data:`_BLOCK` rows: (a) each block scanned in row order, all
    blocks at once; (b) the blocks' last rows, scanned the same way (recursively) with a reset where a block
    holds a start, give the product that runs into each block; (c) that product is put in front of each row
    whose chain reaches back to its block's first row.
    """
    n = q.shape[0]
    if n <= _BLOCK:
        out = q.copy()
        for k in range(1, n):
            if not start[k]:
                out[k] = _quaternion_product(out[k - 1], out[k])
        return out
    blocks = -(-n // _BLOCK)
    padded = np.zeros((blocks * _BLOCK, 4))
    padded[:, 0] = 1.0
    padded[:n] = q
    flags = np.zeros(blocks * _BLOCK, dtype=bool)
    flags[:n] = start
    flags[0] = True
    rows = padded.reshape(blocks, _BLOCK, 4)
    resets = flags.reshape(blocks, _BLOCK)
    for j in range(1, _BLOCK):  # (a)
        product = _quaternion_product(rows[:, j - 1], rows[:, j])
        rows[:, j] = np.where(resets[:, j, None], rows[:, j], product) if resets[:, j].any() else product
    reaches = ~np.logical_or.accumulate(resets, axis=1)  # the row's chain runs back into the block before
    totals = _segmented_scan(rows[:, -1], ~reaches[:, -1])  # (b): the product up to each block's last row
    inbound = np.broadcast_to(totals[:-1, None, :], (blocks - 1, _BLOCK, 4))
    rows[1:] = np.where(reaches[1:, :, None], _quaternion_product(inbound, rows[1:]), rows[1:])  # (c)
    return padded[:n]


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
    phi = (mean_rates - beta) * dt[:, None]
    angle = np.linalg.norm(phi, axis=1)
    sinc = np.where(angle > 1e-12, np.sin(0.5 * angle) / np.maximum(angle, 1e-300), 0.5)
    n = start.size
    q = np.empty((n, 4))
    q[0] = (1.0, 0.0, 0.0, 0.0)
    q[1:, 0] = np.cos(0.5 * angle)
    q[1:, 1:] = phi * sinc[:, None]
    q[start] = (1.0, 0.0, 0.0, 0.0)  # a stretch starts from itself
    s, x, y, z = np.ascontiguousarray(_segmented_scan(q, start).T)
    xx, yy, zz, xy, xz, yz, sx, sy, sz = x * x, y * y, z * z, x * y, x * z, y * z, s * x, s * y, s * z
    # Entry by entry, each contiguous over the samples: the (n, 3, 3) view's running sums over the samples (the
    # caller's) then walk memory in order.
    r = np.empty((9, n))
    r[0], r[1], r[2] = 1 - 2 * (yy + zz), 2 * (xy - sz), 2 * (xz + sy)
    r[3], r[4], r[5] = 2 * (xy + sz), 1 - 2 * (xx + zz), 2 * (yz - sx)
    r[6], r[7], r[8] = 2 * (xz - sy), 2 * (yz + sx), 1 - 2 * (xx + yy)
    return r.T.reshape(n, 3, 3)


def _unit(angles: NDArray[np.float64]) -> NDArray[np.float64]:
    """Unit vectors (m, 3) from (elevation, azimuth) pairs (m, 2), radians."""
    elevation, azimuth = angles[:, 0], angles[:, 1]
    return np.column_stack(
        [np.cos(elevation) * np.cos(azimuth), np.cos(elevation) * np.sin(azimuth), np.sin(elevation)]
    )
