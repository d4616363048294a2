"""``magfit live --web``: the live view as a local page, with the 3-D point cloud and the coverage sphere.

A small HTTP server bound to 127.0.0.1 (never another interface: the page shows a sensor's data and
accepts no input) serves two things: ``/``, one self-contained HTML page (its script and style inline,
nothing fetched from elsewhere), and ``/state.json``, the session's snapshot, which the page asks for four
times a second. The page draws on a 2-D canvas, in software, so it needs no WebGL: the corrected samples
of the even subset (on the unit sphere when the fit is right) and the 100 equal-area cells of the coverage,
green when reached, red when not; drag to turn it.

The server answers only requests addressed to a loopback name (a page elsewhere that rebinds its own name
to 127.0.0.1 gets 403), serves a bounded number of connections at once and closes idle ones, and does not
report clients that go away.
"""

from __future__ import annotations

import json
import sys
import threading
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from typing import Any

import numpy as np

from ..diagnostics.coverage import partition
from .runner import LiveRun
from .session import COVERAGE_CELLS

__all__ = ["WebView"]

#: Points of the cloud sent to the page (the even subset is at most this large anyway).
_MAX_POINTS = 2000


def state(run: LiveRun) -> dict[str, Any]:
    """The snapshot of ``run`` as JSON-ready data (what ``/state.json`` returns)."""
    snapshot = run.session.snapshot()
    fit = snapshot.fit
    calibration = fit.calibration if fit is not None else None
    points: list[list[float]] = []
    subset = run.session.subset()
    if subset.shape[0]:
        if calibration is not None:
            corrected = calibration.apply(subset, normalized=True)
        else:  # before the first fit: the raw cloud, centred and scaled, so that it shows the motion
            centred = subset - subset.mean(axis=0)
            corrected = centred / max(float(np.abs(centred).max()), 1e-12)
        points = np.round(corrected[:_MAX_POINTS], 4).tolist()
    verdict = snapshot.verdict
    return {
        "source": run.source.name,
        "stream": run.parser.describe(),
        "samples": snapshot.n_samples,
        "rate": round(snapshot.rate_hz, 1),
        "elapsed": round(snapshot.elapsed, 1),
        "good": verdict.good,
        "checks": [list(check) for check in verdict.checks],
        "warnings": list(verdict.warnings),
        "missing": list(snapshot.coverage.missing) if snapshot.coverage is not None else [],
        "reached": snapshot.reached.tolist(),
        "fit": None
        if calibration is None
        else {
            "model": calibration.auto.chosen if calibration.auto is not None else calibration.method,
            "offset": [round(float(v), 4) for v in calibration.offset],
            "field": round(calibration.field_strength, 4),
            "unit": run.parser.unit,
        },
        "error": None if fit is None else fit.error,
        "ended": run.ended,
        "points": points,
    }


#: Host names the page answers to. A page elsewhere can make a browser resolve its own name to 127.0.0.1
#: (DNS rebinding) and read /state.json as if it were its own: such a request carries that name in its Host
#: header, and is refused.
LOOPBACK_HOSTS = ("127.0.0.1", "localhost", "[::1]")
#: Connections served at once; more are closed at once (each has a thread while it is open).
MAX_CONNECTIONS = 16
#: Seconds a connection may stay silent before it is closed (an idle one would hold its thread for ever).
IDLE_SECONDS = 10.0


def host_allowed(host: str | None, port: int) -> bool:
    """Whether a request's Host header names this server: a loopback name, with no port or with ``port``."""
    if not host:
        return False
    host = host.strip().lower()
    if host.startswith("["):  # an IPv6 address: "[::1]" or "[::1]:8000"
        inside, _, rest = host.partition("]")
        name, given = inside + "]", rest[1:] if rest.startswith(":") else rest
        if rest and not rest.startswith(":"):
            return False
    else:
        name, _, given = host.partition(":")
    return name in LOOPBACK_HOSTS and given in ("", str(port))


class _Server(ThreadingHTTPServer):
    """One thread per connection, at most :data:`MAX_CONNECTIONS` of them; a client that goes away is no error."""

    daemon_threads = True
    request_queue_size = 64  # the listen backlog: a burst of connections waits to be accepted (or closed)

    def __init__(self, address: tuple[str, int], handler: type[BaseHTTPRequestHandler], limit: int) -> None:
        super().__init__(address, handler)
        self._slots = threading.BoundedSemaphore(limit)

    def process_request(self, request: Any, client_address: Any) -> None:
        if not self._slots.acquire(blocking=False):  # every slot taken: this connection is closed unserved
            self.shutdown_request(request)
            return
        try:
            super().process_request(request, client_address)
        except BaseException:
            self._slots.release()
            raise

    def process_request_thread(self, request: Any, client_address: Any) -> None:
        try:
            super().process_request_thread(request, client_address)
        finally:
            self._slots.release()

    def handle_error(self, request: Any, client_address: Any) -> None:
        """A client that resets or drops its connection (a closed tab, a timeout) is not reported; the socket
        server would print a traceback over the live view for each."""
        error = sys.exc_info()[1]
        if isinstance(error, OSError):
            return
        super().handle_error(request, client_address)


class WebView:
    """Serve the page of ``run`` on 127.0.0.1 (``port`` 0: any free port) from a background thread.

    Only requests whose Host header is a loopback name are answered (403 otherwise); at most
    ``max_connections`` are open at once, each closed after ``idle_seconds`` of silence.
    """

    def __init__(
        self,
        run: LiveRun,
        port: int = 0,
        *,
        max_connections: int = MAX_CONNECTIONS,
        idle_seconds: float = IDLE_SECONDS,
    ) -> None:
        self.run = run
        page = _PAGE.replace("__CELLS__", json.dumps(np.round(partition(COVERAGE_CELLS).centres(), 4).tolist()))
        body = page.encode("utf-8")
        view = self

        class Handler(BaseHTTPRequestHandler):
            timeout = idle_seconds  # StreamRequestHandler sets it on the connection's socket

            def do_GET(self) -> None:
                if not host_allowed(self.headers.get("Host"), view.port):
                    self.send_error(403, "this page answers to 127.0.0.1 and localhost only")
                elif self.path == "/":
                    self._send(body, "text/html; charset=utf-8")
                elif self.path == "/state.json":
                    self._send(json.dumps(state(view.run)).encode("utf-8"), "application/json")
                else:
                    self.send_error(404)

            def _send(self, data: bytes, kind: str) -> None:
                self.send_response(200)
                self.send_header("Content-Type", kind)
                self.send_header("Content-Length", str(len(data)))
                self.send_header("Cache-Control", "no-store")
                self.end_headers()
                self.wfile.write(data)

            def log_message(self, format: str, *args: Any) -> None:  # no access log on the terminal
                pass

        self._server = _Server(("127.0.0.1", port), Handler, max_connections)
        self._thread = threading.Thread(target=self._server.serve_forever, name="magfit-live-web", daemon=True)

    @property
    def port(self) -> int:
        return int(self._server.server_address[1])

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.port}/"

    def start(self) -> WebView:
        self._thread.start()
        return self

    def close(self) -> None:
        self._server.shutdown()
        self._server.server_close()


_PAGE = """<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>magfit live</title><link rel="icon" href="data:,">
<style>
body { font: 14px system-ui, sans-serif; margin: 16px; background: #fafafa; color: #222; }
#layout { display: flex; gap: 24px; align-items: flex-start; }
canvas { background: #fff; border: 1px solid #ccc; cursor: grab; }
table { border-collapse: collapse; } td { padding: 2px 10px 2px 0; }
#signal { padding: 6px 10px; font-weight: bold; color: #fff; display: inline-block; margin: 8px 0; }
.good { background: #2e7d32; } .bad { background: #c62828; } .warn { color: #a15c00; } .dim { color: #777; }
</style></head>
<body>
<h2>magfit live</h2>
<div id="head" class="dim">waiting for the first state</div>
<div id="layout">
  <canvas id="sphere" width="560" height="560"></canvas>
  <div>
    <div id="signal" class="bad">NOT YET</div>
    <table id="checks"></table>
    <h3>Current fit (auto)</h3><div id="fit" class="dim">waiting for samples</div>
    <div id="missing" class="warn"></div>
    <div id="warnings" class="warn"></div>
    <p class="dim">Grey dots: the corrected samples (the unit sphere when the fit is right). Green and red
    discs: the 100 equal-area directions, reached or not. Drag to turn.</p>
  </div>
</div>
<script>
"use strict";
const CELLS = __CELLS__;
const TURN = {"+": "down and north (along the field)", "\\u2212": "up and south (against the field)"};
let state = null, yaw = 0.6, pitch = -0.4, drag = null;
const canvas = document.getElementById("sphere"), ctx = canvas.getContext("2d");
canvas.addEventListener("mousedown", e => { drag = [e.clientX, e.clientY]; });
window.addEventListener("mouseup", () => { drag = null; });
window.addEventListener("mousemove", e => {
  if (!drag) return;
  yaw += (e.clientX - drag[0]) * 0.01; pitch += (e.clientY - drag[1]) * 0.01; drag = [e.clientX, e.clientY]; draw();
});
function project(p) {
  const cy = Math.cos(yaw), sy = Math.sin(yaw), cp = Math.cos(pitch), sp = Math.sin(pitch);
  const x = cy * p[0] - sy * p[1], y0 = sy * p[0] + cy * p[1];
  const y = cp * y0 - sp * p[2], z = sp * y0 + cp * p[2];
  const s = canvas.width * 0.36;
  return [canvas.width / 2 + s * x, canvas.height / 2 - s * z, y];
}
function draw() {
  ctx.clearRect(0, 0, canvas.width, canvas.height);
  ctx.strokeStyle = "#ddd"; ctx.beginPath();
  ctx.arc(canvas.width / 2, canvas.height / 2, canvas.width * 0.36, 0, 2 * Math.PI); ctx.stroke();
  if (!state) return;
  const items = [];
  for (const p of state.points) items.push([project(p), "rgba(90,90,90,0.55)", 2]);
  CELLS.forEach((c, i) => items.push([project(c.map(v => v * 1.08)), state.reached[i] ? "#2e7d32" : "#c62828", 6]));
  items.sort((a, b) => b[0][2] - a[0][2]);  // far first
  for (const [q, colour, r] of items) {
    ctx.fillStyle = colour; ctx.globalAlpha = q[2] > 0 ? 0.35 : 1.0;
    ctx.beginPath(); ctx.arc(q[0], q[1], r, 0, 2 * Math.PI); ctx.fill();
  }
  ctx.globalAlpha = 1.0;
  for (const [name, v] of [["x", [1.25, 0, 0]], ["y", [0, 1.25, 0]], ["z", [0, 0, 1.25]]]) {
    const o = project([0, 0, 0]), q = project(v);
    ctx.strokeStyle = "#555"; ctx.beginPath(); ctx.moveTo(o[0], o[1]); ctx.lineTo(q[0], q[1]); ctx.stroke();
    ctx.fillStyle = "#000"; ctx.fillText("+" + name, q[0] + 4, q[1] - 4);
  }
}
function text(id, value) { document.getElementById(id).textContent = value; }
function show(s) {
  state = s;
  text("head", `${s.source} \\u00b7 ${s.stream} \\u00b7 samples ${s.samples} \\u00b7 rate ${s.rate}/s \\u00b7 ` +
       `time ${s.elapsed} s` + (s.ended ? ` \\u00b7 ${s.ended}` : ""));
  const signal = document.getElementById("signal");
  signal.textContent = s.good ? "GOOD ENOUGH: save it" : "NOT YET: keep turning the sensor";
  signal.className = s.good ? "good" : "bad";
  const table = document.getElementById("checks"); table.textContent = "";
  for (const [label, now, needed, ok] of s.checks) {
    const row = table.insertRow();
    for (const v of [label, now, "needs " + needed, ok ? "ok" : "not yet"]) row.insertCell().textContent = v;
  }
  text("fit", s.fit ? `${s.fit.model}: offset (${s.fit.offset.join(", ")}), field ${s.fit.field} ${s.fit.unit || ""}`
                    : (s.error ? "refused: " + s.error : "waiting for samples"));
  text("missing", s.missing.map(a => `missing ${a}: point the ${a[1]} axis ${TURN[a[0]] || ""}`).join("; "));
  text("warnings", s.warnings.join(" "));
  draw();
}
async function poll() {
  try { const r = await fetch("/state.json", {cache: "no-store"}); if (r.ok) show(await r.json()); }
  catch (e) { text("head", "magfit live has stopped"); }
  setTimeout(poll, 250);
}
poll();
</script></body></html>
"""
