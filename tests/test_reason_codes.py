"""Every reason code is documented, and the codes travel with a refusal and through JSON."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

import magfit
from magfit.findings import Reason, ReasonList, Support

DOCS = Path(__file__).resolve().parents[1] / "docs" / "diagnostics.md"


def test_docs_list_every_code_with_its_meaning() -> None:
    text = DOCS.read_text(encoding="utf-8")
    for code, meaning in magfit.REASON_CODES.items():
        assert f"| `{code}` | {meaning} |" in text, code


def test_an_unknown_code_is_refused_by_the_judges_list() -> None:
    reasons = ReasonList()
    with pytest.raises(KeyError, match="unknown reason code"):
        reasons.add("not_a_code", "words")


def test_codes_survive_the_json_and_a_refusal() -> None:
    support = Support.judged([Reason("too few", "too_few_samples")], [Reason("sparse", "low_coverage")], "record")
    again = Support.from_dict(json.loads(json.dumps(support.to_dict())))
    assert again.codes == ("too_few_samples", "low_coverage") and again.refusals[0] == "too few"
    flat = np.random.default_rng(0).normal(size=(400, 3)) * [1.0, 1.0, 1e-6] + [0.0, 0.0, 1.0]
    with pytest.raises(magfit.CalibrationError) as refused:
        magfit.fit(flat, method="ellipsoid")
    assert refused.value.codes and set(refused.value.codes) <= set(magfit.REASON_CODES)
