"""docs/cli.md runs: its ``$ magfit ...`` examples, in order in an empty folder, give the documented results.

Each command's exit status must be the one written after it (``# exit N``, else 0). When the lines after a
command show its output in full (no ``...``), the output must be exactly those lines.
"""

from __future__ import annotations

import re
import shlex
from pathlib import Path

import pytest
from click.testing import CliRunner

from magfit.cli import cli

DOC = Path(__file__).resolve().parents[1] / "docs" / "cli.md"
_EXIT = re.compile(r"#\s*exit (\d)")


def _examples() -> list[tuple[str, int, list[str] | None]]:
    """(command line, expected exit status, expected output lines or None) for each ``$ magfit`` line."""
    examples: list[tuple[str, int, list[str] | None]] = []
    in_console = False
    current: list[object] | None = None

    def close() -> None:
        if current is not None:
            command, status, lines = current
            assert isinstance(lines, list)
            shown = lines if lines and not any("..." in line for line in lines) else None
            examples.append((str(command), int(str(status)), shown))

    for line in DOC.read_text(encoding="utf-8").splitlines():
        if line.startswith("```"):
            if in_console:
                close()
                current = None
            in_console = line.strip() == "```console"
            continue
        if not in_console:
            continue
        if line.startswith("$ "):
            close()
            current = None
            if line.startswith("$ magfit "):
                match = _EXIT.search(line)
                current = [line[2:], int(match.group(1)) if match else 0, []]
        elif current is not None:
            lines = current[2]
            assert isinstance(lines, list)
            lines.append(line.rstrip())
    return examples


EXAMPLES = _examples()


def test_the_documentation_has_examples_of_every_command() -> None:
    commands = {shlex.split(command, comments=True)[1] for command, _, _ in EXAMPLES}
    assert commands >= {"demo", "calibrate", "compare", "apply", "simulate"}
    assert any(status == 1 for _, status, _ in EXAMPLES) and any(status == 2 for _, status, _ in EXAMPLES)


def test_the_documented_session_runs_as_documented(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)
    runner = CliRunner()
    for command, status, shown in EXAMPLES:
        words = shlex.split(command, comments=True)[1:]  # drop "magfit"
        target = None
        if ">" in words:
            position = words.index(">")
            words, target = words[:position], words[position + 1]
        result = runner.invoke(cli, words)
        assert result.exit_code == status, f"{command}\n{result.output}"
        if target is not None:
            (tmp_path / target).write_text(result.stdout)
        if shown is not None:
            produced = [line.rstrip() for line in result.output.rstrip("\n").splitlines()]
            assert produced == shown, command
