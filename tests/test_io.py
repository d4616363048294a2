"""magfit.io: sniffing and reading the file shapes users have, the column rule, chunks = whole file."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from magfit import DataFileError, OptionError
from magfit.io import ChunkReader, find_magnetometer_columns, iter_sample_chunks, read_samples, sniff

#: Ten samples with awkward values (negative, small, large) used by the layout tests.
VALUES = np.array(
    [
        [28.0, -22.800001, -79.400001],
        [28.300001, -21.899999, -77.700004],
        [-0.011998045920859795, -0.7108842208109428, 1e-3],
        [6202.0, 682.0, 4812.0],
        [-413.0, 758.0, 318.0],
        [1.5, 2.25, -3.125],
        [0.0, -0.0, 1e5],
        [12.5, -48.56, 11.2],
        [-645.0, 710.0, -1966.0],
        [55.375, -0.5, 425.0625],
    ]
)


def write(tmp_path: Path, text: str | bytes, name: str = "data.csv") -> Path:
    path = tmp_path / name
    path.write_bytes(text if isinstance(text, bytes) else text.encode())
    return path


def table_text(delimiter: str, header: list[str] | None = None, extra: int = 0, values: np.ndarray = VALUES) -> str:
    """Rows of ``extra`` filler columns (time-like) followed by the three values, joined by ``delimiter``."""
    lines = [delimiter.join(header)] if header is not None else []
    for i, row in enumerate(values):
        cells = [f"{100 + i}"] * extra + [repr(float(v)) for v in row]
        lines.append(delimiter.join(cells))
    return "\n".join(lines) + "\n"


# ---------------------------------------------------------------------------------------------- layouts


@pytest.mark.parametrize(
    ("delimiter", "expected"),
    [(",", ","), (", ", ", "), ("\t", "\t"), (";", ";"), ("|", "|"), (" ", "whitespace"), ("   ", "whitespace")],
)
@pytest.mark.parametrize("header", [None, ["t", "mx", "my", "mz"]])
def test_every_delimiter_with_and_without_header(tmp_path: Path, delimiter: str, expected: str, header) -> None:
    path = write(tmp_path, table_text(delimiter, header, extra=1))
    fmt = sniff(path)
    assert (fmt.kind, fmt.delimiter, fmt.n_columns, fmt.preamble_lines) == ("text", expected, 4, 0)
    assert fmt.header == (tuple(header) if header else None)
    table = read_samples(path)
    if header:
        assert table.columns == ("mx", "my", "mz")
        np.testing.assert_array_equal(table.samples, VALUES)
    else:
        # No header: the leading counter (100, 101 ...) is passed over as a time column, and the table says so.
        assert table.columns == ("column 2", "column 3", "column 4")
        assert table.column_note == "column 1 is monotonic: time or a counter"
        np.testing.assert_array_equal(table.samples, VALUES)
    assert (table.n_rows, table.n_skipped, table.skipped_lines) == (10, 0, ())


def test_aligned_columns_with_leading_spaces(tmp_path: Path) -> None:
    lines = ["      x         y         z"] + ["  ".join(f"{v:>12.6f}" for v in row) for row in VALUES[:, :]]
    path = write(tmp_path, "\n".join(lines) + "\n", "aligned.txt")
    table = read_samples(path)
    assert table.format.delimiter == "whitespace" and table.columns == ("x", "y", "z")
    np.testing.assert_allclose(table.samples, VALUES, atol=5e-7)


def test_preamble_bom_crlf_and_no_final_newline(tmp_path: Path) -> None:
    body = "Fs,50.00\r\nInitialization time,60\r\nmx,my,mz\r\n" + table_text(",", values=VALUES).replace("\n", "\r\n")
    path = write(tmp_path, b"\xef\xbb\xbf" + body.rstrip("\r\n").encode())
    fmt = sniff(path)
    assert (fmt.encoding, fmt.preamble_lines, fmt.header, fmt.data_line) == ("utf-8-sig", 2, ("mx", "my", "mz"), 3)
    np.testing.assert_array_equal(read_samples(path).samples, VALUES)


def test_semicolons_with_decimal_commas(tmp_path: Path) -> None:
    text = "Bx;By;Bz\n" + "".join(";".join(f"{v:.4f}".replace(".", ",") for v in row) + "\n" for row in VALUES)
    table = read_samples(write(tmp_path, text))
    assert (table.format.delimiter, table.format.decimal, table.columns) == (";", ",", ("Bx", "By", "Bz"))
    np.testing.assert_allclose(table.samples, VALUES, atol=5e-5)


def test_quoted_names_and_numbers(tmp_path: Path) -> None:
    text = '"time","mag_x","mag_y","mag_z","note"\n' + "".join(
        f'"0.1",{float(row[0])!r},"{float(row[1])!r}",{float(row[2])!r},"a, b"\n' for row in VALUES
    )
    table = read_samples(write(tmp_path, text))
    assert table.columns == ("mag_x", "mag_y", "mag_z")
    np.testing.assert_array_equal(table.samples, VALUES)


def test_latin1_header_is_read(tmp_path: Path) -> None:
    text = "temp (°C),mx,my,mz\n" + "".join(f"21.5,{float(r[0])!r},{float(r[1])!r},{float(r[2])!r}\n" for r in VALUES)
    table = read_samples(write(tmp_path, text.encode("latin-1")))
    assert table.format.encoding == "latin-1" and table.format.header[0] == "temp (°C)"
    np.testing.assert_array_equal(table.samples, VALUES)


def test_blank_lines_are_not_rows(tmp_path: Path) -> None:
    lines = table_text(",", ["mx", "my", "mz"]).splitlines()
    text = "\n".join([*lines[:4], "", "   ", *lines[4:], "", ""]) + "\n"
    table = read_samples(write(tmp_path, text))
    assert table.n_rows == 10
    np.testing.assert_array_equal(table.samples, VALUES)


# ---------------------------------------------------------------------------------------------- columns


@pytest.mark.parametrize(
    "names",
    [
        ("mx", "my", "mz"),
        ("mag_x", "mag_y", "mag_z"),
        ("magX", "magY", "magZ"),
        ("Bx", "By", "Bz"),
        ("imu_mx", "imu_my", "imu_mz"),
        ("Mx", "My", "Mz"),
        ("m_x", "m_y", "m_z"),
        ("mag.x", "mag.y", "mag.z"),
        ("magnetometer_x", "magnetometer_y", "magnetometer_z"),
        ("mx_raw", "my_raw", "mz_raw"),
        ("MagX(uT)", "MagY(uT)", "MagZ(uT)"),
        ("MAG_X [gauss]", "MAG_Y [gauss]", "MAG_Z [gauss]"),
        ("x_mag", "y_mag", "z_mag"),
        ("compass_x", "compass_y", "compass_z"),
    ],
)
def test_magnetometer_names_win_over_accelerometer_gyro_and_bare_xyz(names: tuple[str, str, str]) -> None:
    header = ["time", "ax", "ay", "az", "gx", "gy", "gz", "Wx", "Wy", "Wz", "Ax", "Ay", "Az", "x", "y", "z", *names]
    best = find_magnetometer_columns(header)[0]
    assert best.names == names
    assert best.indices == (16, 17, 18)


@pytest.mark.parametrize(
    "header",
    [
        ["ax", "ay", "az", "gx", "gy", "gz"],
        ["accel_x", "accel_y", "accel_z", "gyro_x", "gyro_y", "gyro_z"],
        ["Wx", "Wy", "Wz", "Ax", "Ay", "Az"],
        ["pos_x", "pos_y", "pos_z", "vel_x", "vel_y", "vel_z"],
        ["x_m", "y_m", "z_m"],  # metres, not a magnetometer
        ["index", "day", "max"],
    ],
)
def test_other_sensors_are_never_magnetometers(header: list[str]) -> None:
    assert find_magnetometer_columns(header) == []


def test_raw_readings_are_preferred_to_calibrated_ones() -> None:
    header = ["mx_scaled", "my_scaled", "mz_scaled", "mx_raw", "my_raw", "mz_raw"]
    candidates = find_magnetometer_columns(header)
    assert [c.names for c in candidates] == [("mx_raw", "my_raw", "mz_raw"), ("mx_scaled", "my_scaled", "mz_scaled")]
    assert candidates[0].score > candidates[1].score


def test_two_magnetometers_are_an_ambiguity_not_a_guess(tmp_path: Path) -> None:
    path = write(tmp_path, "t,imu_mx,imu_my,imu_mz,mag_x,mag_y,mag_z\n0,1,2,3,4,5,6\n1,1,2,3,4,5,6\n")
    with pytest.raises(DataFileError) as error:
        read_samples(path)
    message = str(error.value)
    assert "(imu_mx,imu_my,imu_mz)" in message and "(mag_x,mag_y,mag_z)" in message
    assert "columns=['imu_mx', 'imu_my', 'imu_mz']" in message and str(path) in message and "\n" not in message
    np.testing.assert_array_equal(read_samples(path, columns=["mag_x", "mag_y", "mag_z"]).samples, [[4, 5, 6]] * 2)


@pytest.mark.parametrize(
    ("columns", "picked", "expected"),
    [
        (["z", "y", "x"], ("z", "y", "x"), VALUES[:, ::-1]),
        (["X", "Y", "Z"], ("x", "y", "z"), VALUES),  # names are case-insensitive
        ([3, 2, 1], ("x", "y", "z"), VALUES),  # 0-based indices, in x, y, z order
        ([1, "y", np.int64(3)], ("z", "y", "x"), VALUES[:, ::-1]),
    ],
)
def test_columns_by_name_or_index_in_the_order_given(tmp_path: Path, columns, picked, expected) -> None:
    # This app writes z, y, x: the columns option says which file column is x, y and z.
    path = write(tmp_path, table_text(",", ["t", "z", "y", "x"], extra=1, values=VALUES[:, ::-1]))
    table = read_samples(path, columns=columns)
    assert table.columns == picked
    np.testing.assert_array_equal(table.samples, expected)


def test_no_header_labels_round_trip_through_columns(tmp_path: Path) -> None:
    path = write(tmp_path, table_text("\t", extra=2))
    table = read_samples(path)
    assert table.columns == ("column 3", "column 4", "column 5")  # two counters before the samples
    again = read_samples(path, columns=table.columns)
    np.testing.assert_array_equal(again.samples, VALUES)
    first = read_samples(path, columns=["column 1", "column 2", "column 3"])
    np.testing.assert_array_equal(first.samples[:, 2], VALUES[:, 0])


def test_no_header_skips_a_leading_text_column(tmp_path: Path) -> None:
    text = "".join(f"2024-01-01T00:00:{i:02d},{','.join(map(repr, map(float, r)))},7\n" for i, r in enumerate(VALUES))
    table = read_samples(write(tmp_path, text))
    assert table.columns == ("column 2", "column 3", "column 4")
    np.testing.assert_array_equal(table.samples, VALUES)


# ---------------------------------------------------------------------------------------------- npy / npz


def test_npy_three_and_more_columns(tmp_path: Path) -> None:
    np.save(tmp_path / "a.npy", VALUES)
    table = read_samples(tmp_path / "a.npy")
    assert table.format.kind == "npy" and table.columns == ("column 1", "column 2", "column 3")
    np.testing.assert_array_equal(table.samples, VALUES)
    wide = np.column_stack([np.arange(10.0), VALUES[:, ::-1], np.ones(10)]).astype(np.float32)
    np.save(tmp_path / "b.npy", wide)
    table = read_samples(tmp_path / "b.npy", columns=[3, 2, 1])
    np.testing.assert_array_equal(table.samples, VALUES.astype(np.float32))


def test_npy_transposed_or_flat_is_refused(tmp_path: Path) -> None:
    np.save(tmp_path / "t.npy", np.zeros((3, 50)))
    with pytest.raises(DataFileError, match=r"shape \(3, 50\): one sample per column; save its transpose"):
        read_samples(tmp_path / "t.npy")
    np.save(tmp_path / "f.npy", np.zeros(30))
    with pytest.raises(DataFileError, match=r"shape \(30,\); save the samples as an \(N, 3\) array"):
        read_samples(tmp_path / "f.npy")


def test_npz_keys_found_by_name(tmp_path: Path) -> None:
    arrays = {"time": np.arange(10.0), "accel_x": np.ones(10), "accel_y": np.ones(10), "accel_z": np.ones(10)}
    arrays |= {"mag_x": VALUES[:, 0], "mag_y": VALUES[:, 1], "mag_z": VALUES[:, 2]}
    np.savez(tmp_path / "log.npz", **arrays)
    table = read_samples(tmp_path / "log.npz")
    assert table.columns == ("mag_x", "mag_y", "mag_z") and table.format.header == tuple(arrays)
    np.testing.assert_array_equal(table.samples, VALUES)
    chunks = iter_sample_chunks(tmp_path / "log.npz", chunk_rows=3)
    assert [len(chunk) for chunk in chunks] == [3, 3, 3, 1]


def test_npz_single_key_and_explicit_keys(tmp_path: Path) -> None:
    np.savez_compressed(tmp_path / "one.npz", samples=VALUES, t=np.arange(10))
    table = read_samples(tmp_path / "one.npz")
    assert table.columns == ("samples[:, 0]", "samples[:, 1]", "samples[:, 2]")
    np.testing.assert_array_equal(table.samples, VALUES)
    np.testing.assert_array_equal(read_samples(tmp_path / "one.npz", columns=table.columns).samples, VALUES)
    np.testing.assert_array_equal(read_samples(tmp_path / "one.npz", columns=["samples"]).samples, VALUES)
    np.savez(tmp_path / "two.npz", left=VALUES, right=VALUES * 2, u=VALUES[:, 0], v=VALUES[:, 1], w=VALUES[:, 2])
    with pytest.raises(DataFileError, match=r"several \(N, 3\) arrays could be the samples: left, right"):
        read_samples(tmp_path / "two.npz")
    np.testing.assert_array_equal(read_samples(tmp_path / "two.npz", columns=["w", "v", "u"]).samples, VALUES[:, ::-1])
    with pytest.raises(DataFileError, match=r"no array named 'q'; the keys are: left \(10, 3\), right \(10, 3\)"):
        read_samples(tmp_path / "two.npz", columns=["u", "v", "q"])


# ---------------------------------------------------------------------------------------------- non-finite rows


def nan_file(tmp_path: Path) -> Path:
    rows = [",".join(repr(float(v)) for v in row) for row in VALUES]
    rows[2] = "1.0,,3.0"  # empty cell
    rows[5] = "nan,2,3"
    rows[7] = "1,inf,3"
    rows[8] = "1,2,-Infinity"
    # line 1 header, line 2 blank, rows 0-3 on lines 3-6, line 7 blank, rows 4-9 on lines 8-13
    return write(tmp_path, "mx,my,mz\n\n" + "\n".join(rows[:4]) + "\n\n" + "\n".join(rows[4:]) + "\n")


def test_nonfinite_rows_are_skipped_counted_and_located(tmp_path: Path) -> None:
    table = read_samples(nan_file(tmp_path))
    assert (table.n_rows, table.n_skipped) == (10, 4)
    assert table.skipped_lines == (5, 9, 11, 12)
    keep = [0, 1, 3, 4, 6, 9]
    np.testing.assert_array_equal(table.samples, VALUES[keep])


def test_nonfinite_error_names_the_first_line(tmp_path: Path) -> None:
    with pytest.raises(DataFileError, match=r"line 5, column 'my': the value is empty or NaN; fix or delete"):
        read_samples(nan_file(tmp_path), nonfinite="error")


def test_npy_nonfinite_rows_are_counted_by_row(tmp_path: Path) -> None:
    values = VALUES.copy()
    values[[3, 6], 1] = np.nan
    np.save(tmp_path / "n.npy", values)
    table = read_samples(tmp_path / "n.npy")
    assert (table.n_skipped, table.skipped_lines) == (2, (4, 7))
    with pytest.raises(DataFileError, match=r"row 4, column 'column 2': the value is empty or NaN"):
        read_samples(tmp_path / "n.npy", nonfinite="error")


# ---------------------------------------------------------------------------------------------- chunks


def many_rows(tmp_path: Path, n: int = 997) -> tuple[Path, np.ndarray]:
    rng = np.random.default_rng(3)
    values = np.round(rng.normal(scale=300.0, size=(n, 3)), 3)
    lines = ["Sampling,100 Hz", "time, gyro, mx, my, mz"]
    for i, row in enumerate(values):
        if i in (10, 400):
            lines.append("")  # blank lines inside the data
        cells = [f"{i * 0.01:.2f}", "0.5", *(repr(float(v)) for v in row)]
        if i in (5, 500, 996):
            cells[3] = "nan"
        lines.append(", ".join(cells))
    return write(tmp_path, "\n".join(lines) + "\n", "many.csv"), values


@pytest.mark.parametrize(("chunk_rows", "block_bytes"), [(1, 50), (7, 300), (100, 4096), (10_000, None)])
def test_chunked_reading_equals_full_reading(tmp_path: Path, chunk_rows: int, block_bytes: int | None) -> None:
    path, values = many_rows(tmp_path)
    full = read_samples(path)
    reader = ChunkReader(path, chunk_rows=chunk_rows, block_bytes=block_bytes)
    chunks = list(reader)
    assert all(1 <= len(chunk) <= chunk_rows for chunk in chunks)
    np.testing.assert_array_equal(np.concatenate(chunks), full.samples)
    assert (reader.n_rows, reader.n_skipped, reader.skipped_lines) == (full.n_rows, full.n_skipped, full.skipped_lines)
    assert full.n_rows == 997 and full.n_skipped == 3
    # data row i sits on line i + 3, plus one per blank line before it
    assert full.skipped_lines == (5 + 3, 500 + 3 + 2, 996 + 3 + 2)
    keep = np.setdiff1d(np.arange(997), [5, 500, 996])
    np.testing.assert_array_equal(full.samples, values[keep])


def test_chunk_reader_reports_columns_and_format_before_iterating(tmp_path: Path) -> None:
    path, _ = many_rows(tmp_path)
    reader = iter_sample_chunks(path, chunk_rows=10)
    assert reader.columns == ("mx", "my", "mz") and reader.column_indices == (2, 3, 4)
    assert reader.format.delimiter == ", " and reader.format.preamble_lines == 1
    assert sum(len(chunk) for chunk in reader) == 994
    assert sum(len(chunk) for chunk in reader) == 994  # a second pass starts again


def test_options_are_checked() -> None:
    with pytest.raises(OptionError, match="nonfinite must be 'skip' or 'error', got 'drop'"):
        ChunkReader(__file__, nonfinite="drop")  # type: ignore[arg-type]
    with pytest.raises(OptionError, match="chunk_rows must be a positive integer, got 0"):
        iter_sample_chunks(__file__, chunk_rows=0)


def test_the_file_formats_page_examples_run(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import doctest

    page = Path(__file__).resolve().parents[1] / "docs" / "file-formats.md"
    monkeypatch.chdir(tmp_path)  # the examples write their files in the current directory
    result = doctest.testfile(str(page), module_relative=False, optionflags=doctest.ELLIPSIS)
    assert result.attempted > 10 and result.failed == 0


def test_read_samples_in_parallel_pieces_is_one_reader(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    # Above PARALLEL_BYTES a text file is read in pieces on threads (lowered here so that 3 pieces are cut):
    # the samples, counts, skipped lines and errors are those of one reader.
    import magfit.io.chunks as chunks

    rng = np.random.default_rng(3)
    values = rng.normal(0.0, 50.0, (3000, 3)).round(3)
    lines = [f"{i},{x},{y},{z}" for i, (x, y, z) in enumerate(values.tolist())]
    for row in (5, 1500, 2990):
        lines[row] = f"{row},nan,1,2"
    lines[1000:1000] = [""] * 60_000  # a run of blank lines longer than a piece: that piece has no rows
    path = write(tmp_path, "t,mx,my,mz\n" + "\n".join(lines) + "\n")
    whole = read_samples(path)
    monkeypatch.setattr(chunks, "PARALLEL_BYTES", 100)
    monkeypatch.setattr(chunks.os, "cpu_count", lambda: 16)  # capped at MAX_PIECES
    pieces = ChunkReader(path).parallel_pieces()
    assert len(pieces) == chunks.MAX_PIECES
    assert min(len(list(piece)) for piece in pieces) == 0
    counted: list[int] = []
    parallel = read_samples(path, progress=counted.append)
    np.testing.assert_array_equal(parallel.samples, whole.samples)
    assert sum(counted) == len(parallel.samples) == 2997 and len(counted) >= chunks.MAX_PIECES - 1
    expected = (3000, 3, (7, 61_502, 62_992))  # file lines: header, then rows shifted by the blank run
    assert (parallel.n_rows, parallel.n_skipped, parallel.skipped_lines) == expected
    assert (whole.n_rows, whole.n_skipped, whole.skipped_lines) == expected
    lines[60_800] = "1,2,3"  # the first error of the file, in the third piece ...
    lines[62_000] = "x,y"  # ... and a later one in the fourth, which may fail first on its thread
    bad = write(tmp_path, "t,mx,my,mz\n" + "\n".join(lines) + "\n", "bad.csv")
    with pytest.raises(DataFileError, match=r"line 60802 has 3 fields"):
        read_samples(bad)


def test_read_pieces_stops_the_pieces_after_a_failure_but_not_those_before(tmp_path: Path) -> None:
    import time

    import magfit.io.chunks as chunks

    lines = [f"{i},{i},{2 * i},{3 * i}" for i in range(4000)]
    path = write(tmp_path, "t,mx,my,mz\n" + "\n".join(lines) + "\n")
    pieces = ChunkReader(path, chunk_rows=100).split(3)
    chunks_read = [0, 0, 0]

    def work(fail_at: dict[int, int]):
        def run(piece: ChunkReader, stopped) -> int:
            index = pieces.index(piece)
            for _chunk in piece:
                if index in fail_at and chunks_read[index] >= fail_at[index]:
                    raise DataFileError(f"piece {index} failed")
                if stopped():
                    break
                chunks_read[index] += 1
                time.sleep(0.02)
            return index

        return run

    # The first piece fails at once: the two after it stop early instead of parsing to their ends.
    with pytest.raises(DataFileError, match="piece 0 failed"):
        chunks.read_pieces(pieces, work({0: 0}))
    assert chunks_read[0] == 0 and max(chunks_read[1:]) < 10  # of about 13 chunks each
    # The last piece fails at once, the first only later (an earlier line of the file): the first piece is
    # not stopped, and its error is the one raised, as one reader would raise it.
    chunks_read[:] = [0, 0, 0]
    with pytest.raises(DataFileError, match="piece 0 failed"):
        chunks.read_pieces(pieces, work({0: 5, 2: 0}))
    assert chunks_read[0] == 5


def test_pieces_report_skipped_lines_as_one_reader(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    # 40 NaN rows spread over every piece: the split read reports the first MAX_REPORTED_LINES of them, in
    # file order, as one reader does (read_samples and calibrate's first pass share PiecesRead).
    import magfit.io.chunks as chunks

    lines = [f"{i},{'nan' if i % 100 == 7 else i},{2 * i},{3 * i}" for i in range(4000)]
    path = write(tmp_path, "t,mx,my,mz\n" + "\n".join(lines) + "\n")
    whole = ChunkReader(path)
    list(whole)
    pieces = ChunkReader(path).split(4)
    for piece in pieces:
        list(piece)
    read = chunks.PiecesRead(pieces)
    assert (read.n_rows, read.n_skipped) == (whole.n_rows, whole.n_skipped) == (4000, 40)
    assert read.skipped_lines == whole.skipped_lines == tuple(range(9, 1000, 100))
