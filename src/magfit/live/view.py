"""The live terminal view (rich, the ``cli`` extra): samples and rate, the coverage map, the fit, the verdict.

:func:`render` turns a :class:`~magfit.live.session.Snapshot` into one rich renderable; it holds no state,
so a test or a screenshot can draw any snapshot. The coverage map shows the 100 equal-area cells of the
sphere of field directions (the cells of :mod:`magfit.diagnostics.coverage`), one band of latitude per
row from the +z pole down to the −z pole, longitude from +x rightwards through +y; a filled cell has at
least one sample. The missing directions are named in words, as the diagnostics name them.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray
from rich.console import Group, RenderableType
from rich.table import Table
from rich.text import Text

from ..diagnostics.coverage import partition
from .session import COVERAGE_CELLS, Snapshot, Thresholds

__all__ = ["missing_words", "render"]

#: How to turn the sensor to see the field along a half-axis (the field points north and, in the
#: northern hemisphere, down: a sensor axis along the field points down and north).
_TURN = {
    "+": "point the {a} axis down and north (along the field)",
    "−": "point the {a} axis up and south (against the field)",
}


def missing_words(axes: Sequence[str]) -> list[str]:
    """Plain instructions for the missing half-axes of a Coverage (``"+x"`` -> "point the x axis down ...")."""
    return [f"{axis}: " + _TURN[axis[0]].format(a=axis[1]) for axis in axes]


def coverage_map(reached: Sequence[bool] | NDArray[np.bool_]) -> Text:
    """The equal-area cells as rows of blocks: ``██`` reached, ``··`` not yet."""
    cells = partition(COVERAGE_CELLS)
    width = 2 * int(cells.cells_per_zone.max())
    text = Text()
    last = len(cells.cells_per_zone) - 1
    for zone, (first, count) in enumerate(zip(cells.first_cell.tolist(), cells.cells_per_zone.tolist(), strict=True)):
        pad = (width - 2 * count) // 2
        label = "+z " if zone == 0 else "−z " if zone == last else "   "
        text.append(label + " " * pad)
        for cell in range(first, first + count):
            if reached[cell]:
                text.append("██", style="green")
            else:
                text.append("··", style="red")
        text.append("\n")
    text.append("    longitude: +x at the left edge, +y a quarter across, −x in the middle", style="dim")
    return text


def _number(value: float, digits: int = 4) -> str:
    text = f"{value:.{digits}g}"
    return "0" if float(text) == 0.0 else text


def render(
    snapshot: Snapshot,
    *,
    source: str,
    stream: str,
    thresholds: Thresholds,
    unit: str | None,
    status: Sequence[str] = (),
    keys: bool = True,
    junk: str = "",
) -> RenderableType:
    """The whole view of one snapshot (see the module docstring)."""
    s = snapshot
    head = Text()
    head.append("magfit live", style="bold")
    head.append(f"  {source}  ·  {stream}\n")
    minutes, seconds = divmod(int(s.elapsed), 60)
    head.append(f"samples {s.n_samples:,}   rate {s.rate_hz:,.0f}/s   time {minutes}:{seconds:02d}")
    if junk:
        head.append(f"   {junk}", style="yellow")

    board = Table.grid(padding=(0, 3))
    board.add_column()
    board.add_column()
    left = Text()
    left.append("Coverage of the field's directions (100 equal areas)\n", style="bold")
    left.append_text(coverage_map(s.reached))
    if s.coverage is not None:
        left.append(f"\nreached {s.coverage.cells_reached} of {s.coverage.cells}")
        for line in missing_words(s.coverage.missing):
            left.append("\nmissing " + line, style="yellow")
    else:
        left.append("\n(the map starts with the first fit)", style="dim")
    board.add_row(left, _fit_panel(s, unit))

    verdict = Table(title=None, show_edge=False, box=None, padding=(0, 2))
    verdict.add_column("check")
    verdict.add_column("now")
    verdict.add_column("needed")
    verdict.add_column("")
    for label, value, needed, passed in s.verdict.checks:
        verdict.add_row(label, value, needed, Text("ok", style="green") if passed else Text("not yet", style="red"))
    signal = (
        Text(" GOOD ENOUGH: press s to save ", style="bold black on green")
        if s.verdict.good
        else Text(" NOT YET: keep turning the sensor ", style="bold white on red")
    )
    parts: list[RenderableType] = [head, Text(), board, Text(), verdict, signal]
    for warning in s.verdict.warnings[:2]:
        parts.append(Text("warning: " + " ".join(warning.split())[:200], style="yellow"))
    for line in status:
        parts.append(Text(line))
    if keys:
        parts.append(Text("keys: s save   r reset   q quit", style="dim"))
    return Group(*parts)


def _fit_panel(s: Snapshot, unit: str | None) -> Text:
    text = Text()
    text.append("Current fit (auto)\n", style="bold")
    u = f" {unit}" if unit else ""
    fit = s.fit
    if fit is None:
        text.append("waiting for samples", style="dim")
        return text
    if fit.calibration is None:
        text.append("refused: ", style="red")
        text.append(" ".join((fit.error or "").split())[:300])
    else:
        cal = fit.calibration
        chosen = cal.auto.chosen if cal.auto is not None else None
        text.append(f"model     {chosen or cal.method}\n")
        text.append("offset    (" + ", ".join(_number(v) for v in cal.offset) + f"){u}\n")
        text.append(f"field     {_number(cal.field_strength)}{u}\n")
        axes = cal.semi_axes
        text.append("semi-axes (" + ", ".join(_number(v) for v in axes) + f"){u}\n")
        diagnostics = cal.diagnostics
        if diagnostics is not None and diagnostics.uncertainty is not None:
            sigma = diagnostics.uncertainty.heading_sigma_deg
            worst = diagnostics.uncertainty.heading_sigma_max_deg
            if sigma is not None and worst is not None:
                text.append(f"heading   ± {sigma:.2f}° (worst ± {worst:.2f}°)\n")
    text.append(f"\nfitted on {fit.n_used:,} even samples of {fit.n_seen:,}\n", style="dim")
    per_fit = s.fit_cpu_seconds / max(1, s.fits_done)
    text.append(f"{s.fits_done} fits, {1000 * per_fit:.0f} ms each", style="dim")
    return text
