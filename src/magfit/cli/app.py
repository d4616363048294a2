"""The ``magfit`` group, its error boundary and :func:`main` (the package docstring gives the exit statuses)."""

from __future__ import annotations

import contextlib
import importlib
import os
import signal
import sys
from collections.abc import Iterator, Sequence
from types import FrameType
from typing import Any

import click

from .. import __version__
from ..remedy import for_command_line
from ._common import CommandError, as_command_error

__all__ = ["MagfitGroup", "cli", "main"]


class Terminated(BaseException):
    """SIGTERM or SIGHUP, raised where the program is so that every cleanup (temporary files) runs."""

    def __init__(self, signum: int) -> None:
        super().__init__(signum)
        self.signum = signum


def _interrupted(error: BaseException) -> click.exceptions.Exit:
    """The exit of an interrupted command: one line on stderr, status 130 or 128 + the signal number."""
    if isinstance(error, Terminated):
        name, status = signal.Signals(error.signum).name, 128 + error.signum
    else:
        name, status = "SIGINT", 128 + signal.SIGINT
    click.echo(f"magfit: interrupted ({name}); existing files are left as they were", err=True)
    return click.exceptions.Exit(status)


def _closed_pipe() -> click.exceptions.Exit:
    """The quiet end of a command whose standard output was closed by its reader, as a Unix tool's: no message,
    status 141 (128 + SIGPIPE, what a shell reports for ``cat big | head``). Standard output is pointed at
    the null device so that the interpreter's last flush cannot fail again on the way out."""
    try:
        null = os.open(os.devnull, os.O_WRONLY)
        os.dup2(null, sys.stdout.fileno())
        os.close(null)
    except (OSError, ValueError, AttributeError):  # no real descriptor (a test's captured stdout)
        pass
    return click.exceptions.Exit(128 + getattr(signal, "SIGPIPE", 13))


class MagfitGroup(click.Group):
    """A click group that reports errors as ``magfit: error: <message>`` with magfit's exit statuses."""

    def make_context(
        self, info_name: str | None, args: list[str], parent: click.Context | None = None, **extra: Any
    ) -> click.Context:
        try:
            return super().make_context(info_name, args, parent=parent, **extra)
        except click.exceptions.NoArgsIsHelpError:
            raise
        except click.UsageError as error:
            raise as_command_error(error) from None

    def list_commands(self, ctx: click.Context) -> list[str]:
        return sorted({*self.commands, *COMMANDS})

    def get_command(self, ctx: click.Context, cmd_name: str) -> click.Command | None:
        return _lazy_command(self, cmd_name)

    def invoke(self, ctx: click.Context) -> Any:
        try:
            with for_command_line():  # the library's messages name remedies as this command's options
                return super().invoke(ctx)
        except (click.exceptions.Exit, click.Abort, CommandError, click.exceptions.NoArgsIsHelpError):
            raise
        except (KeyboardInterrupt, Terminated) as error:  # click would turn Ctrl-C into "Aborted!", status 1
            raise _interrupted(error) from None
        except BrokenPipeError:  # the reader of standard output is gone (magfit apply ... -o - | head)
            raise _closed_pipe() from None
        except Exception as error:
            if ctx.params.get("debug"):
                raise
            raise as_command_error(error) from None


@click.group("magfit", cls=MagfitGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, "-V", "--version", prog_name="magfit")
@click.option("--debug", is_flag=True, help="Show the full traceback of any error (for bug reports).")
def cli(debug: bool) -> None:
    """Calibrate magnetometers: hard- and soft-iron fits, the paper's comparison, firmware exports.

    Every calibration is applied one way: corrected = matrix @ (raw - offset).

    \b
    Start with:
      magfit demo                              the paper's experiment on simulated sensors
      magfit calibrate mag.csv -o cal.json     fit a recording, save the calibration
      magfit compare mag.csv                   the paper's three methods side by side
    """


#: The commands: each is ``<name>_command`` in the module ``magfit.cli.<name>``, imported only when it runs
#: (or when ``--help`` lists them), so that one command does not pay for the others' imports.
COMMANDS = (
    "demo",
    "calibrate",
    "compare",
    "apply",
    "simulate",
    "plot",
    "report",
    "live",
    "inspect",
    "align",
    "fleet",
)


def _lazy_command(group: click.Group, name: str) -> click.Command | None:
    """The command ``name`` of ``group``, imported and added on first use."""
    if name not in group.commands and name in COMMANDS:
        module = importlib.import_module(f"{__package__}.{name}")
        group.add_command(getattr(module, f"{name}_command"))
    return group.commands.get(name)


@contextlib.contextmanager
def _termination_as_exception() -> Iterator[None]:
    """SIGTERM and SIGHUP raise :class:`Terminated` while the command runs (by default they kill the process
    before the temporary file of an output can be removed); the previous handlers come back afterwards."""

    def handler(signum: int, frame: FrameType | None) -> None:
        raise Terminated(signum)

    previous = {}
    try:
        for number in (signal.SIGTERM, getattr(signal, "SIGHUP", None)):
            if number is not None:
                previous[number] = signal.signal(number, handler)
    except ValueError:  # not the main thread: signals cannot be handled here
        pass
    try:
        yield
    finally:
        for number, old in previous.items():
            signal.signal(number, old)


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line on ``argv`` (default: ``sys.argv[1:]``) and return the exit status."""
    try:
        with _termination_as_exception():
            cli.main(args=list(argv) if argv is not None else None, prog_name="magfit")
    except SystemExit as stop:
        if stop.code is None:
            return 0
        return stop.code if isinstance(stop.code, int) else 1
    except (KeyboardInterrupt, Terminated) as error:  # while parsing, before a command runs
        return _interrupted(error).exit_code
    return 0
