"""A file thinned to max_samples bins a strided pool of rows, and every row when the pool would be uneven.

No timings here (they belong in benchmarks/speed.py): these tests check that the cheap path gives the
subsample, and the calibration, that binning every row gives, within the stated bound.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import magfit
import magfit.sampling
from magfit.pipeline import streaming

N = 24_000
LIMIT = 3_000  # a pool step of N // (2 * LIMIT) = 4


def _csv(path: Path, samples: np.ndarray) -> Path:
    np.savetxt(path, samples, delimiter=",", header="mx,my,mz", comments="", fmt="%.2f")
    return path


def _fit(path: Path, monkeypatch: pytest.MonkeyPatch, *, pool: int | None = None) -> tuple[Any, list[int]]:
    """fit_samples_file with ml, --max-samples LIMIT; the pool steps the sampler was run with."""
    steps: list[int] = []
    original = streaming._every

    def every(chunks: Any, step: int) -> Any:
        steps.append(step)
        return original(chunks, step)

    with monkeypatch.context() as patch:
        patch.setattr(streaming, "_every", every)
        if pool is not None:
            patch.setattr(streaming, "SAMPLE_POOL", pool)
        run = streaming.fit_samples_file(streaming.SamplesFileFit(path, "ml", max_samples=LIMIT))
    return run, steps


@pytest.fixture(scope="module")
def tumble() -> magfit.Simulation:
    return magfit.scenario("mpu9250", "smartphone").simulate(N, seed=4)


@pytest.fixture(scope="module")
def parked() -> magfit.Simulation:
    rng = np.random.default_rng(1)
    attitudes = np.degrees(Rotation.random(N, random_state=rng).as_euler("XYZ"))
    attitudes[: int(0.7 * N)] = attitudes[0]  # 70 % of the recording in one attitude
    return magfit.scenario("mpu9250", "smartphone").simulate(N, seed=5, orientations=attitudes)


def test_a_tumble_is_subsampled_from_the_pool_alone(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, tumble: magfit.Simulation
) -> None:
    path = _csv(tmp_path / "tumble.csv", tumble.samples)
    pooled, steps = _fit(path, monkeypatch)
    assert steps == [N // (2 * LIMIT)]  # one pass over the pool, no fall-back to every row
    assert pooled.subsample is not None and pooled.evaluation.n == N
    every_row, steps = _fit(path, monkeypatch, pool=N)  # step 1: every row binned
    assert steps == [1]
    # Both are ml fits of LIMIT rows of the same recording: each within its noise of the truth.
    for run in (pooled, every_row):
        error = np.linalg.norm(run.calibration.offset - tumble.hard_iron) / tumble.field_strength
        assert error < 0.005


def test_a_parked_recording_falls_back_to_binning_every_row(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, parked: magfit.Simulation
) -> None:
    path = _csv(tmp_path / "parked.csv", parked.samples)
    pooled, steps = _fit(path, monkeypatch)
    assert steps == [N // (2 * LIMIT), 1]  # the pool's sparse directions would have lost rows: every row
    every_row, _ = _fit(path, monkeypatch, pool=N)
    np.testing.assert_array_equal(pooled.calibration.offset, every_row.calibration.offset)
    np.testing.assert_array_equal(pooled.calibration.matrix, every_row.calibration.matrix)


def test_the_pool_deficit_counts_what_the_sparse_directions_lose(parked: magfit.Simulation) -> None:
    # The oracle: bin every row and count, per cell, how many rows the even subsample keeps.
    x = parked.samples
    statistics = magfit.Statistics.from_samples(x)
    centre, shape = magfit.sampling.direction_frame(statistics)
    step = N // (2 * LIMIT)

    def sampler(every: int) -> magfit.sampling.EvenSampler:
        return magfit.sampling.even_subsample_chunks(
            lambda: streaming._every([x[i : i + 5000] for i in range(0, N, 5000)], every),
            centre=centre,
            shape=shape,
            max_samples=LIMIT,
            cap_at_median=False,
        )

    exact, pool = sampler(1), sampler(step)
    cells = exact.cells

    def kept(s: magfit.sampling.EvenSampler) -> np.ndarray:
        return np.bincount(cells.index((s.samples - centre) @ shape.T), minlength=cells.count)

    lost = np.clip(kept(exact) - kept(pool), 0, None).sum()  # rows the pool's subsample misses, per cell
    deficit = streaming._pool_deficit(pool, step)
    assert lost > streaming.POOL_DEFICIT * LIMIT  # this recording does need every row
    assert deficit >= 0.8 * lost  # and the estimate from the pool alone says so (it overstates, up to noise)
