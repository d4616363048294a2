"""The README's promises: its commands and its library example stay true."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

README = Path(__file__).resolve().parents[1] / "README.md"


def code_blocks(language: str) -> list[str]:
    return re.findall(rf"```{language}\n(.*?)```", README.read_text(encoding="utf-8"), flags=re.DOTALL)


def test_readme_starts_with_the_two_commands() -> None:
    first_two = code_blocks("sh")[:2]
    assert "magfit demo" in first_two[0] and "pip install" in first_two[0]
    assert "pytest" in first_two[1] and ".[test]" in first_two[1]


def test_readme_library_example_runs(capsys) -> None:  # type: ignore[no-untyped-def]
    (example,) = [block for block in code_blocks("python") if "import magfit" in block][:1]
    exec(compile(example, str(README), "exec"), {})
    printed = capsys.readouterr().out
    assert "ellipsoid mean" in printed and "minmax" in printed


def _golden_script():  # type: ignore[no-untyped-def]
    import importlib.util
    import sys

    path = README.parent / "scripts" / "regenerate_golden.py"
    spec = importlib.util.spec_from_file_location("regenerate_golden", path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up while the file executes
    spec.loader.exec_module(module)
    return module


GOLDEN = _golden_script()


@pytest.mark.parametrize("example", GOLDEN.README_EXAMPLES, ids=lambda example: example.command)
def test_readme_example_output_is_the_programs(example, real_data_dir: Path) -> None:  # type: ignore[no-untyped-def]
    """The README's `magfit calibrate` block, run on the real recording: its output must be the program's."""
    shown = GOLDEN.readme_block(README.read_text(encoding="utf-8"), example).group(1)
    produced = GOLDEN.run_readme_example(example, real_data_dir)
    assert shown == produced, "the README's example is out of date: run `python scripts/regenerate_golden.py`"
