"""examples/dask_fit.py runs, and its distributed statistics equal the statistics of all samples together."""

from __future__ import annotations

import importlib.util
from pathlib import Path
from types import ModuleType

import numpy as np
import pytest

import magfit

pytest.importorskip("dask.array", reason="dask is not installed (pip install 'magfit[dask]')")

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "dask_fit.py"


@pytest.fixture(scope="module")
def example() -> ModuleType:
    spec = importlib.util.spec_from_file_location("dask_fit", EXAMPLE)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_example_runs_and_recovers_the_simulated_offset(
    example: ModuleType, capsys: pytest.CaptureFixture[str]
) -> None:
    assert example.main(["--samples", "60000", "--partitions", "7", "--scheduler", "synchronous"]) == 0
    out = capsys.readouterr().out
    assert "60000 samples in 7 partitions" in out
    assert "truth   [-130. -177. -175.] counts" in out
    offset = np.array([float(v) for v in out.split("offset  [")[1].split("]")[0].split()])
    # 60 000 samples with noise 6.4 counts: the offset's standard error is about 0.1 count per axis.
    np.testing.assert_allclose(offset, [-130.0, -177.0, -175.0], atol=1.0)


@pytest.mark.parametrize("fan_in", [2, 3])
def test_distributed_statistics_equal_those_of_the_concatenated_samples(example: ModuleType, fan_in: int) -> None:
    samples = example.simulated_samples(20_000, partitions=5, seed=3)
    merged = example.distributed_statistics(samples, scheduler="threads", fan_in=fan_in)
    whole = samples.compute()
    assert merged.n == 20_000
    for method in ("ellipsoid", "sphere"):  # the sphere cannot describe the steel case: forced, both ways
        a, b = (magfit.fit(data, method, allow_undetermined=True) for data in (merged, whole))
        # Round-off only (see tests/test_statistics.py): 1e-9 of the field radius.
        np.testing.assert_allclose(a.offset, b.offset, rtol=0, atol=1e-9 * b.field_strength)
        scale = np.linalg.norm(b.ellipsoid_matrix)
        np.testing.assert_allclose(a.ellipsoid_matrix, b.ellipsoid_matrix, rtol=0, atol=1e-9 * scale)


def test_a_badly_chunked_array_is_refused(example: ModuleType) -> None:
    import dask.array as da

    columns_split = da.zeros((100, 3), chunks=(50, 2))
    with pytest.raises(magfit.SampleError, match="chunked along rows only"):
        example.distributed_statistics(columns_split)
