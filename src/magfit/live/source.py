"""Where a live stream comes from: a serial port, a TCP socket, standard input, a file, or the simulated board.

Every source offers the same three calls: ``read(timeout)`` returns the bytes available (``b""`` when
none came within ``timeout`` seconds) and raises :class:`EndOfStream` when the stream is over; ``write``
sends bytes to the board (the calibration packet); ``close``. Serial ports need pyserial, the ``live``
extra, imported only when a port is opened.
"""

from __future__ import annotations

import os
import select
import socket
import stat
import sys
import time
from pathlib import Path
from typing import Any, Protocol

from ..errors import DataFileError, OptionError
from .board import SimulatedBoard

__all__ = ["EndOfStream", "FileLikeSource", "MissingExtraError", "SimulatedSource", "Source", "open_source"]

#: Seconds a serial port that closed is tried again: a board with native USB that reboots leaves and comes
#: back under the same name (1 to 3 s for most; an Arduino Leonardo's bootloader waits 8 s).
REOPEN_SECONDS = 5.0
#: The hint printed when pyserial is missing.
INSTALL_HINT = "reading a serial port needs pyserial: pip install 'magfit[live]'"


class EndOfStream(Exception):
    """The stream ended: end of file, or a port or socket that closed (the message says which)."""


class MissingExtraError(OptionError):
    """An optional dependency is not installed (the message is the install hint)."""


class Source(Protocol):
    """A byte stream from a board (see the module docstring)."""

    #: How the source is named in messages.
    name: str
    #: True for a device or socket opened while the board was printing: the first line may be cut.
    first_line_may_be_cut: bool
    #: True when the end of the stream is its normal end (a file, a pipe), False when it is a hang-up.
    ends_normally: bool
    #: Times the source lost its connection and got it back (the line in progress then is lost).
    reconnections: int

    def read(self, timeout: float) -> bytes: ...
    def write(self, data: bytes) -> None: ...
    def close(self) -> None: ...


def open_source(port: str, *, baud: int = 115200) -> Source:
    """Open ``port``: a serial device path, ``tcp://HOST:PORT``, ``-`` (standard input) or a regular file.

    Raises
    ------
    DataFileError
        The port does not exist or cannot be opened (the message says why and what to check).
    MissingExtraError
        A serial port is named and pyserial is not installed.
    """
    if port == "-":
        try:
            return _FdSource("standard input", sys.stdin.fileno(), ends_normally=True, cut=False)
        except (AttributeError, OSError, ValueError):  # a file-like object with no descriptor (io.UnsupportedOperation)
            return FileLikeSource("standard input", getattr(sys.stdin, "buffer", sys.stdin))
    for scheme in ("tcp://", "socket://"):
        if port.startswith(scheme):
            return _SocketSource(port, port[len(scheme) :])
    path = Path(port)
    try:
        mode = path.stat().st_mode
    except FileNotFoundError:
        raise DataFileError(
            f"{port}: no such port or file; list the serial ports with 'python -m serial.tools.list_ports'"
        ) from None
    except OSError as error:
        raise DataFileError(f"{port}: {error.strerror}") from None
    if stat.S_ISREG(mode):
        try:
            fd = os.open(path, os.O_RDONLY)
        except OSError as error:
            raise DataFileError(f"{port}: cannot read it ({error.strerror})") from None
        return _FdSource(str(path), fd, ends_normally=True, cut=False, owned=True)
    if stat.S_ISFIFO(mode):
        fd = os.open(path, os.O_RDONLY)
        return _FdSource(str(path), fd, ends_normally=True, cut=False, owned=True)
    return _SerialSource(port, baud)


class _FdSource:
    """A file descriptor: standard input, a named pipe, or a regular file read as a stream."""

    first_line_may_be_cut = False
    reconnections = 0

    def __init__(self, name: str, fd: int, *, ends_normally: bool, cut: bool, owned: bool = False) -> None:
        self.name = name
        self._fd = fd
        self.ends_normally = ends_normally
        self.first_line_may_be_cut = cut
        self._owned = owned
        self._regular = stat.S_ISREG(os.fstat(fd).st_mode)

    def read(self, timeout: float) -> bytes:
        if not self._regular:
            ready, _, _ = select.select([self._fd], [], [], timeout)
            if not ready:
                return b""
        data = os.read(self._fd, 65536)
        if not data:
            raise EndOfStream(f"{self.name} ended")
        return data

    def write(self, data: bytes) -> None:
        raise OptionError(f"{self.name} is read-only: a calibration can be sent only to a serial port or a socket")

    def close(self) -> None:
        if self._owned:
            os.close(self._fd)


class FileLikeSource:
    """Any binary file-like object (``read1`` or ``read``): a stream handed over by a program, a test's input.

    Its reads block, so a run over it stops only when the stream ends or gives more bytes.
    """

    first_line_may_be_cut = False
    ends_normally = True
    reconnections = 0

    def __init__(self, name: str, stream: Any) -> None:
        self.name = name
        self._read = getattr(stream, "read1", None) or stream.read

    def read(self, timeout: float) -> bytes:
        data = self._read(65536)
        if not data:
            raise EndOfStream(f"{self.name} ended")
        return data if isinstance(data, bytes) else str(data).encode("utf-8")

    def write(self, data: bytes) -> None:
        raise OptionError(f"{self.name} is read-only: a calibration can be sent only to a serial port or a socket")

    def close(self) -> None:
        pass


class _SocketSource:
    """A TCP connection (a board behind a serial-to-network bridge, or a test)."""

    first_line_may_be_cut = True
    ends_normally = False
    reconnections = 0

    def __init__(self, name: str, address: str) -> None:
        self.name = name
        host, _, port_text = address.rpartition(":")
        if not host or not port_text.isdigit():
            raise OptionError(f"{name}: expected tcp://HOST:PORT, e.g. tcp://127.0.0.1:2000")
        try:
            self._socket = socket.create_connection((host.strip("[]"), int(port_text)), timeout=5.0)
        except OSError as error:
            raise DataFileError(f"{name}: cannot connect ({error.strerror or error}); is the server running?") from None

    def read(self, timeout: float) -> bytes:
        self._socket.settimeout(timeout)
        try:
            data = self._socket.recv(65536)
        except TimeoutError:
            return b""
        except OSError as error:
            raise EndOfStream(f"the connection {self.name} was lost ({error.strerror or error})") from None
        if not data:
            raise EndOfStream(f"the connection {self.name} was closed by the other end")
        return data

    def write(self, data: bytes) -> None:
        self._socket.sendall(data)

    def close(self) -> None:
        self._socket.close()


class _SerialSource:
    """A serial port through pyserial (USB CDC, UART adapters, pseudo-terminals)."""

    first_line_may_be_cut = True
    ends_normally = False

    def __init__(self, port: str, baud: int) -> None:
        try:
            import serial  # the live extra
        except ImportError:
            raise MissingExtraError(INSTALL_HINT) from None
        self.name = port
        self.reconnections = 0
        self._module = serial
        self._baud = baud
        self._errors: tuple[type[BaseException], ...] = (serial.SerialException, OSError)
        try:
            self._serial: Any = serial.Serial(port, baud, timeout=0.05)
        except self._errors as error:
            raise DataFileError(
                f"{port}: cannot open the port ({_reason(error)}); is another program using it?"
            ) from None

    def read(self, timeout: float) -> bytes:
        try:
            self._serial.timeout = timeout
            data = bytes(self._serial.read(1))
            waiting = self._serial.in_waiting
            if waiting:
                data += bytes(self._serial.read(waiting))
            return data
        except self._errors as error:
            if self._reopen():
                return b""
            raise EndOfStream(
                f"the port {self.name} closed ({_reason(error)}) and did not come back within {REOPEN_SECONDS:g} s: "
                "the cable was pulled or the board stopped"
            ) from None

    def _reopen(self) -> bool:
        """Open the port again (a rebooting board re-enumerates under the same name); True when it came back."""
        self.close()
        deadline = time.monotonic() + REOPEN_SECONDS
        while time.monotonic() < deadline:
            time.sleep(0.1)
            try:
                self._serial = self._module.Serial(self.name, self._baud, timeout=0.05)
            except self._errors:
                continue
            self.reconnections += 1
            return True
        return False

    def write(self, data: bytes) -> None:
        try:
            self._serial.write(data)
            self._serial.flush()
        except self._errors as error:
            raise EndOfStream(f"the port {self.name} closed while sending ({_reason(error)})") from None

    def close(self) -> None:
        try:
            self._serial.close()
        except self._errors:
            pass


def _reason(error: BaseException) -> str:
    text = getattr(error, "strerror", None) or str(error) or type(error).__name__
    return " ".join(str(text).split())


class SimulatedSource:
    """The simulated board (:class:`~magfit.live.board.SimulatedBoard`) paced in real time.

    ``read`` returns the lines of the samples due since the last call, so the stream runs at the board's
    rate; ``write`` goes to the board's packet receiver. ``limit`` samples, when given, end the stream.
    """

    first_line_may_be_cut = False
    ends_normally = True
    reconnections = 0

    def __init__(self, board: SimulatedBoard, *, limit: int | None = None) -> None:
        self.board = board
        self.name = f"simulated board ({board.rate_hz:g} Hz)"
        self._limit = limit
        self._start: float | None = None

    def read(self, timeout: float) -> bytes:
        now = time.monotonic()
        if self._start is None:
            self._start = now
        due = int((now - self._start) * self.board.rate_hz) - self.board.samples_sent
        if self._limit is not None:
            if self.board.samples_sent >= self._limit:
                raise EndOfStream(f"the {self.name} sent its {self._limit} samples")
            due = min(due, self._limit - self.board.samples_sent)
        if due <= 0:
            wait = (self.board.samples_sent + 1) / self.board.rate_hz - (now - self._start)
            time.sleep(max(0.0, min(timeout, wait)))
            return b""
        return self.board.raw_lines(due)

    def write(self, data: bytes) -> None:
        self.board.receive(data)

    def close(self) -> None:
        pass
