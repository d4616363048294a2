"""Live calibration from a board's stream: parse the lines, keep the samples, refit, judge, send back.

Data flow, one way: a :mod:`~magfit.live.source` yields bytes; :mod:`~magfit.live.stream` turns them into
samples; :mod:`~magfit.live.session` keeps them (with :mod:`~magfit.live.record` writing them to disk
first), refits an even subset with :func:`magfit.fit` and judges the fit; :mod:`~magfit.live.runner` runs
the reading and fitting threads; :mod:`~magfit.live.view` draws a snapshot; :mod:`~magfit.live.packet`
builds MotionCal's calibration packet for the board. :mod:`~magfit.live.board` is a simulated board
(for ``magfit live --simulate`` and the tests).

``import magfit`` does not import this package; serial ports need pyserial (the ``live`` extra) and the
view needs rich (the ``cli`` extra), each imported only when used.
"""

from __future__ import annotations

from .board import BoardTruth, SimulatedBoard
from .packet import PACKET_SIZE, crc16, motioncal_packet
from .record import Recorder
from .runner import LiveRun, StopRule
from .session import Session, Snapshot, Thresholds, Verdict
from .source import EndOfStream, SimulatedSource, open_source
from .stream import LineParser

__all__ = [
    "PACKET_SIZE",
    "BoardTruth",
    "EndOfStream",
    "LineParser",
    "LiveRun",
    "Recorder",
    "Session",
    "SimulatedBoard",
    "SimulatedSource",
    "Snapshot",
    "StopRule",
    "Thresholds",
    "Verdict",
    "crc16",
    "motioncal_packet",
    "open_source",
]
