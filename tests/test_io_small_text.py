"""Small text files are parsed without pandas: the same samples, bookkeeping and messages as pandas' reader."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import magfit.io.chunks
from magfit import DataFileError
from magfit.io import read_samples
from magfit.pipeline.streaming import _every

GOOD = {
    "plain": "t,mx,my,mz\n0,1.5,-2,3e2\n1,4,5,6\n",
    "nan and blanks": "t,mx,my,mz\n0,1,2,3\n\n1,nan,5,6\n  \n2,7,,9\n3,NA,1,1\n4,inf,1,1\n5,1,2,3\n",
    "crlf and no last newline": "mx,my,mz\r\n1,2,3\r\n4,5,6\r\n7,8,9",
    "decimal comma": "mx;my;mz\n1,5;2,25;-3,0\n4;5;6\n",
    "quoted": 'mx,my,mz\n"1.5","2",3\n4,"5",6\n',
    "whitespace": "mx my mz\n1   2\t3\n 4 5 6\n",
    "blank-led cells": "mx, my, mz\n1, nan, 3\n4, 5, 6\n",
    "no header": "1,2,3\n4,5,6\n7,8,9\n",
    "preamble": "Fs,50.00\nInitialization time,60\nmx,my,mz\n1,2,3\n4,5,6\n",
    "cut last line": "mx,my,mz\n1,2,3\n4,5,6\n7,8",
    "columns reordered": "mz,my,mx\n1,2,3\n4,5,6\n",
    "sensor column": "I,MagX,MagY,MagZ\n0,1,2,3\n0,4,5,6\n0,7,8,9\n",
    "huge value": "mx,my,mz\n1,2,3\n1e200,5,6\n7,8,9\n",
    "bom": "\ufeffmx,my,mz\n1,2,3\n4,5,6\n",
}
BAD = {
    "text cell": "mx,my,mz\n1,2,3\n4,abc,6\n",
    "text cell after blank": "mx,my,mz\n1,2,3\n\n4,5,1.2.3\n",
    "extra field": "mx,my,mz\n1,2,3\n4,5,6,7\n",
    "missing field": "mx,my,mz\n1,2,3\n4,5\n7,8,9\n",
    "carriage return inside": "mx,my,mz\n1,2,3\n4,5\r6\n",
    "interleaved sensors": "I,MagX,MagY,MagZ\n0,1,2,3\n" + "0,4,5,6\n" * 30 + "1,7,8,9\n",
    "text sensor id": "I,MagX,MagY,MagZ\n0,1,2,3\nx,4,5,6\n",
}


def _read(path: Path, parser: str, monkeypatch: pytest.MonkeyPatch, **options: object) -> object:
    """read_samples with the small-file parser, or with pandas (every file counts as large)."""
    with monkeypatch.context() as patch:
        if parser == "pandas":
            patch.setattr(magfit.io.chunks, "SMALL_TEXT_BYTES", -1)
        try:
            return read_samples(path, **options)  # type: ignore[arg-type]
        except DataFileError as error:
            return error


@pytest.mark.parametrize("name", sorted(GOOD))
@pytest.mark.parametrize("nonfinite", ["skip", "error"])
def test_small_files_read_as_pandas_reads_them(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, name: str, nonfinite: str
) -> None:
    path = tmp_path / "data.csv"
    path.write_bytes(GOOD[name].encode())
    mine, theirs = (_read(path, parser, monkeypatch, nonfinite=nonfinite) for parser in ("small", "pandas"))
    if isinstance(theirs, DataFileError):  # nonfinite="error" on a file with NaN: the same message
        assert isinstance(mine, DataFileError) and str(mine) == str(theirs)
        return
    assert not isinstance(mine, DataFileError), mine
    for field in ("columns", "n_rows", "n_skipped", "skipped_lines", "unit", "sensor", "column_note"):
        assert getattr(mine, field) == getattr(theirs, field), field
    np.testing.assert_array_equal(mine.samples, theirs.samples)  # type: ignore[attr-defined]


def test_the_small_parser_reads_the_numbers_written(tmp_path: Path) -> None:
    # A ground truth independent of pandas: the values written (shortest round-trip repr) are those read.
    rng = np.random.default_rng(3)
    values = np.round(rng.normal(0, 300, (500, 3)), 3)
    path = tmp_path / "data.csv"
    path.write_text("mx,my,mz\n" + "".join(f"{x!r},{y!r},{z!r}\n" for x, y, z in values.tolist()))
    assert path.stat().st_size <= magfit.io.chunks.SMALL_TEXT_BYTES
    np.testing.assert_array_equal(read_samples(path).samples, values)


@pytest.mark.parametrize("name", sorted(BAD))
def test_small_files_are_refused_as_pandas_refuses_them(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, name: str
) -> None:
    path = tmp_path / "data.csv"
    path.write_bytes(BAD[name].encode())
    mine, theirs = (_read(path, parser, monkeypatch) for parser in ("small", "pandas"))
    assert isinstance(mine, DataFileError) and isinstance(theirs, DataFileError)
    assert str(mine) == str(theirs)
    assert str(mine).startswith(f"{path}: ") and "\n" not in str(mine)
    assert "line " in str(mine) or name == "interleaved sensors"  # that one is seen in the head, at once


def test_a_small_file_is_read_without_importing_pandas(tmp_path: Path) -> None:
    path = tmp_path / "data.csv"
    path.write_text("t,mx,my,mz\n0,1,2,3\n1,4,5,6\n")
    code = (
        "import sys, magfit.cli, magfit.io; magfit.io.read_samples(sys.argv[1]); "
        "print(sorted(m for m in ('pandas', 'pyarrow') if m in sys.modules))"
    )
    done = subprocess.run([sys.executable, "-c", code, str(path)], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "[]"


@pytest.mark.parametrize("step", [1, 2, 3, 7, 50])
def test_every_step_th_row_across_chunks(step: int) -> None:
    rows = np.arange(300.0).reshape(-1, 3)  # 100 rows
    chunks = [rows[a:b] for a, b in ((0, 13), (13, 14), (14, 14), (14, 60), (60, 100))]
    kept = list(_every(iter(chunks), step))
    np.testing.assert_array_equal(np.concatenate(kept) if kept else np.empty((0, 3)), rows[::step])
