"""How the command line names the columns a message is about (:func:`columns_used`).

The library's messages reach the terminal as they are: a remedy is said in the command line's words where it
is built (:mod:`magfit.remedy`), and a list of models' reasons says each once where it is listed
(:func:`magfit.findings.said_once`). Nothing here rewrites them.
"""

from __future__ import annotations

from collections.abc import Sequence

__all__ = ["columns_used"]


def columns_used(columns: Sequence[object], note: str | None = None) -> str:
    """``columns column 2, column 3, column 4; column 1 is monotonic: time or a counter``: which columns a
    message is about, and for a file without a header why (every message about a fit names them)."""
    return "columns " + ", ".join(str(column) for column in columns) + (f"; {note}" if note else "")
