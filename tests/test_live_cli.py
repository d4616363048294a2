"""``magfit live`` end to end: a simulated board behind a pseudo-terminal, a TCP socket, stdin and --simulate.

The board runs in a thread on the pty's master side and writes MotionCal ``Raw:`` lines (good data, noise,
a reboot, a hang-up); ``magfit live`` reads the slave side as it reads /dev/ttyACM0, through pyserial. The
calibration written is compared with the simulated sensor's truth, the recording with the lines sent, and
the packet the board received with one built here byte by byte.
"""

from __future__ import annotations

import os
import select
import socket
import struct
import threading
import time
import tty
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

import magfit
from magfit.cli import cli
from magfit.live import SimulatedBoard
from test_live import adafruit_receive

serial = pytest.importorskip("serial")

BANNER = b"Adafruit AHRS sensor calibration\r\n"
REBOOT = b"Raw:12,-40,8190,3,1,0,23\x00\xf8\r\n\x00Adafruit AHRS sensor calibration\r\nFXOS8700 found\r\n"
NOISE = b"\x00\xff\xfe\x13\x10noise\x7f\r\n"


class PtyBoard(threading.Thread):
    """A board on the master side of a pty: plays ``script``, then streams until stopped, reading the host's bytes.

    ``script`` items: ``int`` (that many samples), ``bytes`` (written as they are), ``"hangup"`` (close the
    master after the host has read everything). ``rows`` collects the magnetometer values of every sample
    line written, in µT, in order.
    """

    def __init__(
        self, master: int, script: list[object], opened: threading.Event, seed: int = 7, speed: float = 120.0
    ) -> None:
        super().__init__(daemon=True)
        self.master = master
        self.script = script
        self.opened = opened
        self.board = SimulatedBoard(rate_hz=100, speed_dps=speed, seed=seed)
        self.rows: list[list[float]] = []
        self.stop = threading.Event()
        self.error: BaseException | None = None
        os.set_blocking(master, False)

    def _write(self, data: bytes) -> None:
        view = memoryview(data)
        while view and not self.stop.is_set():
            try:
                written = os.write(self.master, view)
                view = view[written:]
            except BlockingIOError:
                select.select([], [self.master], [], 0.05)
            self._listen()

    def _listen(self) -> None:
        while select.select([self.master], [], [], 0)[0]:
            try:
                data = os.read(self.master, 4096)
            except OSError:
                return
            if not data:
                return
            self.board.receive(data)

    def _samples(self, n: int) -> None:
        text = self.board.raw_lines(n)
        for line in text.split(b"\r\n"):
            if line.startswith(b"Raw:"):
                self.rows.append([int(v) * 0.1 for v in line[4:].split(b",")[6:]])
        self._write(text)

    def run(self) -> None:
        try:
            if not self.opened.wait(20):
                raise TimeoutError("magfit never opened the port")
            self._write(BANNER)  # the first line after opening is dropped as possibly cut
            for step in self.script:
                if isinstance(step, int):
                    for _ in range(step // 50):
                        self._samples(50)
                    self._samples(step % 50)
                elif step == "hangup":
                    time.sleep(1.0)  # let the host read what is buffered, then pull the cable
                    os.close(self.master)
                    return
                else:
                    assert isinstance(step, bytes)
                    self._write(step)
            while not self.stop.is_set():
                self._samples(20)
        except BaseException as error:
            self.error = error


@pytest.fixture
def pty_board(monkeypatch: pytest.MonkeyPatch) -> Iterator[object]:
    """A factory: ``start(script)`` -> (slave path, board thread); everything torn down after the test."""
    opened = threading.Event()

    class WatchedSerial(serial.Serial):  # type: ignore[misc, name-defined]
        def open(self) -> None:
            super().open()
            opened.set()

    monkeypatch.setattr(serial, "Serial", WatchedSerial)
    boards: list[PtyBoard] = []
    fds: list[int] = []

    def start(script: list[object], speed: float = 120.0) -> tuple[str, PtyBoard]:
        master, slave = os.openpty()
        tty.setraw(slave)  # no echo, no CR/LF translation: a USB serial port as a board presents it
        fds.append(slave)
        board = PtyBoard(master, script, opened, speed=speed)
        board.start()
        boards.append(board)
        return os.ttyname(slave), board

    yield start
    for board in boards:
        board.stop.set()
        board.join(10)
    for fd in fds:
        os.close(fd)


def _check_truth(path: Path, board: SimulatedBoard) -> magfit.Calibration:
    cal = magfit.Calibration.from_json(path.read_text(encoding="utf-8"))
    truth = board.truth.calibration
    assert cal.unit == "uT"
    np.testing.assert_allclose(cal.offset, truth.offset, atol=0.15)  # µT, of a 48 µT field
    np.testing.assert_allclose(cal.matrix, truth.matrix, atol=0.01)
    assert abs(cal.field_strength / truth.field_strength - 1) < 0.005
    return cal


def _expected_packet(cal: magfit.Calibration) -> bytes:
    """MotionCal's send_calibration, rebuilt from its source: 117, 84, 16 float32 LE, CRC-16/MODBUS LE."""
    m = cal.matrix
    values = [0.0] * 6 + [*cal.offset, cal.field_strength, m[0, 0], m[1, 1], m[2, 2], m[0, 1], m[0, 2], m[1, 2]]
    body = bytes([117, 84]) + struct.pack("<16f", *values)
    crc = 0xFFFF
    for byte in body:
        crc ^= byte
        for _ in range(8):
            crc = (crc >> 1) ^ 0xA001 if crc & 1 else crc >> 1
    return body + bytes([crc & 0xFF, crc >> 8])


@pytest.mark.slow
def test_live_on_a_pty_with_noise_and_a_reboot_calibrates_and_sends(pty_board: object, tmp_path: Path) -> None:
    port, board = pty_board([2000, NOISE, 2000, REBOOT, 2000])  # type: ignore[operator]
    output, record = tmp_path / "cal.json", tmp_path / "raw.csv"
    result = CliRunner().invoke(
        cli, ["live", port, "--samples", "6000", "-o", str(output), "--record", str(record), "--send", "motioncal"]
    )
    board.stop.set()
    board.join(10)
    assert board.error is None, board.error
    assert result.exit_code == 0, result.output + result.stderr
    assert "6000 (4 junk lines, 2 interruptions)" in result.output  # noise; cut line, banner, chip
    assert "the board confirmed it" in result.output
    # Every sample line sent is in the recording, in order, none lost and none added.
    recorded = np.loadtxt(record, delimiter=",", skiprows=1)
    assert recorded.shape == (6000, 4)
    np.testing.assert_allclose(recorded[:, 1:], np.array(board.rows[:6000]), atol=1e-9)
    assert open(record, encoding="utf-8").readline().strip() == "time_s,mx(uT),my(uT),mz(uT)"
    cal = _check_truth(output, board.board)
    # The packet, byte for byte, and what the Adafruit receiver stores from it.
    assert board.board.received == [_expected_packet(cal)]
    (stored,) = adafruit_receive(board.board.received[0])
    np.testing.assert_allclose(stored["softiron"], cal.matrix, atol=1e-6)


@pytest.mark.slow
def test_a_hangup_keeps_the_samples_and_writes_no_calibration(
    pty_board: object, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr("magfit.live.source.REOPEN_SECONDS", 0.5)  # the port does not come back
    port, board = pty_board([1500, "hangup"])  # type: ignore[operator]
    output, record = tmp_path / "cal.json", tmp_path / "raw.csv"
    result = CliRunner().invoke(cli, ["live", port, "--samples", "5000", "-o", str(output), "--record", str(record)])
    assert result.exit_code == 1, result.output + result.stderr
    assert f"the 1500 samples received are kept in {record}" in result.stderr
    assert f"the port {port} closed" in result.stderr and "before 5000 samples" in result.stderr
    assert f"magfit calibrate {record}" in result.stderr
    assert not output.exists()
    recorded = np.loadtxt(record, delimiter=",", skiprows=1)
    np.testing.assert_allclose(recorded[:, 1:], np.array(board.rows), atol=1e-9)
    assert recorded.shape[0] == 1500


def test_until_good_stops_by_itself(pty_board: object, tmp_path: Path) -> None:
    port, board = pty_board([], speed=360.0)  # type: ignore[operator]  # a brisk hand: good within seconds
    output = tmp_path / "cal.json"
    result = CliRunner().invoke(
        cli,
        ["live", port, "--until", "good", "--duration", "60", "--min-coverage", "0.8", "--max-heading-sigma", "1",
         "-o", str(output)],
    )  # fmt: skip
    assert result.exit_code == 0, result.output + result.stderr
    assert "stopped by       a good-enough fit" in result.output
    assert "verdict          good enough" in result.output
    _check_truth(output, board.board)


def test_missing_pyserial_is_one_line_with_the_install_command(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    master, slave = os.openpty()
    try:
        monkeypatch.setitem(__import__("sys").modules, "serial", None)
        result = CliRunner().invoke(cli, ["live", os.ttyname(slave), "--samples", "10"])
    finally:
        os.close(master)
        os.close(slave)
    assert result.exit_code == 2
    assert result.stderr.strip() == "magfit: error: reading a serial port needs pyserial: pip install 'magfit[live]'"


def test_tcp_socket_source(tmp_path: Path) -> None:
    board = SimulatedBoard(rate_hz=100, seed=8)
    server = socket.create_server(("127.0.0.1", 0))
    port = server.getsockname()[1]

    def serve() -> None:
        connection, _ = server.accept()
        with connection:
            connection.sendall(b"tail of a line\r\n" + board.raw_lines(6000))
            time.sleep(2)

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    output = tmp_path / "cal.json"
    result = CliRunner().invoke(cli, ["live", f"tcp://127.0.0.1:{port}", "--samples", "6000", "-o", str(output)])
    server.close()
    assert result.exit_code == 0, result.output + result.stderr
    _check_truth(output, board)


@pytest.mark.slow
def test_simulate_sends_and_the_board_confirms(tmp_path: Path) -> None:
    output = tmp_path / "cal.json"
    result = CliRunner().invoke(
        cli,
        [
            "live",
            "--simulate",
            "--rate",
            "4000",
            "--speed",
            "1500",
            "--samples",
            "8000",
            "-o",
            str(output),
            "--send",
            "motioncal",
            "--web",
        ],
    )
    assert result.exit_code == 0, result.output + result.stderr
    assert "the board confirmed it" in result.output
    assert "magfit: the live page is at http://127.0.0.1:" in result.stderr
    _check_truth(output, SimulatedBoard(seed=0))  # the default truth


def _fxos(real_data_dir: Path) -> np.ndarray:
    return np.loadtxt(real_data_dir / "fxos8700_magneto" / "mag-readings.txt")


#: Magneto v1.2's result published with the FXOS8700 recording (shared/data/real/README.md), µT.
MAGNETO_OFFSET = (28.557458, -39.981060, -27.428035)


def test_stdin_plain_lines_of_a_real_recording(real_data_dir: Path, tmp_path: Path) -> None:
    samples = _fxos(real_data_dir)
    text = "time,mag_x,mag_y,mag_z\n" + "".join(f"{i * 0.01:.2f},{x},{y},{z}\n" for i, (x, y, z) in enumerate(samples))
    output = tmp_path / "cal.json"
    result = CliRunner().invoke(cli, ["live", "-", "--unit", "uT", "-o", str(output)], input=text)
    assert result.exit_code == 0, result.output + result.stderr
    assert "plain lines of 4 numbers, columns mag_x, mag_y, mag_z" in result.output
    cal = magfit.Calibration.from_json(output.read_text(encoding="utf-8"))
    assert cal.n_samples == samples.shape[0] and cal.unit == "uT"
    np.testing.assert_allclose(cal.offset, MAGNETO_OFFSET, atol=0.1)
    np.testing.assert_allclose(cal.offset, magfit.fit(samples, "auto").offset, atol=1e-9)


def test_raw_lines_of_a_real_recording_from_a_file(real_data_dir: Path, tmp_path: Path) -> None:
    counts = np.round(_fxos(real_data_dir) * 10).astype(int)  # as a MotionCal sketch prints it: 0.1 µT
    path = tmp_path / "board.log"
    path.write_bytes(b"".join(b"Raw:0,0,8192,0,0,0,%d,%d,%d\r\n" % tuple(row) for row in counts))
    output = tmp_path / "cal.json"
    result = CliRunner().invoke(cli, ["live", str(path), "-o", str(output)])
    assert result.exit_code == 0, result.output + result.stderr
    cal = magfit.Calibration.from_json(output.read_text(encoding="utf-8"))
    np.testing.assert_allclose(cal.offset, MAGNETO_OFFSET, atol=0.1)


def test_usage_errors_are_one_line_exit_2(tmp_path: Path) -> None:
    record = tmp_path / "raw.csv"
    record.write_text("precious\n", encoding="utf-8")
    cases = [
        (["live"], "give a PORT or --simulate"),
        (["live", "x", "--simulate"], "give a PORT or --simulate"),
        (["live", "--simulate", "--record", str(record)], "never overwrites a recording"),
        (["live", "-", "--send", "motioncal"], "read-only"),
        (["live", str(tmp_path / "ttyNOPE")], "no such port or file"),
        (["live", "--simulate", "--until", "soon"], "the only condition is 'good'"),
        (["live", "tcp://127.0.0.1:1", "--samples", "5"], "cannot connect"),
    ]
    for args, message in cases:
        result = CliRunner().invoke(cli, args, input="")
        assert result.exit_code == 2, (args, result.output, result.stderr)
        lines = result.stderr.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("magfit: error: ") and message in lines[0], (args, lines)
    assert record.read_text(encoding="utf-8") == "precious\n"


def test_a_stream_that_cannot_support_a_fit_exits_1(tmp_path: Path) -> None:
    # Level turns only: the field is never seen near ±z, so no model's vertical offset is determined.
    lines = "".join(f"{30 * np.cos(a) + 5:.3f},{30 * np.sin(a) - 2:.3f},40\n" for a in np.linspace(0, 12, 3000))
    result = CliRunner().invoke(cli, ["live", "-", "-o", str(tmp_path / "cal.json")], input=lines)
    assert result.exit_code == 1, result.output + result.stderr
    assert result.stderr.strip().splitlines()[-1].startswith("magfit: error: ")
    assert not (tmp_path / "cal.json").exists()


@pytest.mark.external
@pytest.mark.slow
def test_interactive_keys_through_a_terminal(tmp_path: Path) -> None:
    """The view on a real terminal (a pty): wait for GOOD ENOUGH, press s, then q; the file saved is the truth's."""
    import subprocess
    import sys

    master, slave = os.openpty()
    command = [sys.executable, "-c", "import sys; from magfit.cli import main; sys.exit(main())"]
    args = ["live", "--simulate", "--rate", "2000", "--speed", "1500", "-o", "cal.json", "--record", "raw.csv"]
    env = {**os.environ, "COLUMNS": "130", "LINES": "50", "TERM": "xterm-256color"}
    process = subprocess.Popen(command + args, stdin=slave, stdout=slave, stderr=slave, cwd=tmp_path, env=env)
    os.close(slave)
    screen = bytearray()

    def wait_for(text: bytes, seconds: float) -> bool:
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            if select.select([master], [], [], 0.1)[0]:
                try:
                    screen.extend(os.read(master, 65536))
                except OSError:  # the process ended and closed the terminal
                    return text in screen
            if text in screen:
                return True
        return False

    try:
        assert wait_for(b"GOOD ENOUGH", 60), screen[-3000:].decode("utf-8", "replace")
        os.write(master, b"s")
        assert wait_for(b"saved to cal.json", 30), screen[-3000:].decode("utf-8", "replace")
        os.write(master, b"q")
        assert wait_for(b"the recording is in raw.csv", 20)
        assert process.wait(20) == 0
    finally:
        if process.poll() is None:
            process.kill()
        os.close(master)
    # The view went from red to green, with the coverage map and the thresholds on screen.
    assert screen.index(b"NOT YET") < screen.index(b"GOOD ENOUGH")
    assert b"Coverage of the field's directions" in screen and b">= 85 %" in screen
    _check_truth(tmp_path / "cal.json", SimulatedBoard(seed=0))
    assert np.loadtxt(tmp_path / "raw.csv", delimiter=",", skiprows=1).shape[1] == 4


def test_outputs_are_checked_before_the_session(tmp_path: Path) -> None:
    cases = [
        (["-o", str(tmp_path / "nodir" / "cal.json")], "not a file in an existing directory"),
        (["--record", str(tmp_path / "nodir" / "raw.csv")], "not a file in an existing directory"),
        (["--record", str(tmp_path)], "is a directory"),
    ]
    for args, message in cases:
        started = time.monotonic()
        result = CliRunner().invoke(cli, ["live", "--simulate", "--samples", "100000", *args])
        assert result.exit_code == 2 and message in result.stderr, result.stderr
        assert time.monotonic() - started < 5  # refused at once, not after 100 000 samples


@pytest.mark.slow
def test_a_usb_board_that_reboots_is_opened_again(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    """A board with native USB leaves and comes back under the same name: here a link re-pointed to a new pty."""
    opens: list[threading.Event] = [threading.Event(), threading.Event()]

    class WatchedSerial(serial.Serial):  # type: ignore[misc, name-defined]
        def open(self) -> None:
            super().open()
            next(event for event in opens if not event.is_set()).set()

    monkeypatch.setattr(serial, "Serial", WatchedSerial)
    link = tmp_path / "ttyBOARD"
    board = SimulatedBoard(rate_hz=100, speed_dps=300, seed=9)
    rows: list[list[float]] = []
    fds: list[int] = []
    stop = threading.Event()

    def pty() -> int:
        master, slave = os.openpty()
        tty.setraw(slave)
        fds.append(slave)
        temporary = tmp_path / "link.tmp"
        os.symlink(os.ttyname(slave), temporary)
        os.replace(temporary, link)
        return master

    def send(master: int, n: int) -> None:
        text = board.raw_lines(n)
        rows.extend([int(v) * 0.1 for v in line[4:].split(b",")[6:]] for line in text.split(b"\r\n") if line)
        os.write(master, text)

    def run() -> None:
        master = first
        assert opens[0].wait(20)
        os.write(master, BANNER)
        for _ in range(30):
            send(master, 50)
            time.sleep(0.01)
        time.sleep(0.5)
        os.close(master)  # the board reboots: its port disappears ...
        time.sleep(0.3)
        master = pty()  # ... and comes back under the same name
        assert opens[1].wait(20)
        os.write(master, BANNER)
        for _ in range(30):
            send(master, 50)
            time.sleep(0.01)
        stop.wait(20)  # hold the port open until magfit is done
        os.close(master)

    first = pty()
    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    output, record = tmp_path / "cal.json", tmp_path / "raw.csv"
    try:
        result = CliRunner().invoke(
            cli, ["live", str(link), "--samples", "3000", "-o", str(output), "--record", str(record)]
        )
    finally:
        stop.set()
        thread.join(10)
        for fd in fds:
            os.close(fd)
    assert result.exit_code == 0, result.output + result.stderr
    assert "1 reconnections" in result.output
    recorded = np.loadtxt(record, delimiter=",", skiprows=1)
    np.testing.assert_allclose(recorded[:, 1:], np.array(rows[:3000]), atol=1e-9)
    _check_truth(output, board)


@pytest.mark.external
@pytest.mark.slow
def test_ctrl_c_exits_130_and_keeps_the_recording(tmp_path: Path) -> None:
    """Ctrl-C stops a session as it stops every command (status 130), the samples so far kept on disk."""
    import signal
    import subprocess
    import sys

    command = [sys.executable, "-c", "import sys; from magfit.cli import main; sys.exit(main())"]
    args = ["live", "--simulate", "--rate", "200", "--duration", "60", "-o", "cal.json", "--record", "raw.csv"]
    process = subprocess.Popen(
        command + args, cwd=tmp_path, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.PIPE
    )
    try:
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline and not (
            (tmp_path / "raw.csv").exists() and (tmp_path / "raw.csv").stat().st_size > 200
        ):
            time.sleep(0.1)
        process.send_signal(signal.SIGINT)
        _, stderr = process.communicate(timeout=30)
    finally:
        if process.poll() is None:
            process.kill()
    assert process.returncode == 130, stderr
    assert b"Traceback" not in stderr and b"interrupted" in stderr
    assert not (tmp_path / "cal.json").exists()
    assert np.loadtxt(tmp_path / "raw.csv", delimiter=",", skiprows=1).shape[0] > 0
