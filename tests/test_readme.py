"""The README's promises: its commands and its library example stay true."""

from __future__ import annotations

import re
from pathlib import Path

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
