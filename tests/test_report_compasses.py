"""`magfit report` on a log of several compasses shows them against each other and the firmware's own tests."""

from __future__ import annotations

from pathlib import Path

import pytest

from magfit.cli import main

LOG = Path(__file__).parent / "data" / "ardupilot_real" / "copter33_log171_trimmed.bin"


@pytest.mark.slow
def test_the_report_of_a_real_three_compass_flight_has_the_compasses_section(tmp_path: Path) -> None:
    output = tmp_path / "report.html"
    assert main(["report", str(LOG), "-o", str(output), "--allow-unfitted"]) == 0
    page = output.read_text(encoding="utf-8")
    assert page.count("class='compasses'") == 1
    assert "COMPASS_CAL_FIT" in page  # the firmware's fitness test replayed on the flight's samples
