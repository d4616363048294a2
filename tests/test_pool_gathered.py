"""The pool of every k-th row gathered while a file is first read is the pool the spill would give.

A file thinned to ``max_samples`` bins every k-th row (k = rows // (SAMPLE_POOL x limit)). Its rows are now
gathered in pass 1 for the k its estimated rows allow; the fit must be the one made from the spill, bit
for bit, and an estimate that misses k must fall back to the spill.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

import magfit
from magfit.io import sniff
from magfit.pipeline import streaming

N = 24_000
LIMIT = 3_000  # a pool step of N // (2 * LIMIT) = 4


@pytest.fixture(scope="module")
def recording(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, magfit.Simulation]:
    simulation = magfit.scenario("mpu9250", "smartphone").simulate(N, seed=7)
    path = tmp_path_factory.mktemp("pool") / "tumble.csv"
    lines = [f"{10 * i},{x:.3f},{y:.3f},{z:.3f}" for i, (x, y, z) in enumerate(simulation.samples.tolist())]
    lines[100] = "1000,nan,1,2"  # a skipped row: the pool's rows are those of the finite rows
    path.write_text("t,mx,my,mz\n" + "\n".join(lines) + "\n")
    return path, simulation


def _fit(path: Path, monkeypatch: pytest.MonkeyPatch, **constants: Any) -> tuple[Any, list[tuple[int, bool]]]:
    used: list[tuple[int, bool]] = []  # (step, whether the gathered pool was read)
    original = streaming._pooled_rows

    def pooled_rows(source: Any, advance: Any, step: int) -> Any:
        used.append((step, isinstance(source, streaming._Gathered)))
        return original(source, advance, step)

    with monkeypatch.context() as patch:
        patch.setattr(streaming, "_pooled_rows", pooled_rows)
        for name, value in constants.items():
            patch.setattr(streaming, name, value)
        run = streaming.fit_samples_file(streaming.SamplesFileFit(path, "ml", max_samples=LIMIT))
    return run, used


def _same(a: Any, b: Any) -> None:
    np.testing.assert_array_equal(a.calibration.offset, b.calibration.offset)
    np.testing.assert_array_equal(a.calibration.matrix, b.calibration.matrix)
    assert a.evaluation == b.evaluation
    assert a.subsample == b.subsample


def test_the_gathered_pool_fits_as_the_spill_does(
    recording: tuple[Path, magfit.Simulation], monkeypatch: pytest.MonkeyPatch
) -> None:
    path, simulation = recording
    gathered, used = _fit(path, monkeypatch)
    step = (N - 1) // (streaming.SAMPLE_POOL * LIMIT)
    assert used[0] == (step, True)
    from_spill, used = _fit(path, monkeypatch, POOL_GATHER_BYTES=0)
    assert used[0] == (step, False)
    _same(gathered, from_spill)
    error = np.linalg.norm(gathered.calibration.offset - simulation.hard_iron) / simulation.field_strength
    assert error < 0.005


def test_a_missed_estimate_reads_the_spill(
    recording: tuple[Path, magfit.Simulation], monkeypatch: pytest.MonkeyPatch
) -> None:
    path, _ = recording
    # An estimate twice the rows: the pools gathered are for steps 7-8, the step needed is 3 (a spill read).
    missed, used = _fit(path, monkeypatch, _rows_spread=lambda path, fmt: 2 * N)
    assert used[0] == ((N - 1) // (streaming.SAMPLE_POOL * LIMIT), False)
    _same(missed, _fit(path, monkeypatch, POOL_GATHER_BYTES=0)[0])


def test_rows_estimated_from_spread_probes(tmp_path: Path) -> None:
    # Lines that lengthen through the file (a growing time stamp): the head alone overstates the rows.
    n = 400_000
    path = tmp_path / "growing.csv"
    path.write_text("t,mx,my,mz\n" + "".join(f"{i * i},1.5,-2.25,3.125\n" for i in range(n)))
    fmt = sniff(path)
    assert abs(streaming._rows_spread(path, fmt) - n) < 0.01 * n
    assert streaming._rows_in(path, fmt) > 1.05 * n
