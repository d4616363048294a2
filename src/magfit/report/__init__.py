"""A self-contained HTML report of calibrations: tables, diagnostics, plots and an interactive 3-D view.

One file that opens with the network off: plotly.js is inline, the figures are base64 PNGs, and a
Content-Security-Policy forbids any request. Needs the ``plot`` extra (matplotlib, plotly), imported
only when a report is written.

>>> import magfit, magfit.report
>>> sim = magfit.scenario("mpu9250", "steel").simulate(2000, seed=1)
>>> section = magfit.report.compare_section("steel (simulated)", sim.samples, truth=sim.truth, unit="counts")
>>> [c.method for c in section.calibrations]
['ellipsoid', 'sphere', 'minmax']
>>> html = magfit.report.report_html([section])   # or write_report("report.html", [section])
>>> html.startswith("<!DOCTYPE html>")
True
"""

from ._html import CONTENT_SECURITY_POLICY, DEFAULT_MAX_POINTS_3D, ReportSection, report_html, write_report
from .compasses import compasses_html
from .sections import compare_section, experiment_sections, section_from_comparison

__all__ = [
    "CONTENT_SECURITY_POLICY",
    "DEFAULT_MAX_POINTS_3D",
    "ReportSection",
    "compare_section",
    "compasses_html",
    "experiment_sections",
    "report_html",
    "section_from_comparison",
    "write_report",
]
