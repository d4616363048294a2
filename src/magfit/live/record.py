"""The raw recording of a live session, written as the samples come so that a crash loses none of them.

The file is a CSV that ``magfit calibrate`` reads as it is: ``time_s,mx,my,mz`` (the unit in brackets when
known, e.g. ``mx(uT)``), one row per sample, ``time_s`` being when the row's batch was read (seconds from
the start). Each batch of rows is written whole, in one write (a full disk leaves no half row: the file
is cut back to its last whole row), and the file is fsync'ed about once a second. An existing
file is never overwritten: the recording is the one output that cannot be made again.
"""

from __future__ import annotations

import os
import time
from pathlib import Path
from typing import BinaryIO

import numpy as np
from numpy.typing import NDArray

from ..errors import DataFileError

__all__ = ["Recorder"]

#: Seconds between fsyncs: a power cut loses at most this much of the recording.
_SYNC_EVERY = 1.0


class Recorder:
    """Append samples to ``path`` (created; an existing file is refused).

    Parameters
    ----------
    path : Path
        The CSV to create.
    """

    def __init__(self, path: Path) -> None:
        self.path = path
        try:
            self._file: BinaryIO = open(path, "xb", buffering=0)
        except FileExistsError:
            raise DataFileError(
                f"{path}: the recording file exists; magfit never overwrites a recording: choose another path"
            ) from None
        except OSError as error:
            raise DataFileError(f"{path}: cannot create the recording ({error.strerror})") from None
        self._header_written = False
        self._closing = False
        self._start = time.monotonic()
        self._synced = self._start
        self._size = 0
        self._unit: str | None = None
        self.rows = 0

    def write(self, samples: NDArray[np.float64], unit: str | None) -> None:
        """Append (n, 3) samples; the header goes first (with the first rows), with ``unit`` when known.

        The rows of a call are written whole or not at all: a write that fails part way (a full disk) is
        cut back to the last whole row, and raises :class:`~magfit.DataFileError` saying how many rows the
        recording keeps.
        """
        if samples.shape[0] == 0 and not self._closing:
            return
        self._unit = unit if unit is not None else self._unit
        text = ""
        if not self._header_written:
            suffix = f"({self._unit})" if self._unit else ""
            text = f"time_s,mx{suffix},my{suffix},mz{suffix}\n"
        now = time.monotonic()
        stamp = f"{now - self._start:.3f}"
        text += "".join(f"{stamp},{x:.10g},{y:.10g},{z:.10g}\n" for x, y, z in samples.tolist())
        if not text:
            return
        self._append(text.encode("utf-8"))
        self._header_written = True
        self.rows += samples.shape[0]
        if now - self._synced >= _SYNC_EVERY:
            os.fsync(self._file.fileno())
            self._synced = now

    def _append(self, data: bytes) -> None:
        """Write ``data`` (whole rows) after the rows already written, or leave the file as it was."""
        descriptor = self._file.fileno()
        done = 0
        try:
            while done < len(data):
                done += os.write(descriptor, data[done:])  # a full disk may take part of it, then refuse
        except OSError as error:
            try:
                os.ftruncate(descriptor, self._size)
                os.lseek(descriptor, self._size, os.SEEK_SET)
            except OSError:
                pass
            kept = (
                f"it keeps the {self.rows} whole rows written before, which 'magfit calibrate' reads"
                if self.rows
                else "it holds no sample yet"
            )
            raise DataFileError(
                f"{self.path}: the recording cannot be written ({error.strerror}); {kept}; free some space"
            ) from None
        self._size += len(data)

    def close(self) -> None:
        """Fsync and close."""
        if self._file.closed:
            return
        try:
            if not self._header_written:  # no sample came: the header alone says what the file is
                self._closing = True
                self.write(np.empty((0, 3)), None)
            os.fsync(self._file.fileno())
        finally:
            self._file.close()
