"""The command line speaks in options, not Python, says each reason once and gives no advice already taken."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from magfit.cli import cli
from magfit.cli._common import option_wording, warn
from magfit.cli._wording import collapse_repeats, unquoted_alternatives, without_own_advice

REASON = (
    "the samples do not outline an ellipsoid (the fitted quadric is a hyperboloid), as every hard- and soft-iron "
    "distortion should: they cover too few directions; the {} fit to them would mean nothing. Record again"
)
REFUSAL = (
    "no model could be fitted to these samples: sphere: "
    + REASON.format("sphere")
    + "; diag: "
    + REASON.format("diag")
    + "; full: the als fit failed: the fitted quadric is a hyperboloid; or use method='sphere' (hard iron only)"
)
#: Python in a message: a keyword argument with a quoted, bracketed, boolean or numeric value.
PYTHON_SYNTAX = re.compile(r"\b[a-z_]+=(?:'|\[|True\b|False\b|None\b|\d)")


def test_a_reason_repeated_for_another_model_is_said_once() -> None:
    text = collapse_repeats(REFUSAL)
    assert text.count("as every hard- and soft-iron distortion should") == 1
    assert "; diag: as sphere; full: the als fit failed" in text
    assert text.startswith("no model could be fitted to these samples: sphere: the samples do not outline")
    assert collapse_repeats("the ellipsoid fit failed: too few samples") == "the ellipsoid fit failed: too few samples"


def test_only_the_repeated_clauses_are_referred_to() -> None:
    """diag's first clause differs from sphere's and is kept; its second is sphere's, named for diag."""
    other = REASON.format("diag").replace("few", "many")
    text = collapse_repeats("no model: sphere: " + REASON.format("sphere") + "; diag: " + other)
    assert text == "no model: sphere: " + REASON.format("sphere") + "; diag: " + other.split("; ")[0] + "; as sphere"


def test_the_model_list_of_auto_is_collapsed_in_either_wording() -> None:
    turned = "the sensor only turned about z: the field was never seen near +z or −z"
    tilt = "tilt the sensor so that both ends of z face the field in turn"
    text = (
        f"the samples determine no calibration model: the sphere model: {turned}; {tilt}; the diag model: the "
        f"fitted ellipsoid is 989602 times longer than it is thick; {turned}; {tilt}; record again"
    )
    assert collapse_repeats(text) == (
        f"the samples determine no calibration model: the sphere model: {turned}; {tilt}; the diag model: the "
        "fitted ellipsoid is 989602 times longer than it is thick; as the sphere model; record again"
    )


def test_keyword_hints_become_options() -> None:
    assert option_wording("prefer method='auto' (or 'ml', 'als')") == "prefer --method auto (or ml, als)"
    assert option_wording("pass field_strength=48.2 or unit='uT'") == "pass --field-strength 48.2 or --unit uT"
    assert option_wording("choose one with columns=[1, 2, 3] (0-based)") == "choose one with --columns 1,2,3 (0-based)"
    assert unquoted_alternatives("--method als (or 'ml')") == "--method als (or ml)"


def test_no_advice_to_use_the_method_that_was_used() -> None:
    warning = "the method is biased on these samples; prefer method='auto' (or 'ml', 'als')"
    assert without_own_advice(warning, "auto") == "the method is biased on these samples; prefer method='ml' (or 'als')"
    assert without_own_advice(warning, "ellipsoid") == warning
    assert without_own_advice("not positive-definite; use method='als'", "als") == "not positive-definite"


def test_warnings_reach_the_terminal_in_option_syntax(capsys: pytest.CaptureFixture[str]) -> None:
    warn("the method is biased on these samples; prefer method='auto' (or 'ml', 'als')")
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
