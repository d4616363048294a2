"""``magfit report``: one self-contained HTML file with the comparison, diagnostics and plots of recordings."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Literal

import click

from ..compare import PAPER_METHODS
from ._common import (
    FitFailedError,
    RegistryChoice,
    console,
    default_method,
    method_names,
    nonfinite_option,
    parse_columns,
    refuse_overwriting_input,
    warn,
)
from ._extras import require
from ._logs import read_recordings, sensor_option, with_streams
from .compare import parse_methods
from .plot import methods_in_order

if TYPE_CHECKING:
    from ..calibration import Calibration
    from ..experiment import Experiment
    from ..report import ReportSection


def check_html_path(output: Path, option: str = "'-o' / '--output'") -> None:
    """Refuse an output that does not end in .html or .htm, before any work is done."""
    if output.suffix.lower() not in (".html", ".htm"):
        raise click.BadParameter(f"{output.name!r} is not an .html file name", param_hint=option)


@click.command("report")
@click.argument("files", nargs=-1, required=True, type=click.Path(dir_okay=False, path_type=Path))
@click.option(
    "-o",
    "--output",
    type=click.Path(dir_okay=False, path_type=Path),
    required=True,
    help="The HTML file to write (self-contained: it opens offline, in any browser).",
)
@click.option(
    "-m",
    "--method",
    type=RegistryChoice("method", method_names),
    default=None,
    help="The main method of each file: its ellipsoid, 3-D views and coverage map are shown "
    "(default: auto when available, else ellipsoid).",
)
@click.option(
    "--methods",
    callback=parse_methods,
    metavar="M,M,...",
    help="Methods compared for each file. Default: the paper's ellipsoid,sphere,minmax.",
)
@click.option(
    "--columns",
    callback=parse_columns,
    metavar="X,Y,Z",
    help="The three magnetometer columns of every file: names or 0-based numbers. Default: detected.",
)
@click.option("--unit", help="Name of the input unit of every file, for the labels (uT, mG, counts ...).")
@click.option("--title", default="magfit calibration report", show_default=True, help="Title of the report.")
@click.option(
    "--max-points",
    type=click.IntRange(min=100),
    default=4000,
    show_default=True,
    help="Samples drawn per panel of the static figures (an even subsample of longer recordings).",
)
@click.option(
    "--max-points-3d",
    type=click.IntRange(min=100),
    default=2000,
    show_default=True,
    help="Samples drawn in each interactive 3-D view (keeps the file at a few MB).",
)
@nonfinite_option
@sensor_option
@click.option(
    "--allow-unfitted",
    is_flag=True,
    help="Write the report even when no method fits a file (its raw samples are shown alone); exit status 0.",
)
def report_command(
    files: tuple[Path, ...],
    output: Path,
    method: str | None,
    methods: tuple[str, ...],
    columns: list[str | int] | None,
    unit: str | None,
    title: str,
    max_points: int,
    max_points_3d: int,
    nonfinite: Literal["skip", "error"],
    sensor: str | None,
    allow_unfitted: bool,
) -> None:
    """Write an HTML report of the calibration of each FILE.

    For each file: the paper's comparison table for every method, the offsets and semi-axes, the
    diagnostics of each fit (coverage, uncertainty, what the data could not determine), the figure of
    'magfit plot' and an interactive 3-D view of the raw and calibrated samples. Everything is inside the
    one file (no network access, no CDN), so it can be mailed or archived as it is. A method that cannot
    fit a file is listed with its reason. When no method fits a file, the exit status is 1 and nothing is
    written (an existing report is kept), unless --allow-unfitted.

    \b
    Examples:
      magfit report mag-readings.txt -o report.html --unit uT
      magfit report flight1.csv flight2.csv --methods ellipsoid,sphere -o flights.html
      magfit report 00000042.BIN -o compasses.html

    A flight log or bag (ULog, DataFlash, ROS) gets a section per compass, or for the one --sensor names.
    """
    from ..compare import compare
    from ..io import atomic_write_text
    from ..report import report_html, section_from_comparison

    require("plot", "magfit report")  # matplotlib and plotly, before anything is read or written
    check_html_path(output)
    refuse_overwriting_input(output, files)
    compared = methods_in_order(method or default_method(), methods or PAPER_METHODS)
    sections: list[ReportSection] = []
    unfitted: list[str] = []
    out = console()
    for path in files:
        for recording in read_recordings(path, columns=columns, nonfinite=nonfinite, sensor=sensor):
            label = str(path) if recording.sensor is None else f"{path} ({recording.sensor})"
            why = f" ({recording.column_note})" if recording.column_note else ""  # no header: why these columns
            notes = [f"Columns {', '.join(map(str, recording.columns))}{why}; {recording.n_rows:,} data rows."]
            if recording.n_skipped:
                notes.append(f"{recording.n_skipped:,} rows with NaN or inf values were skipped.")
            # A method that fails is listed in the report with its reason; the first that succeeds is the main one.
            # vector, gyro: the log's streams, or the samples file's columns found by name (as calibrate finds them)
            samples, streams = with_streams(recording, compared, unit, path=path, columns=columns, nonfinite=nonfinite)
            comparison = compare(samples, compared, streams=streams)
            for result in comparison:
                if not result.ok:
                    warn(f"{label}: {result.method} could not fit these samples: {result.error}")
            if not comparison.any_succeeded:
                unfitted.append(label)
            sections.append(
                section_from_comparison(recording.name, samples, comparison, unit=unit or recording.unit, notes=notes)
            )
            fitted = sum(1 for result in comparison if result.ok)
            out.print(
                f"{label}: {len(samples):,} samples, {fitted} of {len(comparison)} methods fitted",
                soft_wrap=True,
            )
        if sensor is None:
            sections = _with_compasses_section(path, sections)
    if unfitted and not allow_unfitted:  # a failed run leaves an existing report as it was
        raise FitFailedError(
            f"no method could fit {', '.join(map(str, unfitted))}; the report is not written "
            "(remove that file, or pass --allow-unfitted to show its raw samples alone)"
        )
    text = report_html(sections, title=title, max_points=max_points, max_points_3d=max_points_3d)
    atomic_write_text(output, text)
    out.print(f"Wrote the report to {output} ({len(text.encode('utf-8')) / 1e6:.1f} MB)", soft_wrap=True)
    if unfitted:
        warn(f"no method could fit {', '.join(map(str, unfitted))}")


def write_demo_report(output: Path, experiment: Experiment) -> str:
    """Write the HTML report of the paper's simulated experiment (``magfit demo --report``).

    Returns
    -------
    str
        The line to print: where the report went and its size.
    """
    from ..experiment import findings
    from ..io import atomic_write_text
    from ..report import experiment_sections, report_html

    checks = [
        f"{'holds' if item.holds else 'DIFFERS'}: {item.statement} ({item.evidence})" for item in findings(experiment)
    ]
    intro: list[str | list[str]] = [
        "The paper's experiment (section V) re-run on simulated sensors: two sensors, three situations, "
        f"{experiment.n_samples:,} samples per case (seed {experiment.seed}), simulated from the ellipsoids "
        "and offsets the paper reports. Each case shows the three methods, the paper's published numbers "
        "(measured on the authors' real recordings) and the error of each fit against the known truth.",
        "The paper's findings, checked on this run:",
        checks,
    ]
    text = report_html(
        experiment_sections(experiment), title="The paper's experiment on simulated sensors", intro=intro
    )
    atomic_write_text(output, text)
    return f"Wrote the report to {output} ({len(text.encode('utf-8')) / 1e6:.1f} MB)"


def _with_compasses_section(path: Path, sections: list[ReportSection]) -> list[ReportSection]:
    """A log of several compasses: its last section gets the compasses against each other and the firmware's own
    acceptance tests (:func:`magfit.consistency.compare_compasses`, :func:`magfit.firmware_checks.explain_log`)."""
    import dataclasses

    from ..consistency import compare_compasses
    from ..errors import MagfitError
    from ..firmware_checks import explain_log
    from ..pipeline import calibrate_file
    from ..report import compasses_html
    from ..sources import log_kind

    if not sections or log_kind(path) is None:
        return sections
    try:  # forced: the firmware's tests are replayed on every compass, refused ones included
        result = calibrate_file(path, force=True)
    except MagfitError:
        return sections
    comparison = explanation = None
    # Only calibrations the samples support are turned against each other (a forced one would name a rotation
    # that is the calibration's error).
    supported = tuple(c for c in result.compasses if not _forced(c.calibration))
    try:
        kept = dataclasses.replace(result, compasses=supported)
        comparison = compare_compasses(kept) if len(supported) > 1 else None
    except MagfitError:
        comparison = None
    try:
        explanation = explain_log(result)
    except MagfitError:
        explanation = None
    if comparison is None and explanation is None:
        return sections
    last = dataclasses.replace(sections[-1], extra_html=(compasses_html(comparison, explanation),))
    return [*sections[:-1], last]


def _forced(calibration: Calibration) -> bool:
    diagnostics = calibration.diagnostics
    return diagnostics is not None and diagnostics.support is not None and diagnostics.support.forced

