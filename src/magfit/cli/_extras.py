"""Optional dependencies (extras) of the commands: checked before a command writes anything.

A command that draws (``plot``, ``report``, ``calibrate --plot``, ``demo --report``) calls :func:`require`
first, so that a missing extra stops it with one line naming the install command, exit status 2, before
any file is written; :func:`hint_for` turns an ImportError that still reaches the command line's
boundary into the same line instead of "a bug in magfit".
"""

from __future__ import annotations

import importlib

import click

__all__ = ["EXTRAS", "hint_for", "missing", "require", "require_message"]

#: The importable modules each extra provides (pyproject.toml's optional dependencies).
EXTRAS: dict[str, tuple[str, ...]] = {
    "cli": ("click", "rich", "pandas"),
    "plot": ("matplotlib", "plotly"),
    "zstd": ("zstandard",),
    "dask": ("dask",),
}
#: What each module is for, in the messages.
_PURPOSE = {"matplotlib": "figures", "plotly": "the HTML report", "zstandard": ".zst files", "pandas": "text files"}


def install_hint(extra: str) -> str:
    """The install command of ``extra``, quoted for any shell."""
    return f"pip install 'magfit[{extra}]'"


def missing(extra: str, modules: tuple[str, ...] | None = None) -> str | None:
    """The first module of ``extra`` (or of ``modules``) that cannot be imported, or None when all can."""
    for name in modules or EXTRAS[extra]:
        try:
            importlib.import_module(name)
        except ImportError:
            return name
    return None


def require_message(extra: str, what: str, modules: tuple[str, ...] | None = None) -> str | None:
    """None when ``extra`` is installed; else the one-line error for ``what`` (``"magfit plot"``) without it."""
    absent = missing(extra, modules)
    if absent is None:
        return None
    return f"{what} needs {absent}, which is not installed (the {extra} extra): {install_hint(extra)}"


def require(extra: str, what: str, modules: tuple[str, ...] | None = None) -> None:
    """Stop with :func:`require_message` (``magfit: error: ...``, exit status 2) when ``extra`` is missing."""
    message = require_message(extra, what, modules)
    if message is not None:
        raise click.ClickException(message)


def hint_for(error: ImportError) -> str | None:
    """The one-line install hint for an ImportError of an extra's module, or None when it is not one."""
    name = (getattr(error, "name", None) or "").split(".")[0]
    for extra, modules in EXTRAS.items():
        if name in modules:
            purpose = f" for {_PURPOSE[name]}" if name in _PURPOSE else ""
            return f"{name} is not installed (the {extra} extra{purpose}): {install_hint(extra)}"
    text = str(error)
    if "pip install 'magfit[" in text:  # the library's own hints (readers without pandas, .zst without zstandard)
        return " ".join(text.split())
    return None
