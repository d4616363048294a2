"""The report's section on a vehicle's compasses: against each other, and the firmware's acceptance tests.

:func:`compasses_html` renders a :class:`magfit.consistency.CompassComparison` and, when given, a
:class:`magfit.firmware_checks.LogExplanation` as an HTML fragment (tables, plain text escaped), for
:attr:`magfit.report.ReportSection.extra_html`::

    result = magfit.calibrate_file("00000042.BIN")
    fragment = compasses_html(compare_compasses(result), explain_log(result))
    section = dataclasses.replace(section, extra_html=(fragment,))
"""

from __future__ import annotations

import html
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from ..consistency import CompassComparison
    from ..firmware_checks import LogExplanation

__all__ = ["compasses_html"]


def _e(text: object) -> str:
    return html.escape(str(text), quote=True)


def _table(header: list[str], rows: list[list[str]]) -> str:
    head = "".join(f"<th>{_e(h)}</th>" for h in header)
    body = "".join("<tr>" + "".join(f"<td>{_e(c)}</td>" for c in row) + "</tr>" for row in rows)
    return f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


def compasses_html(comparison: CompassComparison | None, explanation: LogExplanation | None = None) -> str:
    """An HTML fragment: the compasses' rotations, the pre-arm figures, the findings and the order to prefer
    them in; then each compass's firmware acceptance tests (either part may be None)."""
    parts = ["<div class='compasses'>"]
    if comparison is not None:
        parts.append("<h3>The compasses against each other</h3>")
        rows = []
        for p in comparison.pairs:
            sigma = f" ± {p.sigma_deg:.1f}" if np.isfinite(p.sigma_deg) else ""
            current = "-"
            if p.current is not None:
                c = p.current
                current = f"R² {c.r_squared:.2f}, {c.at_full_pct:.1f} % at the highest {c.regressor} ({c.source})"
                if c.follower:
                    current += f"; follows: {', '.join(c.follower)}"
            rows.append(
                [
                    p.first,
                    p.second,
                    f"{p.angle_deg:.1f}{sigma}",
                    ", ".join(f"{v:+.2f}" for v in p.axis),
                    f"{p.residual_rms:.3g} {comparison.unit}",
                    "yes" if p.determined else "no",
                    current,
                ]
            )
        parts.append(_table(["first", "second", "angle (deg)", "axis", "residual", "determined", "current"], rows))
        if comparison.ardupilot:
            parts.append("<h4>ArduPilot's pre-arm consistency check (Compass::consistent)</h4>")
            parts.append(
                _table(
                    ["compass", "primary", "3-D angle", "horizontal angle", "horizontal diff.", "fails at", "failing"],
                    [
                        [
                            a.sensor, a.primary, f"{a.xyz_angle_deg:.0f}°", f"{a.xy_angle_deg:.0f}°",
                            f"{a.xy_length:.0f} mG" if np.isfinite(a.xy_length) else "-",
                            f"{100 * a.fail_share:.0f} % ({a.basis})", "; ".join(a.failing) or "-",
                        ]
                        for a in comparison.ardupilot
                    ],
                )
            )  # fmt: skip
        if comparison.px4:
            parts.append("<h4>PX4's magnetometer inconsistency angle (COM_ARM_MAG_ANG)</h4>")
            parts.append(
                _table(
                    ["compass", "primary", "angle", "filtered, at most", "fails at"],
                    [
                        [x.sensor, x.primary, f"{x.angle_deg:.0f}°", f"{x.filtered_max_deg:.0f}°",
                         f"{100 * x.fail_share:.0f} % ({x.basis})"]
                        for x in comparison.px4
                    ],
                )
            )  # fmt: skip
        if comparison.findings:
            items = "".join(f"<li><code>{_e(r.code)}</code> {_e(r)}</li>" for r in comparison.findings)
            parts.append(f"<ul>{items}</ul>")
        parts.append(f"<p>Prefer: {_e(', '.join(comparison.priority))}.</p>")
        parts += [f"<p class='meta'>{_e(note)}</p>" for note in comparison.notes]
    if explanation is not None and explanation.replays:
        parts.append("<h3>The firmware's acceptance tests, replayed</h3>")
        rows = []
        for replay in explanation.replays:
            for test in replay.tests:
                verdict = "not replayed" if test.passed is None else "passes" if test.passed else "FAILS"
                rows.append([replay.sensor, replay.firmware, test.name, test.value, test.limit, verdict, test.margin])
        parts.append(_table(["compass", "firmware", "test", "value", "limit", "", "margin"], rows))
        for replay in explanation.replays:
            parts += [f"<p><code>{_e(r.code)}</code> {_e(r)}</p>" for r in replay.reasons]
        parts += [f"<p class='meta'>{_e(note)}</p>" for note in explanation.notes]
    parts.append("</div>")
    return "".join(parts)
