"""magfit.io properties over generated files: any layout reads back the values written, chunks = whole.

Each example writes a table of known values in a random layout (delimiter, header or not, preamble,
byte-order mark, line ends, blank lines, extra columns around the magnetometer, NaN rows) and checks that
the reader returns exactly those values, skips exactly the NaN rows (by line number), and that reading in
tiny chunks gives the same result; then that a calibrated copy reads back as ``calibration.apply``.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import magfit
from magfit.io import ChunkReader, read_samples, write_calibrated
from magfit.io.writers import SIGNIFICANT_DIGITS

DELIMITERS = (",", ", ", "\t", ";", "|", " ", "  ")
finite = st.floats(min_value=-1e5, max_value=1e5, allow_nan=False, allow_infinity=False, width=32)


@st.composite
def layouts(draw: st.DrawFn) -> dict:
    n_rows = draw(st.integers(3, 30))
    before, after = draw(st.integers(0, 2)), draw(st.integers(0, 2))
    values = np.array(draw(st.lists(st.tuples(finite, finite, finite), min_size=n_rows, max_size=n_rows)))
    nan_rows = draw(st.sets(st.integers(0, n_rows - 1), max_size=n_rows - 1))
    return {
        "values": values,
        "nan_rows": sorted(nan_rows),
        "before": before,
        "after": after,
        "delimiter": draw(st.sampled_from(DELIMITERS)),
        "header": draw(st.booleans()),
        "preamble": draw(st.sampled_from([[], ["Fs,50.00"], ["Logger v2 export", "Initialization time,60"]])),
        "bom": draw(st.booleans()),
        "eol": draw(st.sampled_from(["\n", "\r\n"])),
        "blank_after": draw(st.sets(st.integers(0, n_rows - 1), max_size=3)),
        "final_eol": draw(st.booleans()),
    }


def render(layout: dict) -> tuple[bytes, list[int], list[int]]:
    """The file's bytes, the 0-based positions of mx, my, mz, and the file line of every data row."""
    delimiter, eol = layout["delimiter"], layout["eol"]
    names = (
        [f"t{i}" for i in range(layout["before"])] + ["mx", "my", "mz"] + [f"temp{i}" for i in range(layout["after"])]
    )
    lines = list(layout["preamble"]) + ([delimiter.join(names)] if layout["header"] else [])
    row_lines = []
    for i, row in enumerate(layout["values"]):
        cells = [repr(float(v)) for v in row]
        if i in layout["nan_rows"]:
            # an empty cell cannot exist between runs of spaces: "nan" there
            cells[i % 3] = "nan" if i % 2 or not delimiter.strip() else ""
        lines.append(delimiter.join([f"{i}.5"] * layout["before"] + cells + ["7"] * layout["after"]))
        row_lines.append(len(lines))
        if i in layout["blank_after"]:
            lines.append("")
    text = eol.join(lines) + (eol if layout["final_eol"] else "")
    data = text.encode()
    if layout["bom"]:
        data = b"\xef\xbb\xbf" + data
    start = layout["before"]
    return data, [start, start + 1, start + 2], row_lines


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(layout=layouts(), chunk_rows=st.integers(1, 8))
def test_any_layout_reads_back_exactly(layout: dict, chunk_rows: int) -> None:
    data, indices, row_lines = render(layout)
    keep = np.setdiff1d(np.arange(len(layout["values"])), layout["nan_rows"])
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "data.txt"
        path.write_bytes(data)
        columns = None if layout["header"] else indices
        table = read_samples(path, columns=columns)
        np.testing.assert_array_equal(table.samples, layout["values"][keep])
        assert table.n_rows == len(layout["values"]) and table.n_skipped == len(layout["nan_rows"])
        assert table.skipped_lines == tuple(row_lines[i] for i in layout["nan_rows"])[:10]
        assert table.format.preamble_lines == len(layout["preamble"])
        assert table.format.encoding == ("utf-8-sig" if layout["bom"] else "utf-8")
        reader = ChunkReader(path, columns=columns, chunk_rows=chunk_rows, block_bytes=97)
        chunks = list(reader)
        np.testing.assert_array_equal(np.concatenate(chunks), table.samples)
        assert (reader.n_rows, reader.skipped_lines) == (table.n_rows, table.skipped_lines)


CALIBRATION = magfit.Calibration(
    "example", [12.0, -30.0, 5.5], [[1.05, 0.02, -0.01], [0.02, 0.97, 0.03], [-0.01, 0.03, 0.99]], 50.0
)


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(layout=layouts())
def test_any_layout_calibrated_copy_reads_back_as_apply(layout: dict) -> None:
    data, indices, _ = render(layout)
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "data.txt"
        path.write_bytes(data)
        columns = None if layout["header"] else indices
        table = read_samples(path, columns=columns)
        out = write_calibrated(table, CALIBRATION, Path(folder) / "out.txt")
        written = out.read_bytes()
        assert written[: table.format.data_offset] == data[: table.format.data_offset]  # BOM, preamble, header
        assert written.count(b"\n") == data.count(b"\n") and written.count(b"\r") == data.count(b"\r")
        back = read_samples(out, columns=columns)
        assert back.format == table.format
        assert (back.n_rows, back.skipped_lines) == (table.n_rows, table.skipped_lines)
        expected = CALIBRATION.apply(table.samples)
        # SIGNIFICANT_DIGITS digits per value: off by at most half a unit in the last digit of each value
        np.testing.assert_allclose(back.samples, expected, rtol=0.5 * 10.0 ** (1 - SIGNIFICANT_DIGITS), atol=1e-300)
