"""A command's advice in its own options: the remedies it lacks said through the command that has them."""

from __future__ import annotations

import contextlib
from collections.abc import Iterator, Mapping
from pathlib import Path

import click

from ..remedy import for_command


def flags_of(command: click.Command) -> frozenset[str]:
    """The long options a click command takes (``--columns``, ``--force`` ...)."""
    return frozenset(
        name for parameter in command.params for name in (*parameter.opts, *parameter.secondary_opts)
        if name.startswith("--")
    )  # fmt: skip


@contextlib.contextmanager
def own_options(
    ctx: click.Context, *, renamed: Mapping[str, str] | None = None, file: Path | str = "FILE"
) -> Iterator[None]:
    """Inside, the library's remedies name this command's options, or ``magfit calibrate FILE --option``
    for one it lacks (:func:`magfit.remedy.for_command`)."""
    with for_command(ctx.info_name or ctx.command.name or "", flags_of(ctx.command), renamed=renamed, file=file):
        yield
