"""Standard input, pipes and compressed files (gzip, bzip2, xz, zstd) read like plain files."""

from __future__ import annotations

import bz2
import gzip
import lzma
import os
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from magfit.cli import cli
from magfit.errors import DataFileError
from magfit.io import read_samples
from magfit.io.sources import compression_of

_DIRECTIONS = np.random.default_rng(4).normal(size=(200, 3))
ROWS = 40 * _DIRECTIONS / np.linalg.norm(_DIRECTIONS, axis=1, keepdims=True) + (3.0, -7.0, 11.0)
TEXT = "mx,my,mz\n" + "".join(",".join(repr(float(v)) for v in row) + "\n" for row in ROWS)


def _zstd(data: bytes) -> bytes:
    zstandard = pytest.importorskip("zstandard", reason="zstandard is not installed (pip install 'magfit[zstd]')")
    return bytes(zstandard.ZstdCompressor().compress(data))


COMPRESSORS = {"gz": gzip.compress, "bz2": bz2.compress, "xz": lzma.compress, "zst": _zstd}


@pytest.mark.parametrize("suffix", list(COMPRESSORS))
def test_compressed_files_read_as_the_plain_file(tmp_path: Path, suffix: str) -> None:
    path = tmp_path / f"flight.csv.{suffix}"
    path.write_bytes(COMPRESSORS[suffix](TEXT.encode()))
    table = read_samples(path)
    assert table.columns == ("mx", "my", "mz") and table.path == path
    np.testing.assert_array_equal(table.samples, ROWS)


def test_the_summary_says_the_file_was_decompressed(tmp_path: Path) -> None:
    path = tmp_path / "flight.csv.xz"
    path.write_bytes(lzma.compress(TEXT.encode()))
    result = CliRunner().invoke(cli, ["calibrate", str(path), "-m", "sphere"])
    assert result.exit_code == 0, result.output
    assert f"file             {path} (xz-compressed; text, ','-separated, 3 columns, header)" in result.stdout


def test_compression_is_recognised_by_content_not_by_name(tmp_path: Path) -> None:
    disguised = tmp_path / "flight.csv"  # gzip data under a plain name
    disguised.write_bytes(gzip.compress(TEXT.encode()))
    np.testing.assert_array_equal(read_samples(disguised).samples, ROWS)
    plain = tmp_path / "plain.csv.gz"  # plain text under a compressed name
    plain.write_text(TEXT)
    np.testing.assert_array_equal(read_samples(plain).samples, ROWS)
    assert compression_of(b"\x1f\x8b\x08") == "gzip" and compression_of(b"mx,my") is None


def test_a_compressed_npy_keeps_its_kind(tmp_path: Path) -> None:
    raw = tmp_path / "samples.npy"
    np.save(raw, ROWS)
    path = tmp_path / "samples.npy.xz"
    path.write_bytes(lzma.compress(raw.read_bytes()))
    table = read_samples(path)
    assert table.format.kind == "npy"
    np.testing.assert_array_equal(table.samples, ROWS)


def test_errors_in_a_compressed_file_name_it_not_its_copy(tmp_path: Path) -> None:
    path = tmp_path / "bad.csv.gz"
    path.write_bytes(gzip.compress((TEXT + "1.0,oops,3.0\n").encode()))
    with pytest.raises(DataFileError) as caught:
        read_samples(path)
    assert str(caught.value).startswith(f"{path}: line 202, column 'my'")


def test_a_truncated_compressed_file_is_one_line_exit_2(tmp_path: Path) -> None:
    path = tmp_path / "cut.csv.gz"
    path.write_bytes(gzip.compress(TEXT.encode())[:-30])
    result = CliRunner().invoke(cli, ["calibrate", str(path)])
    assert result.exit_code == 2, result.output
    (line,) = result.stderr.strip().splitlines()
    assert line.startswith(f"magfit: error: {path}: the gzip data cannot be read to its end")


def test_zst_without_zstandard_is_an_install_hint(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    path = tmp_path / "flight.csv.zst"
    path.write_bytes(b"\x28\xb5\x2f\xfd" + b"\x00" * 32)  # the magic number is what counts
    monkeypatch.setitem(sys.modules, "zstandard", None)
    result = CliRunner().invoke(cli, ["calibrate", str(path)])
    assert result.exit_code == 2, result.output
    (line,) = result.stderr.strip().splitlines()
    assert "is zstd-compressed" in line and "pip install 'magfit[zstd]'" in line


@pytest.mark.parametrize("compress", [False, True])
def test_standard_input(tmp_path: Path, compress: bool) -> None:
    data = gzip.compress(TEXT.encode()) if compress else TEXT.encode()
    result = CliRunner().invoke(cli, ["calibrate", "-", "-m", "sphere", "-o", str(tmp_path / "cal.json")], input=data)
    assert result.exit_code == 0, result.output
    how = "standard input, gzip-compressed" if compress else "standard input"
    assert result.stdout.startswith(f"file             - ({how}; text, ','-separated, 3 columns, header)")
    assert "rows             200 read" in result.stdout


def test_standard_input_twice_in_one_process_reads_each_input() -> None:
    runner = CliRunner()
    first = runner.invoke(cli, ["compare", "-", "--methods", "sphere", "--format", "csv"], input=TEXT)
    shifted = "mx,my,mz\n" + "".join(",".join(repr(float(v)) for v in row) + "\n" for row in ROWS + 100)
    second = runner.invoke(cli, ["compare", "-", "--methods", "sphere", "--format", "csv"], input=shifted)
    assert first.exit_code == 0 and second.exit_code == 0
    offsets = [float(line.split(",")[9]) for line in (first.stdout.splitlines()[1], second.stdout.splitlines()[1])]
    assert offsets[1] - offsets[0] == pytest.approx(100)  # the second input, not the first one's copy again


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no named pipes on this system")
def test_a_named_pipe_is_read_as_a_stream(tmp_path: Path) -> None:
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)

    def feed() -> None:
        with open(fifo, "wb") as handle:
            handle.write(gzip.compress(TEXT.encode()))

    writer = threading.Thread(target=feed, daemon=True)
    writer.start()
    table = read_samples(fifo)
    writer.join(timeout=10)
    np.testing.assert_array_equal(table.samples, ROWS)


def test_the_temporary_copies_are_removed_when_the_process_ends(tmp_path: Path) -> None:
    path = tmp_path / "flight.csv.bz2"
    path.write_bytes(bz2.compress(TEXT.encode()))
    scratch = tmp_path / "tmp"
    scratch.mkdir()
    code = "import sys; from magfit.io import read_samples; print(len(read_samples(sys.argv[1]).samples))"
    run = subprocess.run(
        [sys.executable, "-c", code, str(path)],
        capture_output=True,
        text=True,
        env={**os.environ, "TMPDIR": str(scratch)},
        check=True,
    )
    assert run.stdout.strip() == "200"
    assert list(scratch.iterdir()) == []
