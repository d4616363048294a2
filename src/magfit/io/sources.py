"""Where a recording's bytes come from: a plain file, a compressed file, standard input or a pipe.

The readers read a file several times (its layout from the head, then its rows, possibly in pieces on
several threads, and again for an error's line number), so a source that cannot be re-read or seeked is
first copied, decompressed, to a temporary file: standard input (``-``), a named pipe or process
substitution (``<(zcat log.gz)``), and files compressed with gzip, bzip2, xz or zstd. The compression is
recognised by the file's first bytes (its magic number), not by its name. The copy is made once per
process and source, and removed when the process exits; messages name the source as the user gave it.

A named pipe is opened once, and refused when nothing writes into it within :data:`PIPE_WAIT_SECONDS`
(an output pipe, when nothing reads it: :func:`open_pipe_for_writing`). A compressed file is refused once it
expands beyond :func:`expansion_limit` (a decompression bomb), before any reader holds it in memory; damaged
compressed data are a :class:`~magfit.DataFileError`, whichever library reports them.

zstd needs the ``zstandard`` package (the ``zstd`` extra); gzip, bzip2 and xz come with Python.
"""

from __future__ import annotations

import atexit
import bz2
import errno
import gzip
import lzma
import os
import select
import shutil
import stat
import sys
import tempfile
import threading
import time
import zlib
from collections.abc import Callable
from pathlib import Path
from typing import BinaryIO, cast

from ..errors import DataFileError

__all__ = [
    "COMPRESSIONS",
    "STDIN",
    "check_file",
    "compression_of",
    "data_file",
    "describe_source",
    "display_name",
    "file_error",
    "open_pipe_for_writing",
    "read_once",
]

#: The file name that means standard input.
STDIN = "-"
#: Magic numbers of the compressed formats read, and their names.
COMPRESSIONS: dict[bytes, str] = {
    b"\x1f\x8b": "gzip",
    b"BZh": "bzip2",
    b"\xfd7zXZ\x00": "xz",
    b"\x28\xb5\x2f\xfd": "zstd",
}
_SUFFIXES = {".gz": "gzip", ".gzip": "gzip", ".bz2": "bzip2", ".xz": "xz", ".zst": "zstd", ".zstd": "zstd"}
_COPY_BLOCK = 1 << 20
#: How long a named pipe may stay silent before it is refused (its writer not started).
PIPE_WAIT_SECONDS = 2.0
#: A compressed file (or .npz member) may expand to at most this many times its compressed size, or to
#: :data:`EXPANSION_FLOOR` bytes when that is more. Samples compress 2 to 10 times (their last digits are
#: noise); a file that expands 1000 times is a run of identical rows or a decompression bomb (350 KB of gzip
#: that expands to 40 million rows), which every command but a streamed fit would hold in memory whole.
MAX_EXPANSION = 100
#: Bytes any compressed file may expand to, whatever its ratio (about 2 million rows of text).
EXPANSION_FLOOR = 64 << 20

_lock = threading.Lock()
#: Source key -> the temporary copy; temporary copy -> the name messages use.
_copies: dict[tuple[object, ...], Path] = {}
_names: dict[Path, str] = {}
_how: dict[str, list[str]] = {}  # a source's name -> how it was read ("standard input", "gzip-compressed")
_stdin_seen: list[object] = []  # kept alive so that their ids, the keys of their copies, are not reused


def compression_of(head: bytes) -> str | None:
    """The compression whose magic number starts ``head`` (``"gzip"``, ``"bzip2"``, ``"xz"``, ``"zstd"``), or None."""
    for magic, name in COMPRESSIONS.items():
        if head.startswith(magic):
            return name
    return None


def describe_source(path: str | os.PathLike[str]) -> str | None:
    """How a source was read, for a summary (``"standard input, gzip-compressed"``); None for a plain file."""
    how = _how.get(str(path))
    return ", ".join(how) if how else None


def display_name(path: Path) -> str:
    """How messages name ``path``: the source the user gave for a temporary copy, else the path itself."""
    return _names.get(path, str(path))


def file_error(path: Path, message: str) -> DataFileError:
    """The one-line error about ``path``, named as the user gave it (a temporary copy is not named)."""
    return DataFileError(f"{display_name(path)}: {message}")


def check_file(path: str | os.PathLike[str]) -> Path:
    """The regular file to read ``path`` from, after checking that it is readable: the file itself, or the
    decompressed copy of standard input (``-``), a pipe or a compressed file (:func:`data_file`)."""
    if str(path) == STDIN:
        return data_file(path)
    file = Path(path)
    if not file.exists():
        raise file_error(file, "no such file; check the path and the current directory")
    if file.is_dir():
        raise file_error(file, "is a directory, not a data file; give the path of a file inside it")
    if not file.is_file() and not stat.S_ISFIFO(file.stat().st_mode):  # a pipe is copied, as standard input
        raise file_error(
            file,
            "is a device or a socket, not a regular file: magfit reads a file more than once (its layout, then "
            "its rows); save the data to a file first",
        )
    if not os.access(file, os.R_OK):
        raise file_error(file, "permission denied; make the file readable (chmod +r) or copy it")
    return data_file(file)


def data_file(path: str | os.PathLike[str]) -> Path:
    """The regular file that holds the (decompressed) bytes of ``path``.

    A plain regular file is returned as it is; standard input (``"-"``), a pipe and a compressed file are
    copied once to a temporary file (see the module docstring). Checks of existence and permissions are
    the caller's; a broken compressed file is a :class:`~magfit.DataFileError`.
    """
    if str(path) == STDIN:
        # One copy per standard input object (a process that swaps sys.stdin, as tests do, gets a new one).
        _stdin_seen.append(sys.stdin)
        return _decompressed(_copy(("stdin", id(sys.stdin)), STDIN, _open_stdin, None), STDIN)
    file = Path(path)
    try:
        status = file.stat()
    except OSError:
        return file  # the caller reports a missing or unreadable file
    if stat.S_ISFIFO(status.st_mode):
        return _decompressed(_copy(("pipe", str(file)), str(file), lambda: _open_pipe(file), file), str(file))
    if not stat.S_ISREG(status.st_mode):
        return file
    return _decompressed(file, str(file))


def _decompressed(file: Path, name: str) -> Path:
    """``file`` itself, or its decompressed copy when its first bytes are a compression's magic number."""
    try:
        with open(file, "rb") as handle:
            magic = handle.read(8)
        status = file.stat()
    except OSError:
        return file  # the caller reports an unreadable file
    compression = compression_of(magic)
    if compression is None:
        return file
    original = Path(name) if name != STDIN else None
    key = ("decompressed", str(file.resolve()), status.st_size, status.st_mtime_ns)
    content = f"its {compression}-compressed content"
    limit = (expansion_limit(status.st_size), lambda: expansion_error(name, status.st_size, content))
    return _copy(key, name, lambda: _decompressing(file, compression, name), original, compression, limit)


def expansion_limit(compressed_bytes: int) -> int:
    """The most bytes ``compressed_bytes`` of compressed data may expand to (:data:`MAX_EXPANSION`)."""
    return max(MAX_EXPANSION * compressed_bytes, EXPANSION_FLOOR)


def expansion_error(name: str, compressed_bytes: int, what: str, expanded_bytes: int | None = None) -> DataFileError:
    """The refusal of a compressed source that expands beyond :func:`expansion_limit`; ``what`` names what
    expands (``"its gzip data"``), ``expanded_bytes`` how far when it is known (a zip member's header says)."""
    limit = expansion_limit(compressed_bytes)
    size = f"more than {_size_text(limit)}" if expanded_bytes is None else _size_text(expanded_bytes)
    ratio = (limit if expanded_bytes is None else expanded_bytes) // max(compressed_bytes, 1)
    return DataFileError(
        f"{name}: {what} expands to {size} from {_size_text(compressed_bytes)} ({'over ' * (expanded_bytes is None)}"
        f"{ratio} times; magfit reads up to {MAX_EXPANSION} times, or {_size_text(EXPANSION_FLOOR)}): a "
        "decompression bomb, or rows repeated far beyond any recording; if the file is genuine, decompress it "
        "yourself first"
    )


def _size_text(count: int) -> str:
    for unit, size in (("GB", 1 << 30), ("MB", 1 << 20), ("KB", 1 << 10)):
        if count >= size:
            return f"{count / size:.3g} {unit}"
    return f"{count} bytes"


def _open_stdin() -> BinaryIO:
    if sys.stdin is None or sys.stdin.isatty():
        raise DataFileError(
            f"{STDIN}: standard input is a terminal; pipe the samples in (magfit calibrate - < mag.csv)"
        )
    return sys.stdin.buffer


def _open_pipe(file: Path) -> BinaryIO:
    """A named pipe opened for reading once something writes into it, within :data:`PIPE_WAIT_SECONDS`.

    Opening a pipe that nothing writes into would wait for ever: it is opened without blocking, and
    refused when no writer shows up in time.
    """
    descriptor = os.open(file, os.O_RDONLY | os.O_NONBLOCK)
    try:
        if hasattr(select, "poll"):
            poller = select.poll()
            poller.register(descriptor, select.POLLIN | select.POLLHUP)
            if not poller.poll(int(PIPE_WAIT_SECONDS * 1000)):
                raise DataFileError(
                    f"{file}: is a named pipe (FIFO) and nothing wrote into it within {PIPE_WAIT_SECONDS:g} s; start "
                    "its writer first, or save the data to a file first"
                )
        os.set_blocking(descriptor, True)
    except BaseException:
        os.close(descriptor)
        raise
    return os.fdopen(descriptor, "rb")


def read_once(path: str | os.PathLike[str], *, limit: int = 64 << 20) -> bytes:
    """The whole content of a small file such as a calibration, read once: a regular file, or a named pipe
    whose writer starts within :data:`PIPE_WAIT_SECONDS` (waiting for one that never comes would hang).

    Raises
    ------
    FileNotFoundError, IsADirectoryError, PermissionError
        As :func:`open` (the caller words them).
    DataFileError
        A pipe nothing writes into, a device or a socket, or more than ``limit`` bytes.
    """
    file = Path(path)
    mode = file.stat().st_mode
    if stat.S_ISDIR(mode):
        raise IsADirectoryError(errno.EISDIR, os.strerror(errno.EISDIR), str(file))
    if stat.S_ISFIFO(mode):
        handle: BinaryIO = _open_pipe(file)
    elif stat.S_ISREG(mode):
        handle = open(file, "rb")
    else:
        raise file_error(file, "is a device or a socket, not a file; save its content to a file first")
    parts, size = [], 0
    with handle:  # a block at a time: read(limit) would allocate the whole limit at once
        while size <= limit and (block := handle.read(1 << 16)):
            parts.append(block)
            size += len(block)
    data = b"".join(parts)
    if len(data) > limit:
        raise file_error(file, f"holds more than {limit >> 20} MB, far more than the file magfit expects here")
    return data


def open_pipe_for_writing(path: Path) -> int:
    """A descriptor on the named pipe ``path`` opened for writing once a reader has opened it, within
    :data:`PIPE_WAIT_SECONDS`.

    Opening a pipe for writing waits until something reads it; a reader that never comes would hang the command
    after its work is done. The pipe is opened without blocking (which fails while there is no reader) until
    one is there, and refused when none comes in time; the descriptor is then made blocking again.
    """
    deadline = time.monotonic() + PIPE_WAIT_SECONDS
    while True:
        try:
            descriptor = os.open(path, os.O_WRONLY | os.O_NONBLOCK)
            break
        except OSError as error:
            if error.errno != errno.ENXIO:  # ENXIO: no reader yet
                raise
            if time.monotonic() >= deadline:
                raise DataFileError(
                    f"{path}: is a named pipe (FIFO) and nothing read from it within {PIPE_WAIT_SECONDS:g} s; start "
                    "its reader first (cat, a consumer), or write to a regular file"
                ) from None
            time.sleep(0.02)
    os.set_blocking(descriptor, True)
    return descriptor


def _decompressing(file: Path, compression: str, name: str) -> BinaryIO:
    if compression == "gzip":
        return cast(BinaryIO, gzip.open(file, "rb"))
    if compression == "bzip2":
        return cast(BinaryIO, bz2.open(file, "rb"))
    if compression == "xz":
        return cast(BinaryIO, lzma.open(file, "rb"))
    try:
        import zstandard
    except ImportError:
        raise DataFileError(
            f"{name}: is zstd-compressed, and reading it needs the zstandard package: pip install 'magfit[zstd]' "
            "(or decompress it first: zstd -d)"
        ) from None
    return cast(BinaryIO, zstandard.ZstdDecompressor().stream_reader(open(file, "rb"), closefd=True))


def _copy(
    key: tuple[object, ...],
    name: str,
    opener: Callable[[], BinaryIO],
    original: Path | None,
    what: str = "input",
    limit: tuple[int, Callable[[], DataFileError]] | None = None,
) -> Path:
    """The temporary copy of a source (made on first use, under a lock: pieces read on threads share it); a
    ``limit`` (bytes, and the error) refuses a source that expands beyond it."""
    with _lock:
        existing = _copies.get(key)
        if existing is not None and existing.exists():
            return existing
        suffix = _inner_suffix(original) if original is not None else ""
        handle, temporary = tempfile.mkstemp(prefix="magfit-", suffix=suffix)
        target = Path(temporary)
        atexit.register(_remove, target)
        try:
            with os.fdopen(handle, "wb") as out:
                source = opener()
                try:
                    if limit is None:
                        shutil.copyfileobj(source, out, _COPY_BLOCK)
                    else:
                        _copy_at_most(source, out, *limit)
                finally:
                    if source is not getattr(sys.stdin, "buffer", None):
                        source.close()
        except DataFileError:
            _remove(target)
            raise
        except Exception as error:
            _remove(target)
            if not isinstance(error, (OSError, EOFError, lzma.LZMAError, zlib.error, ValueError, *_zstd_errors())):
                raise
            raise DataFileError(
                f"{name}: the {what} data cannot be read to its end ({_reason(error)}); the file is damaged or "
                "was cut short: copy or download it again"
            ) from None
        except BaseException:
            _remove(target)
            raise
        _copies[key] = target
        _names[target] = name
        kind = f"{what}-compressed" if what != "input" else "standard input" if name == STDIN else "a pipe"
        if kind not in _how.setdefault(name, []):
            _how[name].append(kind)
        return target


def _copy_at_most(source: BinaryIO, out: BinaryIO, limit: int, refused: Callable[[], DataFileError]) -> None:
    """Copy ``source`` into ``out`` block by block, refusing it once more than ``limit`` bytes came."""
    copied = 0
    while block := source.read(_COPY_BLOCK):
        copied += len(block)
        if copied > limit:
            raise refused()
        out.write(block)


def _zstd_errors() -> tuple[type[BaseException], ...]:
    """zstandard's error type (a zstd frame with junk after its magic number), when the package is there."""
    try:
        import zstandard
    except ImportError:
        return ()
    return (zstandard.ZstdError,)


def _reason(error: BaseException) -> str:
    text = " ".join(str(error).split())
    return f"{type(error).__name__}: {text}" if text else type(error).__name__


def _inner_suffix(original: Path) -> str:
    """``.npy`` for ``samples.npy.gz``: the suffix the decompressed copy keeps (readers look at it)."""
    suffixes = original.suffixes
    if suffixes and suffixes[-1].lower() in _SUFFIXES:
        suffixes = suffixes[:-1]
    return suffixes[-1] if suffixes and len(suffixes[-1]) <= 8 else ""


def _remove(path: Path) -> None:
    try:
        path.unlink()
    except OSError:
        pass


def _forget_all() -> None:
    """Remove every temporary copy now (tests; a long-running process that read many sources)."""
    with _lock:
        for path in list(_copies.values()):
            _remove(path)
        _copies.clear()
        _names.clear()
