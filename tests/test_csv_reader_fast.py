"""Large text files parsed by pyarrow in blocks (magfit.io.fastcsv) read exactly as the pandas path reads them.

The block reader is used from ``BLOCK_READER_BYTES`` (32 MB); here the threshold is lowered to 0 and the
blocks made small, so that small files cross many blocks. Every file is read both ways and must give the
same samples, counts and skipped line numbers, or the same one-line error.
"""

from __future__ import annotations

import bz2
import gzip
import lzma
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import magfit.io.chunks as chunks
from magfit import DataFileError
from magfit.io import ChunkReader, read_samples
from magfit.io.fastcsv import READER_VARIABLE, block_parser, reader_name

pytest.importorskip("pyarrow")

RNG = np.random.default_rng(24)
VALUES = RNG.normal(0.0, 40.0, (400, 3)).round(3)


def lines(values: np.ndarray = VALUES) -> list[str]:
    return [f"{10 * i},{x},{y},{z}" for i, (x, y, z) in enumerate(values.tolist())]


def write(tmp_path: Path, text: str | bytes, name: str = "data.csv") -> Path:
    path = tmp_path / name
    path.write_bytes(text if isinstance(text, bytes) else text.encode())
    return path


def both_ways(
    path: Path, monkeypatch: pytest.MonkeyPatch, block_bytes: int, **options: object
) -> tuple[object, object, bool]:
    """The read by pandas, the read by pyarrow blocks (a SampleTable or the error's text), and whether the
    block reader was the one used."""
    monkeypatch.setenv(READER_VARIABLE, "pandas")
    reads = []
    for reader in ("pandas", "pyarrow"):
        monkeypatch.setenv(READER_VARIABLE, reader)
        monkeypatch.setattr(chunks, "BLOCK_READER_BYTES", 0)
        monkeypatch.setattr(chunks, "BLOCK_BYTES", block_bytes)
        try:
            reads.append(read_samples(path, **options))  # type: ignore[arg-type]
        except DataFileError as error:
            reads.append(str(error))
    used = ChunkReader(path, **options)._block_parser() is not None  # type: ignore[arg-type]
    return reads[0], reads[1], used


def assert_same(pandas_read: object, arrow_read: object) -> None:
    if isinstance(pandas_read, str):
        assert arrow_read == pandas_read
        return
    assert not isinstance(arrow_read, str), arrow_read
    for name in ("columns", "n_rows", "n_skipped", "skipped_lines", "unit", "column_note"):
        assert getattr(arrow_read, name) == getattr(pandas_read, name), name
    np.testing.assert_array_equal(arrow_read.samples, pandas_read.samples)  # type: ignore[attr-defined]


CASES = {
    "clean": "t,mx,my,mz\n" + "\n".join(lines()) + "\n",
    "crlf": "t,mx,my,mz\r\n" + "\r\n".join(lines()) + "\r\n",
    "no final line end": "t,mx,my,mz\n" + "\n".join(lines()),
    "missing values": "t,mx,my,mz\n"
    + "\n".join(
        line if i not in (3, 150, 151, 399) else f"{i},,1,2" if i == 3 else f"{i},nan,NA,inf"
        for i, line in enumerate(lines())
    )
    + "\n",
    "blank lines": "t,mx,my,mz\n" + "\n".join(lines()[:200]) + "\n\n\n" + "\n".join(lines()[200:]) + "\n\n",
    "bad cell late": "t,mx,my,mz\n" + "\n".join(lines()[:300]) + "\n300,1,oops,3\n" + "\n".join(lines()[301:]) + "\n",
    "surplus field": "t,mx,my,mz\n" + "\n".join(lines()[:250]) + "\n250,1,2,3,4\n" + "\n".join(lines()[251:]) + "\n",
    "missing field": "t,mx,my,mz\n" + "\n".join(lines()[:250]) + "\n250,1,2\n" + "\n".join(lines()[251:]) + "\n",
    "cut last line": "t,mx,my,mz\n" + "\n".join(lines()) + "\n4000,1.5",
    "lone carriage return": "t,mx,my,mz\n"
    + "\n".join(lines()[:100])
    + "\n100,1,2,3\r101,1,2,3\n"
    + "\n".join(lines()[102:])
    + "\n",
    "quoted cells": "t,mx,my,mz\n"
    + "\n".join(f'{i},"{x}",{y},{z}' for i, (x, y, z) in enumerate(VALUES.tolist()))
    + "\n",
    "blank-led missing value": "t,mx,my,mz\n"
    + "\n".join(
        f"{i},{x}, NA,{z}" if i % 50 == 7 else f"{i},{x},{y},{z}" for i, (x, y, z) in enumerate(VALUES.tolist())
    )
    + "\n",
    "headerless": "\n".join(lines()) + "\n",
    "units in the header": "time_ms,mag_x_uT,mag_y_uT,mag_z_uT\n" + "\n".join(lines()) + "\n",
    "columns among others": "t,ax,ay,az,mx,my,mz,temp\n"
    + "\n".join(f"{i},0.1,0.2,9.8,{x},{y},{z},21.5" for i, (x, y, z) in enumerate(VALUES.tolist()))
    + "\n",
    "semicolons": "t;mx;my;mz\n" + "\n".join(line.replace(",", ";") for line in lines()) + "\n",
    "text column": "t,mx,my,mz,note\n" + "\n".join(f"{line},ok" for line in lines()) + "\n",
    "a comment line": "t,mx,my,mz\n"
    + "\n".join(lines()[:120])
    + "\n# power cycled\n"
    + "\n".join(lines()[120:])
    + "\n",
    "header again": "t,mx,my,mz\n" + "\n".join(lines()[:120]) + "\nt,mx,my,mz\n" + "\n".join(lines()[120:]) + "\n",
}


@pytest.mark.parametrize("block_bytes", [41, 1000, 4 << 20])
@pytest.mark.parametrize("case", sorted(CASES))
def test_blocks_read_as_pandas_reads(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, case: str, block_bytes: int
) -> None:
    path = write(tmp_path, CASES[case])
    pandas_read, arrow_read, used = both_ways(path, monkeypatch, block_bytes)
    assert used
    assert_same(pandas_read, arrow_read)


def test_the_samples_written_are_the_samples_read(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    # Ground truth: the values written (3 decimals) come back exactly, in the order asked, and the skipped rows
    # are named by their file lines.
    text = "t,mx,my,mz\n" + "\n".join(line if i != 7 else "70,nan,1,2" for i, line in enumerate(lines())) + "\n"
    path = write(tmp_path, text)
    monkeypatch.setenv(READER_VARIABLE, "pyarrow")
    monkeypatch.setattr(chunks, "BLOCK_READER_BYTES", 0)
    monkeypatch.setattr(chunks, "BLOCK_BYTES", 997)
    table = read_samples(path, columns=["mz", "my", "mx"])
    keep = np.arange(len(VALUES)) != 7
    np.testing.assert_array_equal(table.samples, VALUES[keep][:, ::-1])
    assert (table.n_rows, table.n_skipped, table.skipped_lines) == (400, 1, (9,))


@pytest.mark.parametrize("nonfinite", ["skip", "error"])
def test_nonfinite_error_names_the_line(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, nonfinite: str) -> None:
    text = "t,mx,my,mz\n" + "\n".join(line if i != 333 else "3330,1,inf,2" for i, line in enumerate(lines())) + "\n"
    pandas_read, arrow_read, _ = both_ways(write(tmp_path, text), monkeypatch, 512, nonfinite=nonfinite)
    assert_same(pandas_read, arrow_read)
    if nonfinite == "error":
        assert "line 335, column 'my'" in str(arrow_read)


def _zstd_write(path: Path, text: str) -> None:
    zstandard = pytest.importorskip("zstandard")
    path.write_bytes(zstandard.ZstdCompressor().compress(text.encode()))


@pytest.mark.parametrize("suffix", [".gz", ".bz2", ".xz", ".zst"])
def test_compressed_inputs(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, suffix: str) -> None:
    path = tmp_path / f"data.csv{suffix}"
    text = CASES["missing values"]
    if suffix == ".zst":
        _zstd_write(path, text)
    else:
        opener = {".gz": gzip.open, ".bz2": bz2.open, ".xz": lzma.open}[suffix]
        with opener(path, "wt") as handle:
            handle.write(text)
    pandas_read, arrow_read, _ = both_ways(path, monkeypatch, 777)
    assert_same(pandas_read, arrow_read)
    assert arrow_read.n_skipped == 4  # type: ignore[union-attr]


def test_pandas_reads_without_pyarrow(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    path = write(tmp_path, CASES["clean"])
    monkeypatch.setattr(chunks, "BLOCK_READER_BYTES", 0)
    monkeypatch.delenv(READER_VARIABLE, raising=False)
    assert reader_name() == "pyarrow"
    import importlib.util

    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *args: None)  # as if it were not installed
    assert reader_name() is None
    reader = ChunkReader(path)
    assert reader._block_parser() is None
    np.testing.assert_array_equal(read_samples(path).samples, VALUES)


def test_layouts_pyarrow_does_not_take(tmp_path: Path) -> None:
    # Runs of blanks, a decimal comma: the pandas path reads them.
    from magfit.io import sniff

    spaced = write(tmp_path, "t mx my mz\n" + "\n".join(line.replace(",", "  ") for line in lines()) + "\n", "s.txt")
    comma = write(
        tmp_path,
        "t;mx;my;mz\n" + "\n".join(line.replace(",", ";").replace(".", ",") for line in lines()) + "\n",
        "c.csv",
    )
    for path in (spaced, comma):
        assert block_parser(sniff(path), [1, 2, 3]) is None


def test_small_files_do_not_import_pyarrow(tmp_path: Path) -> None:
    path = write(tmp_path, CASES["clean"])
    code = "import sys; from magfit.io import read_samples; read_samples(sys.argv[1]); print('pyarrow' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code, str(path)], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


def test_big_files_parse_in_blocks_not_pieces(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    # The block reader threads itself: the file is not also cut into pieces on threads.
    path = write(tmp_path, CASES["clean"])
    monkeypatch.setenv(READER_VARIABLE, "pyarrow")
    monkeypatch.setattr(chunks, "BLOCK_READER_BYTES", 0)
    monkeypatch.setattr(chunks, "PARALLEL_BYTES", 100)
    monkeypatch.setattr(chunks.os, "cpu_count", lambda: 4)
    assert len(ChunkReader(path).parallel_pieces()) == 1
    monkeypatch.setenv(READER_VARIABLE, "pandas")
    assert len(ChunkReader(path).parallel_pieces()) > 1


def test_the_command_names_a_bad_row_and_exits_2(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from click.testing import CliRunner

    from magfit.cli import cli

    path = write(tmp_path, CASES["bad cell late"])
    monkeypatch.setenv(READER_VARIABLE, "pyarrow")
    monkeypatch.setattr(chunks, "BLOCK_READER_BYTES", 0)
    monkeypatch.setattr(chunks, "BLOCK_BYTES", 600)
    result = CliRunner().invoke(cli, ["calibrate", str(path), "-m", "ellipsoid"])
    assert result.exit_code == 2
    assert "line 302, column 'my'" in result.stderr and "'oops' is not a number" in result.stderr
    assert len(result.stderr.strip().splitlines()) == 1


def test_the_command_fits_the_same_subsample_either_way(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    # --max-samples below the file's rows: the even subsample, its fit and the score are those of the pandas
    # path (the stride, the pool and the spill see the same rows in the same order). Ground truth: a known sphere.
    import json

    from click.testing import CliRunner

    from magfit.cli import cli

    rng = np.random.default_rng(5)
    v = rng.normal(size=(3000, 3))
    v = v / np.linalg.norm(v, axis=1)[:, None] * 50.0 + [10.0, -5.0, 3.0] + rng.normal(0.0, 0.2, (3000, 3))
    path = write(tmp_path, "mx,my,mz\n" + "\n".join(f"{x:.4f},{y:.4f},{z:.4f}" for x, y, z in v.tolist()) + "\n")
    monkeypatch.setattr(chunks, "BLOCK_READER_BYTES", 0)
    monkeypatch.setattr(chunks, "BLOCK_BYTES", 5000)
    offsets = []
    for reader in ("pandas", "pyarrow"):
        monkeypatch.setenv(READER_VARIABLE, reader)
        output = tmp_path / f"{reader}.json"
        result = CliRunner().invoke(cli, ["calibrate", str(path), "--max-samples", "1500", "-o", str(output)])
        assert result.exit_code == 0, result.stderr
        assert re.search(r"an even subsample: \d+ of 3000 samples", result.stdout), result.stdout
        offsets.append(np.array(json.loads(output.read_text())["offset"]))
    np.testing.assert_allclose(offsets[1], offsets[0], rtol=0, atol=1e-9)
    assert np.linalg.norm(offsets[1] - [10.0, -5.0, 3.0]) < 0.5
