"""magfit.io: every bad input is one DataFileError line that names the file (line, column) and a fix."""

from __future__ import annotations

import os
import re
import zipfile
from pathlib import Path

import numpy as np
import pytest

from magfit import DataFileError, OptionError
from magfit.io import ChunkReader, read_samples, sniff


def write(tmp_path: Path, text: str | bytes, name: str = "data.csv") -> Path:
    path = tmp_path / name
    path.write_bytes(text if isinstance(text, bytes) else text.encode())
    return path


def rows(n: int, template: str = "{i},{x},{y},{z}") -> list[str]:
    return [template.format(i=i, x=i * 1.5, y=-i, z=100 + i) for i in range(n)]


def error_of(path: Path, **options) -> str:
    with pytest.raises(DataFileError) as caught:
        read_samples(path, **options)
    message = str(caught.value)
    assert message.startswith(f"{path}: ") and "\n" not in message, message
    return message


def test_missing_file(tmp_path: Path) -> None:
    message = error_of(tmp_path / "nope.csv")
    assert message.endswith("no such file; check the path and the current directory")


def test_directory_instead_of_file(tmp_path: Path) -> None:
    assert "is a directory, not a data file" in error_of(tmp_path)


def test_unreadable_file(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    path = write(tmp_path, "mx,my,mz\n1,2,3\n")
    path.chmod(0)
    if hasattr(os, "geteuid") and os.geteuid() == 0:  # root reads anything: make the permission check say no
        monkeypatch.setattr(os, "access", lambda *args, **kwargs: False)
    assert "permission denied; make the file readable (chmod +r) or copy it" in error_of(path)


@pytest.mark.parametrize("content", [b"", b"\n\n  \n", b"\xef\xbb\xbf"])
def test_empty_file(tmp_path: Path, content: bytes) -> None:
    assert re.search(
        r"is empty( \(0 bytes\))?; record some samples or give another file", error_of(write(tmp_path, content))
    )


@pytest.mark.parametrize("content", ["mx,my,mz\n", "Fs,50.00\nInitialization time,60\nmx,my,mz\n\n"])
def test_header_without_rows(tmp_path: Path, content: str) -> None:
    assert "has a header but no data rows (line " in error_of(write(tmp_path, content))


def test_non_numeric_cell_names_line_and_column(tmp_path: Path) -> None:
    lines = ["time,mx,my,mz", *rows(3000)]
    lines[2001] = "2000,3000.0,-2000,12O0"  # letter O instead of a zero, on file line 2002
    message = error_of(write(tmp_path, "\n".join(lines) + "\n"))
    assert "line 2002, column 'mz' (column 4): '12O0' is not a number; fix that cell" in message


def test_non_numeric_cell_outside_the_magnetometer_columns_is_fine(tmp_path: Path) -> None:
    lines = ["time,mx,my,mz", *rows(5)]
    lines[3] = "n/a?,3,-2,102"
    assert read_samples(write(tmp_path, "\n".join(lines) + "\n")).n_rows == 5


@pytest.mark.parametrize(("bad", "count"), [("7,1,2,3,4", 5), ("7,1,2", 3), ("7", 1)])
@pytest.mark.parametrize("block_bytes", [None, 64])
def test_row_with_another_number_of_fields(tmp_path: Path, bad: str, count: int, block_bytes: int | None) -> None:
    lines = ["time,mx,my,mz", *rows(400)]
    lines[300] = bad  # file line 301
    path = write(tmp_path, "\n".join(lines) + "\n")
    with pytest.raises(DataFileError) as caught:
        list(ChunkReader(path, block_bytes=block_bytes, chunk_rows=50))
    assert str(caught.value) == (
        f"{path}: line 301 has {count} fields but the header and the first rows have 4 (delimiter ','); "
        "fix or delete that line"
    )


def test_pieces_of_a_split_file_name_the_files_own_lines(tmp_path: Path) -> None:
    # A piece that starts mid-file counts the lines before it only when a message needs a line number.
    lines = ["# exported by a logger", "time,mx,my,mz", *rows(300)]
    lines[40] = ""  # a blank line in the first piece shifts every later line number by one
    lines[250] = "7,1,2"  # file line 251, in the last of three pieces
    lines[180] = "1,nan,2,3"  # file line 181, in the middle piece: skipped and reported
    path = write(tmp_path, "\n".join(lines) + "\n")
    pieces = ChunkReader(path, chunk_rows=20).split(3)
    assert len(pieces) == 3
    list(pieces[1])
    assert (pieces[1].n_skipped, pieces[1].skipped_lines) == (1, (181,))
    with pytest.raises(DataFileError, match=r": line 251 has 3 fields but the header and the first rows have 4"):
        list(pieces[2])


def test_whitespace_row_with_another_number_of_fields(tmp_path: Path) -> None:
    lines = rows(50, "{x} {y}  {z}")
    lines[20] = "1 2 3 4"
    assert "line 21 has 4 fields but the first rows have 3 (delimiter 'whitespace')" in error_of(
        write(tmp_path, "\n".join(lines) + "\n")
    )


def test_header_that_does_not_match_the_rows(tmp_path: Path) -> None:
    path = write(tmp_path, "time,mx,my,mz,temp\n" + "\n".join(rows(3)) + "\n")
    assert "line 1 looks like a header with 5 names, but the rows have 4 fields; make them match" in error_of(path)


def test_magnetometer_columns_not_found(tmp_path: Path) -> None:
    path = write(tmp_path, "time,ax,ay,az,gx,gy,gz\n" + "\n".join(rows(3, "{i},1,2,3,4,5,6")) + "\n")
    message = error_of(path)
    assert message.endswith(
        "no magnetometer columns found among: time, ax, ay, az, gx, gy, gz; name the x, y, z columns with columns=[...]"
    )


def test_named_column_not_there(tmp_path: Path) -> None:
    path = write(tmp_path, "time,mx,my,mz\n" + "\n".join(rows(3)) + "\n")
    message = error_of(path, columns=["mx", "my", "mag_z"])
    assert message.endswith(
        "no column named 'mag_z'; the columns are: time, mx, my, mz; use one of them or a 0-based index"
    )


def test_index_out_of_range(tmp_path: Path) -> None:
    path = write(tmp_path, "\n".join(rows(3)) + "\n")
    assert "column index 4 is out of range: the file has 4 columns, 0 to 3 (0-based)" in error_of(
        path, columns=[1, 2, 4]
    )


@pytest.mark.parametrize(("content", "count"), [("1,2\n3,4\n", 2), ("1\n2\n3\n", 1)])
def test_fewer_than_three_columns(tmp_path: Path, content: str, count: int) -> None:
    message = error_of(write(tmp_path, content))
    assert (
        f"has {count} field{'s' if count > 1 else ''} per row" in message
        and "a magnetometer needs three (x, y, z)" in message
    )


def test_every_row_nonfinite(tmp_path: Path) -> None:
    message = error_of(write(tmp_path, "mx,my,mz\nnan,1,2\n1,,2\n"))
    assert "all 2 rows have no usable value in mx, my, mz: NaN, infinite, empty, or beyond" in message
    assert "(first at line 2)" in message


def test_binary_and_utf16_files(tmp_path: Path) -> None:
    assert "is a binary file" in error_of(write(tmp_path, b"\x00\x01\x02garbage"))
    assert "is UTF-16 encoded; save it as UTF-8" in error_of(write(tmp_path, "mx,my,mz\n1,2,3\n".encode("utf-16")))


def test_text_without_numbers(tmp_path: Path) -> None:
    assert "has no column of numbers" in error_of(write(tmp_path, "a,b,c\nd,e,f\ng,h,i\n"))


def test_broken_npz_and_npy(tmp_path: Path) -> None:
    assert "is not a readable .npz archive" in error_of(write(tmp_path, b"PK\x03\x04broken", "x.npz"))
    assert "is not a readable .npy file" in error_of(write(tmp_path, b"\x93NUMPYbroken", "x.npy"))
    np.save(tmp_path / "words.npy", np.array([["a", "b", "c"]]))
    assert "holds an array of dtype <U1, not numbers" in error_of(tmp_path / "words.npy")
    np.savez(tmp_path / "k.npz", t=np.arange(3.0), temp=np.ones(3))
    assert "no magnetometer arrays found among the keys: t (3,), temp (3,)" in error_of(tmp_path / "k.npz")


def test_an_npy_header_with_a_negative_size_is_refused(tmp_path: Path) -> None:
    # numpy reads a header announcing shape (-100, 3); its memory map then failed with an OverflowError.
    np.save(tmp_path / "n.npy", np.zeros((100, 3)))
    path = write(tmp_path, (tmp_path / "n.npy").read_bytes().replace(b"(100, 3)", b"(-100, 3)"), "neg.npy")
    assert "the header's shape (-100, 3) has a negative size" in error_of(path)
    np.savez(tmp_path / "k.npz", m=np.zeros((100, 3)))
    with zipfile.ZipFile(tmp_path / "k.npz") as archive:
        member = archive.read("m.npy").replace(b"(100, 3)", b"(-100, 3)")
    with zipfile.ZipFile(tmp_path / "neg.npz", "w") as archive:
        archive.writestr("m.npy", member)
    assert "has a negative size" in error_of(tmp_path / "neg.npz")


@pytest.mark.parametrize(
    ("columns", "message"),
    [
        ("mx,my,mz", "columns must be a sequence of three names or 0-based indices, got the string 'mx,my,mz'"),
        (["mx", "my"], "columns must give exactly three columns (x, y, z), got 2: ['mx', 'my']"),
        (["mx", "my", "mx"], "columns must name three different columns, got ['mx', 'my', 'mx']"),
        ([1.0, 2, 3], "columns must hold names (str) or 0-based indices (int), got 1.0"),
        (["mx", "my", 1], "columns ['mx', 'my', 1] name the same column twice"),
    ],
)
def test_bad_columns_option(tmp_path: Path, columns, message: str) -> None:
    path = write(tmp_path, "mx,my,mz\n1,2,3\n")
    with pytest.raises(OptionError) as caught:
        read_samples(path, columns=columns)
    assert str(caught.value).startswith(message)


def test_sniff_reports_the_same_errors(tmp_path: Path) -> None:
    with pytest.raises(DataFileError, match="is empty"):
        sniff(write(tmp_path, ""))
