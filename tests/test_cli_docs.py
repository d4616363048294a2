"""docs/cli.md runs: its ``$ magfit ...`` examples, in order in an empty folder, give the documented results.

Each command's exit status must be the one written after it (``# exit N``, else 0). When the lines after a
command show its output in full (no ``...``), the output must be exactly those lines.
"""

from __future__ import annotations

import importlib.util
import shlex
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _golden_script():  # type: ignore[no-untyped-def]
    """scripts/regenerate_golden.py: the parser and runner the documentation is regenerated with."""
    spec = importlib.util.spec_from_file_location("regenerate_golden", ROOT / "scripts" / "regenerate_golden.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up while the file executes
    spec.loader.exec_module(module)
    return module


GOLDEN = _golden_script()
EXAMPLES = GOLDEN.cli_doc_examples(GOLDEN.CLI_DOC.read_text(encoding="utf-8"))


def test_the_documentation_has_examples_of_every_command() -> None:
    commands = {shlex.split(example.command, comments=True)[1] for example in EXAMPLES}
    assert commands >= {"demo", "calibrate", "compare", "apply", "simulate"}
    assert any(example.status == 1 for example in EXAMPLES) and any(example.status == 2 for example in EXAMPLES)


@pytest.mark.slow
def test_the_documented_session_runs_as_documented(tmp_path: Path) -> None:
    for example in EXAMPLES:
        status, produced = GOLDEN.run_cli_doc_example(example, tmp_path)
        assert status == example.status, f"{example.command}\n{produced}"
        if example.shown is not None:
            assert produced == example.shown, (
                f"{example.command}: docs/cli.md is out of date; run `python scripts/regenerate_golden.py`"
            )


def test_the_golden_outputs_the_documentation_shows_are_the_golden_files() -> None:
    text = GOLDEN.CLI_DOC.read_text(encoding="utf-8")
    for case in GOLDEN.CASES:
        if case.name in GOLDEN.DOC_GOLDENS:
            shown = GOLDEN.golden_doc_block(text, case).group(1)
            assert shown == case.golden_file.read_text(encoding="utf-8"), "run `python scripts/regenerate_golden.py`"
