"""The HTML report (magfit.report) and the ``magfit plot`` / ``magfit report`` commands, without a browser.

The browser test (tests/test_report_browser.py) opens the same kind of report in headless Chromium.
"""

from __future__ import annotations

import base64
import io
import json
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

import magfit
from magfit.errors import OptionError

report = pytest.importorskip("magfit.report")  # needs the plot extra (matplotlib, plotly)
PIL_Image = pytest.importorskip("PIL.Image")


class _Page(HTMLParser):
    """Collects what the tests look at: every src/href, the tables' cells, the <script> blocks, the images."""

    def __init__(self) -> None:
        super().__init__()
        self.links: list[str] = []
        self.images: list[str] = []
        self.tables: dict[str, list[list[str]]] = {}  # the first table of each class
        self.table_list: list[tuple[str, list[list[str]]]] = []  # every table, in order
        self.scripts: list[tuple[dict[str, str | None], str]] = []
        self.meta: list[dict[str, str | None]] = []
        self._table: str | None = None
        self._cell: list[str] | None = None
        self._script: dict[str, str | None] | None = None
        self._script_text: list[str] = []

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        attributes = dict(attrs)
        for name in ("src", "href"):
            if attributes.get(name):
                self.links.append(str(attributes[name]))
        if tag == "img":
            self.images.append(str(attributes.get("src")))
        if tag == "meta":
            self.meta.append(attributes)
        if tag == "table":
            self._table = str(attributes.get("class"))
            self.table_list.append((self._table, []))
            self.tables.setdefault(self._table, self.table_list[-1][1])
        if tag == "tr" and self._table is not None:
            self.table_list[-1][1].append([])
        if tag in ("td", "th") and self._table is not None:
            self._cell = []
        if tag == "script":
            self._script, self._script_text = attributes, []

    def handle_endtag(self, tag: str) -> None:
        if tag in ("td", "th") and self._cell is not None and self._table is not None:
            self.table_list[-1][1][-1].append("".join(self._cell).strip())
            self._cell = None
        if tag == "table":
            self._table = None
        if tag == "script" and self._script is not None:
            self.scripts.append((self._script, "".join(self._script_text)))
            self._script = None

    def handle_data(self, data: str) -> None:
        if self._cell is not None:
            self._cell.append(data)
        if self._script is not None:
            self._script_text.append(data)


def _parse(html: str) -> _Page:
    page = _Page()
    page.feed(html)
    return page


@pytest.fixture(scope="module")
def steel_case():
    """One case of the paper's experiment: the MPU-9250 with the piece of steel (strong, turned soft iron)."""
    from magfit.experiment import run_experiment

    return run_experiment(2000, seed=11, sensors=("mpu9250",), disturbances=("steel",))


@pytest.fixture(scope="module")
def steel_section(steel_case):
    (section,) = report.experiment_sections(steel_case)
    return steel_case.cases[0].simulation, section


@pytest.fixture(scope="module")
def steel_page(steel_case, tmp_path_factory):
    """The report ``magfit demo --report`` writes, for that one case."""
    from magfit.cli.report import write_demo_report

    output = tmp_path_factory.mktemp("demo") / "demo.html"
    line = write_demo_report(output, steel_case)
    assert line.startswith(f"Wrote the report to {output} (") and line.endswith(" MB)")
    html = output.read_text(encoding="utf-8")
    return html, _parse(html)


@pytest.mark.slow
def test_report_is_self_contained_and_forbids_network_access(steel_page) -> None:
    html, page = steel_page
    # Every src/href is in the page itself: in-page anchors or data: URIs; no CDN, no http(s), no file path.
    assert page.links, "the report has images"
    for link in page.links:
        assert link.startswith(("#", "data:")), link
    policy = [m for m in page.meta if (m.get("http-equiv") or "").lower() == "content-security-policy"]
    assert len(policy) == 1
    assert "default-src 'none'" in str(policy[0]["content"])
    assert "connect-src" not in str(policy[0]["content"])  # falls back to 'none': no fetch, no XHR
    # plotly.js itself is inline (no <script src=...>), once.
    inline = [text for attributes, text in page.scripts if "src" not in attributes and "Plotly" in text]
    assert any(len(text) > 1_000_000 for text in inline)
    assert sum(1 for attributes, _ in page.scripts if attributes.get("src")) == 0
    assert html.count("<script>") == 2  # plotly.js and the viewer; the figures are inert JSON blocks
    # A few MB: plotly.js (~4.8 MB) and one section's PNG and 3-D data.
    assert len(html.encode()) < 6.5e6


@pytest.mark.slow
def test_comparison_table_holds_the_papers_metric_and_the_error_to_the_truth(steel_section, steel_page) -> None:
    simulation, section = steel_section
    _, page = steel_page
    rows = page.tables["comparison"]
    header, body = rows[0], rows[1:]
    assert header == [
        "method", "mean", "std", "mean |d|", "RMS", "max |d|", "published mean", "published std",
        "offset error (counts)", "shape error",
    ]  # fmt: skip
    # sphere and minmax cannot remove the steel's soft iron: scored as the paper did, marked as not supported
    assert [row[0] for row in body] == ["ellipsoid", "sphere (not supported)", "minmax (not supported)"]
    # The paper's own numbers for this case (section V, MPU-9250, piece of steel), beside the simulated ones.
    assert [row[6:8] for row in body] == [["0.0088", "0.0462"], ["0.0079", "0.1254"], ["0.0469", "0.1550"]]
    for row, calibration in zip(body, section.calibrations, strict=True):
        score = magfit.evaluate(calibration, simulation.samples)
        assert row[1:6] == [
            f"{score.mean:+.4f}",
            f"{score.std:.4f}",
            f"{score.mean_abs:.4f}",
            f"{score.rms:.4f}",
            f"{score.max_abs:.4f}",
        ]
        offset_error = np.linalg.norm(calibration.offset - simulation.truth.offset)
        assert row[-2] == f"{offset_error:.4g}"
    # The ground truth of the steel case: the ellipsoid fit finds the offset to ~1 count (noise 6.4 counts
    # over 2000 samples) and A within 1 %; the sphere and min/max fits cannot model the steel's soft iron.
    ellipsoid, sphere, minmax = body
    assert float(ellipsoid[-2]) < 3.0 and float(ellipsoid[-1].rstrip("%")) < 1.0
    assert float(sphere[-1].rstrip("%")) > 50 and float(minmax[-1].rstrip("%")) > 50


def test_parameter_table_has_offsets_semi_axes_and_the_truth(steel_section, steel_page) -> None:
    simulation, _ = steel_section
    _, page = steel_page
    rows = page.tables["parameters"]
    assert rows[0][:4] == ["method", "B (counts)", "offset V (counts)", "semi-axes (counts)"]
    assert [row[0] for row in rows[1:]] == ["ellipsoid", "sphere (not supported)", "minmax (not supported)", "truth"]
    truth_row = rows[-1]
    assert truth_row[2] == "(" + ", ".join(f"{v:.5g}" for v in simulation.truth.offset) + ")"
    assert truth_row[3] == "(" + ", ".join(f"{v:.5g}" for v in simulation.truth.semi_axes) + ")"
    # The paper's steel ellipsoid: semi-axes 193, 714, 1362 counts.
    np.testing.assert_allclose(simulation.truth.semi_axes, [193, 714, 1362], rtol=1e-9)


def test_report_embeds_the_figure_as_a_png_and_the_3d_view_as_data(steel_page) -> None:
    html, page = steel_page
    (image,) = page.images
    assert image.startswith("data:image/png;base64,")
    png = base64.b64decode(image.split(",", 1)[1])
    with PIL_Image.open(io.BytesIO(png)) as picture:
        assert picture.size == (1600, 1200)
        pixels = np.asarray(picture.convert("RGB"), dtype=np.float64)
    assert pixels.std() > 20
    assert "All 2,000 samples shown. The 3-D panels show one in 2 of them." in html  # the figure's caption
    (figure_json,) = [text for attributes, text in page.scripts if attributes.get("type") == "application/json"]
    figure = json.loads(figure_json)
    kinds = [(trace["type"], trace.get("mode"), trace["name"]) for trace in figure["data"]]
    assert ("scatter3d", "markers", "raw samples") in kinds
    assert ("scatter3d", "lines", "fitted ellipsoid (ellipsoid)") in kinds
    assert [name for _, mode, name in kinds if name.startswith("calibrated by")] == [
        "calibrated by ellipsoid",
        "calibrated by sphere (not supported)",
        "calibrated by minmax (not supported)",
    ]
    raw = next(trace for trace in figure["data"] if trace["name"] == "raw samples")
    n_points = len(base64.b64decode(raw["x"]["bdata"])) // 4  # float32
    assert raw["x"]["dtype"] == "f4" and n_points == 2000  # all of them: within the 3-D budget of 2000
    assert figure["layout"]["scene"]["xaxis"]["title"]["text"] == "x (counts)"


def test_diagnostics_of_each_fit_are_shown(steel_section, steel_page) -> None:
    html, _ = steel_page
    _, section = steel_section
    if "diagnostics" not in section.calibrations[0].details:
        pytest.skip("this magfit does not attach diagnostics to its fits")
    assert "Diagnostics: coverage, uncertainty, what the data could not determine" in html
    assert "Coverage: the samples reach" in html
    assert "Uncertainty (one-sigma)" in html


def test_report_html_refuses_bad_input(tmp_path) -> None:
    with pytest.raises(OptionError, match="at least one section"):
        report.report_html([])
    samples = magfit.simulate(100, seed=1).samples
    with pytest.raises(OptionError, match="no calibration and no failure"):
        report.ReportSection("empty", samples, ())
    section = report.ReportSection("ok", samples, (magfit.Calibration.identity(),))
    with pytest.raises(OptionError, match="does not exist"):
        report.write_report(tmp_path / "missing" / "report.html", [section])


def test_experiment_sections_name_each_case_and_carry_its_truth(steel_section) -> None:
    simulation, section = steel_section
    assert section.title == "MPU-9250, 0.8 kg piece of steel (simulated)"
    assert section.truth is simulation.truth
    assert section.display_unit == "counts"


# ---------------------------------------------------------------------- the commands


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    """A CSV with a time column and the paper's MPU-9250 next to a smartphone (strong hard iron)."""
    simulation = magfit.scenario("mpu9250", "smartphone").simulate(1500, seed=13)
    path = tmp_path_factory.mktemp("report") / "phone.csv"
    time = np.arange(1500) * 0.01
    np.savetxt(path, np.column_stack([time, simulation.samples]), fmt="%.10g", delimiter=",", header="t,mx,my,mz")
    return path, simulation


def test_plot_command_refuses_a_non_figure_output_its_own_input_and_a_failed_main_fit(recording, tmp_path) -> None:
    from magfit.cli import cli

    path, _ = recording
    result = CliRunner().invoke(cli, ["plot", str(path), "-o", str(tmp_path / "figure.txt")])
    assert result.exit_code == 2
    assert "'figure.txt' has no figure extension; use one of .png, .svg, .pdf" in result.output
    odd = tmp_path / "samples.svg"  # a recording whose name ends like a figure: never overwritten
    odd.write_bytes(path.read_bytes())
    result = CliRunner().invoke(cli, ["plot", str(odd), "-o", str(odd)])
    assert result.exit_code == 2 and "is the input file" in result.output
    # Samples in a plane (level turns at zero inclination): the main fit fails, there is nothing to draw.
    flat = tmp_path / "flat.txt"
    np.savetxt(flat, magfit.simulate(300, orientations="yaw", inclination_deg=0.0, field_strength=50.0, seed=2).samples)
    result = CliRunner().invoke(cli, ["plot", str(flat), "--method", "ellipsoid", "-o", str(tmp_path / "flat.png")])
    assert result.exit_code == 1
    where = f"{flat} (columns column 1, column 2, column 3)"
    assert f"{where}: the ellipsoid fit failed, nothing to plot: the samples lie in a plane" in result.output
    assert not (tmp_path / "flat.png").exists()


@pytest.mark.slow
def test_report_command_writes_one_html_for_several_files(recording, tmp_path) -> None:
    from magfit.cli import cli

    path, _ = recording
    # Level turns only, at zero inclination: the samples lie in a plane, so no method can fit them.
    flat = tmp_path / "flat.txt"
    np.savetxt(flat, magfit.simulate(300, orientations="yaw", inclination_deg=0.0, field_strength=50.0, seed=2).samples)
    output = tmp_path / "report.html"
    result = CliRunner().invoke(
        cli,
        ["report", str(path), str(flat), "--method", "ellipsoid", "--max-points", "300", "--max-points-3d", "200",
         "--allow-unfitted", "-o", str(output)],
    )  # fmt: skip
    # With --allow-unfitted the report is written with the unfitted file's raw samples (without: exit 1, nothing
    # written, tests/test_reliability.py).
    assert result.exit_code == 0, result.output
    assert f"Wrote the report to {output}" in result.output
    assert f"no method could fit {flat}" in result.output
    page = _parse(output.read_text(encoding="utf-8"))
    assert [link for link in page.links if link.startswith("#")] == ["#section-0", "#section-1"]
    assert all(link.startswith(("#", "data:")) for link in page.links)
    assert len(page.images) == 1  # the flat file has no calibration to plot ...
    views = [json.loads(text) for attributes, text in page.scripts if attributes.get("type") == "application/json"]
    assert len(views) == 2  # ... but its raw samples are shown in 3-D, to see why
    assert [trace["name"] for trace in views[1]["data"]] == ["raw samples"]
    assert "No method could fit these samples: the raw samples are shown alone." in output.read_text(encoding="utf-8")
    comparisons = [rows for kind, rows in page.table_list if kind == "comparison"]
    assert [row[0] for row in comparisons[0][1:]] == ["ellipsoid", "sphere", "minmax"]
    failed = comparisons[1][1:]
    assert [row[0] for row in failed] == ["ellipsoid", "sphere", "minmax"]
    assert all(row[1].startswith("could not fit: the samples lie in a plane") for row in failed)
    bad = CliRunner().invoke(cli, ["report", str(path), "-o", str(tmp_path / "report.pdf")])
    assert bad.exit_code == 2 and "'report.pdf' is not an .html file name" in bad.output


@pytest.mark.slow
def test_plot_command_on_a_real_recording(real_data_dir: Path, tmp_path: Path) -> None:
    from magfit.cli import cli
    from magfit.io import read_samples

    recording = real_data_dir / "fxos8700_magneto" / "mag-readings.txt"  # 324 samples, µT, tab-separated
    output = tmp_path / "fxos.png"
    result = CliRunner().invoke(
        cli,
        ["plot", str(recording), "--method", "ellipsoid", "--methods", "sphere", "--unit", "uT", "--dpi", "40",
         "-o", str(output)],
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    with PIL_Image.open(output) as picture:
        assert picture.size == (640, 480)  # 16 x 12 inches at 40 dpi
        assert np.asarray(picture.convert("L"), dtype=np.float64).std() > 20
    # The main method first, then the others asked for (each once); the numbers are magfit.evaluate's.
    samples = read_samples(recording).samples
    lines = [line for line in result.output.splitlines() if "sphere distance" in line]
    assert [line.split()[0] for line in lines] == ["ellipsoid", "sphere"]
    for line, method in zip(lines, ("ellipsoid", "sphere"), strict=True):
        score = magfit.evaluate(magfit.fit(samples, method=method), samples)
        assert line.endswith(f"sphere distance mean {score.mean:.4f}  std {score.std:.4f}")
    assert f"All 324 samples shown. Wrote the figure to {output}" in result.output


@pytest.mark.slow
def test_calibrate_plot_draws_the_fit_it_saved(recording, tmp_path) -> None:
    from magfit.cli import cli

    path, _ = recording
    figure, saved = tmp_path / "fit.png", tmp_path / "fit.json"
    result = CliRunner().invoke(
        cli, ["calibrate", str(path), "--method", "sphere", "--unit", "counts", "-o", str(saved), "--plot", str(figure)]
    )
    assert result.exit_code == 0, result.output
    assert f"All 1,500 samples shown. Wrote the figure to {figure}" in result.output
    with PIL_Image.open(figure) as picture:
        assert picture.size == (1600, 1200)
        assert np.asarray(picture.convert("L"), dtype=np.float64).std() > 20
    refused = CliRunner().invoke(cli, ["calibrate", str(path), "--plot", str(tmp_path / "fit.txt")])
    assert refused.exit_code == 2 and "Invalid value for '--plot': 'fit.txt' has no figure extension" in refused.output


def test_demo_report_is_refused_before_the_experiment_runs(tmp_path, steel_page) -> None:
    from magfit.cli import cli

    refused = CliRunner().invoke(cli, ["demo", "--report", str(tmp_path / "demo.pdf")])
    assert (
        refused.exit_code == 2
        and "Invalid value for '--report': 'demo.pdf' is not an .html file name" in refused.output
    )
    assert "Distance of the calibrated samples" not in refused.output  # nothing ran
    # The report it writes states the paper's findings on the run (steel_page is write_demo_report's output).
    html, _ = steel_page
    assert "The paper&#x27;s findings, checked on this run:</p>" in html
    assert "<ul><li>holds: MPU-9250, steel: ellipsoid std 3x or more below sphere and minmax" in html
