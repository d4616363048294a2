"""Pieces every command shares: error reporting, option types, consoles and number formatting."""

from __future__ import annotations

import os
import sys
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import Any, Literal, NoReturn

import click
import numpy as np
from numpy.typing import ArrayLike
from rich.console import Console

from ..errors import CalibrationError, MagfitError, OptionError
from ..remedy import command_line as command_line  # (the commands import it from here)
from ._extras import hint_for

#: What to do with rows holding NaN or inf (the readers' ``nonfinite`` argument).
Nonfinite = Literal["skip", "error"]

#: Exit status of a fit that fails on the data (a CalibrationError).
EXIT_FIT_FAILED = 1
#: Exit status of a usage or input error (bad option, unreadable file, malformed samples ...).
EXIT_USAGE = 2
#: Exit status of an unexpected error (a bug in magfit: please report it).
EXIT_INTERNAL = 3

#: Width of the tables when the output is not a terminal (files, pipes, tests): wide enough for the
#: comparison table, and fixed so that the text does not depend on the environment.
PIPE_WIDTH = 120


class CommandError(click.ClickException):
    """A usage or input error, reported as the single line ``magfit: error: <message>`` (exit status 2)."""

    exit_code = EXIT_USAGE

    def show(self, file: Any = None) -> None:
        click.echo(f"magfit: error: {self.format_message()}", file=file, err=file is None)


class FitFailedError(CommandError):
    """A fit that failed on the data (exit status 1)."""

    exit_code = EXIT_FIT_FAILED


class InternalError(CommandError):
    """An unexpected exception: a bug in magfit (exit status 3)."""

    exit_code = EXIT_INTERNAL


def one_line(message: str) -> str:
    """Collapse a message onto one line (file names and solver messages may carry newlines)."""
    return " ".join(str(message).split())


def as_command_error(error: BaseException) -> CommandError:
    """The :class:`CommandError` (message and exit status) that reports ``error``."""
    if isinstance(error, CalibrationError):
        return FitFailedError(one_line(str(error)))
    if isinstance(error, MagfitError):
        return CommandError(one_line(str(error)))
    if isinstance(error, click.UsageError):
        hint = f" (see '{error.ctx.command_path} --help')" if error.ctx is not None else ""
        return CommandError(one_line(error.format_message()) + hint)
    if isinstance(error, click.ClickException):
        return CommandError(one_line(error.format_message()))
    if isinstance(error, OSError):
        target = f"{error.filename}: " if error.filename else ""
        return CommandError(f"{target}{error.strerror or error}")
    if isinstance(error, ImportError) and (install := hint_for(error)) is not None:
        return CommandError(install)  # a missing extra: the install command, not "a bug in magfit"
    if isinstance(error, MemoryError):  # a file too big for this machine is no bug either
        return CommandError(
            "not enough memory for this file; fit it with a linear method (-m ellipsoid, sphere, als), which "
            "streams, or on a subsample (--max-samples N)"
        )
    return InternalError(
        f"unexpected {type(error).__name__}: {one_line(str(error))} (a bug in magfit: rerun with --debug "
        "and report the traceback)"
    )


def fail(message: str) -> NoReturn:
    """Stop the command with ``magfit: error: <message>`` (exit status 2)."""
    raise CommandError(message)


def warn(message: str) -> None:
    """Print ``magfit: warning: <message>`` on stderr."""
    click.echo(f"magfit: warning: {one_line(message)}", err=True)


# ---------------------------------------------------------------------- output


class _Console(Console):
    """rich's Console, except that a closed standard output ends the command as every other write does: the
    CLI's boundary turns the BrokenPipeError into a quiet exit 141 (rich's own handler exits 1, which means
    "the data cannot support the fit")."""

    def on_broken_pipe(self) -> None:
        self.quiet = True
        raise BrokenPipeError


def console(*, stderr: bool = False) -> Console:
    """A rich console on stdout (or stderr), created per call so that redirected streams are honoured.

    Markup is off (file names may contain brackets); outside a terminal the width is fixed and there
    is no colour, so piped output is plain, stable text.
    """
    stream = sys.stderr if stderr else sys.stdout
    terminal = stream.isatty()
    return _Console(
        file=stream,
        markup=False,
        highlight=False,
        emoji=False,
        width=None if terminal else PIPE_WIDTH,
        no_color=not terminal or "NO_COLOR" in os.environ,
    )


def fixed(value: float, decimals: int = 4) -> str:
    """``value`` with ``decimals`` decimals, the paper's style; never prints a negative zero."""
    text = f"{value:.{decimals}f}"
    if float(text) == 0.0:
        text = text.lstrip("-")
    return text


def significant(value: float, digits: int = 4) -> str:
    """``value`` to ``digits`` significant digits (``262.1``, ``-0.01203``); no negative zero."""
    text = f"{value:.{digits}g}"
    return "0" if float(text) == 0.0 else text


def time_span(start_s: float, end_s: float, time_base: str) -> str:
    """A log's time span in words: ``2026-01-01 10:00:00 to 10:01:03 UTC (63.0 s)`` on an epoch time base (a ROS
    bag's stamps), ``12.3 to 75.4 s after boot (63.1 s)`` on a boot clock, ``no time stamps`` without."""
    import datetime
    import math

    if not (math.isfinite(start_s) and math.isfinite(end_s)):
        return "no time stamps"
    span = f"({end_s - start_s:.1f} s)"
    # A "boot" clock past 1e9 s (2001) is a wall clock: PX4's SITL stamps its ULogs with the host's time (pyulog's
    # sample_px4_events.ulg: 1710773350 s, the day its GPS fixes give).
    if time_base.startswith("seconds since the epoch") or start_s >= 1e9:
        utc = datetime.timezone.utc
        first = datetime.datetime.fromtimestamp(start_s, tz=utc)
        last = datetime.datetime.fromtimestamp(end_s, tz=utc)
        end = last.strftime("%H:%M:%S" if last.date() == first.date() else "%Y-%m-%d %H:%M:%S")
        return f"{first:%Y-%m-%d %H:%M:%S} to {end} UTC {span}"
    after = " after boot" if "boot" in time_base else ""
    return f"{start_s:.1f} to {end_s:.1f} s{after} {span}"


def vector(values: ArrayLike, formatter: Callable[[float], str] = fixed) -> str:
    """A 3-vector as ``(a, b, c)``."""
    return "(" + ", ".join(formatter(float(v)) for v in np.asarray(values, dtype=float).ravel()) + ")"


# ---------------------------------------------------------------------- option types


class RegistryChoice(click.ParamType):
    """A choice among names read when the option is used (methods and formats others may register).

    Parameters
    ----------
    kind : str
        What the names are ("method", "format"), for the messages.
    names : callable
        Returns the valid names; called at parse time, so late registrations count.
    """

    def __init__(self, kind: str, names: Callable[[], Iterable[str]]) -> None:
        self.kind = kind
        self.names = names
        self.name = kind

    def get_metavar(self, param: click.Parameter, ctx: click.Context | None = None) -> str:
        try:
            return "[" + "|".join(self.names()) + "]"
        except MagfitError:
            return self.kind.upper()

    def convert(self, value: Any, param: click.Parameter | None, ctx: click.Context | None) -> str:
        names = list(self.names())
        if value in names:
            return str(value)
        self.fail(f"unknown {self.kind} {value!r}; valid {self.kind}s: {', '.join(names)}", param, ctx)


class FieldStrength(click.ParamType):
    """``--field-strength``: a positive number in the samples' unit, or ``wmm`` (the World Magnetic Model's)."""

    name = "field strength"

    def convert(self, value: Any, param: click.Parameter | None, ctx: click.Context | None) -> float | str:
        if str(value).strip().lower() == "wmm":
            return "wmm"
        try:
            number = float(value)
        except ValueError:
            number = float("nan")
        if not (np.isfinite(number) and number > 0):
            self.fail(f"expected a positive number (in the samples' unit) or 'wmm', got {value!r}", param, ctx)
        return number


def geomag_option(parse: Callable[[str], Any]) -> Callable[[click.Context, click.Parameter, str | None], Any]:
    """A callback that parses ``--location`` or ``--date`` with :mod:`magfit.geomag`'s parser (usage error if bad)."""

    def callback(ctx: click.Context, param: click.Parameter, value: str | None) -> Any:
        if value is None:
            return None
        try:
            return parse(value)
        except OptionError as error:
            raise click.BadParameter(str(error), ctx, param) from None

    return callback


def method_names() -> list[str]:
    """The registered calibration methods, in registration order."""
    from ..methods import METHODS

    return list(METHODS)


def default_method() -> str:
    """The method ``calibrate`` uses when none is given: ``auto`` when registered, else ``ellipsoid``."""
    from ..methods import METHODS

    return "auto" if "auto" in METHODS else "ellipsoid"


def export_format_names() -> list[str]:
    """The firmware export formats of :mod:`magfit.export`."""
    try:
        from ..export import FORMATS
    except ImportError as error:  # pragma: no cover - only while magfit.export is being written
        raise OptionError(f"firmware exports are not available in this installation ({error})") from None
    return list(FORMATS)


#: What to do with rows holding NaN or inf, the --nonfinite option of every command that reads samples.
NONFINITE_CHOICES = ("skip", "error")
nonfinite_option = click.option(
    "--nonfinite",
    type=click.Choice(NONFINITE_CHOICES),
    default="skip",
    show_default=True,
    help="Rows with NaN or inf: skip them (with a warning) or refuse the file.",
)


def parse_columns(ctx: click.Context, param: click.Parameter, value: str | None) -> list[str | int] | None:
    """``--columns mx,my,mz`` or ``--columns 0,1,2`` (0-based) into three names or indices; ``--columns mag``,
    one name, is the (N, 3) array of an .npz archive."""
    if value is None:
        return None
    items = [item.strip() for item in value.split(",")]
    if len(items) == 1 and items[0] and not items[0].isdigit():
        return [items[0]]
    if len(items) != 3 or not all(items):
        raise click.BadParameter(
            f"expected three comma-separated column names or 0-based numbers (x,y,z), or the name of an .npz "
            f"file's (N, 3) array, got {value!r}",
            ctx,
            param,
        )
    return [int(item) if item.isdigit() else item for item in items]


def parse_stream(ctx: click.Context, param: click.Parameter, value: str | None) -> list[str | int] | None:
    """``--attitude roll,pitch,yaw`` or ``--gyro 7,8,9`` (0-based, as --columns) into names or indices."""
    if value is None:
        return None
    items = [item.strip() for item in value.split(",")]
    if not all(items):
        raise click.BadParameter(f"expected comma-separated column names or 0-based numbers, got {value!r}", ctx, param)
    return [int(item) if item.isdigit() else item for item in items]


def float_list(count: int) -> Callable[[click.Context, click.Parameter, str | None], list[float] | None]:
    """A callback that parses ``count`` comma-separated numbers (``--offset -91.5,104,-274``)."""

    def parse(ctx: click.Context, param: click.Parameter, value: str | None) -> list[float] | None:
        if value is None:
            return None
        items = value.replace(";", ",").split(",")
        try:
            numbers = [float(item) for item in items]
        except ValueError:
            raise click.BadParameter(f"expected {count} comma-separated numbers, got {value!r}", ctx, param) from None
        if len(numbers) != count:
            raise click.BadParameter(f"expected {count} comma-separated numbers, got {len(numbers)}", ctx, param)
        if not all(np.isfinite(numbers)):
            raise click.BadParameter(f"the numbers must be finite, got {value!r}", ctx, param)
        return numbers

    return parse


def columns_text(columns: Sequence[object]) -> str:
    """Column names or indices as ``mx, my, mz``."""
    return ", ".join(str(column) for column in columns)


def same_file(first: Path, second: Path) -> bool:
    """True when both paths name the same file (also through links, or before either exists)."""
    try:
        if first.exists() and second.exists():
            return os.path.samefile(first, second)
    except OSError:
        pass
    # realpath, not resolve(): a symbolic link loop is no error here (check_output names it).
    return os.path.realpath(first) == os.path.realpath(second)


def refuse_overwriting_input(output: Path, inputs: Iterable[Path]) -> None:
    """Stop with a usage error when ``output`` is one of ``inputs`` (it would clobber the data)."""
    for source in inputs:
        if same_file(output, source):
            fail(f"the output {output} is the input file {source}; write to another path")
