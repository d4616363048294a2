"""The pool of every k-th row keeps only its rows, not the chunks they were read from."""

from __future__ import annotations

import gc
import weakref
from collections.abc import Iterator

import numpy as np

from magfit.pipeline.streaming import POOL_BLOCK_ROWS, _every


def test_the_pool_does_not_hold_the_chunks_its_rows_came_from() -> None:
    refs: list[weakref.ref[np.ndarray]] = []
    alive: list[int] = []  # chunks read before still in memory, counted as each new one is read

    def chunks() -> Iterator[np.ndarray]:
        for i in range(40):
            gc.collect()
            alive.append(sum(ref() is not None for ref in refs))
            chunk = np.full((10_000, 3), float(i))
            refs.append(weakref.ref(chunk))
            yield chunk
            del chunk

    step = 100  # 100 rows a chunk: 40 chunks stay below POOL_BLOCK_ROWS, so all are gathered before one block
    assert 40 * 10_000 // step < POOL_BLOCK_ROWS
    blocks = list(_every(chunks(), step))
    assert max(alive) <= 1, f"the kept rows pin the chunks they came from: {max(alive)} of 40 chunks in memory"
    rows = np.concatenate(blocks)
    assert rows.shape == (4000, 3) and np.array_equal(rows[::100, 0], np.arange(40.0))
