"""The block reader's two tries (magfit.io.fastcsv): a block is parsed with only the empty cell as missing,
and again with every missing-value word when it holds another; either way the samples are the pandas path's.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from test_csv_reader_fast import VALUES, assert_same, both_ways, lines, write

pytest.importorskip("pyarrow")

#: Each missing-value word (and the NaN words pyarrow converts itself) in a later block than the first.
WORDS = ["nan", "NaN", "NAN", "-nan", "-NaN", "NA", "N/A", "n/a", "null", "NULL", "None", "#N/A", ""]


def text(words: list[str], rows_of_nan: tuple[int, ...] = ()) -> str:
    body = lines()
    for k, word in enumerate(words):
        i = 120 + 20 * k
        body[i] = f"{10 * i},{word},{VALUES[i, 1]},{VALUES[i, 2]}"
    for i in rows_of_nan:  # a row of NaN words, not a blank line
        body[i] = f"{10 * i},nan,NaN,-nan"
    return "t,mx,my,mz\n" + "\n".join(body) + "\n"


@pytest.mark.parametrize("block_bytes", [300, 4000, 4 << 20])
@pytest.mark.parametrize(
    "words", [WORDS, WORDS[:5], ["NA"], list(reversed(WORDS))], ids=["all", "nan words", "NA", "reversed"]
)
def test_missing_words_read_as_pandas_reads(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, words: list[str], block_bytes: int
) -> None:
    path = write(tmp_path, text(words, rows_of_nan=(50, 390)))
    pandas_read, arrow_read, used = both_ways(path, monkeypatch, block_bytes)
    assert used
    assert_same(pandas_read, arrow_read)
    assert not isinstance(arrow_read, str)
    assert arrow_read.n_skipped == len(words) + 2  # type: ignore[attr-defined]
    kept = np.delete(VALUES, [120 + 20 * k for k in range(len(words))] + [50, 390], axis=0)
    np.testing.assert_array_equal(arrow_read.samples, kept)  # type: ignore[attr-defined]


def test_a_bad_word_after_a_missing_word_is_still_named(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    body = text(["NA"]).splitlines()
    body[301] = "3000,1,oops,3"
    path = write(tmp_path, "\n".join(body) + "\n")
    pandas_read, arrow_read, _ = both_ways(path, monkeypatch, 500)
    assert isinstance(arrow_read, str) and "line 302" in arrow_read and "oops" in arrow_read
    assert arrow_read == pandas_read
