"""Atomic file writes: a reader never sees a half-written file, a failure never damages an existing one.

The data go to a temporary file in the target's own directory (so the final rename stays on one file
system), are flushed and fsync'ed, and the temporary file is renamed over the target with
:func:`os.replace`, which is atomic on POSIX and Windows. On any exception the temporary file is removed
and the target, if it existed, is left exactly as it was.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import IO, Any

from ..errors import DataFileError, OptionError

__all__ = ["atomic_open", "atomic_write_text"]


def _final_mode(target: Path) -> int:
    """Permission bits for the new file: those of the file it replaces, else the usual 0o666 minus umask."""
    try:
        return target.stat().st_mode & 0o7777
    except FileNotFoundError:
        umask = os.umask(0)
        os.umask(umask)
        return 0o666 & ~umask


def _fsync_directory(directory: Path) -> None:
    """Make the rename itself durable (best effort: not every platform can open a directory)."""
    try:
        fd = os.open(directory, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


@contextlib.contextmanager
def atomic_open(path: str | os.PathLike[str], mode: str = "w", **kwargs: Any) -> Iterator[IO[Any]]:
    """Open ``path`` for writing through a temporary file that replaces it only on success.

    Parameters
    ----------
    path : str or path-like
        The file to create or replace. Its directory must exist.
    mode : {"w", "wb", "wt"}
        Text or binary writing; ``kwargs`` (``encoding``, ``newline`` ...) go to :func:`open`.

    Yields
    ------
    file object
        Write to it inside the ``with`` block. When the block exits normally the data are flushed,
        fsync'ed and the file is renamed onto ``path``; when it raises, the temporary file is removed and
        an existing ``path`` is untouched.

    Raises
    ------
    OptionError
        For a mode that is not a plain write mode (append or read modes cannot be atomic).
    DataFileError
        When the directory does not exist or is not writable.
    """
    if mode not in ("w", "wb", "wt"):
        raise OptionError(f"atomic_open() writes a whole new file: mode must be 'w', 'wt' or 'wb', got {mode!r}")
    target = Path(path)
    directory = target.parent if str(target.parent) else Path(".")
    if not directory.is_dir():
        raise DataFileError(f"{target}: the directory {directory} does not exist; create it or choose another path")
    try:
        fd, temp_name = tempfile.mkstemp(dir=directory, prefix=f".{target.name}.", suffix=".tmp")
    except OSError as error:
        raise DataFileError(f"{target}: cannot write in {directory} ({error.strerror}); choose another path") from None
    temp = Path(temp_name)
    try:
        with os.fdopen(fd, mode, **kwargs) as handle:
            yield handle
            handle.flush()
            os.fsync(handle.fileno())
        os.chmod(temp, _final_mode(target))
        os.replace(temp, target)
    except BaseException:
        temp.unlink(missing_ok=True)
        raise
    _fsync_directory(directory)


def atomic_write_text(path: str | os.PathLike[str], text: str, *, encoding: str = "utf-8") -> None:
    """Write ``text`` to ``path`` atomically (see :func:`atomic_open`).

    Parameters
    ----------
    path : str or path-like
        The file to create or replace.
    text : str
        The whole content. Newlines are written as ``"\\n"`` on every platform.
    encoding : str
        Text encoding, UTF-8 by default.
    """
    with atomic_open(path, "w", encoding=encoding, newline="") as handle:
        handle.write(text)
