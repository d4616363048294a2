"""Library messages as the command line shows them.

The library speaks Python (``method='auto'``) and lists one reason per model it tried; the command line
rewrites that at its boundary (``_common.option_wording``), without changing the library's messages:

- :func:`collapse_repeats`: ``sphere: <reason>; diag: <the same reason>`` becomes ``sphere: <reason>;
  diag: as sphere`` (and ``the diag model: ...`` likewise);
- :func:`after_keywords`: once ``name='value'`` is ``--name value``, flags are named
  (``allow_undetermined=True`` -> ``--force``) and an option's alternatives unquoted
  (:func:`unquoted_alternatives`: ``--method auto (or 'ml', 'als')`` -> ``--method auto (or ml, als)``);
- :func:`without_own_advice`: a suggestion to use the method that was used is dropped (``prefer
  method='auto' (or 'ml', 'als')`` after an ``auto`` fit becomes ``prefer method='ml' (or 'als')``);
- :func:`columns_used`: the columns a message is about (every message about a fit names them).
"""

from __future__ import annotations

import re
from collections.abc import Sequence

__all__ = ["after_keywords", "collapse_repeats", "columns_used", "unquoted_alternatives", "without_own_advice"]

#: The names a refusal lists its reasons by: the models auto chooses among, and the methods.
_NAMES = ("sphere", "diag", "full", "ellipsoid", "minmax", "als", "ml", "robust", "auto")
#: Where one item of such a list starts: ``sphere: `` or ``the sphere model: ``, at a clause's start or
#: after the message's lead (``no model could be fitted: sphere: ...``).
_ITEM = re.compile(rf"(?:^|(?<=: ))((?:the )?({'|'.join(_NAMES)})(?: model)?): ")
#: Shorter clauses are said again rather than referred to.
_MIN_REPEAT = 30
#: ``--method auto (or 'ml', 'als')`` once the keyword has become an option.
_ALTERNATIVES = re.compile(r"(--[a-z-]+ [\w.-]+) \(or ('[\w.-]+'(?:, '[\w.-]+')*)\)")
#: ``prefer method='auto' (or 'ml', 'als')`` and ``use method='als'``.
_ADVICE = re.compile(
    r"(?P<verb>prefer|use) method='(?P<first>[a-z_]+)'(?: \(or (?P<others>'[a-z_]+'(?:, '[a-z_]+')*)\))?"
)


def collapse_repeats(message: str) -> str:
    """Say each reason of a refusal once: in a list of items (``sphere: <reasons>; diag: <reasons>`` or ``the
    sphere model: ...``), a clause (between ``; ``) that an earlier item already gave, the item's own name
    aside, becomes ``as <that item>`` (``diag: as sphere``), said once for consecutive such clauses."""
    out: list[str] = []
    seen: dict[str, str] = {}  # a clause, its item's name blanked -> the item that gave it first
    item: str | None = None  # the item the clauses belong to (None before the list starts)
    name = ""
    referred: str | None = None  # the item the last clause written referred to
    for clause in message.split("; "):
        marker = _ITEM.search(clause)
        head, body = "", clause
        if marker is not None:
            item, name = marker.group(1), marker.group(2)
            head, body = clause[: marker.end()], clause[marker.end() :]
            referred = None
        key = re.sub(rf"\b{re.escape(name)}\b", "\0", body) if name else body
        first = seen.get(key)
        if item is not None and first is not None and first != item and len(body) >= _MIN_REPEAT:
            if head:
                out.append(f"{head}as {first}")
            elif referred != first:
                out.append(f"as {first}")
            referred = first
            continue
        if item is not None:
            seen.setdefault(key, item)
        out.append(clause)
        referred = None
    return "; ".join(out)


#: Library keywords whose command-line form is a flag.
_FLAGS = {"allow_undetermined=True": "--force", "even=True": "--even"}


def after_keywords(message: str) -> str:
    """The last touches once ``name='value'`` hints are options: flags named (``allow_undetermined=True`` ->
    ``--force``), an option's alternatives unquoted."""
    for keyword, flag in _FLAGS.items():
        message = message.replace(keyword, flag)
    return unquoted_alternatives(message)


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
