"""Which three columns of a file are read: the ``columns`` argument (names or 0-based positions), the
names of a header or of an npz file's keys (:mod:`magfit.io.columns`), or, without a header, what the
columns hold (:func:`magfit.io.columns.choose_columns_by_content` on rows from the file).

Errors name the file and the columns there are, and say how to choose (``columns=[...]``).
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import DataFileError, OptionError
from ..remedy import audience, option
from .columns import (
    CONTENT_ROWS,
    ContentChoice,
    Converter,
    choose_columns_by_content,
    find_magnetometer_columns,
    name_unit,
    recognise_converter,
)
from .layout import HEAD_BYTES, FileFormat, cell_kind, decode_lines, read_head, split_fields, text_encoding
from .npy import NpyInfo, is_numeric_dtype
from .sources import file_error

_NPZ_COLUMN_LABEL = re.compile(r"^(.*)\[:,\s*(\d+)\]$")
_COLUMN_LABEL = re.compile(r"^column (\d+)$")

__all__ = [
    "NpzSelection",
    "columns_origin",
    "npy_content_choice",
    "resolve_npz_columns",
    "resolve_table_columns",
    "text_content_choice",
]


def _ambiguity(path: Path, candidates: Sequence[Any]) -> DataFileError:
    listed = "; ".join(f"({triple.describe()})" for triple in candidates[:6])
    example = option("columns", list(candidates[0].names))
    return file_error(path, f"several magnetometer column triples match: {listed}; choose one with {example}")


def _check_columns_option(columns: Sequence[str | int]) -> list[str | int]:
    if isinstance(columns, (str, bytes)):
        raise OptionError(f"columns must be a sequence of three names or 0-based indices, got the string {columns!r}")
    chosen = list(columns)
    for item in chosen:
        if isinstance(item, bool) or not isinstance(item, (str, int, np.integer)):
            raise OptionError(f"columns must hold names (str) or 0-based indices (int), got {item!r}")
    if len(set(chosen)) != len(chosen):
        raise OptionError(f"columns must name three different columns, got {chosen}")
    return [int(item) if isinstance(item, np.integer) else item for item in chosen]


def _match_name(path: Path, wanted: str, labels: Sequence[str], has_header: bool) -> int:
    """Index of the column called ``wanted``: exact name, then case-insensitive, then a ``column N`` label."""
    stripped = wanted.strip()
    exact = [i for i, label in enumerate(labels) if label == stripped]
    if len(exact) == 1:
        return exact[0]
    folded = [i for i, label in enumerate(labels) if label.casefold() == stripped.casefold()]
    if len(folded) == 1:
        return folded[0]
    if len(exact) > 1 or len(folded) > 1:
        raise file_error(path, f"several columns are named {wanted!r}; choose them by 0-based index instead")
    label = _COLUMN_LABEL.match(stripped.lower())
    if label and 1 <= int(label.group(1)) <= len(labels):
        return int(label.group(1)) - 1
    seen = ", ".join(labels) if has_header else f"none, the file has no header ({len(labels)} columns)"
    raise file_error(path, f"no column named {wanted!r}; the columns are: {seen}; use one of them or a 0-based index")


def resolve_table_columns(
    path: Path, fmt: FileFormat, columns: Sequence[str | int] | None, content: ContentChoice | None = None
) -> tuple[tuple[int, int, int], tuple[str, str, str]]:
    """The 0-based positions and labels of the x, y, z columns of a text or npy file (``content``: the
    choice by content for a file without a header, :func:`magfit.io.columns.choose_columns_by_content`)."""
    n = fmt.n_columns
    labels = [fmt.column_label(i) for i in range(n)]
    where = (
        ("column" if fmt.kind == "npy" else "field")
        + ("" if n == 1 else "s")
        + ("" if fmt.kind == "npy" else " per row")
    )
    if n < 3:
        raise file_error(
            path,
            f"has {n} {where} ({fmt.describe()}); a magnetometer needs three (x, y, z): check the delimiter "
            "or export all three axes",
        )
    if columns is None:
        if fmt.header is not None:
            candidates = find_magnetometer_columns(fmt.header)
            if not candidates:
                raise file_error(
                    path,
                    f"no magnetometer columns found among: {', '.join(labels)}; name the x, y, z columns with "
                    f"{option('columns', '...')}",
                )
            best = [triple for triple in candidates if triple.score == candidates[0].score]
            if len(best) > 1:
                raise _ambiguity(path, best)
            indices = best[0].indices
        else:
            # No header: chosen by what the columns hold (time and counters passed over), and reported.
            choice = content or ContentChoice((0, 1, 2))
            if choice.rivals:
                spreads = dict(choice.candidates)
                found = "; ".join(
                    "("
                    + ", ".join(labels[i] for i in triple)
                    + ")"
                    + (f" {100 * spreads[triple]:.2g} % spread" if triple in spreads else "")
                    for triple in (choice.indices, *choice.rivals)
                )
                raise file_error(
                    path,
                    f"has no header and several column triples look like a magnetometer: {found}"
                    + (f" ({note})" if (note := choice.describe(labels)) else "")
                    + f"; an accelerometer turned about keeps its norm as a magnetometer does: name the "
                    f"magnetometer's three with {option('columns', 'X,Y,Z')} (0-based)",
                )
            indices = choice.indices
    else:
        chosen = _check_columns_option(columns)
        if len(chosen) != 3:
            raise OptionError(f"columns must give exactly three columns (x, y, z), got {len(chosen)}: {chosen}")
        positions = []
        for item in chosen:
            if isinstance(item, int):
                if not 0 <= item < n:
                    raise file_error(
                        path, f"column index {item} is out of range: the file has {n} columns, 0 to {n - 1} (0-based)"
                    )
                positions.append(item)
            else:
                positions.append(_match_name(path, item, labels, fmt.header is not None))
        if len(set(positions)) != 3:
            raise OptionError(f"columns {chosen} name the same column twice; give three different columns")
        indices = (positions[0], positions[1], positions[2])
    return indices, (labels[indices[0]], labels[indices[1]], labels[indices[2]])


def columns_origin(labels: Sequence[str], header: Sequence[str] | None) -> tuple[str | None, Converter | None]:
    """The unit of the x, y, z columns ``labels`` and the converter that wrote them, as far as the names say.

    The unit the three names state alike (``mag_x_uT``, ``MagX (mG)``), else the converter's
    (:func:`magfit.io.columns.recognise_converter`); None, None for a file without a header.
    """
    if header is None:
        return None, None
    converter = recognise_converter(labels, header)
    units = {name_unit(label) for label in labels}
    stated = units.pop() if len(units) == 1 else None
    return stated or (converter.unit if converter is not None else None), converter


def _three_columns_of(key: str, matrices: Mapping[str, NpyInfo]) -> str:
    """How to choose three columns of the array ``key``, in the reader's words: Python names them
    (``key[:, 0]``); the command line's ``--columns`` takes their numbers, which only a file with one 2-D
    array makes unambiguous (a name there holds no comma)."""
    keys = ["mag_x", "mag_y", "mag_z"]
    if key not in matrices:  # not a 2-D array of three columns or more
        return f"give an (N, 3) array, or three 1-D arrays x, y, z: {option('columns', keys)}"
    if audience() == "python":
        return f"give three columns, e.g. columns=['{key}[:, 0]', '{key}[:, 1]', '{key}[:, 2]']"
    if len(matrices) == 1:
        return f"give three of its columns by number, e.g. {option('columns', '0,1,2')}"
    return f"save its x, y and z columns as three 1-D arrays and name them: {option('columns', keys)}"


@dataclass(frozen=True)
class NpzSelection:
    """Where the x, y, z values of an npz file are: three 1-D keys, or three columns of one 2-D key."""

    keys: tuple[str, ...]
    key_columns: tuple[int, int, int] | None
    n_rows: int

    @property
    def labels(self) -> tuple[str, str, str]:
        if self.key_columns is None:
            return (self.keys[0], self.keys[1], self.keys[2])
        key = self.keys[0]
        first, second, third = (f"{key}[:, {i}]" for i in self.key_columns)
        return (first, second, third)


def resolve_npz_columns(path: Path, members: dict[str, NpyInfo], columns: Sequence[str | int] | None) -> NpzSelection:
    listing = ", ".join(f"{key} {members[key].shape}" for key in members)
    vectors = {key: info for key, info in members.items() if len(info.shape) == 1 and is_numeric_dtype(info.dtype)}
    matrices = {
        key: info
        for key, info in members.items()
        if len(info.shape) == 2 and info.shape[1] >= 3 and is_numeric_dtype(info.dtype)
    }

    def from_vectors(keys: Sequence[str]) -> NpzSelection:
        lengths = {members[key].shape[0] for key in keys}
        if len(lengths) != 1:
            shapes = ", ".join(f"{key} {members[key].shape}" for key in keys)
            raise file_error(path, f"the arrays {shapes} have different lengths; x, y and z need one value per sample")
        return NpzSelection(tuple(keys), None, lengths.pop())

    def from_matrix(key: str, cols: tuple[int, int, int]) -> NpzSelection:
        return NpzSelection((key,), cols, members[key].shape[0])

    if columns is None:
        candidates = find_magnetometer_columns(list(vectors))
        if candidates:
            best = [triple for triple in candidates if triple.score == candidates[0].score]
            if len(best) > 1:
                raise _ambiguity(path, best)
            return from_vectors(best[0].names)
        # Several (N, 3) arrays are refused whatever their names, as a text file with several column triples
        # is: a key's name ("mag_raw", "mag_cal", "magnitude") does not say which of them holds the raw samples.
        triples = [key for key, info in matrices.items() if info.shape[1] == 3]
        if len(triples) == 1:
            return from_matrix(triples[0], (0, 1, 2))
        if len(triples) > 1:
            shapes = ", ".join(f"{key} {members[key].shape}" for key in triples)
            raise file_error(
                path,
                f"several (N, 3) arrays could be the samples: {', '.join(triples)} ({shapes}); choose the raw "
                f"magnetometer's with {option('columns', triples[0])}",
            )
        raise file_error(
            path,
            f"no magnetometer arrays found among the keys: {listing}; name them with "
            f"{option('columns', ['mag_x', 'mag_y', 'mag_z'])} (three 1-D keys) or {option('columns', 'key')} (one "
            "(N, 3) key)",
        )
    chosen = _check_columns_option(columns)
    if len(chosen) == 1 and isinstance(chosen[0], str):
        key = chosen[0]
        if key not in members:
            raise file_error(path, f"no array named {key!r}; the keys are: {listing}")
        if key not in matrices or members[key].shape[1] != 3:
            raise file_error(
                path, f"array {key!r} has shape {members[key].shape}, not (N, 3); {_three_columns_of(key, matrices)}"
            )
        return from_matrix(key, (0, 1, 2))
    if len(chosen) != 3:
        raise OptionError(f"columns must give three keys (x, y, z) or one (N, 3) key, got {len(chosen)}: {chosen}")
    if all(isinstance(item, int) for item in chosen):
        if len(matrices) != 1:
            raise file_error(
                path, f"column indices need exactly one 2-D array in the file; name the keys instead: {listing}"
            )
        key = next(iter(matrices))
        width = members[key].shape[1]
        for item in chosen:
            if not 0 <= int(item) < width:
                raise file_error(path, f"column index {item} is out of range: {key!r} has columns 0 to {width - 1}")
        return from_matrix(key, (int(chosen[0]), int(chosen[1]), int(chosen[2])))
    labels = [_NPZ_COLUMN_LABEL.match(str(item)) for item in chosen]
    if all(labels):
        keys = {label.group(1) for label in labels if label}
        key = keys.pop()
        if keys or key not in matrices:
            raise file_error(path, f"columns {chosen} must all be columns of one 2-D array; the keys are: {listing}")
        cols = [int(label.group(2)) for label in labels if label]
        width = members[key].shape[1]
        if max(cols) >= width:
            raise file_error(path, f"column index {max(cols)} is out of range: {key!r} has {width} columns")
        return from_matrix(key, (cols[0], cols[1], cols[2]))
    for item in chosen:
        if not isinstance(item, str) or item not in members:
            raise file_error(path, f"no array named {item!r}; the keys are: {listing}")
        if item not in vectors:
            raise file_error(
                path, f"array {item!r} has shape {members[item].shape}; x, y and z keys must be 1-D numbers"
            )
    return from_vectors([str(item) for item in chosen])


# ---------------------------------------------------------------------------------------------- by content


def npy_content_choice(path: Path, fmt: FileFormat) -> ContentChoice:
    """The x, y, z columns of an (N, k > 3) .npy array, chosen from its first rows (as for headerless text)."""
    head = np.asarray(np.load(path, mmap_mode="r", allow_pickle=False)[:CONTENT_ROWS], dtype=np.float64)
    return choose_columns_by_content(head, range(fmt.n_columns))


def _rows_further_in(path: Path, fmt: FileFormat, per_window: int) -> list[list[str]]:
    """Up to ``per_window`` rows at each of 1/4, 1/2 and 3/4 of a file longer than its head, in file order."""
    size = path.stat().st_size
    rows: list[list[str]] = []
    with open(path, "rb") as handle:
        for quarter in (1, 2, 3):
            handle.seek(fmt.data_offset + (size - fmt.data_offset) * quarter // 4)
            text = handle.read(HEAD_BYTES // 4).decode(text_encoding(fmt), errors="replace")
            lines = text.split("\n")[1:-1]  # the first and last are cut by the window
            fields = (split_fields(line.rstrip("\r"), fmt.delimiter) for line in lines[:per_window])
            rows += [row for row in fields if len(row) == fmt.n_columns]
    return rows


def text_content_choice(path: Path, fmt: FileFormat) -> ContentChoice:
    """The x, y, z columns of a text file without a header, chosen from the values of its rows (the first
    ones, and for a file longer than its head, rows from further in as well)."""
    head, truncated = read_head(path)
    _, lines, _ = decode_lines(path, head, truncated)
    rows = [split_fields(line, fmt.delimiter) for line in lines[fmt.data_line :][:CONTENT_ROWS]]
    rows = [row for row in rows if len(row) == fmt.n_columns]
    if truncated:  # half from the head, half from further in: a recording may start at rest (a warm-up)
        rows = rows[: CONTENT_ROWS // 2] + _rows_further_in(path, fmt, CONTENT_ROWS // 6)
    # Columns of numbers in the first 50 rows (a leading date or label column is passed over).
    numeric = [
        j for j in range(fmt.n_columns) if rows and all(cell_kind(row[j], fmt.decimal) != "text" for row in rows[:50])
    ]

    def number(cell: str) -> float:
        if cell_kind(cell, fmt.decimal) != "number":
            return np.nan
        return float(cell.replace(",", ".") if fmt.decimal == "," else cell)

    head_values = np.full((len(rows), fmt.n_columns), np.nan)
    for j in numeric:
        cells = [row[j] for row in rows]
        try:  # the usual column of plain numbers, at once
            if fmt.decimal != ".":
                raise ValueError("decimal commas")
            head_values[:, j] = np.asarray(cells, dtype=np.float64)
        except ValueError:  # missing values, decimal commas: cell by cell
            head_values[:, j] = [number(cell) for cell in cells]
    return choose_columns_by_content(head_values, numeric)
