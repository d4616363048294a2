"""A self-contained HTML report: one file that opens anywhere, with the network off.

Everything is inside the file: plotly.js inline in one ``<script>``, the figures as base64 PNG data URIs,
the styles inline. A Content-Security-Policy ``<meta>`` forbids the page any network access
(``default-src 'none'``), so even a browser that is online fetches nothing when the report is opened.
"""

from __future__ import annotations

import base64
import datetime
import html
import io
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .. import __version__
from .._validation import as_samples
from ..calibration import CONVENTION, Calibration
from ..errors import MagfitError, OptionError
from ..plot._figure import DEFAULT_MAX_POINTS, METHOD_COLOURS, method_labels, shown_caption
from ..plot._geometry import scan, subsample_for_plot

__all__ = [
    "CONTENT_SECURITY_POLICY",
    "DEFAULT_MAX_POINTS_3D",
    "ReportSection",
    "report_html",
    "write_report",
]

#: Samples drawn in each interactive 3-D scene; keeps a report with several files at a few MB.
DEFAULT_MAX_POINTS_3D = 2000
#: What the report page may load: nothing from the network, only its own inline scripts, styles and
#: data: images. plotly's WebGL code compiles shaders with ``new Function`` (hence 'unsafe-eval').
CONTENT_SECURITY_POLICY = (
    "default-src 'none'; script-src 'unsafe-inline' 'unsafe-eval'; style-src 'unsafe-inline'; "
    "img-src data: blob:; font-src data:; worker-src blob:"
)


@dataclass(frozen=True, eq=False)
class ReportSection:
    """One data set of a report: its samples, the calibrations fitted to them and what else is known.

    Attributes
    ----------
    title : str
        What the data are: a file name, a scenario.
    samples : ndarray, shape (N, 3)
        Raw samples, input units.
    calibrations : tuple of Calibration
        The fits to compare; the first is the main one (3-D views, coverage).
    unit : str or None
        Input unit; default the first calibration's.
    failures : mapping of str to str
        Methods that could not fit the samples, with the reason.
    truth : Calibration or None
        The true calibration when known (simulated data): shown beside the fits.
    published : mapping of str to (float, float)
        Published mean and std of the sphere distance per method (the paper's table), when there is one.
    notes : tuple of str
        Paragraphs shown under the title (plain text).
    diagnostics : mapping or None
        Diagnostics of the data (coverage, uncertainty, what could not be determined) for the whole
        section; each calibration's own ``details["diagnostics"]`` is shown as well.
    extra_html : tuple of str
        Ready HTML fragments shown after the notes (:func:`magfit.report.compasses.compasses_html`).
    """

    title: str
    samples: NDArray[np.float64]
    calibrations: tuple[Calibration, ...]
    unit: str | None = None
    failures: Mapping[str, str] = field(default_factory=dict)
    truth: Calibration | None = None
    published: Mapping[str, tuple[float, float]] = field(default_factory=dict)
    notes: tuple[str, ...] = ()
    diagnostics: Mapping[str, Any] | None = None
    extra_html: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        object.__setattr__(self, "samples", as_samples(self.samples))
        object.__setattr__(self, "calibrations", tuple(self.calibrations))
        for item in self.calibrations:
            if not isinstance(item, Calibration):
                raise OptionError(f"ReportSection.calibrations must hold magfit.Calibration, got {type(item).__name__}")
        if not self.calibrations and not self.failures:
            raise OptionError(f"report section {self.title!r} has no calibration and no failure to show")

    @property
    def display_unit(self) -> str:
        if self.unit:
            return self.unit
        for item in self.calibrations:
            if item.unit:
                return item.unit
        return "raw units"


# ---------------------------------------------------------------------------------------------- the page


def report_html(
    sections: Iterable[ReportSection],
    *,
    title: str = "magfit calibration report",
    intro: Sequence[str | Sequence[str]] = (),
    max_points: int = DEFAULT_MAX_POINTS,
    max_points_3d: int = DEFAULT_MAX_POINTS_3D,
    seed: int | None = 0,
) -> str:
    """Render the report as one self-contained HTML document.

    Parameters
    ----------
    sections : iterable of ReportSection
        One per data set (file), in order.
    title : str
        Page title and heading.
    intro : sequence of str or of sequences of str
        Under the heading: each str is a paragraph, each sequence of str a bulleted list (plain text).
    max_points : int
        Samples drawn in each panel of the static figure (see :func:`magfit.plot.calibration_figure`).
    max_points_3d : int
        Samples drawn in each interactive 3-D scene.
    seed : int or None
        Seed of the subsamples.

    Returns
    -------
    str
        The HTML text (UTF-8). About 5 MB of it is plotly.js; each section adds a few hundred kB.
    """
    import plotly.offline

    items = list(sections)
    if not items:
        raise OptionError("a report needs at least one section (one data file)")
    generated = datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    body = [
        f"<header><h1>{_e(title)}</h1>",
        f"<p class='meta'>Generated by magfit {_e(__version__)} on {generated}. "
        f"Every calibration is applied as <code>{_e(CONVENTION)}</code>; the corrected samples lie on a "
        "sphere of radius B (the field strength).</p>",
        *[_intro_html(part) for part in intro],
        "<p class='meta'>The comparison metric is the paper's (section V): the signed distance "
        "<code>|corrected| / B − 1</code> of every sample to the unit sphere, its mean and standard deviation. "
        "It is measured on the samples the methods were fitted to, so a method with more parameters never "
        "looks worse on it.</p>",
        "</header>",
    ]
    if len(items) > 1:
        links = "".join(f"<li><a href='#section-{i}'>{_e(s.title)}</a></li>" for i, s in enumerate(items))
        body.append(f"<nav><h2>Contents</h2><ol>{links}</ol></nav>")
    for index, section in enumerate(items):
        body.append(_section_html(index, section, max_points=max_points, max_points_3d=max_points_3d, seed=seed))
    return _PAGE.format(
        csp=_e(CONTENT_SECURITY_POLICY),
        title=_e(title),
        style=_STYLE,
        plotly=plotly.offline.get_plotlyjs(),
        body="\n".join(body),
        viewer=_VIEWER,
    )


def _intro_html(part: str | Sequence[str]) -> str:
    if isinstance(part, str):
        return f"<p>{_e(part)}</p>"
    return "<ul>" + "".join(f"<li>{_e(item)}</li>" for item in part) + "</ul>"


def write_report(path: str | Path, sections: Iterable[ReportSection], **options: Any) -> Path:
    """Write :func:`report_html` to ``path`` (UTF-8) and return the path.

    ``options`` are those of :func:`report_html` (``title``, ``intro``, ``max_points``, ``max_points_3d``,
    ``seed``).
    """
    target = Path(path)
    if not target.parent.is_dir():
        raise OptionError(f"cannot write the report {target}: the folder {target.parent} does not exist")
    target.write_text(report_html(sections, **options), encoding="utf-8")
    return target


# ---------------------------------------------------------------------------------------------- a section


def _section_html(index: int, section: ReportSection, *, max_points: int, max_points_3d: int, seed: int | None) -> str:
    from ..plot import calibration_figure, figure_png
    from ._interactive import interactive_figure, raw_figure

    unit = section.display_unit
    samples = section.samples
    labels = method_labels(section.calibrations)
    parts = [f"<section id='section-{index}'><h2>{_e(section.title)}</h2>"]
    summary = f"{samples.shape[0]:,} samples, unit: {unit}."
    if section.calibrations:
        main = section.calibrations[0]
        summary += f" Field strength B = {main.field_strength:.5g} {unit} ({labels[0]} fit)."
    parts.append(f"<p>{_e(summary)}</p>")
    parts += [f"<p>{_e(note)}</p>" for note in section.notes]
    parts += list(section.extra_html)
    parts.append(_comparison_table(section, labels))
    if section.calibrations:
        parts.append(_parameter_table(section, labels, unit))
    parts.append(_diagnostics_html(section, labels))
    if not section.calibrations:
        # Nothing calibrated to plot, but the raw samples show why: a cap, a ring, a plane, not an ellipsoid.
        step = max(1, int(np.ceil(samples.shape[0] / max_points_3d)))
        shown = samples[::step]
        parts.append("<p class='failure'>No method could fit these samples: the raw samples are shown alone.</p>")
        caption = (
            f"All {samples.shape[0]:,} samples shown."
            if step == 1
            else f"{shown.shape[0]:,} of {samples.shape[0]:,} samples shown: one in {step}, in recording order."
        )
        parts.append(_view_html(index, raw_figure(shown, unit=unit), caption))
        parts.append("</section>")
        return "\n".join(parts)

    figure = calibration_figure(
        samples,
        section.calibrations,
        unit=unit,
        title=section.title,
        seed=seed,
        max_points=max_points,
    )
    png = _compact_png(figure_png(figure))
    caption = figure.get_supxlabel()  # "N of M samples shown ..."
    parts.append(
        "<figure class='static'>"
        f"<img alt='Calibration plots for {_e(section.title)}' src='data:image/png;base64,"
        f"{base64.b64encode(png).decode('ascii')}'>"
        f"<figcaption>{_e(caption)} Top: raw samples with the fitted ellipsoid, the calibrated samples on "
        "the unit sphere, and the directions the field took in the sensor frame (equal-area map). Middle and "
        "bottom: the XY, XZ and YZ projections before and after calibration, each method's distance to the "
        "unit sphere and its fitted parameters.</figcaption></figure>"
    )
    shown_3d = subsample_for_plot(samples, section.calibrations[0], max_points_3d, seed=seed)
    view = interactive_figure(samples[shown_3d], section.calibrations, labels, unit=unit)
    caption = shown_caption(shown_3d.size, samples.shape[0]) + " Other methods can be switched on in the legend."
    parts.append(_view_html(index, view, caption))
    parts.append("</section>")
    return "\n".join(parts)


def _view_html(index: int, view: Any, caption: str) -> str:
    """A lazily drawn plotly view: an empty div and its figure as inert JSON (see ``_VIEWER``)."""
    view_json = view.to_json(validate=False, pretty=False).replace("</", "<\\/")  # cannot close the <script>
    return (
        "<figure class='interactive'><h3>Interactive 3-D view (drag to turn, scroll to zoom)</h3>"
        f"<div class='view-3d' id='view-3d-{index}'></div>"
        f"<script type='application/json' id='view-3d-{index}-figure'>{view_json}</script>"
        f"<figcaption>{_e(caption)}</figcaption></figure>"
    )


def _comparison_table(section: ReportSection, labels: Sequence[str]) -> str:
    published = dict(section.published)
    truth = section.truth
    head = ["method", "mean", "std", "mean |d|", "RMS", "max |d|"]
    if published:
        head += ["published mean", "published std"]
    if truth is not None:
        head += [f"offset error ({section.display_unit})", "shape error"]
    rows = []
    all_distances, _ = scan(section.samples, section.calibrations) if section.calibrations else ((), None)
    for index, (calibration, label, distances) in enumerate(
        zip(section.calibrations, labels, all_distances, strict=True)
    ):
        magnitude = np.abs(distances)
        cells = [
            _method_cell(label, index),
            _number(distances.mean(), "+.4f"),
            _number(distances.std(), ".4f"),
            _number(magnitude.mean(), ".4f"),
            _number(np.sqrt(np.mean(distances**2)), ".4f"),
            _number(magnitude.max(), ".4f"),
        ]
        if published:
            reference = published.get(calibration.method)
            cells += [_number(reference[0], ".4f"), _number(reference[1], ".4f")] if reference else ["<td>–</td>"] * 2
        if truth is not None:
            offset_error = float(np.linalg.norm(calibration.offset - truth.offset))
            # Only A = matrixᵀ matrix / B² is identifiable (eq. 2): compare that, relative to the truth's.
            shape_error = float(
                np.linalg.norm(calibration.ellipsoid_matrix - truth.ellipsoid_matrix)
                / np.linalg.norm(truth.ellipsoid_matrix)
            )
            cells += [_number(offset_error, ".4g"), _number(shape_error, ".2%")]
        rows.append(f"<tr>{''.join(cells)}</tr>")
    for method, reason in section.failures.items():
        rows.append(
            f"<tr class='failure'><td>{_e(method)}</td>"
            f"<td colspan='{len(head) - 1}'>could not fit: {_e(reason)}</td></tr>"
        )
    notes = "Distance d = |corrected| / B − 1 of each sample to the unit sphere (dimensionless)."
    if truth is not None:
        notes += (
            " Offset error: distance between the fitted and the true hard-iron offset. Shape error: "
            "‖A − A_true‖ / ‖A_true‖ for the ellipsoid matrix A of eq. (2), the part of the soft iron the data fix."
        )
    return _table("The paper's comparison (section V)", head, rows, notes, css_class="comparison")


def _parameter_table(section: ReportSection, labels: Sequence[str], unit: str) -> str:
    head = ["method", f"B ({unit})", f"offset V ({unit})", f"semi-axes ({unit})", "correction matrix (dimensionless)"]
    entries: list[tuple[str, Calibration, int | None]] = [
        (label, calibration, index)
        for index, (calibration, label) in enumerate(zip(section.calibrations, labels, strict=True))
    ]
    if section.truth is not None:
        entries.append(("truth", section.truth, None))
    rows = []
    for label, calibration, index in entries:
        matrix = "<br>".join(" ".join(f"{value:+.5f}" for value in row) for row in calibration.matrix)
        rows.append(
            "<tr>"
            + (_method_cell(label, index) if index is not None else f"<td><em>{_e(label)}</em></td>")
            + _number(calibration.field_strength, ".5g")
            + f"<td class='num'>{_vector(calibration.offset)}</td>"
            + f"<td class='num'>{_vector(calibration.semi_axes)}</td>"
            + f"<td class='num matrix'>{matrix}</td></tr>"
        )
    return _table(
        "Fitted parameters",
        head,
        rows,
        "Semi-axis i is the ellipsoid axis closest to sensor axis i (x, y, z), as in the paper's tables.",
        css_class="parameters",
    )


def _diagnostics_html(section: ReportSection, labels: Sequence[str]) -> str:
    """Each fit's diagnostics (``details["diagnostics"]``, see :mod:`magfit.diagnostics`), warnings first.

    The main fit's are open, the others folded. Diagnostics in a layout this magfit cannot read are shown
    as they are stored.
    """
    blocks = []
    if section.diagnostics:
        blocks.append(f"<details open><summary>The data</summary>{_mapping_html(section.diagnostics)}</details>")
    for index, (label, calibration) in enumerate(zip(labels, section.calibrations, strict=True)):
        stored = calibration.details.get("diagnostics")
        if not stored:
            continue
        lines = _diagnostic_lines(stored)
        warned = any(line.startswith("WARNING") for line in lines)
        status = "<span class='warn'>warnings</span>" if warned else "no warning"
        body = (
            "<ul>" + "".join(f"<li class='{_line_class(line)}'>{_e(line)}</li>" for line in lines) + "</ul>"
            if lines
            else _mapping_html(stored)
        )
        opened = " open" if index == 0 or warned else ""
        blocks.append(f"<details{opened}><summary>{_e(label)}: {status}</summary>{body}</details>")
    if not blocks:
        return ""
    return (
        "<div class='diagnostics'><h3>Diagnostics: coverage, uncertainty, what the data could not determine</h3>"
        + "".join(blocks)
        + "</div>"
    )


def _diagnostic_lines(stored: Mapping[str, Any]) -> list[str]:
    """The plain-language summary of stored diagnostics, or [] when their layout is not readable here."""
    try:
        from ..diagnostics import Diagnostics

        return list(Diagnostics.from_dict(dict(stored)).summary())
    except (ImportError, MagfitError, KeyError, TypeError, ValueError):
        return []


def _line_class(line: str) -> str:
    return "warning" if line.startswith("WARNING") else "finding"


def _mapping_html(value: Any) -> str:
    """Nested mappings and lists as nested definition lists; numbers with 4 significant digits."""
    if isinstance(value, Mapping):
        items = "".join(
            f"<dt>{_e(str(key).replace('_', ' '))}</dt><dd>{_mapping_html(item)}</dd>" for key, item in value.items()
        )
        return f"<dl>{items}</dl>"
    if isinstance(value, (list, tuple)):
        if all(isinstance(item, (int, float)) and not isinstance(item, bool) for item in value):
            return "(" + ", ".join(_format_scalar(item) for item in value) + ")"
        return "<ul>" + "".join(f"<li>{_mapping_html(item)}</li>" for item in value) + "</ul>"
    return _e(_format_scalar(value))


def _format_scalar(value: Any) -> str:
    if isinstance(value, bool) or value is None:
        return {True: "yes", False: "no", None: "–"}[value]
    if isinstance(value, float):
        return f"{value:.4g}"
    return str(value)


# ---------------------------------------------------------------------------------------------- helpers


def _e(text: str) -> str:
    return html.escape(text, quote=True)


def _number(value: float, spec: str) -> str:
    return f"<td class='num'>{format(float(value), spec)}</td>"


def _vector(values: ArrayLike) -> str:
    return "(" + ", ".join(f"{value:.5g}" for value in np.asarray(values, dtype=np.float64)) + ")"


def _method_cell(label: str, index: int | None) -> str:
    colour = METHOD_COLOURS[(index or 0) % len(METHOD_COLOURS)]
    return f"<td><span class='swatch' style='background:{colour}'></span>{_e(label)}</td>"


def _table(caption: str, head: Sequence[str], rows: Sequence[str], note: str, *, css_class: str) -> str:
    header = "".join(f"<th>{_e(name)}</th>" for name in head)
    return (
        f"<table class='{css_class}'><caption>{_e(caption)}</caption><thead><tr>{header}</tr></thead>"
        f"<tbody>{''.join(rows)}</tbody></table><p class='note'>{_e(note)}</p>"
    )


def _compact_png(png: bytes) -> bytes:
    """Re-encode a PNG with a 256-colour palette: a plot has few colours, and the file shrinks ~3x."""
    from PIL import Image  # Pillow ships with matplotlib

    with Image.open(io.BytesIO(png)) as image:
        palette = image.convert("RGB").quantize(colors=256, method=Image.Quantize.MEDIANCUT, dither=Image.Dither.NONE)
        buffer = io.BytesIO()
        palette.save(buffer, format="PNG", optimize=True)
    return buffer.getvalue()


_STYLE = """
body { font-family: system-ui, -apple-system, "Segoe UI", Roboto, sans-serif; margin: 0 auto; max-width: 1640px;
       padding: 0 24px 48px; color: #222; line-height: 1.45; }
h1 { margin-top: 24px; } h2 { border-bottom: 2px solid #1f77b4; padding-bottom: 4px; margin-top: 40px; }
.meta, .note { color: #555; font-size: 0.92em; }
table { border-collapse: collapse; margin: 12px 0 4px; font-size: 0.95em; }
caption { text-align: left; font-weight: 600; padding-bottom: 6px; }
th, td { border: 1px solid #ccc; padding: 4px 10px; }
th { background: #f1f4f8; } td.num { text-align: right; font-variant-numeric: tabular-nums; }
td.matrix { font-family: ui-monospace, monospace; font-size: 0.85em; white-space: nowrap; }
tr.failure td { color: #a00; }
.swatch { display: inline-block; width: 10px; height: 10px; margin-right: 6px; border-radius: 2px; }
figure { margin: 20px 0; } figure img { max-width: 100%; height: auto; border: 1px solid #ddd; }
div.view-3d { height: 540px; width: 100%; }
figcaption { color: #555; font-size: 0.92em; margin-top: 6px; }
.diagnostics dl { display: grid; grid-template-columns: max-content auto; gap: 2px 16px; margin: 4px 0; }
.diagnostics dt { font-weight: 600; } .diagnostics dd { margin: 0; }
.diagnostics summary { font-weight: 600; cursor: pointer; margin: 6px 0; }
.diagnostics li.warning, .warn { color: #a00; font-weight: 600; }
p.failure { color: #a00; font-weight: 600; }
"""

# Each 3-D view is drawn when it comes near the window and freed when it leaves: a browser keeps only
# about 16 WebGL contexts alive, and a report of many files would otherwise lose the first views.
_VIEWER = """
(function () {
  // No plotly logo link and no "share chart" upload button: the report stays offline.
  var config = {displaylogo: false, showSendToCloud: false, showLink: false, responsive: true};
  function draw(div) {
    if (div.dataset.drawn) return;
    var figure = JSON.parse(document.getElementById(div.id + "-figure").textContent);
    div.dataset.drawn = "1";
    Plotly.newPlot(div, figure.data, figure.layout, config);
  }
  function free(div) {
    if (!div.dataset.drawn) return;
    delete div.dataset.drawn;
    Plotly.purge(div);
  }
  var views = document.querySelectorAll(".view-3d");
  if (!("IntersectionObserver" in window)) { views.forEach(draw); return; }
  var observer = new IntersectionObserver(function (entries) {
    entries.forEach(function (entry) { (entry.isIntersecting ? draw : free)(entry.target); });
  }, {rootMargin: "600px 0px"});
  views.forEach(function (div) { observer.observe(div); });
})();
"""

_PAGE = """<!DOCTYPE html>
<html lang="en">
<head>
<meta charset="utf-8">
<meta http-equiv="Content-Security-Policy" content="{csp}">
<meta name="viewport" content="width=device-width, initial-scale=1">
<title>{title}</title>
<style>{style}</style>
<script>{plotly}</script>
</head>
<body>
{body}
<script>{viewer}</script>
</body>
</html>
"""
