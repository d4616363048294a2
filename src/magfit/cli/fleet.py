"""``magfit fleet``: every compass of many recordings of many vehicles in one run, into one table."""

from __future__ import annotations

import datetime
import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

import click
from rich.console import Console

from ..fleet import FleetResult, fleet
from ..geomag import parse_date, parse_location
from ._common import FitFailedError, console, geomag_option


@click.command("fleet")
@click.argument("paths", nargs=-1, required=True)
@click.option("-o", "--output", type=click.Path(dir_okay=False, path_type=Path), required=True,
              help="The table: .csv, .parquet or .jsonl (chosen by the extension).")  # fmt: skip
@click.option("-m", "--method", default="auto", show_default=True, help="The method for each recording.")
@click.option("--unit", default=None, help="The samples' unit, for samples files that do not say (uT, G, counts).")
@click.option("--field-strength", "field_strength", default=None,
              help="The known field strength in the samples' unit, or 'wmm' (the World Magnetic Model's at each "
              "log's own fixes).")  # fmt: skip
@click.option("--location", callback=geomag_option(parse_location), metavar="LAT,LON[,ALT]",
              help="Where the recordings were made (degrees; ALT in km, or 500m), for the World Magnetic Model: "
              "with --field-strength wmm, and the field compared in the table. Default: each log's own GNSS fixes.")
@click.option("--date", "model_date", callback=geomag_option(parse_date), metavar="YYYY-MM-DD",
              help="When the recordings were made, for the World Magnetic Model (default: each log's GNSS time).")
@click.option("--workers", type=click.IntRange(min=1), default=None,
              help="Local processes, this one among them [default: the machine's cores].")  # fmt: skip
@click.option("--scheduler", default=None, metavar="ADDRESS",
              help="A Dask scheduler (tcp://host:8786): run the recordings on that cluster (pip install "
              "'magfit[fleet]').")  # fmt: skip
@click.option("--no-resume", "no_resume", is_flag=True,
              help="Start afresh: do not skip the recordings the table's journal already holds.")  # fmt: skip
@click.option("--no-combine", "no_combine", is_flag=True, help="Do not combine each vehicle's flights.")
@click.option("--report", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="Also write the fleet's HTML report: combined calibrations, changes, each vehicle's history.")
def fleet_command(
    paths: tuple[str, ...],
    output: Path,
    method: str,
    unit: str | None,
    field_strength: str | None,
    location: tuple[float, float, float] | None,
    model_date: datetime.date | None,
    workers: int | None,
    scheduler: str | None,
    no_resume: bool,
    no_combine: bool,
    report: Path | None,
) -> None:
    """Calibrate every compass of every recording given, and each vehicle's compasses over all its flights.

    PATHS are recordings (logs, bags, samples files), folders (walked for recordings), globs ('logs/**/*.bin')
    and @LIST files naming one recording a line (the tables, journals and HTML reports of earlier runs that a
    folder or glob finds are left out). Each recording is fitted as 'magfit calibrate' fits it, in
    parallel; its rows (one per compass: verdict and reason codes, offset, matrix, field against the World
    Magnetic Model, heading one-sigma) go into one table. A recording that fails is a row with its reason.

    The flights of one vehicle (the folder that holds them) are combined per compass: partial flights that
    each cover too little of the sphere merge into one calibration the union determines. Flights that stop
    agreeing (a magnetised vehicle, changed hardware or payload) are named with their date and combined apart.

    The run can be resumed: the journal beside the table (TABLE.journal.jsonl) holds every finished recording,
    which a second run skips.

    \b
    Examples:
      magfit fleet logs/ -o fleet.csv --report fleet.html
      magfit fleet 'survey/**/*.bin' -o fleet.parquet --field-strength wmm
      magfit fleet @flights.txt -o fleet.jsonl --scheduler tcp://10.0.0.5:8786
    """
    out = console()
    strength: float | str | None = field_strength
    if field_strength is not None and field_strength != "wmm":
        try:
            strength = float(field_strength)
        except ValueError:
            raise click.BadParameter("a number in the samples' unit, or 'wmm'", param_hint="--field-strength") from None
    with _progress_bar() as advance:
        result = fleet(
            paths, output, method=method, unit=unit, field_strength=strength,  # type: ignore[arg-type]
            location=location, date=None if model_date is None else model_date.isoformat(), workers=workers,
            scheduler=scheduler, resume=not no_resume, combine=not no_combine, progress=advance,
        )  # fmt: skip
    _summary(out, result, output)
    if report is not None:
        from ..report.fleet import write_fleet_report

        out.print(f"wrote {write_fleet_report(report, result)}", soft_wrap=True)
    if not any(row.verdict in ("supported", "weak") for row in result.rows):
        raise FitFailedError(
            f"none of the {len(result.flights())} compass fits gave a calibration (the table says why, row by row)"
        )


@contextmanager
def _progress_bar() -> Iterator[Callable[[int, int, str], None]]:
    """``advance(done, total, path)``: a bar on stderr when it is a terminal; nothing at all otherwise (a log or
    a pipe gets no progress noise, not even the blank line a finished bar leaves)."""
    if not sys.stderr.isatty():
        yield lambda done, total, path: None
        return
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

    with Progress(
        TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeRemainingColumn(),
        console=console(stderr=True), transient=True,
    ) as bar:  # fmt: skip
        task = bar.add_task("recordings", total=None)

        def advance(done: int, total: int, path: str) -> None:
            bar.update(task, completed=done, total=total, description=Path(path).name[:30])

        yield advance


def _summary(out: Console, result: FleetResult, table: Path) -> None:
    """What a fleet operator reads first: counts by verdict, each vehicle's combined calibrations, the changes."""
    flights = result.flights()
    counts: dict[str, int] = {}
    for row in flights:
        counts[row.verdict] = counts.get(row.verdict, 0) + 1
    tally = ", ".join(f"{count} {verdict}" for verdict, count in sorted(counts.items()))
    resumed = f" ({result.skipped} recordings from the journal)" if result.skipped else ""
    print_ = out.print
    print_(f"{len(flights)} compass fits{resumed}: {tally or 'none'}", soft_wrap=True)
    for row in result.combined():
        unit = f" {row.unit}" if row.unit else ""
        where = f" {row.sensor}" if row.sensor else ""
        where += f" (device {row.device_id})" if row.device_id is not None else ""
        if row.verdict == "refused":
            print_(f"{row.vehicle}{where}: {row.flights} flights combined: refused: {row.reason}", soft_wrap=True)
            continue
        offset = ", ".join(f"{value:.4g}" for value in row.offset)
        codes = f" ({row.codes})" if row.codes else ""
        print_(
            f"{row.vehicle}{where}: {row.flights} flights combined ({row.date}): {row.verdict}{codes}, offset "
            f"({offset}){unit}, field {row.field_strength:.4g}{unit}",
            soft_wrap=True,
        )
    for event in result.events:
        print_(f"change: {event}", soft_wrap=True)
    print_(f"wrote {table} ({len(result.rows)} rows)", soft_wrap=True)
