"""``.npy`` and ``.npz`` files read from their headers: shapes and dtypes without loading the arrays, and the
members of an archive streamed a chunk at a time (numpy's own loader inflates a whole member at once).
"""

from __future__ import annotations

import math
import tokenize
import warnings
import zipfile
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..errors import DataFileError
from .sources import display_name, expansion_error, expansion_limit, file_error

__all__ = ["BROKEN_NPY", "NpyInfo", "NpyStream", "check_npy_array", "npy_info", "npz_members", "one_line"]


@dataclass(frozen=True)
class NpyInfo:
    """What an .npy header says: the array's shape, dtype and memory order."""

    shape: tuple[int, ...]
    dtype: np.dtype[Any]
    fortran: bool


#: What numpy's header parser raises on a damaged .npy header (it evaluates the header's Python literal).
BROKEN_NPY = (ValueError, OSError, EOFError, SyntaxError, TypeError, RecursionError, tokenize.TokenError)


def one_line(error: BaseException) -> str:
    """An exception's message on one line, cut at 200 characters (numpy's may span many)."""
    return " ".join(str(error).split())[:200]


def read_npy_header(handle: Any) -> NpyInfo:
    version = np.lib.format.read_magic(handle)
    with warnings.catch_warnings():  # numpy's "created on Python 2" advice: the header is read all the same
        warnings.simplefilter("ignore", UserWarning)
        if version == (1, 0):
            shape, fortran, dtype = np.lib.format.read_array_header_1_0(handle)
        else:
            shape, fortran, dtype = np.lib.format.read_array_header_2_0(handle)
    if any(not isinstance(size, int) or size < 0 for size in shape):  # numpy reads (-100, 3) and fails in its map
        raise ValueError(f"the header's shape {tuple(shape)} has a negative size")
    return NpyInfo(tuple(shape), np.dtype(dtype), bool(fortran))


def npz_members(path: Path) -> dict[str, NpyInfo]:
    """Shapes and dtypes of the arrays of an npz file, read from their headers only; a member that expands
    beyond :func:`~magfit.io.sources.expansion_limit` is refused (every command but a streamed fit would
    inflate it whole)."""
    members: dict[str, NpyInfo] = {}
    try:
        with zipfile.ZipFile(path) as archive:
            for info in archive.infolist():
                if not info.filename.endswith(".npy"):
                    continue
                key = info.filename[: -len(".npy")]
                if info.compress_type != zipfile.ZIP_STORED and info.file_size > expansion_limit(info.compress_size):
                    raise expansion_error(
                        display_name(path), info.compress_size, f"its member {key!r}", info.file_size
                    )
                with archive.open(info) as handle:
                    members[key] = read_npy_header(handle)
    except DataFileError:
        raise
    except (zipfile.BadZipFile, zlib.error, *BROKEN_NPY) as error:
        raise file_error(
            path, f"is not a readable .npz archive ({one_line(error)}); re-save it with numpy.savez"
        ) from None
    if not members:
        raise file_error(path, "is an .npz archive without arrays; save the samples with numpy.savez")
    return members


def npy_info(path: Path) -> NpyInfo:
    try:
        with open(path, "rb") as handle:
            info = read_npy_header(handle)
            data_offset = handle.tell()
    except BROKEN_NPY as error:
        raise file_error(path, f"is not a readable .npy file ({one_line(error)}); re-save it with numpy.save") from None
    # A truncated copy would otherwise fail inside numpy's memory map, with no word about the file.
    expected = info.dtype.itemsize * math.prod(info.shape)
    available = path.stat().st_size - data_offset
    if info.dtype != object and available < expected:
        raise file_error(
            path,
            f"is truncated: its header announces {info.dtype} values of shape {info.shape} ({expected} bytes) but the "
            f"file holds {max(available, 0)}; copy it again or re-save it with numpy.save",
        )
    return info


def check_npy_array(path: Path, info: NpyInfo) -> None:
    """Refuse an npy array that cannot hold samples: not numbers, not 2-D, or one sample per column."""
    if not is_numeric_dtype(info.dtype):
        raise file_error(path, f"holds an array of dtype {info.dtype}, not numbers; save the samples as floats")
    if len(info.shape) != 2:
        raise file_error(
            path, f"holds an array of shape {info.shape}; save the samples as an (N, 3) array, one per row"
        )
    if info.shape[0] == 3 and info.shape[1] > 3:
        raise file_error(
            path, f"holds an array of shape {info.shape}: one sample per column; save its transpose (arr.T)"
        )


def is_numeric_dtype(dtype: np.dtype[Any]) -> bool:
    return bool(np.issubdtype(dtype, np.floating) or np.issubdtype(dtype, np.integer))


@dataclass
class NpyStream:
    """Rows of one array of an npz archive, read a chunk at a time (C order) or loaded whole (Fortran)."""

    archive: zipfile.ZipFile
    key: str
    chunk_rows: int
    _handle: Any = field(init=False)
    _info: NpyInfo = field(init=False)
    _whole: NDArray[Any] | None = field(init=False, default=None)
    _position: int = field(init=False, default=0)

    def __post_init__(self) -> None:
        self._handle = self.archive.open(f"{self.key}.npy")
        self._info = read_npy_header(self._handle)
        if self._info.fortran and len(self._info.shape) > 1:
            self._handle.close()
            with self.archive.open(f"{self.key}.npy") as handle:
                self._whole = np.lib.format.read_array(handle, allow_pickle=False)

    @property
    def shape(self) -> tuple[int, ...]:
        return self._info.shape

    @property
    def dtype(self) -> np.dtype[Any]:
        return self._info.dtype

    def next_rows(self) -> NDArray[Any]:
        total = self._info.shape[0]
        count = min(self.chunk_rows, total - self._position)
        start = self._position
        self._position += count
        if self._whole is not None:
            return self._whole[start : start + count]
        row_shape = self._info.shape[1:]
        row_bytes = self._info.dtype.itemsize * int(np.prod(row_shape, dtype=np.int64))
        data = self._handle.read(count * row_bytes)
        return np.frombuffer(data, dtype=self._info.dtype).reshape((count, *row_shape))

    def close(self) -> None:
        if self._whole is None:
            self._handle.close()
