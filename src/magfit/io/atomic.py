"""Safe output files: a reader never sees a half-written file, a failure never damages an existing one.

The data go to a temporary file in the target's own directory (so the final rename stays on one file
system), are flushed and fsync'ed, and the temporary file is renamed over the target with
:func:`os.replace`, which is atomic on POSIX and Windows. On any exception (and on SIGINT/SIGTERM, which
the command line turns into exceptions) the temporary file is removed and the target, if it existed, is
left exactly as it was.

Three kinds of target are not replaced but written into: ``"-"`` (standard output), and an existing
FIFO or character device (``/dev/null``, a named pipe a consumer reads): replacing those by a regular
file would break them. A symbolic link is followed: the file it names is replaced, the link stays.
Block devices, sockets and directories are refused. :func:`check_output` runs those checks before any
work, so a command can refuse a bad path before computing anything; :func:`write_all` commits several
outputs together (all temporary files written first, then the renames), so a failure writing one leaves
all of them as they were.
"""

from __future__ import annotations

import contextlib
import errno
import os
import stat
import sys
import tempfile
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import IO, Any

from ..errors import DataFileError, OptionError
from .sources import open_pipe_for_writing

__all__ = ["STDOUT", "atomic_open", "atomic_write_text", "check_output", "write_all"]

#: The output path that means standard output.
STDOUT = "-"


def _is_stdout(path: str | os.PathLike[str]) -> bool:
    return os.fspath(path) == STDOUT


def _target_stat(target: Path) -> os.stat_result | None:
    """``os.stat`` of the target through its links; None when it does not exist (or is a dangling link)."""
    try:
        return os.stat(target)
    except FileNotFoundError:
        return None
    except OSError as error:
        if error.errno == errno.ELOOP:
            raise DataFileError(
                f"{target}: is a symbolic link loop (too many levels of links); remove the link or choose another path"
            ) from None
        if error.errno == errno.ENOTDIR:
            raise DataFileError(
                f"{target}: a part of this path is a file, not a directory; choose another path"
            ) from None
        raise DataFileError(f"{target}: cannot be checked ({error.strerror}); choose another path") from None


def _is_stream(info: os.stat_result | None) -> bool:
    """A target written into rather than replaced: a FIFO or a character device."""
    return info is not None and (stat.S_ISFIFO(info.st_mode) or stat.S_ISCHR(info.st_mode))


def check_output(path: str | os.PathLike[str]) -> Path:
    """Check that ``path`` can be written, before any work is done; returns the path to replace.

    Returns the real path behind symbolic links (the file that will be replaced), ``path`` itself for
    standard output (``"-"``), a FIFO or a character device (written into).

    Raises
    ------
    DataFileError
        ``path`` is a directory, a block device or a socket, a symbolic link loop, or its directory does
        not exist or is not writable.
    """
    if _is_stdout(path):
        return Path(STDOUT)
    target = Path(path)
    info = _target_stat(target)
    if info is not None:
        if stat.S_ISDIR(info.st_mode):
            raise DataFileError(f"{target}: is a directory; give a file name inside it")
        if _is_stream(info):
            return target
        if not stat.S_ISREG(info.st_mode):
            raise DataFileError(f"{target}: is a block device or a socket, not a file; choose another path")
    real = Path(os.path.realpath(target))
    directory = real.parent
    if not directory.is_dir():
        raise DataFileError(f"{target}: the directory {directory} does not exist; create it or choose another path")
    if not os.access(directory, os.W_OK | os.X_OK):
        raise DataFileError(f"{target}: the directory {directory} is not writable; choose another path")
    return real


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
        The file to create or replace (its directory must exist); ``"-"`` for standard output; an
        existing FIFO or character device is written into, not replaced.
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
        When the path cannot be written (see :func:`check_output`).
    """
    if mode not in ("w", "wb", "wt"):
        raise OptionError(f"atomic_open() writes a whole new file: mode must be 'w', 'wt' or 'wb', got {mode!r}")
    target = check_output(path)
    if _is_stdout(target):
        yield _stdout(mode)
        return
    if _is_stream(_target_stat(target)):
        with _open_stream(target, mode, **kwargs) as stream:
            yield stream
        return
    directory = target.parent
    try:
        fd, temp_name = tempfile.mkstemp(dir=directory, prefix=f".{target.name}.", suffix=".tmp")
    except OSError as error:
        raise DataFileError(f"{path}: cannot write in {directory} ({error.strerror}); choose another path") from None
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


def _stdout(mode: str) -> IO[Any]:
    sys.stdout.flush()
    return sys.stdout.buffer if "b" in mode else sys.stdout


@contextlib.contextmanager
def _open_stream(target: Path, mode: str, **kwargs: Any) -> Iterator[IO[Any]]:
    """Write into a FIFO or a device. A FIFO waits for its reader, as a shell redirection does, but only
    :data:`~magfit.io.sources.PIPE_WAIT_SECONDS`: then it is refused, where the shell would wait for ever."""
    try:
        if stat.S_ISFIFO(os.stat(target).st_mode):
            handle = os.fdopen(open_pipe_for_writing(target), mode, **kwargs)
        else:
            handle = open(target, mode, **kwargs)
    except OSError as error:
        raise DataFileError(f"{target}: cannot be opened for writing ({error.strerror}); choose another path") from None
    with handle:
        yield handle


def write_all(outputs: Sequence[tuple[str | os.PathLike[str], bytes]]) -> None:
    """Write several outputs together: every temporary file first, then the renames.

    A failure while writing any of them (a full disk, an interruption) leaves every target as it was.
    Standard output, FIFOs and devices are written last, after the regular files are in place.

    Raises
    ------
    DataFileError
        Two outputs name the same file, or one cannot be written (see :func:`check_output`).
    """
    targets = [check_output(path) for path, _ in outputs]
    seen: dict[Path, str] = {}
    for (path, _), target in zip(outputs, targets, strict=True):
        key = target if _is_stdout(target) else Path(os.path.realpath(target))
        if key in seen:
            raise DataFileError(f"{path}: is also the output {seen[key]}; give each output its own path")
        seen[key] = os.fspath(path)
    with contextlib.ExitStack() as stack:
        staged: list[tuple[Path, Path]] = []
        streams: list[tuple[Path, bytes]] = []
        for (_, data), target in zip(outputs, targets, strict=True):
            if _is_stdout(target) or _is_stream(_target_stat(target)):
                streams.append((target, data))
                continue
            temp = _stage(target, data)
            stack.callback(temp.unlink, missing_ok=True)  # removed on failure; a no-op once renamed
            staged.append((temp, target))
        for temp, target in staged:
            os.chmod(temp, _final_mode(target))
        for temp, target in staged:
            os.replace(temp, target)
        for target, data in streams:
            with atomic_open(target, "wb") as stream:
                stream.write(data)
    for directory in {target.parent for _, target in staged}:
        _fsync_directory(directory)


def _stage(target: Path, data: bytes) -> Path:
    """``data`` written and fsync'ed into a temporary file beside ``target``."""
    try:
        fd, temp_name = tempfile.mkstemp(dir=target.parent, prefix=f".{target.name}.", suffix=".tmp")
    except OSError as error:
        raise DataFileError(
            f"{target}: cannot write in {target.parent} ({error.strerror}); choose another path"
        ) from None
    temp = Path(temp_name)
    try:
        with os.fdopen(fd, "wb") as handle:
            handle.write(data)
            handle.flush()
            os.fsync(handle.fileno())
    except BaseException:
        temp.unlink(missing_ok=True)
        raise
    return temp


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
