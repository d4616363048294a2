"""Rewrite the documented outputs from the program: the golden outputs of ``magfit compare`` on the real
recordings (tests/golden/), the README's example session (the ``magfit calibrate`` block, run on the real
FXOS8700 recording) and the outputs docs/cli.md shows in full (its ``$ magfit`` session, run in an empty folder).

Run it after a deliberate change of a method or of the output layout, then review the diff::

    .venv/bin/python scripts/regenerate_golden.py              # uses ../shared/data/real
    MAGFIT_REAL_DATA=/path/to/real .venv/bin/python scripts/regenerate_golden.py

tests/test_cli_compare.py imports :data:`CASES` and :func:`run_case` from this file, and tests/test_readme.py
:data:`README_EXAMPLES`, :func:`run_readme_example` and :func:`readme_block`, so the tests and the script
always run the same command lines. Outputs are printed with 4 decimals (the paper's mean and
std) and 6 significant digits (field strength, semi-axes, offsets): last-digit float noise cannot change
them.
"""

from __future__ import annotations

import os
import re
import shlex
import shutil
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
GOLDEN_DIR = ROOT / "tests" / "golden"
README = ROOT / "README.md"
CLI_DOC = ROOT / "docs" / "cli.md"
_EXIT = re.compile(r"#\s*exit (\d)")
DEFAULT_DATA_DIR = ROOT.parent / "shared" / "data" / "real"


@dataclass(frozen=True)
class GoldenCase:
    """One golden output: ``magfit compare <path> <args> --format markdown`` run in the data folder."""

    name: str
    path: str
    args: tuple[str, ...] = ()

    @property
    def golden_file(self) -> Path:
        return GOLDEN_DIR / f"compare_{self.name}.md"

    @property
    def argv(self) -> list[str]:
        return ["compare", self.path, *self.args, "--format", "markdown"]


CASES: tuple[GoldenCase, ...] = (
    # Small, clean, full tumble, tab-separated without a header (Magneto's reference data).
    GoldenCase("fxos8700", "fxos8700_magneto/mag-readings.txt"),
    # Two preamble lines, strong hard and soft iron, 22 745 samples.
    GoldenCase("unc_qmc5883l", "unc_qmc5883l/filtered_raw_data.csv"),
    # A drone log: ", " separators, gyro columns after the magnetometer, no header.
    GoldenCase("betaflight_tpu03", "betaflight_apex5_qmc5883/20231014_apex5_mag_on_tpu_03.txt", ("--columns", "0,1,2")),
    # The paper's sensor type (MPU-9250), UTF-8 BOM and CRLF line ends.
    GoldenCase("mxl_mpu9250", "mxl_umich_mpu9250_rm3100/preflight_data_original_imu.csv"),
    # Gauss, known field 0.47 G.
    GoldenCase("hamagure_set1", "hamagure_gauss/data-set_1.csv", ("--unit", "G")),
    # A failure case: tilting only, no tumble; every method must say why it cannot calibrate.
    GoldenCase("android_tilt", "android_phone_kritiksoman/data_mag.txt"),
)


def data_dir() -> Path:
    """The folder of real recordings (``MAGFIT_REAL_DATA`` overrides ../shared/data/real)."""
    return Path(os.environ.get("MAGFIT_REAL_DATA", DEFAULT_DATA_DIR))


def run_case(case: GoldenCase, data: Path) -> tuple[str, int]:
    """Run the case in-process from ``data`` (so the printed file names are relative); (stdout, exit status)."""
    from click.testing import CliRunner

    from magfit.cli import cli

    previous = Path.cwd()
    os.chdir(data)
    try:
        result = CliRunner().invoke(cli, case.argv)
    finally:
        os.chdir(previous)
    if result.exit_code not in (0, 1):
        raise RuntimeError(f"{case.name}: magfit {' '.join(case.argv)} exited {result.exit_code}: {result.output}")
    return result.stdout, result.exit_code


@dataclass(frozen=True)
class ReadmeExample:
    """A ``$ magfit ...`` block of the README: the command, run in a scratch folder holding a copy of ``source``
    (a real recording, under its own name), and its output as the user sees it (stdout and stderr)."""

    command: str
    source: str

    @property
    def argv(self) -> list[str]:
        return shlex.split(self.command)[1:]


README_EXAMPLES: tuple[ReadmeExample, ...] = (
    ReadmeExample("magfit calibrate mag-readings.txt --unit uT -o cal.json", "fxos8700_magneto/mag-readings.txt"),
)


def run_readme_example(example: ReadmeExample, data: Path) -> str:
    """The block's text: ``$ <command>`` and the output lines, as the README shows them."""
    from click.testing import CliRunner

    from magfit.cli import cli

    previous = Path.cwd()
    with tempfile.TemporaryDirectory() as scratch:
        shutil.copyfile(data / example.source, Path(scratch) / Path(example.source).name)
        os.chdir(scratch)
        try:
            result = CliRunner().invoke(cli, example.argv)
        finally:
            os.chdir(previous)
    if result.exit_code != 0:
        raise RuntimeError(f"README example {example.command!r} exited {result.exit_code}: {result.output}")
    lines = [line.rstrip() for line in result.output.rstrip("\n").splitlines()]
    return "\n".join([f"$ {example.command}", *lines]) + "\n"


def readme_block(text: str, example: ReadmeExample) -> re.Match[str]:
    """The README's ```text block that starts with ``$ <command>``."""
    pattern = re.compile(r"```text\n(\$ " + re.escape(example.command) + r"\n.*?)```", re.DOTALL)
    match = pattern.search(text)
    if match is None:
        raise LookupError(f"README.md has no ```text block starting with '$ {example.command}'")
    return match


@dataclass
class DocExample:
    """One ``$ magfit ...`` line of docs/cli.md: its exit status (``# exit N``, else 0), the output lines shown
    after it (None when shortened with ``...``: not compared) and where they are in the file (line numbers)."""

    command: str
    status: int
    shown: list[str] | None
    first_line: int
    end_line: int


def cli_doc_examples(text: str) -> list[DocExample]:
    """The ``$ magfit`` examples of docs/cli.md's ```console blocks, in order."""
    examples: list[DocExample] = []
    in_console = False
    current: DocExample | None = None
    lines: list[str] = []

    def close(end: int) -> None:
        if current is not None:
            current.shown = lines[:] if lines and not any("..." in line for line in lines) else None
            current.end_line = end
            examples.append(current)

    for number, line in enumerate(text.splitlines()):
        if line.startswith("```"):
            if in_console:
                close(number)
                current = None
            in_console = line.strip() == "```console"
            continue
        if not in_console:
            continue
        if line.startswith("$ "):
            close(number)
            current, lines = None, []
            if line.startswith("$ magfit "):
                match = _EXIT.search(line)
                current = DocExample(line[2:], int(match.group(1)) if match else 0, None, number + 1, number + 1)
        elif current is not None:
            lines.append(line.rstrip())
    return examples


def run_cli_doc_example(example: DocExample, folder: Path) -> tuple[int, list[str]]:
    """Run one example in ``folder`` (``> file`` redirects stdout there); (exit status, output lines)."""
    from click.testing import CliRunner

    from magfit.cli import cli

    words = shlex.split(example.command, comments=True)[1:]  # drop "magfit"
    target = None
    if ">" in words:
        position = words.index(">")
        words, target = words[:position], words[position + 1]
    previous = Path.cwd()
    os.chdir(folder)
    try:
        result = CliRunner().invoke(cli, words)
    finally:
        os.chdir(previous)
    if target is not None:
        (folder / target).write_text(result.stdout)
    return result.exit_code, [line.rstrip() for line in result.output.rstrip("\n").splitlines()]


def regenerate_cli_doc() -> int:
    """Rewrite the outputs docs/cli.md shows in full with the program's; the number of examples changed."""
    text = CLI_DOC.read_text(encoding="utf-8")
    lines = text.splitlines()
    changed = 0
    with tempfile.TemporaryDirectory() as scratch:
        replacements = []
        for example in cli_doc_examples(text):
            status, produced = run_cli_doc_example(example, Path(scratch))
            if status != example.status:
                raise RuntimeError(f"docs/cli.md: {example.command!r} exited {status}, documented {example.status}")
            if example.shown is not None and produced != example.shown:
                replacements.append((example, produced))
    for example, produced in reversed(replacements):  # from the end: earlier line numbers stay valid
        lines[example.first_line : example.end_line] = produced
        changed += 1
    CLI_DOC.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return changed


#: Golden outputs that docs/cli.md also shows (a ```text block starting with the golden file's first line).
DOC_GOLDENS = ("fxos8700",)


def golden_doc_block(text: str, case: GoldenCase) -> re.Match[str]:
    """docs/cli.md's ```text block that shows ``case``'s golden output."""
    first = case.golden_file.read_text(encoding="utf-8").splitlines()[0]
    match = re.search(r"```text\n(" + re.escape(first) + r"\n.*?)```", text, flags=re.DOTALL)
    if match is None:
        raise LookupError(f"docs/cli.md has no ```text block starting with {first!r}")
    return match


def main() -> int:
    data = data_dir()
    if not data.is_dir():
        print(f"the real recordings are not at {data}; set MAGFIT_REAL_DATA", file=sys.stderr)
        return 2
    GOLDEN_DIR.mkdir(parents=True, exist_ok=True)
    for case in CASES:
        output, status = run_case(case, data)
        previous = case.golden_file.read_text(encoding="utf-8") if case.golden_file.exists() else None
        case.golden_file.write_text(output, encoding="utf-8")
        state = "unchanged" if previous == output else ("new" if previous is None else "CHANGED")
        print(f"{case.golden_file.relative_to(ROOT)}: exit {status}, {state}")
    readme = README.read_text(encoding="utf-8")
    for example in README_EXAMPLES:
        block = readme_block(readme, example)
        output = run_readme_example(example, data)
        state = "unchanged" if block.group(1) == output else "CHANGED"
        readme = readme[: block.start(1)] + output + readme[block.end(1) :]
        print(f"README.md, '$ {example.command}': {state}")
    README.write_text(readme, encoding="utf-8")
    print(f"docs/cli.md: {regenerate_cli_doc()} example output(s) CHANGED")
    doc = CLI_DOC.read_text(encoding="utf-8")
    for case in CASES:
        if case.name in DOC_GOLDENS:
            block = golden_doc_block(doc, case)
            doc = doc[: block.start(1)] + case.golden_file.read_text(encoding="utf-8") + doc[block.end(1) :]
    CLI_DOC.write_text(doc, encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())
