"""Statistics: one-pass accumulation, exact merges, numerical frame, chunking, float32, errors.

Tolerances. The merge and the re-framing are exact in exact arithmetic (``d(a z + t) = T d(z)``), so two
ways of accumulating the same samples must agree to round-off: float64 epsilon (2e-16) amplified by the
conditioning of the 10x10 eigenproblem (about 1e3 here) and by the ten-term polynomial transform. We
allow 1e-9 relative, far below any real difference (a wrongly weighted or dropped sample moves a
3000-sample fit by about 1e-4).
"""

from __future__ import annotations

import pickle
import tracemalloc
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import magfit
from magfit import CalibrationError, OptionError, SampleError, Statistics
from magfit.statistics import design_matrix, design_transform

ROUND_OFF = 1e-9
LINEAR_METHODS = sorted(name for name, spec in magfit.METHODS.items() if spec.data == "statistics")
SAMPLE_METHODS = sorted(name for name, spec in magfit.METHODS.items() if spec.data == "samples")


@pytest.fixture(scope="module")
def steel() -> magfit.Simulation:
    """The paper's hardest case: MPU-9250 raw counts beside a steel plate (semi-axes 193 to 1362 counts)."""
    return magfit.scenario("mpu9250", "steel").simulate(3000, seed=11)


@pytest.fixture(scope="module")
def phone() -> magfit.Simulation:
    """MPU-9250 beside a smartphone: mild, nearly axis-aligned soft iron that every linear method can fit."""
    return magfit.scenario("mpu9250", "smartphone").simulate(3000, seed=11)


def assert_same_fit(a: magfit.Calibration, b: magfit.Calibration, radius: float, rtol: float = ROUND_OFF) -> None:
    """Same ellipsoid: the identifiable quantities (offset, A, B), relative to the field radius."""
    np.testing.assert_allclose(a.offset, b.offset, rtol=0, atol=rtol * radius)
    np.testing.assert_allclose(a.field_strength, b.field_strength, rtol=rtol)
    np.testing.assert_allclose(a.ellipsoid_matrix, b.ellipsoid_matrix, rtol=0, atol=rtol / radius**2)


def assert_same_statistics(a: Statistics, b: Statistics, rtol: float = ROUND_OFF) -> None:
    assert a.n == b.n
    spread = float(np.sqrt(np.trace(b.covariance)))
    np.testing.assert_allclose(a.mean, b.mean, rtol=0, atol=rtol * spread)
    np.testing.assert_allclose(a.covariance, b.covariance, rtol=0, atol=rtol * spread**2)
    np.testing.assert_array_equal(a.minimum, b.minimum)
    np.testing.assert_array_equal(a.maximum, b.maximum)


# ---------------------------------------------------------------------- oracle


def test_scatter_is_the_design_scatter_of_the_normalised_samples(steel: magfit.Simulation) -> None:
    stats = Statistics.from_samples(steel.samples, chunk_size=700)
    z = (steel.samples - stats.centre) / stats.scale
    design = design_matrix(z)
    np.testing.assert_allclose(stats.scatter, design.T @ design, rtol=1e-12, atol=1e-12 * stats.n)
    np.testing.assert_allclose(stats.mean, steel.samples.mean(axis=0), rtol=1e-12)
    np.testing.assert_allclose(stats.covariance, np.cov(steel.samples.T, bias=True), rtol=1e-10)
    np.testing.assert_array_equal(stats.minimum, steel.samples.min(axis=0))
    np.testing.assert_array_equal(stats.maximum, steel.samples.max(axis=0))
    assert stats.moment((0, 0, 0)) == stats.n
    np.testing.assert_allclose(stats.moment((2, 1, 1)), np.sum(z[:, 0] ** 2 * z[:, 1] * z[:, 2]), rtol=1e-10)


def test_design_transform_maps_design_vectors() -> None:
    rng = np.random.default_rng(3)
    z = rng.normal(size=(50, 3))
    gain, shift = 0.37, np.array([1.5, -2.0, 0.25])
    transform = design_transform(gain, shift)
    np.testing.assert_allclose(design_matrix(gain * z + shift), design_matrix(z) @ transform.T, rtol=1e-13, atol=1e-13)


# ---------------------------------------------------------------------- merge == concatenation


@pytest.mark.parametrize("method", LINEAR_METHODS)
def test_merge_equals_concatenation_for_every_linear_method(phone: magfit.Simulation, method: str) -> None:
    samples = phone.samples
    whole = magfit.fit(samples, method)
    # Uneven parts, one of them tiny and one alone too small to fit anything.
    parts = [Statistics.from_samples(part) for part in np.split(samples, [5, 1000, 1010])]
    left_to_right = parts[0].merge(parts[1]).merge(parts[2]).merge(parts[3])
    tree = (parts[3] + parts[1]) + (parts[2] + parts[0])
    for merged in (left_to_right, tree, sum(parts)):
        assert isinstance(merged, Statistics)
        assert_same_statistics(merged, Statistics.from_samples(samples))
        assert_same_fit(magfit.fit(merged, method), whole, phone.field_strength)


def test_merge_leaves_its_inputs_unchanged(steel: magfit.Simulation) -> None:
    a = Statistics.from_samples(steel.samples[:1000])
    b = Statistics.from_samples(steel.samples[1000:])
    before_a, before_b = a.scatter, b.scatter
    a.merge(b)
    _ = b + a
    np.testing.assert_array_equal(a.scatter, before_a)
    np.testing.assert_array_equal(b.scatter, before_b)
    assert (a.n, b.n) == (1000, 2000)


def test_merge_of_a_still_part_and_a_tumble_keeps_full_precision(steel: magfit.Simulation) -> None:
    # A sensor left still (1000 identical readings) merged with a tumble, in both orders: the frame must
    # follow the wider part, else the tumble is expressed in a frame of zero width.
    still = Statistics.from_samples(np.repeat(steel.samples[:1], 1000, axis=0))
    tumble = Statistics.from_samples(steel.samples)
    whole = magfit.fit(np.vstack([np.repeat(steel.samples[:1], 1000, axis=0), steel.samples]))
    assert_same_fit(magfit.fit(still + tumble), whole, steel.field_strength)
    assert_same_fit(magfit.fit(tumble + still), whole, steel.field_strength)


def test_merge_of_two_separate_still_clusters_has_their_spread() -> None:
    a = Statistics.from_samples(np.tile([100.0, 0.0, 0.0], (10, 1)))
    b = Statistics.from_samples(np.tile([100.0, 4.0, 0.0], (30, 1)))
    merged = a + b
    np.testing.assert_allclose(merged.mean, [100.0, 3.0, 0.0], rtol=1e-14)
    # Variance along y: 0.25 * 0.75 * 4² = 3.
    np.testing.assert_allclose(merged.covariance, np.diag([0.0, 3.0, 0.0]), atol=1e-12)


@settings(max_examples=25, deadline=None)
@given(cuts=st.lists(st.integers(min_value=0, max_value=400), max_size=4), chunk=st.integers(1, 500))
def test_any_split_and_chunking_give_the_same_statistics(cuts: list[int], chunk: int) -> None:
    samples = magfit.scenario("ellipse2a", "smartphone").simulate(400, seed=5).samples
    parts = np.split(samples, sorted(cuts))
    merged = sum(Statistics(chunk).update(part) for part in parts)
    assert isinstance(merged, Statistics)
    assert_same_statistics(merged, Statistics.from_samples(samples))


# ---------------------------------------------------------------------- the normalised frame


def far_away(simulation: magfit.Simulation, multiple: float) -> tuple[np.ndarray, np.ndarray]:
    """The noise-free samples moved ``multiple`` field radii away from the origin, and the shift."""
    shift = multiple * simulation.field_strength * np.array([0.6, -0.48, 0.64])
    return simulation.clean + shift, shift


@pytest.mark.parametrize("chunk_size", [1, 7, 4096])
def test_offset_of_1e4_radii_is_recovered_to_round_off(steel: magfit.Simulation, chunk_size: int) -> None:
    # The samples hold 16 digits of which 4 are spent on the offset: 12 digits remain for the ellipsoid.
    # Without centring, the degree-4 moments (1e16 radius⁴) would leave none; with a frame that does not
    # follow the data (chunk_size=1 sets it from one sample) the fit was 1 % off.
    samples, shift = far_away(steel, 1e4)
    cal = magfit.fit(Statistics(chunk_size).update(samples), "ellipsoid")
    radius = steel.field_strength
    np.testing.assert_allclose(cal.offset, steel.truth.offset + shift, rtol=0, atol=1e-8 * radius)
    np.testing.assert_allclose(cal.ellipsoid_matrix, steel.truth.ellipsoid_matrix, rtol=0, atol=1e-8 / radius**2)


@pytest.mark.parametrize("method", LINEAR_METHODS)
def test_every_linear_method_moves_with_an_offset_of_1e4_radii(phone: magfit.Simulation, method: str) -> None:
    # Translation equivariance: shifting every sample shifts the offset and changes nothing else.
    samples, shift = far_away(phone, 1e4)
    near, far = magfit.fit(phone.clean, method), magfit.fit(samples, method)
    radius = phone.field_strength
    np.testing.assert_allclose(far.offset - shift, near.offset, rtol=0, atol=1e-8 * radius)
    np.testing.assert_allclose(far.field_strength, near.field_strength, rtol=1e-8)
    np.testing.assert_allclose(far.ellipsoid_matrix, near.ellipsoid_matrix, rtol=0, atol=1e-8 / radius**2)


def test_a_still_start_does_not_spoil_the_frame(steel: magfit.Simulation) -> None:
    # The first chunk (2000 identical readings, e.g. a warm-up before the tumble) fixes no useful frame.
    samples, _ = far_away(steel, 1e4)
    still = np.repeat(samples[:1], 2000, axis=0)
    stats = Statistics(chunk_size=2000).update(still).update(samples)
    cal = magfit.fit(stats, "ellipsoid")
    reference = magfit.fit(np.vstack([samples, still]), "ellipsoid")  # tumble first: a good frame at once
    assert_same_fit(cal, reference, steel.field_strength, rtol=1e-8)
    assert stats.scale == pytest.approx(np.sqrt(np.trace(stats.covariance)), rel=1.0)  # within 2x of the spread


# ---------------------------------------------------------------------- dtypes, chunk sizes


def test_float32_input_is_fitted_in_float64(phone: magfit.Simulation) -> None:
    single = phone.samples.astype(np.float32)
    for method in LINEAR_METHODS:
        assert_same_fit(magfit.fit(single, method), magfit.fit(single.astype(np.float64), method), phone.field_strength)


def test_float32_input_is_converted_chunk_by_chunk() -> None:
    # A whole float64 copy of 1e6 samples is 24 MB; the chunked update needs one 5 MB chunk buffer.
    single = np.random.default_rng(0).normal(size=(1_000_000, 3)).astype(np.float32)
    tracemalloc.start()
    try:
        Statistics().update(single)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 12e6, f"update() allocated {peak / 1e6:.1f} MB at peak"


def _fit_peak_memory(samples: np.ndarray, method: str) -> tuple[magfit.Calibration, float]:
    magfit.fit(samples[:2000], method)  # lazy imports outside the measurement
    tracemalloc.start()
    try:
        calibration = magfit.fit(samples, method)
        return calibration, tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


@pytest.mark.parametrize("method", ["ellipsoid", "auto"])
@pytest.mark.slow
def test_fit_of_float32_samples_makes_no_whole_float64_copy(method: str) -> None:
    # fit() itself, diagnostics included: the linear methods read float32 through Statistics' chunks and
    # the diagnostics convert only the rows they analyse, so float32 input costs what float64 input does;
    # the iterative methods need one float64 copy (24 MB here).
    sim = magfit.scenario("mpu9250", "steel").simulate(1_000_000, seed=3)
    single = sim.samples.astype(np.float32)
    calibration, peak_single = _fit_peak_memory(single, method)
    _, peak_double = _fit_peak_memory(single.astype(np.float64), method)
    np.testing.assert_allclose(calibration.offset, sim.hard_iron, atol=0.01 * sim.field_strength)
    assert calibration.diagnostics is not None and calibration.diagnostics.n_samples == 1_000_000
    copy = single.size * 8
    if method == "ellipsoid":
        assert peak_single < peak_double + 0.2 * copy, f"{peak_single / 1e6:.1f} MB vs {peak_double / 1e6:.1f} MB"
    else:
        assert peak_single > peak_double + 0.8 * copy  # the measurement does see a copy when there is one


def test_integer_counts_are_accepted() -> None:
    counts = np.round(magfit.scenario("mpu9250", "none").simulate(500, seed=2).samples).astype(np.int16)
    assert_same_statistics(Statistics.from_samples(counts), Statistics.from_samples(counts.astype(np.float64)))


@pytest.mark.parametrize("chunk_size", [1, 2, 3, 64, 999, 1 << 16])
def test_chunk_size_does_not_change_the_result(phone: magfit.Simulation, chunk_size: int) -> None:
    samples = phone.samples[:1500]
    reference = Statistics.from_samples(samples)
    stats = Statistics(chunk_size).update(samples)
    assert_same_statistics(stats, reference)
    for method in LINEAR_METHODS:
        assert_same_fit(magfit.fit(stats, method), magfit.fit(reference, method), phone.field_strength)


def test_from_chunks_equals_update(steel: magfit.Simulation) -> None:
    chunks = (steel.samples[i : i + 250] for i in range(0, 3000, 250))
    assert_same_statistics(Statistics.from_chunks(chunks), Statistics.from_samples(steel.samples))


# ---------------------------------------------------------------------- empty and edge cases


def test_empty_statistics() -> None:
    empty = Statistics()
    assert empty.n == 0
    assert repr(empty) == "Statistics(n=0)"
    with pytest.raises(SampleError, match=r"no samples yet: call update\(\)"):
        _ = empty.mean
    with pytest.raises(CalibrationError, match="needs at least 9 samples, got 0"):
        magfit.fit(empty, "ellipsoid")
    assert empty.update(np.empty((0, 3))).n == 0


def test_merging_with_empty_changes_nothing(steel: magfit.Simulation) -> None:
    full = Statistics.from_samples(steel.samples)
    for merged in (full + Statistics(), Statistics() + full, Statistics().merge(full)):
        assert_same_statistics(merged, full, rtol=0)
        np.testing.assert_array_equal(merged.scatter, full.scatter)
    assert (Statistics() + Statistics()).n == 0


def test_pickle_round_trip_for_processes_and_clusters(steel: magfit.Simulation) -> None:
    # Dask's process scheduler, Spark and Ray ship Statistics between processes by pickling them.
    stats = Statistics.from_samples(steel.samples)
    _ = stats.scatter  # a cached canonical frame must travel (or be rebuilt) consistently
    copy = pickle.loads(pickle.dumps(stats))
    np.testing.assert_array_equal(copy.scatter, stats.scatter)
    assert_same_fit(magfit.fit(copy + stats), magfit.fit(np.vstack([steel.samples] * 2)), steel.field_strength)


def test_copy_is_independent(steel: magfit.Simulation) -> None:
    original = Statistics.from_samples(steel.samples[:100])
    duplicate = original.copy()
    duplicate.update(steel.samples[100:])
    assert (original.n, duplicate.n) == (100, 3000)


def test_all_identical_samples_are_refused_with_the_reason() -> None:
    with pytest.raises(CalibrationError, match="samples are identical"):
        magfit.fit(Statistics.from_samples(np.tile([5.0, 6.0, 7.0], (50, 1))), "sphere")


# ---------------------------------------------------------------------- errors


def test_nan_names_the_row_and_leaves_the_statistics_unchanged(steel: magfit.Simulation) -> None:
    stats = Statistics(chunk_size=100).update(steel.samples[:300])
    bad = steel.samples[300:800].copy()
    bad[237, 1] = np.nan
    with pytest.raises(SampleError, match=r"NaN or inf in 1 row\(s\), the first is row 237"):
        stats.update(bad)
    assert_same_statistics(stats, Statistics.from_samples(steel.samples[:300]))


def test_inf_is_refused() -> None:
    samples = np.ones((10, 3))
    samples[4, 2] = -np.inf
    with pytest.raises(SampleError, match="the first is row 4"):
        Statistics().update(samples)


def test_values_too_large_for_float64_are_refused() -> None:
    # Their squares overflow; values below magfit's limit of 1e150 do not: the normalised frame keeps z⁴ of order one.
    samples = np.random.default_rng(1).normal(size=(20, 3)) * 1e160
    with pytest.raises(SampleError, match=r"values beyond ±1e\+150 in 20 row\(s\), the first is row 0"):
        Statistics().update(samples)
    moderate = Statistics().update(samples * 1e-12)
    np.testing.assert_allclose(moderate.mean, samples.mean(axis=0) * 1e-12, rtol=1e-12)


@pytest.mark.parametrize(
    ("samples", "message"),
    [
        (np.zeros((3, 40)), r"got shape \(3, 40\); it looks like one sample per column: pass samples.T"),
        (np.zeros(3), r"got shape \(3,\); a single sample needs shape \(1, 3\)"),
        (np.array([["a", "b", "c"]]), "samples must be numbers"),
    ],
)
def test_bad_shapes_and_types_are_refused(samples: np.ndarray, message: str) -> None:
    with pytest.raises(SampleError, match=message):
        Statistics().update(samples)


@pytest.mark.parametrize("chunk_size", [0, -5, 2.5, True])
def test_bad_chunk_size(chunk_size: object) -> None:
    with pytest.raises(OptionError, match="chunk_size must be a positive integer"):
        Statistics(chunk_size)  # type: ignore[arg-type]


def test_merge_needs_statistics() -> None:
    with pytest.raises(
        SampleError, match=r"merge\(\) takes another Statistics, got ndarray; to add samples use update"
    ):
        Statistics().merge(np.ones((5, 3)))  # type: ignore[arg-type]
    with pytest.raises(TypeError):
        _ = Statistics() + 1  # type: ignore[operator]


@pytest.mark.skipif(not SAMPLE_METHODS, reason="no method that needs the samples is registered yet")
@pytest.mark.parametrize("method", SAMPLE_METHODS or ["none"])
def test_methods_that_need_samples_refuse_statistics(steel: magfit.Simulation, method: str) -> None:
    with pytest.raises(OptionError, match=f"method '{method}' needs the samples, not Statistics"):
        magfit.fit(Statistics.from_samples(steel.samples), method)


# ---------------------------------------------------------------------- files streamed into Statistics


@pytest.mark.parametrize(
    "row",
    [
        "{x},{y},{z}",  # plain: parsed without stripping blanks (the fast path)
        "{x}, {y}, {z}",  # comma and space
        "{x},  {y},\t{z}",  # aligned by hand: blanks before some cells
    ],
)
def test_chunked_file_statistics_equal_the_array_statistics(tmp_path: Path, row: str) -> None:
    from magfit.io import iter_sample_chunks

    samples = magfit.scenario("ellipse2a", "steel").simulate(3000, seed=3).samples
    lines = [row.format(x=x, y=y, z=z) for x, y, z in samples.tolist()]
    lines[1234] = row.format(x=1.0, y="nan", z=2.0)  # a missing value, written with the row's blanks
    path = tmp_path / "samples.csv"
    path.write_text("mx,my,mz\n" + "\n".join(lines) + "\n")
    reader = iter_sample_chunks(path, chunk_rows=700)
    stats = Statistics.from_chunks(reader)
    assert reader.n_skipped == 1
    assert_same_statistics(stats, Statistics.from_samples(np.delete(samples, 1234, axis=0)), rtol=1e-12)


@pytest.mark.parametrize("parts", [2, 3, 8])
def test_file_pieces_read_apart_merge_to_the_whole(tmp_path: Path, parts: int) -> None:
    # ChunkReader.split cuts a text file at line ends; each piece keeps the file's line numbers.
    from magfit.io import iter_sample_chunks

    samples = magfit.scenario("mpu9250", "smartphone").simulate(5000, seed=4).samples
    lines = ["Fs,50.00", "mx,my,mz"] + [f"{x:.1f},{y:.1f},{z:.1f}" for x, y, z in samples.tolist()]
    lines[4002] = "1.0,,2.0"  # file line 4003: a missing value, skipped
    path = tmp_path / "pieces.csv"
    path.write_text("\n".join(lines) + "\n")
    whole = iter_sample_chunks(path, chunk_rows=600)
    reference = Statistics.from_chunks(whole)
    pieces = whole.split(parts)
    assert len(pieces) == parts
    merged = sum(Statistics.from_chunks(piece) for piece in pieces)
    assert isinstance(merged, Statistics)
    assert_same_statistics(merged, reference)
    assert sum(piece.n_rows for piece in pieces) == 5000
    assert [line for piece in pieces for line in piece.skipped_lines] == [4003] == list(whole.skipped_lines)
