"""The command line speaks in options, not Python, says each reason once and gives no advice already taken."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from magfit.cli import cli
from magfit.cli._common import warn
from magfit.findings import said_once
from magfit.remedy import for_command_line, option

REASON = (
    "the samples do not outline an ellipsoid (the fitted quadric is a hyperboloid), as every hard- and soft-iron "
    "distortion should: they cover too few directions; the {} fit to them would mean nothing. Record again"
)
#: Python in a message: a keyword argument with a quoted, bracketed, boolean or numeric value.
PYTHON_SYNTAX = re.compile(r"\b[a-z_]+=(?:'|\[|True\b|False\b|None\b|\d)")


def test_a_reason_repeated_for_another_model_is_said_once() -> None:
    items = [
        ("sphere", "sphere", [REASON.format("sphere")]),
        ("diag", "diag", [REASON.format("diag")]),
        ("full", "full", ["the als fit failed: the fitted quadric is a hyperboloid"]),
    ]
    text = said_once(items)
    assert text.count("as every hard- and soft-iron distortion should") == 1
    assert "; diag: as sphere; full: the als fit failed" in text
    assert text.startswith("sphere: the samples do not outline")
    assert said_once([("ellipsoid", "ellipsoid", ["too few samples"])]) == "ellipsoid: too few samples"


def test_only_the_repeated_clauses_are_referred_to() -> None:
    """diag's first clause differs from sphere's and is kept; its second is sphere's, named for diag."""
    other = REASON.format("diag").replace("few", "many")
    text = said_once([("sphere", "sphere", [REASON.format("sphere")]), ("diag", "diag", [other])])
    assert text == "sphere: " + REASON.format("sphere") + "; diag: " + other.split("; ")[0] + "; as sphere"


def test_remedies_are_said_as_options_inside_the_command() -> None:
    with for_command_line():
        assert f"prefer {option('method', 'auto')} (or ml, als)" == "prefer --method auto (or ml, als)"
        assert f"pass {option('field_strength', 48.2)}" == "pass --field-strength 48.2"
        assert option("columns", [1, 2, 3]) == "--columns 1,2,3"
    assert option("columns", [1, 2, 3]) == "columns=[1, 2, 3]"


def test_warnings_reach_the_terminal_as_the_library_said_them(capsys: pytest.CaptureFixture[str]) -> None:
    with for_command_line():
        warn(f"the method is biased on these samples; prefer {option('method', 'auto')} (or ml, als)")
    assert (
        capsys.readouterr().err
        == "magfit: warning: the method is biased on these samples; prefer --method auto (or ml, als)\n"
    )


def _refused(tmp_path: Path) -> Path:
    """A sensor that only yawed and tilted a little: no model of auto can be fitted."""
    angle = np.linspace(0, 6 * np.pi, 600)
    ring = np.column_stack([30 * np.cos(angle), 30 * np.sin(angle), 20 + 0.5 * np.sin(7 * angle)])
    path = tmp_path / "ring.csv"
    np.savetxt(path, ring, delimiter=",", header="mx,my,mz", comments="")
    return path


@pytest.mark.parametrize("method", ["auto", "ellipsoid", "sphere", "ml", "als", "diag", "minmax", "robust"])
def test_refusals_name_options_not_keywords(tmp_path: Path, method: str) -> None:
    result = CliRunner().invoke(cli, ["calibrate", str(_refused(tmp_path)), "-m", method])
    assert result.exit_code == (1 if method == "auto" else result.exit_code) and result.exit_code in (0, 1), (
        result.output
    )
    for line in result.stderr.splitlines():
        assert line.startswith(("magfit: error: ", "magfit: warning: ")), line
        assert not PYTHON_SYNTAX.search(line), line
        if result.exit_code == 1:
            assert "(columns mx, my, mz)" in result.stderr


def test_real_refusal_says_each_reason_once(real_data_dir: Path) -> None:
    """The HMC5883L recording that only yawed: auto's refusal gave sphere's and diag's identical reasons twice."""
    result = CliRunner().invoke(cli, ["calibrate", str(real_data_dir / "hmc5883l_nliaudat_partial/mag_out_sample.txt")])
    assert result.exit_code == 1, result.output
    (line,) = result.stderr.strip().splitlines()
    sentences = [part.strip() for part in re.split(r"[;.]", line) if len(part.strip()) > 40]
    assert len(sentences) == len(set(sentences)), line
    assert not PYTHON_SYNTAX.search(line), line
