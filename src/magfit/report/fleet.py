"""The fleet report: one self-contained HTML page for a :func:`magfit.fleet` run.

What a fleet operator reads first: how many compasses were fitted and with which verdicts, each vehicle's
combined calibrations, the changes found between flights, and each vehicle's history over time (its flights'
offsets by date, a figure per vehicle); then every row of the table. Like the calibration report, it opens with
the network off (the figures are base64 PNGs and a Content-Security-Policy forbids any request).
"""

from __future__ import annotations

import base64
import datetime
import io
import math
from collections.abc import Sequence
from pathlib import Path

from ..fleet import FleetResult, FleetRow
from ..io.atomic import atomic_write_text
from ._html import _STYLE, CONTENT_SECURITY_POLICY, _compact_png, _e

__all__ = ["fleet_report_html", "write_fleet_report"]

_VERDICT_COLOURS = {"supported": "#2ca02c", "weak": "#ff7f0e", "refused": "#d62728", "error": "#7f7f7f"}


def fleet_report_html(result: FleetResult, title: str = "magfit fleet report") -> str:
    """The page for ``result`` (HTML text)."""
    flights = result.flights()
    counts: dict[str, int] = {}
    for row in flights:
        counts[row.verdict] = counts.get(row.verdict, 0) + 1
    tally = ", ".join(f"{count} {verdict}" for verdict, count in sorted(counts.items())) or "none"
    vehicles = sorted({row.vehicle for row in result.rows})
    parts = [
        f"<h1>{_e(title)}</h1>",
        f"<p class='meta'>{len(flights)} compass fits over {len(vehicles)} vehicles: {_e(tally)}. "
        f"Written {datetime.datetime.now(datetime.timezone.utc):%Y-%m-%d %H:%M} UTC.</p>",
        _combined_table(result.combined()),
    ]
    if result.events:
        items = "".join(f"<li class='warn'>{_e(event)}</li>" for event in result.events)
        parts.append(f"<h2>Changes between flights</h2><ul>{items}</ul>")
    parts.append("<h2>History per vehicle</h2>")
    for vehicle in vehicles:
        rows = [row for row in flights if row.vehicle == vehicle]
        figure = _history_png(vehicle, rows)
        if figure is not None:
            parts.append(
                f"<figure><img alt='offset history of {_e(vehicle)}' src='data:image/png;base64,{figure}'>"
                f"<figcaption>{_e(vehicle)}: each compass's offset per flight, by date (hollow: not supported "
                "alone)</figcaption></figure>"
            )
    parts.append(_all_rows_table(result.rows))
    body = "\n".join(parts)
    return (
        "<!DOCTYPE html>\n<html lang='en'><head><meta charset='utf-8'>"
        f"<meta http-equiv='Content-Security-Policy' content=\"{CONTENT_SECURITY_POLICY}\">"
        f"<title>{_e(title)}</title><style>{_STYLE}</style></head><body>{body}</body></html>\n"
    )


def write_fleet_report(path: str | Path, result: FleetResult, title: str = "magfit fleet report") -> Path:
    """Write :func:`fleet_report_html` to ``path`` atomically; returns the path."""
    path = Path(path)
    atomic_write_text(path, fleet_report_html(result, title))
    return path


def _cell(value: float, digits: int = 4) -> str:
    return "<td class='num'>–</td>" if not math.isfinite(value) else f"<td class='num'>{value:.{digits}g}</td>"


def _verdict_cell(row: FleetRow) -> str:
    colour = _VERDICT_COLOURS.get(row.verdict, "#222")
    codes = f" <span class='note'>({_e(row.codes)})</span>" if row.codes else ""
    return f"<td style='color:{colour};font-weight:600'>{_e(row.verdict)}{codes}</td>"


def _combined_table(rows: Sequence[FleetRow]) -> str:
    if not rows:
        return "<h2>Combined calibrations</h2><p class='note'>No vehicle has two flights of one compass to combine.</p>"
    body = []
    for row in rows:
        matrix = (
            f"[{row.matrix_xx:.4f} {row.matrix_xy:.4f} {row.matrix_xz:.4f}; {row.matrix_yx:.4f} {row.matrix_yy:.4f} "
            f"{row.matrix_yz:.4f}; {row.matrix_zx:.4f} {row.matrix_zy:.4f} {row.matrix_zz:.4f}]"
        )
        body.append(
            f"<tr><td>{_e(row.vehicle)}</td><td>{_e(row.sensor or '–')}</td><td>{_device(row)}</td>"
            f"<td>{row.flights}</td>"
            f"<td>{_e(row.date)}</td>{_verdict_cell(row)}"
            f"{_cell(row.offset_x)}{_cell(row.offset_y)}{_cell(row.offset_z)}"
            f"<td class='matrix'>{_e(matrix)}</td>{_cell(row.field_strength)}<td>{_e(row.unit)}</td></tr>"
        )
    head = ["vehicle", "compass", "device id", "flights", "dates", "verdict", "offset x", "offset y", "offset z",
            "matrix", "field", "unit"]  # fmt: skip
    header = "".join(f"<th>{name}</th>" for name in head)
    return (
        "<h2>Combined calibrations</h2><table><thead><tr>" + header + "</tr></thead><tbody>" + "".join(body)
        + "</tbody></table><p class='note'>Each vehicle's agreeing flights of one compass (one device id, whichever "
        "slot the log gave it), merged through their statistics and fitted once (the verdict is on the union).</p>"
    )


def _device(row: FleetRow) -> str:
    return "–" if row.device_id is None else str(row.device_id)


def _compass(row: FleetRow) -> str:
    """A compass in a figure's legend: its device id where the log gives one (a slot such as ``MAG/0`` may hold
    another compass in another flight), else its id in the log."""
    if row.device_id is None:
        return row.sensor or "compass"
    return f"{row.sensor} ({row.device_id})" if row.sensor else str(row.device_id)


def _all_rows_table(rows: Sequence[FleetRow]) -> str:
    body = []
    for row in rows:
        body.append(
            f"<tr><td>{_e(row.kind)}</td><td>{_e(row.vehicle)}</td><td>{_e(Path(row.path).name if row.kind != 'combined' else row.path)}</td>"  # noqa: E501
            f"<td>{_e(row.sensor or '–')}</td><td>{_device(row)}</td><td>{_e(row.date)}</td><td>{_e(row.method)}</td>"
            f"{_verdict_cell(row)}"
            f"{_cell(row.offset_x)}{_cell(row.offset_y)}{_cell(row.offset_z)}{_cell(row.field_vs_model, 3)}"
            f"{_cell(row.heading_sigma_deg, 2)}<td class='note'>{_e(row.reason[:400])}</td></tr>"
        )
    head = ["kind", "vehicle", "recording", "compass", "device id", "date", "method", "verdict", "offset x",
            "offset y", "offset z", "field / model", "heading ±°", "reason"]  # fmt: skip
    header = "".join(f"<th>{name}</th>" for name in head)
    return (
        "<h2>Every row</h2><details><summary>the table</summary><table><thead><tr>" + header + "</tr></thead><tbody>"
        + "".join(body) + "</tbody></table></details>"
    )


def _history_png(vehicle: str, rows: Sequence[FleetRow]) -> str | None:
    """Each compass's offset components per flight by date; None when no flight has an offset."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fitted = [row for row in rows if math.isfinite(row.offset_x)]
    if not fitted:
        return None
    def key(row: FleetRow) -> str:  # one compass across flights: its device id where known, as the fleet combines
        return f"device {row.device_id}" if row.device_id is not None else row.sensor

    compasses = sorted({key(row) for row in fitted})
    figure, axes = plt.subplots(1, 3, figsize=(13, 3.4), sharex=True)
    for index, compass in enumerate(compasses):
        mine = sorted((row for row in fitted if key(row) == compass), key=lambda row: row.date)
        labels = [row.date[:16] for row in mine]
        for axis, name, values in zip(axes, "xyz", zip(*(row.offset for row in mine), strict=True), strict=True):
            colour = f"C{index % 10}"
            axis.plot(labels, values, "-", color=colour, alpha=0.5)
            for label, value, row in zip(labels, values, mine, strict=True):
                hollow = row.verdict != "supported"
                axis.plot([label], [value], "o", color=colour, markerfacecolor="white" if hollow else colour,
                          label=_compass(mine[0]))  # fmt: skip
            axis.set_title(f"offset {name}" + (f" ({mine[0].unit})" if mine[0].unit else ""))
    for axis in axes:
        axis.tick_params(axis="x", labelrotation=30, labelsize=7)
        axis.grid(alpha=0.3)
    handles, labels = axes[0].get_legend_handles_labels()
    unique = dict(zip(labels, handles, strict=True))
    if len(unique) > 1:
        axes[0].legend(unique.values(), unique.keys(), fontsize=7)
    figure.suptitle(vehicle)
    figure.tight_layout()
    buffer = io.BytesIO()
    figure.savefig(buffer, format="png", dpi=90)
    plt.close(figure)
    return base64.b64encode(_compact_png(buffer.getvalue())).decode("ascii")
