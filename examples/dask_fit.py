"""Distributed calibration with Dask: one Statistics per partition, merged by a tree reduction, one fit.

    pip install "magfit[dask]"
    python examples/dask_fit.py --samples 20000000 --partitions 40

The samples never meet in one place. Each partition of a Dask array of samples, shape (N, 3), is reduced
where it lives to a :class:`magfit.Statistics` (a 10x10 matrix and a few numbers, about 1 kB); only
those travel, and they merge exactly (the merged statistics equal those of the concatenated samples to
round-off). The linear methods (``ellipsoid``, ``sphere``, ``als``, ``diag``, ``minmax``) then fit the
merged statistics as if they had seen every sample. Here the partitions are simulated lazily from the
paper's MPU-9250 + steel scenario, so the result can be checked against the truth; in practice they
would come from ``dask.array.from_zarr``, ``dask.dataframe.read_csv(...).to_dask_array(lengths=True)``
or any other chunked source.
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

import magfit

SCENARIO = ("mpu9250", "steel")


def simulated_partition(size: int, seed: int) -> NDArray[np.float64]:
    """One partition of raw samples, shape (size, 3), counts (the paper's scenario, its own seed)."""
    return magfit.scenario(*SCENARIO).simulate(size, seed=seed).samples


def simulated_samples(n: int, partitions: int, seed: int = 0):  # -> dask.array.Array
    """A lazy (n, 3) Dask array whose partitions are simulated only when a worker computes them."""
    import dask
    import dask.array as da

    sizes = [n // partitions + (1 if i < n % partitions else 0) for i in range(partitions)]
    blocks = [
        da.from_delayed(dask.delayed(simulated_partition)(size, seed + i), shape=(size, 3), dtype=np.float64)
        for i, size in enumerate(sizes)
    ]
    return da.concatenate(blocks, axis=0)


def distributed_statistics(samples, *, scheduler: str = "threads", fan_in: int = 2) -> magfit.Statistics:
    """Statistics of a Dask array of samples (N, 3): per partition, then merged ``fan_in`` at a time.

    Parameters
    ----------
    samples : dask.array.Array, shape (N, 3)
        Chunked along rows only (one chunk across the three columns).
    scheduler : str
        Any Dask scheduler name ("threads", "processes", "synchronous") or a distributed Client's.
    fan_in : int
        How many statistics each merge task combines (a tree of depth log_fan_in(partitions)).
    """
    import dask

    if samples.ndim != 2 or samples.shape[1] != 3 or len(samples.chunks[1]) != 1:
        raise magfit.SampleError(f"samples must be a Dask array (N, 3) chunked along rows only, got {samples}")
    # map: one Statistics per partition, computed where the partition lives.
    level = [dask.delayed(magfit.Statistics.from_samples)(block) for block in samples.to_delayed().ravel()]
    # reduce: a tree of merges, so no single task receives every partition's statistics.
    while len(level) > 1:
        level = [dask.delayed(_merge_all)(level[i : i + fan_in]) for i in range(0, len(level), fan_in)]
    (statistics,) = dask.compute(level[0], scheduler=scheduler)
    return statistics


def _merge_all(parts: Sequence[magfit.Statistics]) -> magfit.Statistics:
    merged = parts[0]
    for part in parts[1:]:
        merged = merged.merge(part)
    return merged


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--samples", type=int, default=2_000_000, help="number of samples (default 2e6)")
    parser.add_argument("--partitions", type=int, default=16, help="number of Dask partitions (default 16)")
    parser.add_argument("--scheduler", default="threads", help="Dask scheduler (threads, processes, synchronous)")
    parser.add_argument("--method", default="ellipsoid", help="a linear magfit method (default ellipsoid)")
    args = parser.parse_args(argv)

    samples = simulated_samples(args.samples, args.partitions)
    start = time.perf_counter()
    statistics = distributed_statistics(samples, scheduler=args.scheduler)
    calibration = magfit.fit(statistics, args.method)
    elapsed = time.perf_counter() - start

    truth = magfit.scenario(*SCENARIO).simulate(1).truth
    shape_error = np.linalg.norm(calibration.ellipsoid_matrix - truth.ellipsoid_matrix) / np.linalg.norm(
        truth.ellipsoid_matrix
    )
    print(f"{statistics.n} samples in {args.partitions} partitions, {args.scheduler} scheduler: {elapsed:.2f} s")
    print(f"offset  {np.array2string(calibration.offset, precision=2)} counts")
    print(f"truth   {np.array2string(truth.offset, precision=2)} counts")
    print(f"ellipsoid shape A: relative error {shape_error:.1e}")
    print(f"matrix  (corrected = matrix @ (raw - offset))\n{np.array2string(calibration.matrix, precision=4)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
