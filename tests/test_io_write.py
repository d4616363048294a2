"""magfit.io writers: calibrated copies keep everything but the magnetometer values; atomic writes."""

from __future__ import annotations

import os
import re
import zipfile
from pathlib import Path

import numpy as np
import pytest

import magfit
from magfit import DataFileError, OptionError
from magfit.io import atomic_open, atomic_write_text, read_samples, write_calibrated
from magfit.io.writers import SIGNIFICANT_DIGITS

#: Written values carry SIGNIFICANT_DIGITS digits: relative rounding error at most half a unit in the last.
RTOL = 0.5 * 10.0 ** (1 - SIGNIFICANT_DIGITS)


@pytest.fixture(scope="module")
def calibration() -> magfit.Calibration:
    """A known distortion fitted back from simulated samples (hard iron + soft iron, as in the paper)."""
    sim = magfit.scenario("mpu9250", "steel").simulate(500, seed=4)
    return magfit.fit(sim.samples, method="ellipsoid")


@pytest.fixture(scope="module")
def raw() -> np.ndarray:
    return np.round(magfit.scenario("mpu9250", "steel").simulate(40, seed=5).samples, 4)


def fields_of(line: bytes, delimiter: bytes) -> list[bytes]:
    return line.split() if delimiter == b" " else line.split(delimiter)


def assert_kept(source: bytes, output: bytes, skip: int, delimiter: bytes, mag: tuple[int, ...]) -> None:
    """Same first ``skip`` lines and line ends, and the same bytes in every non-magnetometer field."""
    src_lines, out_lines = source.split(b"\n"), output.split(b"\n")
    assert len(src_lines) == len(out_lines)
    assert src_lines[:skip] == out_lines[:skip]
    for before, after in zip(src_lines[skip:], out_lines[skip:], strict=True):
        assert before.endswith(b"\r") == after.endswith(b"\r")
        a, b = fields_of(before.rstrip(b"\r"), delimiter), fields_of(after.rstrip(b"\r"), delimiter)
        assert len(a) == len(b)
        assert [f for i, f in enumerate(a) if i not in mag] == [f for i, f in enumerate(b) if i not in mag]


def test_text_copy_keeps_bom_preamble_header_delimiter_and_other_columns(tmp_path: Path, calibration, raw) -> None:
    lines = ["Fs,50.00", "Initialization time,60", "time, gyro_x, mx, my, mz, label"]
    for i, row in enumerate(raw):
        x, y, z = map(float, row)
        lines.append(f"{i * 0.02:.2f}, {np.sin(i):.6f}, {x!r}, {y!r}, {z!r}, turn {i % 3}")
    lines[10] = "0.16, 0.1, nan, 3.0, 4.0, turn 1"  # a skipped row: no calibrated value, so nan in all three
    source = b"\xef\xbb\xbf" + "\r\n".join(lines).encode() + b"\r\n"
    path = tmp_path / "in.csv"
    path.write_bytes(source)
    table = read_samples(path)
    out = write_calibrated(table, calibration, tmp_path / "out.csv")
    output = out.read_bytes()
    assert output.startswith(b"\xef\xbb\xbf")
    assert_kept(source, output, 3, b",", (2, 3, 4))
    assert output.split(b"\r\n")[10] == b"0.16, 0.1, nan, nan, nan, turn 1"
    back = read_samples(out)
    assert back.format == table.format and back.columns == ("mx", "my", "mz") and back.n_skipped == 1
    np.testing.assert_allclose(back.samples, calibration.apply(table.samples), rtol=RTOL, atol=0)


def test_whitespace_copy_keeps_the_other_columns(tmp_path: Path, calibration, raw) -> None:
    text = "".join(f"{i:6d}   {row[0]:10.4f} {row[1]:10.4f} {row[2]:10.4f}   7.5\n" for i, row in enumerate(raw))
    path = tmp_path / "in.txt"
    path.write_text(text)
    out = write_calibrated(path, calibration, tmp_path / "out.txt", columns=[1, 2, 3], normalized=True)
    assert_kept(text.encode(), out.read_bytes(), 0, b" ", (1, 2, 3))
    back = read_samples(out, columns=[1, 2, 3])
    np.testing.assert_allclose(back.samples, calibration.apply(raw, normalized=True), rtol=RTOL, atol=1e-12)


def test_reversed_columns_and_decimal_commas(tmp_path: Path, calibration, raw) -> None:
    text = "t;Z;Y;X\n" + "".join(
        ";".join([str(i), *(f"{v:.4f}".replace(".", ",") for v in row[::-1])]) + "\n" for i, row in enumerate(raw)
    )
    path = tmp_path / "in.csv"
    path.write_text(text)
    out = write_calibrated(path, calibration, tmp_path / "out.csv", columns=["X", "Y", "Z"])
    assert_kept(text.encode(), out.read_bytes(), 1, b";", (1, 2, 3))
    back = read_samples(out, columns=["X", "Y", "Z"])
    np.testing.assert_allclose(back.samples, calibration.apply(raw), rtol=RTOL)


def test_blank_lines_quotes_and_spaced_cells_take_the_line_by_line_path(tmp_path: Path, calibration, raw) -> None:
    lines = ["time,mx,my,mz,note"]
    for i, row in enumerate(raw):
        x, y, z = map(float, row)
        if i % 7 == 0:
            lines.append(f'{i},{x!r},{y!r},{z!r},"turn, {i}"')
        else:
            lines.append(f"{i}, {x!r} ,{y!r},{z!r},plain" if i == 1 else f"{i},{x!r},{y!r},{z!r},plain")
        if i in (3, 20):
            lines.append("")
    text = "\n".join(lines) + "\n"
    path = tmp_path / "in.csv"
    path.write_text(text)
    out = write_calibrated(path, calibration, tmp_path / "out.csv")
    written = out.read_text().split("\n")
    blank = [i for i, line in enumerate(text.split("\n")) if not line]
    assert [i for i, line in enumerate(written) if not line] == blank
    for before, after in zip(text.split("\n"), written, strict=True):
        assert before.split(",")[0] == after.split(",")[0]  # time column, spacing included
        assert before.rsplit(",", 1)[-1] == after.rsplit(",", 1)[-1]  # note column, quotes included
    assert written[2].startswith("1, ") and written[2].split(",")[1].endswith(" ")  # spaces around mx are kept
    back = read_samples(out)
    np.testing.assert_allclose(back.samples, calibration.apply(raw), rtol=RTOL)


def test_npy_copy(tmp_path: Path, calibration, raw) -> None:
    array = np.column_stack([np.arange(len(raw)), raw[:, ::-1] * 10, np.full(len(raw), 3)]).astype(np.int32)
    array[4, 2] = 0
    np.save(tmp_path / "in.npy", array)
    out = write_calibrated(tmp_path / "in.npy", calibration, tmp_path / "out.npy", columns=[3, 2, 1])
    written = np.load(out)
    assert written.dtype == np.float64 and written.shape == array.shape
    np.testing.assert_array_equal(written[:, [0, 4]], array[:, [0, 4]])
    np.testing.assert_allclose(written[:, [3, 2, 1]], calibration.apply(array[:, [3, 2, 1]]), rtol=1e-14)


def test_npz_copy_keeps_other_keys_and_compression(tmp_path: Path, calibration, raw) -> None:
    mag = raw.astype(np.float32)
    mag[7, 0] = np.nan
    arrays = {"time": np.arange(len(raw)), "mag_x": mag[:, 0], "mag_y": mag[:, 1], "mag_z": mag[:, 2], "gain": 1.0}
    np.savez_compressed(tmp_path / "in.npz", **arrays)
    out = write_calibrated(tmp_path / "in.npz", calibration, tmp_path / "out.npz")
    with zipfile.ZipFile(out) as archive:
        assert {info.compress_type for info in archive.infolist()} == {zipfile.ZIP_DEFLATED}
    with np.load(out) as written:
        assert written.files == ["time", "mag_x", "mag_y", "mag_z", "gain"]
        np.testing.assert_array_equal(written["time"], arrays["time"])
        assert written["time"].dtype == arrays["time"].dtype and float(written["gain"]) == 1.0
        got = np.column_stack([written["mag_x"], written["mag_y"], written["mag_z"]])
    finite = np.isfinite(mag).all(axis=1)
    np.testing.assert_allclose(got[finite], calibration.apply(mag[finite].astype(np.float64)), rtol=1e-14)
    assert np.isnan(got[7]).all()  # no calibrated value: NaN in all three, never raw numbers among corrected ones


def test_refuses_to_overwrite_the_input(tmp_path: Path, calibration) -> None:
    path = tmp_path / "in.csv"
    path.write_text("mx,my,mz\n1,2,3\n4,5,6\n7,8,10\n")
    (tmp_path / "sub").mkdir()
    link = tmp_path / "link.csv"
    link.symlink_to(path)
    for target in (path, tmp_path / "sub" / ".." / "in.csv", link):
        with pytest.raises(DataFileError) as caught:
            write_calibrated(path, calibration, target)
        assert str(caught.value) == (
            f"{target}: this is the input file; refusing to overwrite it, write to another name "
            f"(e.g. {tmp_path / 'in_calibrated.csv'})"
        )
    assert path.read_text() == "mx,my,mz\n1,2,3\n4,5,6\n7,8,10\n"


def no_temp_files(directory: Path) -> bool:
    return not [p for p in directory.iterdir() if p.name.endswith(".tmp")]


def test_failure_in_the_middle_leaves_the_target_untouched(tmp_path: Path, calibration, raw) -> None:
    lines = ["mx,my,mz", *(",".join(map(repr, map(float, row))) for row in raw)] * 3000
    lines[-2] = "1,2,oops"
    path = tmp_path / "in.csv"
    path.write_text("\n".join(lines[:1] + [line for line in lines[1:] if line != "mx,my,mz"]) + "\n")
    out = tmp_path / "out.csv"
    out.write_text("previous result\n")
    with pytest.raises(DataFileError, match=r"line \d+, column 'mz' \(column 3\): 'oops' is not a number"):
        write_calibrated(path, calibration, out)
    assert out.read_text() == "previous result\n"
    assert no_temp_files(tmp_path)


def test_atomic_write_text_and_open(tmp_path: Path) -> None:
    target = tmp_path / "cal.json"
    atomic_write_text(target, '{"a": 1}\n')
    assert target.read_text() == '{"a": 1}\n'
    target.chmod(0o640)
    with atomic_open(target, "w", encoding="utf-8") as handle:
        handle.write("new\n")
    assert target.read_text() == "new\n" and (target.stat().st_mode & 0o777) == 0o640
    with pytest.raises(RuntimeError, match="disk full"), atomic_open(target, "wb") as handle:
        handle.write(b"half of it")
        raise RuntimeError("disk full")
    assert target.read_text() == "new\n"
    assert no_temp_files(tmp_path)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cal.json"]


def test_atomic_open_rejects_append_and_missing_directory(tmp_path: Path) -> None:
    with pytest.raises(OptionError, match="mode must be 'w', 'wt' or 'wb', got 'a'"), atomic_open(tmp_path / "f", "a"):
        pass
    missing = tmp_path / "no" / "f.txt"
    with pytest.raises(DataFileError, match=re.escape(f"{missing}: the directory {missing.parent} does not exist")):
        atomic_write_text(missing, "x")
    assert not os.path.exists(missing.parent)


def test_bom_before_headerless_data_is_kept(tmp_path: Path, calibration, raw) -> None:
    # Found by the property test: the byte-order mark sat in the first data line and was lost.
    path = tmp_path / "in.csv"
    path.write_bytes(b"\xef\xbb\xbf" + "".join(",".join(map(repr, map(float, row))) + "\n" for row in raw).encode())
    assert read_samples(path).format.data_offset == 3
    out = write_calibrated(path, calibration, tmp_path / "out.csv")
    assert out.read_bytes().startswith(b"\xef\xbb\xbf") and out.read_bytes()[3:4] != b"\xef"
    np.testing.assert_allclose(read_samples(out).samples, calibration.apply(raw), rtol=RTOL)


def test_quoted_cells_keep_their_quotes(tmp_path: Path) -> None:
    path = tmp_path / "in.csv"
    path.write_text('time,mx,my,mz,note\n"2024-01-01, 00:00",1,2,3,"a, ""b"""\n"x", "4" ,5,6,plain\n')
    shift = magfit.Calibration("shift", [1.0, 2.0, 3.0], np.eye(3), 50.0)
    out = write_calibrated(path, shift, tmp_path / "out.csv")
    assert out.read_text() == 'time,mx,my,mz,note\n"2024-01-01, 00:00",0,0,0,"a, ""b"""\n"x", "3" ,3,3,plain\n'


def test_copy_whose_bottom_half_is_missing_values_reads_back(tmp_path: Path, calibration) -> None:
    # Regression (found by the layout property test): most rows NaN, so the copy's lower half is "nan".
    path = tmp_path / "in.csv"
    path.write_text("1,2,3\n" + "nan,nan,nan\n" * 3 + "4,5,6\n" + "7,nan,9\n" * 3)
    out = write_calibrated(read_samples(path), calibration, tmp_path / "out.csv")
    assert out.read_text().splitlines()[-1] == "nan,nan,nan"
    back = read_samples(out)
    np.testing.assert_allclose(back.samples, calibration.apply(np.array([[1.0, 2, 3], [4, 5, 6]])), rtol=1e-9)
