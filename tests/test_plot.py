"""Figures of a calibration (magfit.plot): geometry against closed forms, then the rendered PNG itself."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import magfit
import magfit.sampling
from magfit.errors import OptionError, SampleError

plot = pytest.importorskip("magfit.plot")  # needs the plot extra (matplotlib)
PIL_Image = pytest.importorskip("PIL.Image")

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def steel():
    """The paper's MPU-9250 with a piece of steel (strong, rotated soft iron), and the three paper fits."""
    simulation = magfit.scenario("mpu9250", "steel").simulate(3000, seed=7)
    # sphere and minmax cannot remove this soft iron: returned anyway, as the paper's figures compare all three
    fits = [
        magfit.fit(simulation.samples, method=method, allow_undetermined=True)
        for method in ("ellipsoid", "sphere", "minmax")
    ]
    return simulation, fits


def test_importing_magfit_loads_no_plotting_library() -> None:
    code = (
        "import sys, magfit, magfit.plot, magfit.report, magfit.cli; "
        "print(sorted(m for m in ('matplotlib', 'plotly') if m in sys.modules))"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert result.stdout.strip() == "[]"


# ---------------------------------------------------------------------- geometry (closed forms)


def test_ellipse_outline_of_an_axis_aligned_ellipsoid_is_its_xy_ellipse() -> None:
    # An ellipsoid with semi-axes (a, b, c) along x, y, z seen along z is the ellipse of semi-axes (a, b).
    a, b, c = 300.0, 200.0, 100.0
    strength = (a * b * c) ** (1 / 3)
    offset = np.array([10.0, -20.0, 30.0])
    calibration = magfit.Calibration("test", offset, np.diag(strength / np.array([a, b, c])), strength)
    outline = plot.ellipse_outline(calibration, (0, 1))
    x, y = outline[:, 0] - offset[0], outline[:, 1] - offset[1]
    np.testing.assert_allclose((x / a) ** 2 + (y / b) ** 2, 1.0, rtol=1e-12)
    np.testing.assert_allclose([x.max(), y.max()], [a, b], rtol=1e-3)  # 181 points: max within 0.1%


@pytest.mark.parametrize("plane", [(0, 1), (0, 2), (1, 2)])
def test_ellipse_outline_is_the_shadow_of_a_rotated_ellipsoid(steel, plane) -> None:
    # Every point of the true ellipsoid projects inside the outline, and the densest sampling touches it.
    simulation, _ = steel
    truth = simulation.truth
    outline = plot.ellipse_outline(truth, plane)
    surface = np.vstack(plot.ellipsoid_wireframe(truth, n_lines=60, n_points=241))
    block = np.linalg.inv(truth.ellipsoid_matrix)[np.ix_(plane, plane)]
    inside = np.einsum(
        "ni,ij,nj->n",
        surface[:, plane] - truth.offset[list(plane)],
        np.linalg.inv(block),
        surface[:, plane] - truth.offset[list(plane)],
    )
    on_outline = np.einsum(
        "ni,ij,nj->n", outline - truth.offset[list(plane)], np.linalg.inv(block), outline - truth.offset[list(plane)]
    )
    np.testing.assert_allclose(on_outline, 1.0, rtol=1e-10)
    assert inside.max() <= 1.0 + 1e-9
    assert inside.max() > 0.99  # a 60-line wireframe reaches the silhouette to within 1%


def test_ellipsoid_wireframe_lies_on_the_fitted_ellipsoid(steel) -> None:
    _, fits = steel
    for calibration in fits:
        points = np.vstack(plot.ellipsoid_wireframe(calibration))
        radii = np.linalg.norm(calibration.apply(points, normalized=True), axis=1)
        np.testing.assert_allclose(radii, 1.0, rtol=1e-12)


def test_scan_matches_apply_and_sphere_distances(steel) -> None:
    # Oracle: the fast pass gives what Calibration.apply and magfit.sphere_distances give, across blocks.
    simulation, fits = steel
    samples = np.vstack([simulation.samples] * 400)  # 1.2 million rows: two blocks of CHUNK_ROWS
    distances, cover = plot.scan(samples, tuple(fits))
    for calibration, found in zip(fits, distances, strict=True):
        np.testing.assert_allclose(found, magfit.sphere_distances(calibration, samples), rtol=0, atol=1e-13)
    np.testing.assert_allclose(
        plot.corrected_unit(fits[0], simulation.samples), fits[0].apply(simulation.samples, normalized=True), atol=1e-14
    )
    np.testing.assert_array_equal(cover.counts, 400 * plot.coverage(fits[0].apply(simulation.samples)).counts)


def test_coverage_of_a_full_tumble_visits_every_cell() -> None:
    # 30 000 uniform directions over 648 equal-area cells: about 46 per cell, P(an empty cell) ~ 648 e^-46.
    directions = magfit.simulate(30_000, seed=3).samples
    cover = plot.coverage(directions)
    assert cover.counts.shape == (18, 36)
    assert cover.fraction_visited == 1.0
    # Equal areas: the counts of a uniform sample are Poisson(46); their spread matches, no band is favoured.
    assert abs(cover.counts.mean() - 30_000 / 648) < 1e-9
    assert cover.counts.std() < 1.3 * np.sqrt(30_000 / 648)
    np.testing.assert_allclose(np.sin(cover.elevation_edges), np.linspace(-1, 1, 19), atol=1e-12)


def test_coverage_of_level_turns_is_one_band_at_the_inclination() -> None:
    # Yaw-only turns keep the field's vertical component B sin(δ): every direction sits at elevation δ = 64°,
    # so only the band holding sin(64°) = 0.899 (band 17 of 18, sin in [0.889, 1]) is visited.
    simulation = magfit.simulate(5000, orientations="yaw", inclination_deg=64.0, seed=4)
    cover = plot.coverage(simulation.samples)
    visited_rows = np.flatnonzero(cover.counts.sum(axis=1))
    assert visited_rows.tolist() == [17]
    assert cover.fraction_visited == pytest.approx(36 / 648)


def test_subsample_for_plot_thins_a_dwell_and_keeps_rare_directions() -> None:
    rng = np.random.default_rng(5)
    spread = rng.normal(size=(2_000, 3))  # a full tumble ...
    dwell = np.array([1.0, 0.0, 0.0]) + 0.01 * rng.normal(size=(98_000, 3))  # ... and a long rest facing +x
    samples = np.vstack([dwell, spread])
    identity = magfit.Calibration.identity()
    chosen = plot.subsample_for_plot(samples, identity, 2_000, seed=1)
    assert 1_600 <= chosen.size <= 2_000  # every cell capped at the same whole count: at most the budget
    assert np.all(np.diff(chosen) > 0)  # unique and in recording order
    # The rest, 98% of the recording, is a small share of the picture; every direction cell the tumble
    # reached is still in it (400 cells of the shared sampler: ~5 tumble samples each, at least 1 kept).
    assert np.count_nonzero(chosen < 98_000) / chosen.size < 0.02
    cells = magfit.sampling.SphereCells.make(400)
    assert np.unique(cells.index(samples[chosen])).size == np.unique(cells.index(samples)).size


def test_subsample_for_plot_uses_the_calibrated_directions() -> None:
    # A strongly distorted ellipsoid: raw directions from the centre crowd towards its long axis, the
    # calibrated ones are uniform. Subsampling in the calibrated frame keeps the picture uniform.
    simulation = magfit.scenario("mpu9250", "steel").simulate(20_000, seed=8)
    chosen = plot.subsample_for_plot(simulation.samples, simulation.truth, 2_000, seed=3)
    directions = simulation.truth.apply(simulation.samples[chosen])
    counts = plot.coverage(directions, 12, 6).counts  # 72 cells, ~28 points each when even
    assert counts.min() >= 0.5 * counts.mean()
    assert counts.max() <= 1.5 * counts.mean()


def test_subsample_for_plot_returns_everything_when_small_and_is_repeatable() -> None:
    identity = magfit.Calibration.identity()
    samples = magfit.simulate(500, seed=6).samples
    np.testing.assert_array_equal(plot.subsample_for_plot(samples, identity, 500), np.arange(500))
    big = magfit.simulate(5_000, seed=6).samples
    first = plot.subsample_for_plot(big, identity, 300, seed=2)
    np.testing.assert_array_equal(first, plot.subsample_for_plot(big, identity, 300, seed=2))
    with pytest.raises(OptionError, match="max_points must be at least 1"):
        plot.subsample_for_plot(big, identity, 0)


# ---------------------------------------------------------------------- the rendered figure


def _png_pixels(path: Path) -> np.ndarray:
    assert path.read_bytes()[:8] == PNG_SIGNATURE
    with PIL_Image.open(path) as image:
        return np.asarray(image.convert("RGB"), dtype=np.float64)


@pytest.mark.slow
def test_calibration_figure_png_has_the_requested_size_and_is_not_blank(steel, tmp_path) -> None:
    simulation, fits = steel
    figure = plot.calibration_figure(simulation.samples, fits, title="steel", max_points=800, size=(16, 12), dpi=50)
    path = plot.save_figure(figure, tmp_path / "steel.png")
    pixels = _png_pixels(path)
    assert pixels.shape == (600, 800, 3)  # 16 x 12 inches at 50 dpi
    assert pixels.std() > 20  # a white page has 0; the panels, points and text give tens of grey levels
    # Not one colour repeated: the three method colours are in the picture (tab blue, red, green).
    colours = {tuple(c) for c in pixels.reshape(-1, 3)[::7].astype(int)}
    assert len(colours) > 200


def test_calibration_figure_panels_carry_units_methods_and_the_papers_metric(steel) -> None:
    simulation, fits = steel
    figure = plot.calibration_figure(simulation.samples, fits, unit="counts", title="steel", max_points=800)
    panels = {axes.get_label(): axes for axes in figure.axes}
    expected = {"raw-3d", "calibrated-3d", "coverage", "histogram", "parameters"} | {
        f"{when}-{plane}" for when in ("before", "after") for plane in ("xy", "xz", "yz")
    }
    assert expected <= set(panels)
    assert panels["raw-3d"].get_xlabel() == "x (counts)"
    assert panels["raw-3d"].get_zlabel() == "z (counts)"
    assert panels["calibrated-3d"].get_ylabel() == "y / B"
    assert (panels["before-xz"].get_xlabel(), panels["before-xz"].get_ylabel()) == ("x (counts)", "z (counts)")
    assert panels["after-yz"].get_xlabel().startswith("y / B")
    assert "distance to the unit sphere" in panels["histogram"].get_xlabel()
    # 3000 samples: a 24 x 12 grid of 15° cells (~10 samples each), every cell reached (P(empty) ~ e^-10.4).
    cover = plot.coverage(fits[0].apply(simulation.samples), 24, 12)
    assert cover.fraction_visited == 1.0
    share = fits[0].diagnostics.coverage.share  # the number the CLI prints, not the map's grid
    assert (
        panels["coverage"]
        .get_title()
        .startswith(
            f"Directions visited: {share:.0%} of the sphere (the diagnostics' 100 equal-area regions)\n"
            "map: 288 of 288 cells 15° wide reached"
        )
    )
    # Methods named in the histogram legend with the paper's mean/std, equal to magfit.evaluate's.
    legend = [text.get_text() for text in panels["histogram"].get_legend().get_texts()]
    title = figure.get_suptitle()
    for calibration, entry in zip(fits, legend, strict=True):
        score = magfit.evaluate(calibration, simulation.samples)
        refused = calibration.support.verdict == "refused"  # sphere and minmax on this soft iron
        name = f"{calibration.method} (not supported)" if refused else calibration.method
        assert entry.startswith(f"{name}: mean {score.mean:+.4f}, std {score.std:.4f}")
        assert f"{name} {score.mean:+.4f} / {score.std:.4f}" in title
    marked = ["ellipsoid", "sphere (not supported)", "minmax (not supported)"]
    assert [entry.split(":")[0] for entry in legend] == marked
    assert f"B = {fits[0].field_strength:.4g} counts" in title
    shown = int(figure.get_supxlabel().split(" of ")[0])
    assert 640 <= shown <= 800  # 200 cells capped at the same whole count: within 20% of the budget
    assert figure.get_supxlabel() == f"{shown} of 3,000 samples shown, spread evenly over the directions visited."


def test_scatter_panels_draw_at_most_max_points(steel) -> None:
    simulation, fits = steel
    figure = plot.calibration_figure(simulation.samples, fits[:1], max_points=500)
    panels = {axes.get_label(): axes for axes in figure.axes}
    points = [len(collection.get_offsets()) for collection in panels["before-xy"].collections]
    assert len(points) == 1 and 400 <= points[0] <= 500
    assert figure.get_supxlabel().startswith(f"{points[0]} of 3,000 samples shown")
    # All 3000 in the 2-D panels; the 3-D panels, where a dense cloud hides the wireframe, one in two.
    everything = plot.calibration_figure(simulation.samples, fits[0], max_points=3000)
    assert everything.get_supxlabel() == "All 3,000 samples shown. The 3-D panels show one in 2 of them."
    cloud = {a.get_label(): a for a in everything.axes}["raw-3d"].collections[0]
    assert len(cloud.get_offsets()) == 1500
    # The unit falls back to the calibration's, then to "raw units".
    assert panels["before-xy"].get_xlabel() == "x (raw units)"
    labelled = plot.calibration_figure(simulation.samples[:300], fits[0].with_unit("uT"), max_points=100)
    small = {a.get_label(): a for a in labelled.axes}
    assert small["before-xy"].get_xlabel() == "x (uT)"
    # 300 samples cannot fill 648 cells: the map coarsens to 72 cells of 30°, ~4 samples each.
    assert "of 72 cells 30° wide reached" in small["coverage"].get_title()


def test_calibration_figure_refuses_bad_input(steel, tmp_path) -> None:
    simulation, fits = steel
    with pytest.raises(OptionError, match="at least one calibration"):
        plot.calibration_figure(simulation.samples, [])
    with pytest.raises(SampleError, match=r"shape \(N, 3\)"):
        plot.calibration_figure(simulation.samples.T, fits)
    figure = plot.calibration_figure(simulation.samples[:200], fits[0], max_points=100, size=(4, 3), dpi=30)
    with pytest.raises(OptionError, match="use one of the extensions"):
        plot.save_figure(figure, tmp_path / "figure.xyz")
    with pytest.raises(OptionError, match="does not exist"):
        plot.save_figure(figure, tmp_path / "missing" / "figure.png")


def test_method_labels_number_repeated_methods() -> None:
    identity = magfit.Calibration.identity()
    assert plot.method_labels([identity, identity, identity]) == ("identity", "identity #2", "identity #3")


@pytest.mark.slow
def test_the_figure_and_the_cli_give_the_same_coverage(real_data_dir: Path, tmp_path: Path) -> None:
    """A half-sphere recording: the figure said 8 % (its own fine grid), the CLI 13 %; now one number."""
    from click.testing import CliRunner

    from magfit.cli import cli
    from magfit.io import read_samples

    path = real_data_dir / "hamagure_gauss" / "data-set_2.csv"
    samples = read_samples(path).samples
    calibration = magfit.fit(samples, method="sphere")  # the half the samples cover determines a sphere
    share = calibration.diagnostics.coverage.share
    assert 0.1 < share < 0.6  # only the z < 0 half was recorded
    figure = plot.calibration_figure(samples, calibration)
    title = {axes.get_label(): axes for axes in figure.axes}["coverage"].get_title()
    assert title.startswith(f"Directions visited: {share:.0%} of the sphere")
    result = CliRunner().invoke(cli, ["calibrate", str(path), "-m", "sphere", "--plot", str(tmp_path / "f.png")])
    assert result.exit_code == 0, result.output
    assert f"cover only {100 * share:.0f} % of the directions" in result.stderr
    assert f"{share:.0%}" == f"{100 * share:.0f}%"


@pytest.mark.slow
def test_plot_draws_unsupported_comparisons_marked_and_refuses_an_unsupported_main_fit(steel, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    from click.testing import CliRunner

    from magfit.cli import cli

    simulation, _ = steel
    path = tmp_path / "steel.csv"
    np.savetxt(path, simulation.samples, delimiter=",", header="mx,my,mz", comments="")
    drawn = CliRunner().invoke(cli, ["plot", str(path), "-m", "ellipsoid", "-o", str(tmp_path / "steel.png")])
    assert drawn.exit_code == 0, drawn.output
    assert "sphere (not supported) sphere distance mean" in drawn.stdout and (tmp_path / "steel.png").exists()
    refused = CliRunner().invoke(cli, ["plot", str(path), "-m", "sphere", "-o", str(tmp_path / "sphere.png")])
    assert refused.exit_code == 1, refused.output
    assert "nothing to plot: the samples do not support the sphere calibration" in refused.stderr
    assert not (tmp_path / "sphere.png").exists()
