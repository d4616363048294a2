"""Even sampling: equal-area cells, the cap, streaming == in memory, and the pull of a long stay removed."""

from __future__ import annotations

import math
import re
import tempfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

import magfit
from magfit import OptionError, SampleError
from magfit.sampling import EvenSampler, SphereCells, direction_frame, even_subsample, even_subsample_chunks


def stay_simulation(seed: int, n: int = 5000, stay: float = 0.8) -> magfit.Simulation:
    """The paper's steel scenario, but ``stay`` of the samples taken in one attitude (parked, then tumbled)."""
    rng = np.random.default_rng(seed)
    attitudes = np.degrees(Rotation.random(n, random_state=rng).as_euler("XYZ"))
    attitudes[: int(stay * n)] = attitudes[0]
    return magfit.scenario("mpu9250", "steel").simulate(n, seed=seed, orientations=attitudes)


# ---------------------------------------------------------------------- the cells


@pytest.mark.parametrize("count", [3, 4, 10, 100, 400, 1000, 5000])
def test_cells_have_exactly_equal_areas(count: int) -> None:
    cells = SphereCells.make(count)
    assert cells.count == count
    # Archimedes: the area between heights z₁ < z₀ is 2π (z₀ − z₁); a band's sectors share it equally.
    areas = 2.0 * math.pi * -np.diff(cells.z_edges) / cells.sectors
    np.testing.assert_allclose(areas, 4.0 * math.pi / count, rtol=1e-12)
    assert cells.z_edges[0] == 1.0 and cells.z_edges[-1] == -1.0


def test_cells_are_roughly_square() -> None:
    # Leopardi's construction keeps each cell about as tall (in colatitude) as it is wide.
    cells = SphereCells.make(400)
    colatitude = np.arccos(np.clip(cells.z_edges, -1, 1))
    middle = 0.5 * (colatitude[1:-2] + colatitude[2:-1])
    height = np.diff(colatitude)[1:-1]
    width = 2 * math.pi * np.sin(middle) / cells.sectors[1:-1]
    assert np.all((width / height > 0.5) & (width / height < 2.0))


def test_uniform_directions_fill_the_cells_evenly() -> None:
    cells = SphereCells.make(400)
    counts = np.bincount(cells.index(np.random.default_rng(0).normal(size=(400_000, 3))), minlength=400)
    # 1000 per cell expected, Poisson standard deviation 32: all within 5 sigma.
    assert counts.min() > 1000 - 5 * 32 and counts.max() < 1000 + 5 * 32


def test_index_puts_each_direction_in_its_band_and_sector() -> None:
    cells = SphereCells.make(100)
    directions = np.random.default_rng(1).normal(size=(5000, 3)) * 7.5  # any length
    index = cells.index(directions)
    band = np.searchsorted(cells.first, index, side="right") - 1
    unit = directions / np.linalg.norm(directions, axis=1, keepdims=True)
    assert np.all(unit[:, 2] <= cells.z_edges[band] + 1e-15)
    assert np.all(unit[:, 2] >= cells.z_edges[band + 1] - 1e-15)
    longitude = np.mod(np.arctan2(unit[:, 1], unit[:, 0]), 2 * math.pi)
    sector = index - cells.first[band]
    width = 2 * math.pi / cells.sectors[band]
    assert np.all((longitude >= sector * width - 1e-12) & (longitude <= (sector + 1) * width + 1e-12))


@pytest.mark.parametrize("count", [2, 0, 2.5, True])
def test_bad_cell_count(count: object) -> None:
    with pytest.raises(OptionError, match="cells must be an integer >= 3"):
        SphereCells.make(count)  # type: ignore[arg-type]


# ---------------------------------------------------------------------- the pull of a long stay


def _forced(samples: np.ndarray, method: str) -> magfit.Calibration:
    return magfit.fit(samples, method, allow_undetermined=True, diagnostics=False)


@pytest.mark.slow
def test_thinning_removes_the_pull_of_a_long_stay() -> None:
    # 80 % of the samples in one attitude. Ground truth: the simulated offset. Over 8 recordings the
    # thinned fits land closer to it: the ellipsoid fit by a factor 2.2 on average (0.0114 -> 0.0051 of
    # the field over 10 seeds), the sphere fit (whose model error the stay amplifies) by a factor 12.
    # The bounds below leave room for the spread between seeds (about 30 % of the mean).
    raw = {"ellipsoid": [], "sphere": []}
    thinned = {"ellipsoid": [], "sphere": []}
    for seed in range(8):
        sim = stay_simulation(seed)
        kept = even_subsample(sim.samples)
        assert np.count_nonzero(kept < 4000) < 60  # the 4000 samples of the stay share one or two cells
        for method in raw:  # the sphere cannot describe the steel case: forced, to measure the stay's pull
            raw[method].append(np.linalg.norm(_forced(sim.samples, method).offset - sim.hard_iron))
            thinned[method].append(np.linalg.norm(_forced(sim.samples[kept], method).offset - sim.hard_iron))
    radius = magfit.scenario("mpu9250", "steel").field_strength
    assert np.mean(thinned["ellipsoid"]) < 0.6 * np.mean(raw["ellipsoid"])
    assert np.mean(thinned["ellipsoid"]) < 0.007 * radius
    assert np.mean(thinned["sphere"]) < 0.2 * np.mean(raw["sphere"])


def test_an_even_recording_is_hardly_thinned_and_fits_as_well() -> None:
    sim = magfit.scenario("mpu9250", "steel").simulate(5000, seed=4)
    kept = even_subsample(sim.samples)
    # Cell counts of a uniform tumble scatter (Poisson, about 12 per cell) around their median: capping
    # at the median drops the excess of the fuller half only.
    assert kept.size > 0.8 * 5000
    whole = np.linalg.norm(magfit.fit(sim.samples).offset - sim.hard_iron)
    part = np.linalg.norm(magfit.fit(sim.samples[kept]).offset - sim.hard_iron)
    # The offset's noise std is about 0.001 of the field (1.6 counts) here; thinning must not add more.
    assert part < whole + 0.003 * sim.field_strength


# ---------------------------------------------------------------------- the cap and the budget


def test_max_samples_caps_every_cell_with_the_largest_cap_that_fits() -> None:
    sim = stay_simulation(1)
    centre, shape = sim.truth.offset, sim.truth.matrix
    kept = even_subsample(sim.samples, max_samples=700, centre=centre, shape=shape, cells=200)
    assert kept.size <= 700
    cells = SphereCells.make(200)
    cell = cells.index((sim.samples - centre) @ shape.T)
    counts = np.bincount(cell, minlength=200)
    taken = np.bincount(cell[kept], minlength=200)
    cap = taken.max()
    np.testing.assert_array_equal(taken, np.minimum(counts, cap))  # cells below the cap keep everything
    assert np.minimum(counts, cap + 1).sum() > 700  # one more per cell would not fit


def test_everything_is_kept_when_the_budget_allows() -> None:
    samples = magfit.scenario("ellipse2a", "none").simulate(300, seed=2).samples
    np.testing.assert_array_equal(even_subsample(samples, max_samples=300), np.arange(300))


def test_indices_are_increasing_unique_and_repeatable() -> None:
    samples = stay_simulation(2).samples
    first = even_subsample(samples, seed=5)
    assert np.all(np.diff(first) > 0) and first[0] >= 0 and first[-1] < len(samples)
    np.testing.assert_array_equal(first, even_subsample(samples, seed=5))
    assert not np.array_equal(first, even_subsample(samples, seed=6))  # the stay cell's picks change


@settings(max_examples=10, deadline=None)
@given(chunk=st.integers(min_value=1, max_value=3000), budget=st.integers(min_value=1, max_value=3000))
def test_streaming_keeps_exactly_what_the_whole_array_keeps(chunk: int, budget: int) -> None:
    samples = stay_simulation(3, n=3000).samples
    centre = np.array([-130.0, -177.0, -175.0])
    sampler = EvenSampler(budget, centre=centre, cells=100, seed=9)
    for start in range(0, len(samples), chunk):
        sampler.update(samples[start : start + chunk])
    filled = int(np.count_nonzero(sampler._counts))
    if budget < filled:  # fewer than one per filled cell: refused, not an empty subsample
        with pytest.raises(OptionError, match="fewer than the .* cells of directions the samples fill"):
            even_subsample(samples, max_samples=budget, centre=centre, cells=100, seed=9)
        return
    expected = even_subsample(samples, max_samples=budget, centre=centre, cells=100, seed=9)
    np.testing.assert_array_equal(sampler.indices, expected)
    np.testing.assert_array_equal(sampler.samples, samples[expected])
    assert sampler.seen == 3000 and len(sampler.indices) <= budget


@pytest.mark.parametrize("max_samples", [None, 150])
def test_chunked_stream_keeps_what_the_whole_array_keeps(max_samples: int | None) -> None:
    samples = stay_simulation(4, n=3000).samples
    centre, shape = np.array([-130.0, -177.0, -175.0]), np.diag([1 / 200, 1 / 700, 1 / 1300])

    def chunks() -> list[np.ndarray]:
        return [samples[start : start + 700] for start in range(0, 3000, 700)]

    sampler = even_subsample_chunks(chunks, centre=centre, shape=shape, max_samples=max_samples, cells=100)
    expected = even_subsample(samples, centre=centre, shape=shape, cells=100)
    if max_samples is not None:  # the median cap, then at most 150: the densest cells give way first
        assert len(expected) > 150
        within = even_subsample(samples, max_samples=150, centre=centre, shape=shape, cells=100)
        np.testing.assert_array_equal(sampler.indices, within)
    else:
        np.testing.assert_array_equal(sampler.indices, expected)
    np.testing.assert_array_equal(sampler.samples, samples[sampler.indices])


def test_chunked_stream_without_the_median_cap_keeps_everything_that_fits() -> None:
    samples = stay_simulation(5, n=2000).samples
    sampler = even_subsample_chunks(lambda: [samples], centre=np.zeros(3), max_samples=2000, cap_at_median=False)
    np.testing.assert_array_equal(sampler.indices, np.arange(2000))
    with pytest.raises(OptionError, match="max_samples is required when cap_at_median is false"):
        even_subsample_chunks(lambda: [samples], centre=np.zeros(3), cap_at_median=False)


def test_planar_samples_fall_back_to_the_quantile_frame() -> None:
    # Level turns only: no ellipsoid fit, so the directions start from the mid-range of the samples.
    attitudes = np.zeros((2000, 3))
    attitudes[:, 2] = np.linspace(-180, 180, 2000)
    attitudes[:1500, 2] = 30.0  # a long stay at one heading
    sim = magfit.simulate(2000, hard_iron=[50.0, -20.0, 5.0], noise=0.01, orientations=attitudes, seed=0)
    with pytest.raises(magfit.CalibrationError):
        magfit.fit(sim.samples)
    kept = even_subsample(sim.samples, cells=100)
    # The stay weighed 75 % of the samples; the noise across the flat axis still spreads it over a few
    # cells (about a third of the kept samples: a few caps' worth), but it no longer dominates.
    assert np.count_nonzero(kept < 1500) < 0.35 * kept.size
    assert np.count_nonzero(kept >= 1500) > 0.6 * 500


# ---------------------------------------------------------------------- errors


def test_bad_arguments_are_refused() -> None:
    samples = np.random.default_rng(0).normal(size=(50, 3))
    with pytest.raises(OptionError, match="max_samples must be a positive integer, got 0"):
        even_subsample(samples, max_samples=0)
    with pytest.raises(OptionError, match=r"centre must be 3 finite numbers \(x, y, z\), got \[1.0, 2.0\]"):
        even_subsample(samples, centre=[1.0, 2.0])
    with pytest.raises(OptionError, match="shape must be an invertible, finite 3x3 matrix"):
        even_subsample(samples, centre=[0.0, 0.0, 0.0], shape=np.zeros((3, 3)))
    with pytest.raises(SampleError, match=r"at least one row, got shape \(0, 3\)"):
        even_subsample(np.empty((0, 3)))
    with pytest.raises(SampleError, match="pass samples.T"):
        even_subsample(samples.T)
    bad = samples.copy()
    bad[7, 0] = np.nan
    with pytest.raises(SampleError, match="the first is row 7"):
        even_subsample(bad)


# ---------------------------------------------------------------------- docs/scaling.md


def test_the_scaling_guide_examples_run_and_print_what_it_says(capsys: pytest.CaptureFixture[str]) -> None:
    guide = Path(__file__).resolve().parents[1] / "docs" / "scaling.md"
    blocks = re.findall(r"```python\n(.*?)```", guide.read_text(encoding="utf-8"), flags=re.DOTALL)
    assert len(blocks) >= 4
    namespace: dict[str, object] = {}
    for block in blocks:
        exec(compile(block, str(guide), "exec"), namespace)
    printed = capsys.readouterr().out.splitlines()
    # Each print carries its output in a comment: the guide must show what the code prints.
    expected = [
        "[-130.  -176.9 -174.9]",
        "30000",
        "30000 [-130.  -176.9 -174.9]",
        "854 8",
        "all 0.0362",
        "even 0.0039",
    ]
    assert printed == expected
    text = guide.read_text(encoding="utf-8")
    for line in expected:
        assert line in text, f"docs/scaling.md does not show the printed {line!r}"


def test_direction_frame_from_statistics() -> None:
    # A tumble: the frame is the ellipsoid fit's. Level turns only: the min/max box, flat axis floored.
    sim = magfit.scenario("mpu9250", "steel").simulate(3000, seed=6)
    centre, shape = direction_frame(magfit.Statistics.from_samples(sim.samples))
    fitted = magfit.fit(sim.samples)
    np.testing.assert_allclose(centre, fitted.offset, rtol=1e-12)
    np.testing.assert_allclose(shape, fitted.matrix, rtol=1e-12)
    attitudes = np.zeros((500, 3))
    attitudes[:, 2] = np.linspace(-180, 180, 500)
    level = magfit.simulate(500, hard_iron=[5.0, 0.0, 0.0], orientations=attitudes, seed=1).samples
    centre, shape = direction_frame(magfit.Statistics.from_samples(level))
    low, high = level.min(axis=0), level.max(axis=0)
    np.testing.assert_allclose(centre, 0.5 * (low + high))
    widest = 0.5 * float(np.max(high - low))
    np.testing.assert_allclose(np.diag(shape), 1.0 / np.maximum(0.5 * (high - low), 0.1 * widest))


# ---------------------------------------------------------------------- magfit calibrate --even / --max-samples


@pytest.fixture(scope="module")
def parked_csv(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, magfit.Simulation]:
    """A 20 000-row CSV, 80 % of it parked in one attitude, MPU-9250 beside a smartphone (mild soft iron)."""
    rng = np.random.default_rng(0)
    attitudes = np.degrees(Rotation.random(20_000, random_state=rng).as_euler("XYZ"))
    attitudes[:16_000] = attitudes[0]
    sim = magfit.scenario("mpu9250", "smartphone").simulate(20_000, seed=0, orientations=attitudes)
    path = tmp_path_factory.mktemp("parked") / "parked.csv"
    np.savetxt(path, sim.samples, delimiter=",", header="mx,my,mz", comments="", fmt="%.1f")
    return path, sim


def _calibrate(*args: str) -> tuple[str, magfit.Calibration]:
    click_testing = pytest.importorskip("click.testing", reason="the cli extra (click) is not installed")
    from magfit.cli import cli

    with tempfile.TemporaryDirectory() as folder:
        output = Path(folder) / "cal.json"
        result = click_testing.CliRunner().invoke(cli, ["calibrate", *args, "-o", str(output)])
        assert result.exit_code == 0, result.output
        return result.stdout, magfit.Calibration.from_json(output.read_text())


def test_calibrate_even_removes_the_pull_of_the_stay(parked_csv: tuple[Path, magfit.Simulation]) -> None:
    path, sim = parked_csv
    plain_out, plain = _calibrate(str(path), "-m", "sphere")
    even_out, even = _calibrate(str(path), "-m", "sphere", "--even")
    assert "fitted on" not in plain_out
    assert re.search(r"fitted on\s+an even subsample: \d+ of 20000 samples \(--even\)", even_out)
    # The sphere fit's offset error is about 3.5 % of the field on all samples and below 0.1 % on the even
    # subsample (the docs/scaling.md recording, 4x longer); the score still covers every sample.
    plain_error = np.linalg.norm(plain.offset - sim.hard_iron) / sim.field_strength
    even_error = np.linalg.norm(even.offset - sim.hard_iron) / sim.field_strength
    assert even_error < 0.3 * plain_error and even_error < 0.006
    assert "n = 20000" in even_out


def test_calibrate_fits_an_even_subsample_when_the_file_exceeds_max_samples(
    parked_csv: tuple[Path, magfit.Simulation], monkeypatch: pytest.MonkeyPatch
) -> None:
    if "ml" not in magfit.METHODS:
        pytest.skip("the ml method is not registered")
    path, sim = parked_csv

    def no_whole_file(*args: object, **kwargs: object) -> None:
        raise AssertionError("a file above --max-samples must be streamed, not loaded whole")

    monkeypatch.setattr(magfit.io, "read_samples", no_whole_file)
    out, cal = _calibrate(str(path), "-m", "ml", "--max-samples", "3000")
    match = re.search(r"fitted on\s+an even subsample: (\d+) of 20000 samples \(the file has more rows than", out)
    assert match and 2000 < int(match.group(1)) <= 3000
    assert "--max-samples 3000)" in out and "(streamed)" in out
    # ml on ~3000 evenly spread samples: the offset's noise std is about 0.2 % of the field here.
    assert np.linalg.norm(cal.offset - sim.hard_iron) / sim.field_strength < 0.01


def test_calibrate_reads_a_big_text_file_in_parallel_pieces_with_the_same_result(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # Above PARALLEL_BYTES a text file is cut into pieces read on threads (one Statistics each, merged
    # exactly) and scored piece by piece (metrics pooled). Lowered here so that a small file is cut in 3.
    import magfit.pipeline.streaming as calibrate

    sim = magfit.scenario("mpu9250", "steel").simulate(20_000, seed=8)
    lines = [f"{t},{x:.1f},{y:.1f},{z:.1f}" for t, (x, y, z) in enumerate(sim.samples.tolist())]
    lines[12_345] = "12345,nan,1.0,2.0"  # a skipped row in a middle piece
    path = tmp_path / "big.csv"
    path.write_text("t,mx,my,mz\n" + "\n".join(lines) + "\n")
    diagnosed: list[np.ndarray] = []
    original = calibrate._with_diagnostics

    def recorded(
        calibration: magfit.Calibration, subsample: np.ndarray, n_total: int, allow_undetermined: bool = False
    ) -> magfit.Calibration:
        diagnosed.append(subsample)
        return original(calibration, subsample, n_total, allow_undetermined)

    monkeypatch.setattr(calibrate, "_with_diagnostics", recorded)
    sequential = magfit.calibrate_file(path, "ellipsoid").compasses[0]
    monkeypatch.setattr(magfit.io.chunks, "PARALLEL_BYTES", 1000)
    monkeypatch.setattr(magfit.io.readers.os, "cpu_count", lambda: 3)
    split = magfit.io.ChunkReader.split
    pieces: list[int] = []
    monkeypatch.setattr(magfit.io.ChunkReader, "split", lambda self, n: pieces.append(n) or split(self, n))
    parallel = magfit.calibrate_file(path, "ellipsoid").compasses[0]
    assert pieces == [3]
    for run in (sequential, parallel):
        assert (run.n_rows, run.n_skipped, run.skipped_lines) == (20_000, 1, (12_347,))
    a, b = parallel.calibration, sequential.calibration
    np.testing.assert_allclose(a.offset, b.offset, rtol=0, atol=1e-9 * b.field_strength)
    np.testing.assert_allclose(a.ellipsoid_matrix, b.ellipsoid_matrix, rtol=0, atol=1e-9 / b.field_strength**2)
    for name in ("n", "mean", "std", "mean_abs", "rms", "max_abs"):
        assert getattr(parallel.evaluation, name) == pytest.approx(getattr(sequential.evaluation, name), rel=1e-9)
    np.testing.assert_array_equal(diagnosed[1], diagnosed[0])  # the same strided rows were diagnosed
