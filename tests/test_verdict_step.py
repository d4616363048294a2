"""The one verdict step (diagnostics.settle) and the registry's part in it: every path refuses or returns alike."""

from __future__ import annotations

import ast
from pathlib import Path

import numpy as np
import pytest

import magfit
from magfit.diagnostics.settle import settle, starting_weakness, with_reasons
from magfit.findings import Reason, Support

SRC = Path(magfit.__file__).parent


def _calibration() -> magfit.Calibration:
    sim = magfit.simulate(2000, hard_iron=[4.0, -2.0, 1.0], field_strength=50.0, noise=0.2, seed=3)
    calibration = magfit.fit(sim.samples, "sphere")
    np.testing.assert_allclose(calibration.offset, [4.0, -2.0, 1.0], atol=0.05)  # the simulated truth
    return calibration


def test_a_refusal_is_raised_with_its_codes_or_returned_forced() -> None:
    calibration = _calibration()
    refused = Support.judged(
        (Reason("too few directions", "coverage"),), (Reason("a weak axis", "weakly_determined"),), "record more"
    )
    with pytest.raises(magfit.CalibrationError) as raised:
        settle(calibration, refused, method="sphere")
    assert raised.value.codes == ("coverage", "weakly_determined")
    forced = settle(calibration, refused, allow_undetermined=True)
    assert forced.support is not None and forced.support.forced and forced.support.verdict == "refused"
    assert forced.support.warnings[0].code == "coverage"
    weak = settle(calibration, with_reasons(calibration.support or refused, (), (Reason("mine", "biased"),)))
    assert weak.support is not None and weak.support.verdict == "weak" and weak.support.codes[-1] == "biased"


def test_the_alignment_cap_is_the_starting_calibrations_first_reason() -> None:
    calibration = _calibration()
    assert calibration.support is not None and calibration.support.verdict == "supported"
    assert starting_weakness(calibration) is None
    weak = settle(calibration, Support.judged((), (Reason("cap of directions", "coverage"),), ""))
    cap = starting_weakness(weak)
    assert cap is not None and cap.code == "coverage" and "(cap of directions)" in cap


def test_fit_names_no_method_and_imports_no_method_module() -> None:
    tree = ast.parse((SRC / "fit.py").read_text(encoding="utf-8"))
    imported = {node.module for node in ast.walk(tree) if isinstance(node, ast.ImportFrom) and node.module}
    assert not {m for m in imported if m.startswith("methods.") and m not in ("methods.core", "methods.registry")}
    compared = {
        side.value
        for node in ast.walk(tree)
        if isinstance(node, ast.Compare)
        for side in (node.left, *node.comparators)
        if isinstance(side, ast.Constant)
    }
    assert not compared & set(magfit.METHODS)  # no `method == "auto"`: what a method adds is in its registry entry


def test_the_robust_rule_lives_in_one_place() -> None:
    for path in (SRC / "diagnostics").glob("*.py"):
        assert "1.4826" not in path.read_text(encoding="utf-8"), path
    assert "1.4826 =" not in (SRC / "methods" / "robust.py").read_text(encoding="utf-8").replace("MAD_TO_SIGMA", "")
