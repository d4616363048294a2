"""Library messages as the command line shows them.

The library speaks Python (``method='auto'``) and lists one reason per model it tried; the command line
rewrites that at its boundary (``_common.option_wording``), without changing the library's messages:

- :func:`collapse_repeats`: ``sphere: <reason>; diag: <the same reason>`` becomes ``sphere: <reason>;
  diag: as sphere``;
- :func:`unquoted_alternatives`: ``--method auto (or 'ml', 'als')`` becomes ``--method auto (or ml, als)``;
- :func:`without_own_advice`: a suggestion to use the method that was used is dropped (``prefer
  method='auto' (or 'ml', 'als')`` after an ``auto`` fit becomes ``prefer method='ml' (or 'als')``).
"""

from __future__ import annotations

import re
from collections.abc import Sequence

__all__ = ["collapse_repeats", "columns_used", "unquoted_alternatives", "without_own_advice"]

#: The names a refusal lists its reasons by: the models auto chooses among, and the methods.
_NAMES = ("sphere", "diag", "full", "ellipsoid", "minmax", "als", "ml", "robust", "auto")
#: Where one ``name: reason`` item of such a list starts (after the message's lead or the previous item).
_ITEM_START = re.compile(rf"(?:(?<=: )|(?<=; ))({'|'.join(_NAMES)}): ")
#: ``--method auto (or 'ml', 'als')`` once the keyword has become an option.
_ALTERNATIVES = re.compile(r"(--[a-z-]+ [\w.-]+) \(or ('[\w.-]+'(?:, '[\w.-]+')*)\)")
#: ``prefer method='auto' (or 'ml', 'als')`` and ``use method='als'``.
_ADVICE = re.compile(
    r"(?P<verb>prefer|use) method='(?P<first>[a-z_]+)'(?: \(or (?P<others>'[a-z_]+'(?:, '[a-z_]+')*)\))?"
)


def collapse_repeats(message: str) -> str:
    """Replace each ``name: reason`` item whose reason repeats an earlier one (its own name aside) by ``name: as
    <earlier name>``: a refusal listing several models does not repeat a long reason word for word."""
    starts = list(_ITEM_START.finditer(message))
    if len(starts) < 2:
        return message
    pieces = [message[: starts[0].start()]]
    seen: dict[str, str] = {}
    for index, start in enumerate(starts):
        end = starts[index + 1].start() if index + 1 < len(starts) else len(message)
        item = message[start.start() : end]
        name = start.group(1)
        reason = item[len(start.group(0)) :]
        tail = "; " if reason.endswith("; ") else ""
        key = re.sub(rf"\b{re.escape(name)}\b", "\0", reason.removesuffix("; "))
        if len(key) >= 60 and key in seen:
            item = f"{name}: as {seen[key]}{tail}"
        else:
            seen.setdefault(key, name)
        pieces.append(item)
    return "".join(pieces)


def unquoted_alternatives(message: str) -> str:
    """``--method auto (or 'ml', 'als')`` -> ``--method auto (or ml, als)``: an option's other values as typed."""
    return _ALTERNATIVES.sub(lambda match: f"{match.group(1)} (or {match.group(2).replace(chr(39), '')})", message)


def without_own_advice(message: str, method: str) -> str:
    """``message`` without a suggestion to use ``method``, the method that was used (advice it already took)."""

    def advice(match: re.Match[str]) -> str:
        names = [match.group("first"), *re.findall(r"'([a-z_]+)'", match.group("others") or "")]
        rest = [name for name in names if name != method]
        if len(rest) == len(names):
            return match.group(0)
        if not rest:
            return ""
        others = f" (or {', '.join(repr(name) for name in rest[1:])})" if len(rest) > 1 else ""
        return f"{match.group('verb')} method={rest[0]!r}{others}"

    text = _ADVICE.sub(advice, message)
    # A clause emptied of its advice leaves "…; " or ", or " behind.
    text = re.sub(r"(;|,)\s*(or\s*)?(?=$|;)", "", text).rstrip(" ;,:")
    return text


def columns_used(columns: Sequence[object], note: str | None = None) -> str:
    """``columns column 2, column 3, column 4; column 1 is monotonic: time or a counter``: which columns a
    message is about, and for a file without a header why (every message about a fit names them)."""
    return "columns " + ", ".join(str(column) for column in columns) + (f"; {note}" if note else "")
