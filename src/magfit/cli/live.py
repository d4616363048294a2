"""``magfit live``: calibrate while the board is turned, from a serial port, a socket, stdin or the simulator."""

from __future__ import annotations

import contextlib
import select
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import click
import numpy as np
from rich.console import Console, RenderableType
from rich.live import Live

from ..calibration import Calibration
from ..errors import CalibrationError, MagfitError
from ..live import LineParser, LiveRun, Recorder, Session, SimulatedBoard, SimulatedSource, StopRule, Thresholds
from ..live.packet import motioncal_packet
from ..live.source import EndOfStream, Source, open_source
from ._common import (
    FitFailedError,
    RegistryChoice,
    console,
    export_format_names,
    fail,
    fixed,
    parse_columns,
    refuse_overwriting_input,
    same_file,
    vector,
    warn,
)

#: Seconds between two redraws of the view (the issue asks for at least 5 a second).
REDRAW = 0.15
#: Seconds to wait for the board's Cal1:/Cal2: echo after sending a calibration.
ECHO_WAIT = 3.0


def _parse_until(ctx: click.Context, param: click.Parameter, value: str | None) -> bool:
    if value is None:
        return False
    if value != "good":
        raise click.BadParameter(f"the only condition is 'good', got {value!r}", ctx, param)
    return True


@click.command("live")
@click.argument("port", required=False)
@click.option("--simulate", is_flag=True, help="Read a simulated board turned by a hand instead of a port.")
@click.option("--baud", type=click.IntRange(min=1), default=115200, show_default=True, help="Serial port speed.")
@click.option("--samples", "n_samples", type=click.IntRange(min=1), help="Stop after N samples.")
@click.option("--duration", type=click.FloatRange(min=0, min_open=True), help="Stop after S seconds.")
@click.option("--until", "until_good", callback=_parse_until, metavar="good", help="Stop once the fit is good enough.")
@click.option("-o", "--output", type=click.Path(dir_okay=False, path_type=Path), help="Write the calibration here.")
@click.option("--export", "export_format", type=RegistryChoice("format", export_format_names), help="Firmware format.")
@click.option("--record", type=click.Path(dir_okay=False, path_type=Path), help="Keep every sample in this new CSV.")
@click.option("--send", type=click.Choice(["motioncal"]), help="Send the calibration to the board (68-byte packet).")
@click.option(
    "--columns", callback=parse_columns, help="Plain lines: the x,y,z columns by header name or 0-based index."
)
@click.option("--unit", help="Unit of plain lines (Raw:/Uni: lines are 0.1 uT / uT).")
@click.option("--min-coverage", type=click.FloatRange(0, 1), default=Thresholds.min_coverage, show_default=True,
              help="Good enough: share of the 100 directions reached.")  # fmt: skip
@click.option("--max-heading-sigma", type=click.FloatRange(min=0, min_open=True),
              default=Thresholds.max_heading_sigma_deg, show_default=True,
              help="Good enough: heading one-sigma at level attitude, degrees.")  # fmt: skip
@click.option("--web", is_flag=True, help="Also show the view as a page on 127.0.0.1 (its address is printed).")
@click.option("--rate", type=click.FloatRange(1, 5000), default=100.0, show_default=True,
              help="--simulate: samples per second.")  # fmt: skip
@click.option("--speed", type=click.FloatRange(1, 3600), default=120.0, show_default=True,
              help="--simulate: how fast the hand turns the board, degrees per second.")  # fmt: skip
@click.option("--seed", type=int, default=0, show_default=True, help="--simulate: seed of the hand's motion.")
def live_command(
    port: str | None,
    simulate: bool,
    baud: int,
    n_samples: int | None,
    duration: float | None,
    until_good: bool,
    output: Path | None,
    export_format: str | None,
    record: Path | None,
    send: str | None,
    columns: list[str | int] | None,
    unit: str | None,
    min_coverage: float,
    max_heading_sigma: float,
    web: bool,
    rate: float,
    speed: float,
    seed: int,
) -> None:
    """Calibrate live: read PORT, refit as the sensor turns, save (and send) when good enough.

    PORT is a serial device (/dev/ttyACM0, COM3; needs pip install 'magfit[live]'), tcp://HOST:PORT,
    '-' for standard input, or a file. Lines may be MotionCal's Raw: (9 integers, magnetometer in
    0.1 uT), Uni: (9 numbers, uT) or plain lines of 3 or more numbers.

    Without --samples, --duration or --until on a terminal, the view is interactive: s saves, r
    resets, q quits. With one of them it stops by itself, writes -o / --export and exits.

    \b
    Examples:
      magfit live --simulate
      magfit live /dev/ttyACM0 --until good --record raw.csv -o cal.json --send motioncal
      magfit live - --columns mx,my,mz --unit uT -o cal.json < log.csv
    """
    if simulate == (port is not None):
        fail("give a PORT or --simulate (not both)")
    if record is not None and output is not None and same_file(record, output):
        fail(f"--record and -o are the same file {record}; choose two paths")
    if port is not None and port != "-" and "://" not in port and Path(port).is_file():
        # A recording read as the port: neither the calibration nor a new recording may be written over it.
        for written in (output, record):
            if written is not None:
                refuse_overwriting_input(written, [Path(port)])
    for path in (output, record):
        # Checked now, not after the session: a typo must not cost the user a whole calibration run.
        if path is not None and (path.is_dir() or not (path.parent if str(path.parent) else Path(".")).is_dir()):
            fail(f"{path}: not a file in an existing directory; choose another path")
    if unit is not None:
        from ..units import canonical_name

        unit = canonical_name(unit)  # an unknown unit is a usage error now, listing the valid ones
    stop = StopRule(samples=n_samples, duration=duration, until_good=until_good)
    thresholds = Thresholds(min_coverage=min_coverage, max_heading_sigma_deg=max_heading_sigma)
    source: Source
    if simulate:
        source = SimulatedSource(SimulatedBoard(rate_hz=rate, speed_dps=speed, seed=seed))
    else:
        assert port is not None
        source = open_source(port, baud=baud)
    if send is not None and getattr(source, "ends_normally", False) and not simulate:
        source.close()
        fail(f"--send needs a serial port or a socket to write to; {source.name} is read-only")
    # The keys need a POSIX terminal (termios); elsewhere the run goes on until the stream ends.
    interactive = not stop.given and sys.stdin.isatty() and sys.stdout.isatty() and port != "-" and _has_termios()
    try:
        recorder = Recorder(record) if record is not None else None
    except MagfitError:
        source.close()
        raise
    parser = LineParser(columns=columns, first_line_may_be_cut=source.first_line_may_be_cut)
    session = Session(thresholds=thresholds)
    run = LiveRun(source, parser, session, recorder=recorder, stop=stop)
    page = None
    if web:
        from ..live.web import WebView

        page = WebView(run).start()
        click.echo(f"magfit: the live page is at {page.url}", err=True)
    try:
        if interactive:
            _interactive(run, thresholds, unit, output, export_format, send)
            return
        _until_stopped(run, thresholds, unit)
    finally:
        run.close()
        source.close()
        if page is not None:
            page.close()


# ---------------------------------------------------------------------- non-interactive


def _until_stopped(run: LiveRun, thresholds: Thresholds, unit: str | None) -> None:
    """Run until the stop rule or the end of the stream, then fit, write and send (the click context's args)."""
    ctx = click.get_current_context()
    params = ctx.params
    err = console(stderr=True)
    run.start()
    try:
        with _view(err, run, thresholds, unit, enabled=err.is_terminal):
            while not run.poll():
                time.sleep(0.05)
    except KeyboardInterrupt:  # stop the run, say where the recording is, then exit 130 as every command does
        run.close()
        _kept(run)
        raise
    run.close()
    if run.error is not None:
        _kept(run)
        raise run.error
    n = run.session.n_samples
    if run.stopped_by is None and run.stop.given:
        _kept(run)
        why = run.ended or "the stream ended"
        raise FitFailedError(
            f"{why} after {n} samples, before {run.stop.describe()}: no calibration was written"
            + (f"; fit the recording with 'magfit calibrate {run.recorder.path}'" if run.recorder else "")
        )
    if run.ended is not None and not run.source.ends_normally:
        warn(f"{run.ended}; the {n} samples received so far are used")
    try:
        calibration = _final(run, unit)
    except CalibrationError:
        _kept(run)
        raise
    verdict = run.session.judge(calibration)
    if run.stop.until_good and not verdict.good:
        _kept(run)
        raise FitFailedError(
            f"stopped by {run.stopped_by} before the fit was good enough ("
            + "; ".join(f"{c[0]} {c[1]}, needs {c[2]}" for c in verdict.checks if not c[3])
            + "): no calibration was written"
        )
    out = console(stderr=params["export_format"] is not None and params["output"] is None)
    _summary(out, run, calibration, verdict)
    _write(calibration, params["output"], params["export_format"], out)
    if params["send"] is not None:
        _send(run, calibration, out)


def _kept(run: LiveRun) -> None:
    if run.recorder is not None and run.recorder.rows:
        click.echo(f"magfit: the {run.recorder.rows} samples received are kept in {run.recorder.path}", err=True)


def _final(run: LiveRun, unit: str | None) -> Calibration:
    """The calibration to save, labelled with the stream's unit (µT for MotionCal lines)."""
    stream_unit = run.parser.unit
    if stream_unit is not None and unit is not None and unit != "uT":
        warn(f"--unit {unit} ignored: {run.parser.describe()} are in uT")
    calibration = run.session.final_calibration()
    label = stream_unit or unit
    return calibration.with_unit(label) if label else calibration


def _summary(out: Console, run: LiveRun, calibration: Calibration, verdict: object) -> None:
    counts = run.parser.counts
    u = f" {calibration.unit}" if calibration.unit else ""
    rows = [
        ("source", run.source.name),
        ("stream", run.parser.describe()),
        (
            "samples",
            f"{run.session.n_samples} ({counts.junk} junk lines, {counts.interruptions} interruptions"
            + (f", {run.source.reconnections} reconnections)" if run.source.reconnections else ")"),
        ),
        ("stopped by", run.stopped_by or run.ended or "the end of the stream"),
        ("chose", calibration.auto.chosen if calibration.auto is not None else calibration.method),
        ("offset", vector(calibration.offset) + u),
    ]
    m = calibration.matrix
    rows.append(("matrix", vector(m[0], lambda v: f"{v:9.6f}")))
    rows.append(("", vector(m[1], lambda v: f"{v:9.6f}")))
    rows.append(("", vector(m[2], lambda v: f"{v:9.6f}")))
    rows.append(("field strength", fixed(calibration.field_strength) + u))
    for label, value, needed, passed in getattr(verdict, "checks", ()):
        rows.append((label, f"{value} (needs {needed}){'' if passed else ' - NOT MET'}"))
    rows.append(("verdict", "good enough" if getattr(verdict, "good", False) else "NOT good enough"))
    for label, value in rows:
        out.print(f"{label:<16} {value}")
    diagnostics = calibration.diagnostics
    if diagnostics is not None:
        for warning in diagnostics.warnings:
            warn(warning)


def _write(calibration: Calibration, output: Path | None, export_format: str | None, out: Console) -> Path | None:
    """Write the calibration: JSON (or the export) to ``output``, or the export to stdout."""
    from ..io import atomic_write_text

    if export_format is not None:
        from ..export import export

        text = export(calibration, export_format)
    else:
        text = calibration.to_json() + "\n"
    if output is None:
        if export_format is not None:
            click.echo(text, nl=False)
        return None
    atomic_write_text(output, text)
    out.print(f"wrote the {'calibration' if export_format is None else export_format + ' export'} to {output}")
    return output


def _send(run: LiveRun, calibration: Calibration, out: Console) -> bool:
    """Send MotionCal's packet and wait for the board's Cal1:/Cal2: echo; True when it confirmed."""
    packet = motioncal_packet(calibration)
    run.send(packet)
    out.print(f"sent the MotionCal calibration packet ({len(packet)} bytes) to {run.source.name}")
    if _confirmed(run.source, packet):
        out.print("the board confirmed it (its Cal1:/Cal2: lines carry the new calibration)")
        return True
    warn(
        f"the board did not echo the calibration within {ECHO_WAIT:g} s (a sketch that prints no Cal1:/Cal2: "
        "lines cannot confirm it); check on the board that it was stored"
    )
    return False


def _confirmed(source: Source, packet: bytes) -> bool:
    """Read the board's output until its Cal1:/Cal2: lines match ``packet`` (or :data:`ECHO_WAIT` passes)."""
    parser = LineParser(first_line_may_be_cut=True)
    deadline = time.monotonic() + ECHO_WAIT
    while time.monotonic() < deadline:
        try:
            parser.feed(source.read(0.05))
        except EndOfStream:
            return False
        if _echoes(parser, packet):
            return True
    return False


# ---------------------------------------------------------------------- the view


@contextlib.contextmanager
def _view(out: Console, run: LiveRun, thresholds: Thresholds, unit: str | None, *, enabled: bool) -> Iterator[None]:
    """Redraw the view on ``out`` every :data:`REDRAW` seconds while the block runs (when ``enabled``)."""
    if not enabled:
        yield
        return
    import threading

    halt = threading.Event()
    with Live(console=out, auto_refresh=False, transient=False) as screen:

        def draw() -> None:
            while not halt.wait(REDRAW):
                screen.update(_render(run, thresholds, unit, (), keys=False), refresh=True)

        painter = threading.Thread(target=draw, daemon=True)
        painter.start()
        try:
            yield
        finally:
            halt.set()
            painter.join()
            screen.update(_render(run, thresholds, unit, (), keys=False), refresh=True)


def _render(
    run: LiveRun, thresholds: Thresholds, unit: str | None, status: tuple[str, ...], *, keys: bool
) -> RenderableType:
    from ..live.view import render

    counts = run.parser.counts
    junk = f"junk {counts.junk} lines, {counts.interruptions} interruptions" if counts.junk else ""
    if run.source.reconnections:
        junk += f"{', ' if junk else ''}reconnected {run.source.reconnections} times"
    lines = list(status)
    if run.ended is not None:
        lines.insert(0, f"{run.ended}: {run.session.n_samples} samples kept")
    if run.error is not None:
        lines.insert(0, f"error: {run.error}")
    return render(
        run.session.snapshot(),
        source=run.source.name,
        stream=run.parser.describe(),
        thresholds=thresholds,
        unit=run.parser.unit or unit,
        status=lines,
        keys=keys,
        junk=junk,
    )


# ---------------------------------------------------------------------- interactive


def _interactive(
    run: LiveRun,
    thresholds: Thresholds,
    unit: str | None,
    output: Path | None,
    export_format: str | None,
    send: str | None,
) -> None:
    """The view with keys: s saves (and sends), r resets, q quits."""
    out = console()
    status: list[str] = []
    run.start()
    with _cbreak(), Live(console=out, auto_refresh=False, screen=False) as screen:
        while True:
            screen.update(_render(run, thresholds, unit, tuple(status[-3:]), keys=True), refresh=True)
            key = _key(REDRAW)
            if key in ("q", "Q", "\x03"):
                break
            if key in ("r", "R"):
                run.session.reset()
                status.append("reset: the samples so far are forgotten (the recording keeps them)")
            if key in ("s", "S"):
                status.append(_save(run, unit, output, export_format, send))
    if run.recorder is not None:
        out.print(f"the recording is in {run.recorder.path}")


def _save(run: LiveRun, unit: str | None, output: Path | None, export_format: str | None, send: str | None) -> str:
    """The ``s`` key: fit, write, send; returns the status line."""
    target = output or Path(time.strftime("magfit-live-%Y%m%d-%H%M%S.json"))
    try:
        calibration = _final(run, unit)
    except CalibrationError as error:
        return f"not saved: {error}"
    try:
        quiet = Console(quiet=True)  # the messages go to the status line
        _write(calibration, target, export_format, quiet)
        message = f"saved to {target}"
        if send is not None:
            confirmed = _send_quietly(run, calibration)
            message += "; sent to the board" + (" and confirmed" if confirmed else " (no confirmation yet)")
        return message
    except MagfitError as error:
        return f"not saved: {error}"


def _send_quietly(run: LiveRun, calibration: Calibration) -> bool:
    """Send the packet while the reader runs; True once the reader has seen the board echo it."""
    packet = motioncal_packet(calibration)
    run.send(packet)
    deadline = time.monotonic() + ECHO_WAIT
    while time.monotonic() < deadline:
        if _echoes(run.parser, packet):
            return True
        time.sleep(0.05)
    return False


def _echoes(parser: LineParser, packet: bytes) -> bool:
    """True when the parser's last Cal1:/Cal2: lines carry the values of ``packet``."""
    if parser.cal1 is None or parser.cal2 is None:
        return False
    values = np.frombuffer(packet[2:66], dtype="<f4").astype(np.float64)
    # Cal2 lists the 3x3 matrix row by row; the packet holds [0][0], [1][1], [2][2], [0][1], [0][2], [1][2].
    s = values[10:]
    cal2 = np.array([s[0], s[3], s[4], s[3], s[1], s[5], s[4], s[5], s[2]])
    # The sketches print 3 decimals on Cal1: and 4 on Cal2:.
    return bool(
        np.allclose(parser.cal1, values[:10], rtol=0, atol=6e-4) and np.allclose(parser.cal2, cal2, rtol=0, atol=6e-5)
    )


def _has_termios() -> bool:
    try:
        import termios  # noqa: F401 - POSIX only
    except ImportError:
        return False
    return True


@contextlib.contextmanager
def _cbreak() -> Iterator[None]:
    """Keys without Enter and without echo while the view runs; the terminal restored after."""
    import termios
    import tty

    fd = sys.stdin.fileno()
    saved = termios.tcgetattr(fd)
    try:
        tty.setcbreak(fd)
        yield
    finally:
        termios.tcsetattr(fd, termios.TCSADRAIN, saved)


def _key(timeout: float) -> str | None:
    ready, _, _ = select.select([sys.stdin], [], [], timeout)
    return sys.stdin.read(1) if ready else None
