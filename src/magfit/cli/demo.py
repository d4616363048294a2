"""``magfit demo``: the paper's experiment on simulated sensors, printed as the paper's tables."""

from __future__ import annotations

from pathlib import Path

import click
from rich.console import Console
from rich.table import Table
from rich.text import Text

from ..compare import PAPER_METHODS
from ..experiment import (
    DEFAULT_SAMPLES,
    DEFAULT_SEED,
    DISTURBANCE_LABELS,
    METHOD_LABELS,
    PAPER_DISTANCES,
    SENSOR_LABELS,
    Experiment,
    findings,
    run_experiment,
)
from ..simulate import DISTURBANCES, SENSORS
from ._common import console, fixed, significant, vector
from ._extras import require

#: Fewest samples per case: below this the ellipsoid fit of the steel case is not reliably determined.
MIN_DEMO_SAMPLES = 100


@click.command("demo")
@click.option("--seed", type=int, default=DEFAULT_SEED, show_default=True, help="Seed of the simulation.")
@click.option(
    "-n",
    "--samples",
    "n_samples",
    type=click.IntRange(min=MIN_DEMO_SAMPLES),
    default=DEFAULT_SAMPLES,
    show_default=True,
    help="Samples simulated per sensor and disturbance.",
)
@click.option(
    "--report",
    "report_path",
    type=click.Path(dir_okay=False, path_type=Path),
    help="Also write the experiment as a self-contained HTML report (tables, plots, 3-D views).",
)
def demo_command(seed: int, n_samples: int, report_path: Path | None) -> None:
    """Re-run the paper's experiment on simulated sensors and print its tables.

    Two sensors (MPU-9250 in raw counts, SBG Ellipse 2A in normalised units) in three situations (no
    perturbation, a 0.8 kg piece of steel, a smartphone) are simulated from the ellipsoids the paper
    reports; the three methods (ellipsoid: soft + hard iron; sphere: hard iron only; minmax:
    pseudo-calibration) are fitted to each and scored as in the paper's section V: the mean and std of
    the distance of the calibrated samples to the unit sphere. The published values are shown under the
    simulated ones, the true ellipsoids beside the fitted ones, and the paper's conclusions are checked.

    \b
    Example:
      magfit demo
      magfit demo --seed 7 -n 20000
      magfit demo --report demo.html
    """
    from .report import check_html_path, write_demo_report

    if report_path is not None:
        require("plot", "'magfit demo --report'")  # matplotlib and plotly, before the experiment runs
        check_html_path(report_path, "'--report'")
    experiment = run_experiment(n_samples, seed=seed)
    out = console()
    print_distance_tables(out, experiment)
    print_ellipsoid_tables(out, experiment)
    print_findings(out, experiment)
    if report_path is not None:
        out.print(write_demo_report(report_path, experiment), soft_wrap=True)


def print_distance_tables(out: Console, experiment: Experiment) -> None:
    """The paper's first three tables: mean and std of the sphere distances, per disturbance."""
    out.print(Text("Distance of the calibrated samples to the unit sphere (paper, section V)", style="bold"))
    out.print(
        f"{experiment.n_samples} simulated samples per case, seed {experiment.seed}; "
        "the paper's measured values in parentheses"
    )
    for disturbance in DISTURBANCES:
        table = Table(title=DISTURBANCE_LABELS[disturbance], title_justify="left", title_style="bold")
        table.add_column("Method")
        for sensor in SENSORS:
            for statistic in ("mean", "std"):
                table.add_column(f"{SENSOR_LABELS[sensor]}\n{statistic}", justify="right")
        for method in PAPER_METHODS:
            cells = []
            published = []
            for sensor in SENSORS:
                result = experiment.case(sensor, disturbance).comparison[method]
                if result.evaluation is None:
                    cells += ["failed", ""]
                else:
                    cells += [fixed(result.evaluation.mean), fixed(result.evaluation.std)]
                paper = PAPER_DISTANCES[disturbance, method, sensor]
                published += [f"({fixed(paper[0])})", f"({fixed(paper[1])})"]
            table.add_row(f"{METHOD_LABELS[method]} ({method})", *cells)
            table.add_row(Text("  paper", style="dim"), *(Text(cell, style="dim") for cell in published))
        out.print(table)
    failures = [
        f"{case.scenario.name} {result.method}: {result.error}"
        for case in experiment.cases
        for result in case.comparison
        if not result.ok
    ]
    for failure in failures:
        out.print(Text(f"failed: {failure}", style="red"))


def print_ellipsoid_tables(out: Console, experiment: Experiment) -> None:
    """The paper's last two tables: the soft + hard iron fit's semi-axes and offsets, above the truth."""
    out.print(Text("Ellipsoid semi-axes and hard-iron offsets (soft and hard-iron calibration)", style="bold"))
    out.print("Input units; truth: the paper's values, which the simulation uses")
    for sensor in SENSORS:
        table = Table(title=SENSOR_LABELS[sensor], title_justify="left", title_style="bold")
        table.add_column("Case")
        table.add_column("")
        table.add_column("Ellipsoid semi-axes", justify="right")
        table.add_column("Hard-iron offset", justify="right")
        for disturbance in DISTURBANCES:
            case = experiment.case(sensor, disturbance)
            truth = case.simulation.truth
            calibration = case.comparison["ellipsoid"].calibration
            if calibration is None:
                table.add_row(DISTURBANCE_LABELS[disturbance], "fit", "failed", "failed")
            else:
                table.add_row(
                    DISTURBANCE_LABELS[disturbance],
                    "fit",
                    vector(calibration.semi_axes, significant),
                    vector(calibration.offset, significant),
                )
            table.add_row(
                "",
                Text("truth", style="dim"),
                Text(vector(truth.semi_axes, significant), style="dim"),
                Text(vector(truth.offset, significant), style="dim"),
                end_section=True,
            )
        out.print(table)


def print_findings(out: Console, experiment: Experiment) -> None:
    """The paper's conclusions, each marked as holding or not on this run."""
    out.print(Text("The paper's findings on this run", style="bold"))
    for finding in findings(experiment):
        mark = Text("[holds]  ", style="green") if finding.holds else Text("[DIFFERS] ", style="bold red")
        out.print(mark + Text(f"{finding.statement}: {finding.evidence}"))
