"""find_clipped's one-pass search against the test written on whole columns (the oracle below)."""

from __future__ import annotations

import numpy as np
import pytest

from magfit.saturation import CLIP_RATIO, FULL_SCALE_CODES, MIN_CLIPPED, NEIGHBOURS, find_clipped


def _oracle(samples: np.ndarray) -> tuple[np.ndarray, tuple[tuple[str, float, int], ...]]:
    """The saturation module's test, column by column on every row: the clipped rows and the ends."""
    clipped = np.zeros(samples.shape[0], dtype=bool)
    ends = []
    for axis in range(3):
        column = samples[:, axis]
        if column.max() == column.min():
            continue
        for extreme in (column.max(), column.min()):
            held = column == extreme
            count = int(held.sum())
            inner = column[~held]
            counts = np.unique(inner, return_counts=True)[1]
            neighbours = (counts[::-1] if extreme == column.max() else counts)[:NEIGHBOURS]
            integral = bool(np.all(np.mod(column, 1) == 0))
            is_clipped = count >= 2 and (
                (float(extreme) in FULL_SCALE_CODES and integral)
                or (count >= MIN_CLIPPED and (inner.size == 0 or count >= CLIP_RATIO * float(np.mean(neighbours))))
            )
            if is_clipped:
                clipped |= held
                ends.append(("xyz"[axis], float(extreme), count))
    return clipped, tuple(ends)


def sensor_samples(seed: int, sizes: tuple[int, ...]) -> np.ndarray:
    """A sensor's samples of a size drawn from ``sizes``, by ``seed % 5``: integer counts in floats, an int16
    sensor, clipped at a range of its own, clipped at a 16-bit full-scale code, or coarse float32 steps."""
    rng = np.random.default_rng(seed)
    n = int(rng.choice(sizes))
    directions = rng.normal(size=(n, 3))
    directions /= np.linalg.norm(directions, axis=1)[:, None]
    samples = directions * rng.uniform(50, 500) + rng.normal(0, 40, 3)
    kind = seed % 5
    if kind == 0:
        return np.round(samples)
    if kind == 1:
        return np.round(samples).astype(np.int16)
    if kind == 2:
        limit = np.round(rng.uniform(0.3, 1.0) * np.abs(samples).max(axis=0))
        return np.clip(np.round(samples), -limit, limit)
    if kind == 3:
        return np.clip(np.round(samples * 60), -32768, 32767).astype(np.int32)
    return np.round(samples / rng.uniform(5, 200)).astype(np.float32)


@pytest.mark.parametrize("seed", range(60))
@pytest.mark.slow
def test_find_clipped_matches_the_whole_column_test(seed: int) -> None:
    samples = sensor_samples(seed, (5, 40, 300, 5_000, 70_000, 150_000))
    if seed % 7 == 0:
        samples[:, seed % 3] = 7  # a dead axis
    found = find_clipped(samples)
    clipped, ends = _oracle(samples)
    assert found.ends == ends
    np.testing.assert_array_equal(found.clipped, clipped)
