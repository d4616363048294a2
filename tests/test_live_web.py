"""``magfit live --web``: the page on 127.0.0.1 follows the session, in headless Chromium (Debian's, via selenium)."""

from __future__ import annotations

import json
import socket
import struct
import threading
import time
import urllib.request
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from magfit.live import LineParser, LiveRun, Session, SimulatedBoard, SimulatedSource, StopRule
from magfit.live.web import WebView, host_allowed
from test_report_browser import CHROMEDRIVER, CHROMIUM, CHROMIUM_FLAGS, _missing


@pytest.fixture
def page() -> Iterator[WebView]:
    source = SimulatedSource(SimulatedBoard(rate_hz=2000, speed_dps=1500, seed=3))
    run = LiveRun(source, LineParser(), Session(), stop=StopRule(duration=60)).start()
    web = WebView(run).start()
    try:
        yield web
    finally:
        web.close()
        run.close()


@pytest.mark.slow
def test_state_follows_the_session_and_the_server_listens_on_loopback_only(page: WebView) -> None:
    assert page.url.startswith("http://127.0.0.1:")
    assert page._server.server_address[0] == "127.0.0.1"
    deadline = time.monotonic() + 30
    while time.monotonic() < deadline:
        with urllib.request.urlopen(page.url + "state.json", timeout=5) as response:
            state = json.load(response)
        if state["fit"] is not None and state["points"]:
            break
        time.sleep(0.2)
    assert state["fit"] is not None, state
    assert state["samples"] > 0 and len(state["reached"]) == 100 and len(state["checks"]) == 4
    assert state["fit"]["unit"] == "uT"
    radii = [sum(v * v for v in point) ** 0.5 for point in state["points"]]
    assert abs(sorted(radii)[len(radii) // 2] - 1.0) < 0.05  # corrected samples lie on the unit sphere
    with pytest.raises(urllib.error.HTTPError):
        urllib.request.urlopen(page.url + "other", timeout=5)


def _get(web: WebView, path: str, host: str | None) -> tuple[int, bytes]:
    """A GET with the Host header ``host`` (none when None), on a raw socket: its status and body."""
    with socket.create_connection(("127.0.0.1", web.port), timeout=10) as connection:
        header = f"Host: {host}\r\n" if host is not None else ""
        connection.sendall(f"GET {path} HTTP/1.0\r\n{header}\r\n".encode())
        reply = b""
        while chunk := connection.recv(65536):
            reply += chunk
    status = int(reply.split(b" ", 2)[1])
    return status, reply.partition(b"\r\n\r\n")[2]


def test_only_requests_addressed_to_loopback_are_answered(page: WebView) -> None:
    port = page.port
    for host in (f"127.0.0.1:{port}", f"localhost:{port}", f"[::1]:{port}", "localhost"):
        status, body = _get(page, "/state.json", host)
        assert status == 200 and "samples" in json.loads(body), host
    # A page that rebinds its own name to 127.0.0.1 sends that name: refused, and nothing of the state leaks.
    for host in (f"evil.example:{port}", f"127.0.0.1.evil.example:{port}", f"127.0.0.1:{port + 1}", "", None):
        status, body = _get(page, "/state.json", host)
        assert status == 403 and b"samples" not in body, host
    assert not host_allowed(f"localhost:{port}:{port}", port) and not host_allowed("[::1]x", port)


def _reset(port: int, data: bytes) -> None:
    """Connect, send ``data`` and close with a reset (SO_LINGER 0), as a client whose connection dies."""
    connection = socket.create_connection(("127.0.0.1", port), timeout=5)
    connection.sendall(data)
    connection.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
    connection.close()


@pytest.mark.slow
def test_clients_that_reset_their_connection_print_nothing(page: WebView, capfd: pytest.CaptureFixture[str]) -> None:
    for _ in range(30):
        _reset(page.port, b"GET /state")  # reset while the server reads the request line
        _reset(page.port, f"GET /state.json HTTP/1.1\r\nHost: 127.0.0.1:{page.port}\r\n\r\n".encode())
    time.sleep(1.0)
    assert _get(page, "/", f"127.0.0.1:{page.port}")[0] == 200  # still serving
    captured = capfd.readouterr()
    assert "Traceback" not in captured.err and "Exception" not in captured.err, captured.err[:2000]


def test_idle_connections_hold_a_bounded_number_of_threads_for_a_bounded_time() -> None:
    source = SimulatedSource(SimulatedBoard(rate_hz=200, speed_dps=300, seed=3))
    run = LiveRun(source, LineParser(), Session(), stop=StopRule(duration=60)).start()
    web = WebView(run, max_connections=8, idle_seconds=0.5).start()
    idle: list[socket.socket] = []
    try:
        before = threading.active_count()
        idle = [socket.create_connection(("127.0.0.1", web.port), timeout=5) for _ in range(60)]
        time.sleep(0.3)
        assert threading.active_count() <= before + 8, threading.active_count() - before  # 60 made 60 threads
        deadline = time.monotonic() + 10
        while threading.active_count() > before and time.monotonic() < deadline:
            time.sleep(0.1)
        assert threading.active_count() <= before, "idle connections were not closed"
        assert _get(web, "/state.json", f"localhost:{web.port}")[0] == 200  # the slots are free again
    finally:
        for connection in idle:
            connection.close()
        web.close()
        run.close()


@pytest.fixture
def browser(tmp_path: Path) -> Iterator[Any]:
    for program in (CHROMIUM, CHROMEDRIVER):
        if not (Path(program).is_file()):
            _missing(f"{program} not found: apt-get install -y chromium chromium-driver")
    try:
        from selenium import webdriver
        from selenium.webdriver.chrome.service import Service
    except ImportError:
        _missing("selenium is not installed: pip install selenium (the test extra)")
    options = webdriver.ChromeOptions()
    options.binary_location = CHROMIUM
    for flag in CHROMIUM_FLAGS:
        options.add_argument(flag)
    options.add_argument(f"--user-data-dir={tmp_path / 'profile'}")
    options.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    driver = webdriver.Chrome(service=Service(CHROMEDRIVER), options=options)
    driver.set_page_load_timeout(60)
    try:
        yield driver
    finally:
        driver.quit()


@pytest.mark.external
def test_page_draws_the_sphere_and_turns_green(page: WebView, browser: Any) -> None:
    browser.get(page.url)
    deadline = time.monotonic() + 60
    signal = ""
    while time.monotonic() < deadline:
        signal = browser.execute_script("return document.getElementById('signal').textContent")
        if "GOOD ENOUGH" in signal:
            break
        time.sleep(0.3)
    assert "GOOD ENOUGH" in signal
    head = browser.execute_script("return document.getElementById('head').textContent")
    assert "MotionCal Raw: lines" in head and "samples" in head
    # The canvas holds the cloud and the green cells: count its green pixels.
    green = browser.execute_script(
        """const c = document.getElementById('sphere');
        const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;
        let n = 0; for (let i = 0; i < d.length; i += 4) if (d[i + 1] > 100 && d[i] < 80 && d[i + 2] < 80) n++;
        return n;"""
    )
    assert green > 1000
    errors = [entry for entry in browser.get_log("browser") if entry["level"] == "SEVERE"]
    assert errors == []
