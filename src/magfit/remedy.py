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

A command that lacks an option says it through the command that has it (:func:`for_command`):

>>> with for_command_line(), for_command("inspect", [], file="mag.csv"):
...     option("method", "vector")
'magfit calibrate mag.csv --method vector'
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

__all__ = [
    "STREAM_ARGUMENTS",
    "Audience",
    "audience",
    "command_line",
    "for_command",
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
FLAGS = {"allow_undetermined": "--force", "allow_unit_mismatch": "--force", "force": "--force", "even": "--even"}


@dataclass(frozen=True)
class _Command:
    """The ``magfit`` command running: its options' flags, those it takes under another name, and the command
    (with the file) that a remedy it lacks is said through."""

    name: str
    flags: frozenset[str]
    renamed: Mapping[str, str] = field(default_factory=dict)
    elsewhere: str = "calibrate"
    file: str = "FILE"


#: The commands running (innermost last), when a command says which options it has.
_commands: list[_Command] = []


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


@contextlib.contextmanager
def for_command(
    name: str,
    flags: Iterable[str],
    *,
    renamed: Mapping[str, str] | None = None,
    elsewhere: str = "calibrate",
    file: str | Path = "FILE",
) -> Iterator[None]:
    """Say the command line's remedies as the ``magfit NAME`` command can take them while inside.

    ``flags`` are its options (``"--columns"``, ...): a remedy among them is said as that option; one it takes
    under another name (``renamed``, e.g. ``{"--method": "--methods"}``) by that name; any other through the
    command that has it, ``magfit calibrate FILE --method vector`` (``elsewhere``, ``file``). Only messages
    for the command line (inside :func:`for_command_line`) change.
    """
    _commands.append(_Command(name, frozenset(flags), dict(renamed or {}), elsewhere, str(file)))
    try:
        yield
    finally:
        _commands.pop()


def _running(flag: str) -> _Command | None:
    """The command running when it lacks ``flag`` (its remedy is then said another way), else None."""
    if not _commands or flag in _commands[-1].flags:
        return None
    return _commands[-1]


def _flag_name(name: str) -> str:
    return FLAGS.get(name) or f"--{name.replace('_', '-')}"


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
    """One remedy in the current audience's words: ``unit='uT'`` or ``--unit uT`` (or, in a command without
    that option, ``magfit calibrate FILE --unit uT``: :func:`for_command`)."""
    text = _as_text(value)
    if audience() == "command line":
        said, flag = _flag(name, text), _flag_name(name)
        command = _running(flag)
        if command is None or not said:
            return said
        if flag in command.renamed:
            return command.renamed[flag] + said[len(flag) :]
        return f"magfit {command.elsewhere} {command.file} {said}"
    return f"{name}={_python_value(name, text)}"


def options(pairs: Sequence[tuple[str, object]]) -> str:
    """Several remedies, space-separated on the command line, comma-separated in Python."""
    if audience() == "command line":
        for name, _ in pairs:  # one of them only another command takes: the whole call as that command
            command = _running(_flag_name(name))
            if command is not None and _flag_name(name) not in command.renamed:
                return command_line(command.elsewhere, command.file, [(n, _as_text(v)) for n, v in pairs])
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
