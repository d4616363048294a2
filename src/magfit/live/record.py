"""The raw recording of a live session, written as the samples come so that a crash loses none of them.

The file is a CSV that ``magfit calibrate`` reads as it is: ``time_s,mx,my,mz`` (the unit in brackets when
known, e.g. ``mx(uT)``), one row per sample, ``time_s`` being when the row's batch was read (seconds from
the start). Rows are flushed after every batch and the file is fsync'ed about once a second. An existing
file is never overwritten: the recording is the one output that cannot be made again.
"""

from __future__ import annotations

import os
import time
from pathlib import Path
from typing import TextIO

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
            self._file: TextIO = open(path, "x", encoding="utf-8", newline="")
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
        self.rows = 0

    def write(self, samples: NDArray[np.float64], unit: str | None) -> None:
        """Append (n, 3) samples; the header goes first (with the first rows), with ``unit`` when known."""
        if samples.shape[0] == 0 and not self._closing:
            return
        if not self._header_written:
            suffix = f"({unit})" if unit else ""
            self._file.write(f"time_s,mx{suffix},my{suffix},mz{suffix}\n")
            self._header_written = True
        if samples.shape[0] == 0:
            return
        now = time.monotonic()
        stamp = f"{now - self._start:.3f}"
        self._file.write("".join(f"{stamp},{x:.10g},{y:.10g},{z:.10g}\n" for x, y, z in samples.tolist()))
        self._file.flush()
        self.rows += samples.shape[0]
        if now - self._synced >= _SYNC_EVERY:
            os.fsync(self._file.fileno())
            self._synced = now

    def close(self) -> None:
        """Flush, fsync and close."""
        if self._file.closed:
            return
        if not self._header_written:  # no sample came: the header alone says what the file is
            self._closing = True
            self.write(np.empty((0, 3)), None)
        self._file.flush()
        os.fsync(self._file.fileno())
        self._file.close()
