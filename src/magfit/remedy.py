"""A remedy is an argument with a value; a message names it in the words of whoever reads it.

The library speaks Python (``method='vector'``, ``allow_undetermined=True``), the ``magfit`` command its
options (``--method vector``, ``--force``). A message that suggests a remedy builds it with :func:`option`
(one argument) or :func:`options` (several), which render it for the process's audience: keywords by
default, options while :func:`for_command_line` is active (the ``magfit`` command enters it at its boundary,
:class:`magfit.cli.app.MagfitGroup`, for the whole process: the threads that read a file in pieces or fit a
live session say it the same way). So no layer rewrites another's words: the command line never parses the
library's prose, and the library never names a flag.

The same pairs are the data a :class:`magfit.findings.Reason` or a :class:`magfit.MagfitError` carries
(``remedy``): :func:`python_call` and :func:`command_line` render them as a whole call.

>>> option("method", "vector")
"method='vector'"
>>> with for_command_line():
...     option("method", "vector"), option("allow_undetermined", True), option("columns", ["mx", "my", "mz"])
('--method vector', '--force', '--columns mx,my,mz')
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Literal

__all__ = [
    "STREAM_ARGUMENTS",
    "Audience",
    "audience",
    "command_line",
    "for_command_line",
    "option",
    "options",
    "python_call",
]

Audience = Literal["python", "command line"]
#: Who reads the messages built now (a process-wide setting: the command line is a whole process).
_audience: list[Audience] = ["python"]

#: The arguments whose value is a list of columns (``attitude=['roll', 'pitch', 'yaw']``; ``--attitude roll,...``).
STREAM_ARGUMENTS = ("columns", "attitude", "reference", "gyro", "accel", "time", "accel_columns", "gyro_columns")
#: Arguments whose command-line form is a flag: given when true, absent when false.
FLAGS = {"allow_undetermined": "--force", "force": "--force", "even": "--even"}


def audience() -> Audience:
    """Who reads the messages built now: ``"python"`` (the default) or ``"command line"``."""
    return _audience[-1]


@contextlib.contextmanager
def for_command_line() -> Iterator[None]:
    """Build messages for the ``magfit`` command while inside: remedies as its options."""
    _audience.append("command line")
    try:
        yield
    finally:
        _audience.pop()


def _as_text(value: object) -> str:
    """A value as the pairs carry it: a list of columns comma-separated, a boolean ``True``/``False``."""
    if isinstance(value, (list, tuple)):
        return ",".join(str(item) for item in value)
    return str(value)


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _python_value(name: str, value: str) -> str:
    """``value`` (as the pairs carry it) as a Python literal: ``['roll', 'pitch', 'yaw']``, ``'uT'``, ``1e5``."""
    if name in STREAM_ARGUMENTS:
        items = [item.strip() for item in value.split(",")]
        if items == ["X", "Y", "Z"] or items == ["..."]:
            return "[...]"
        return "[" + ", ".join(item if item.isdigit() else repr(item) for item in items) + "]"
    if name == "location":  # a tuple: (52.1, 4.3) or the placeholder (LAT, LON[, ALT])
        parts = [item.strip() for item in value.split(",")]
        return "(" + ", ".join(parts) + ")" if len(parts) > 1 else repr(value)
    if value in ("True", "False", "None") or _is_number(value):
        return value
    return repr(value)


def _flag(name: str, value: str) -> str:
    """``name`` and ``value`` as the command line's words: ``--max-samples 100000``, ``--force``, ``''``."""
    if name in FLAGS:
        return FLAGS[name] if value == "True" else ""
    if name in STREAM_ARGUMENTS and value.strip() in ("", "..."):
        value = "X,Y,Z"
    return f"--{name.replace('_', '-')} {value}"


def option(name: str, value: object) -> str:
    """One remedy in the current audience's words: ``unit='uT'`` or ``--unit uT``."""
    text = _as_text(value)
    if audience() == "command line":
        return _flag(name, text)
    return f"{name}={_python_value(name, text)}"


def options(pairs: Sequence[tuple[str, object]]) -> str:
    """Several remedies, space-separated on the command line, comma-separated in Python."""
    said = [option(name, value) for name, value in pairs]
    return (" " if audience() == "command line" else ", ").join(word for word in said if word)


def python_call(path: Path | str, remedy: Sequence[tuple[str, str]], function: str = "calibrate_file") -> str:
    """``magfit.calibrate_file('flight.csv', method='vector', attitude=['roll', 'pitch', 'yaw'])``."""
    arguments = ", ".join(f"{name}={_python_value(name, _as_text(value))}" for name, value in remedy)
    return f"magfit.{function}({str(path)!r}" + (f", {arguments})" if arguments else ")")


def command_line(command: str, path: Path | str, remedy: Sequence[tuple[str, str]]) -> str:
    """``magfit calibrate flight.csv --method vector --attitude roll,pitch,yaw``."""
    words = ["magfit", command, str(path), *(_flag(name, _as_text(value)) for name, value in remedy)]
    return " ".join(word for word in words if word)
