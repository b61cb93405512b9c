"""One rule for the names users and devices give things (units, robots, methods, links).

Names are free strings in the contract (``su1``, ``forearm_left``, ``Unterarm-links``), so this
module does not restrict the alphabet; it refuses only what no reader or writer can carry safely:
an empty name, ``/`` (an HDF5 path separator), ``.``/``..``, control characters (ESC sequences and
newlines reach terminals and split one-line messages; NUL ends C strings), leading or trailing
white space, and more than :data:`MAX_NAME_CHARS` characters. Everything else is escaped where it
is written (an XML library for URDF/launch XML, data literals for code, formula neutralisation for
CSV): see :mod:`skincal.data.export`.

The dataset reader, the result reader and the hardware receiver all call :func:`name_problem`, so a
name is accepted or refused the same way wherever it enters.
"""

from __future__ import annotations

import re
import unicodedata

MAX_NAME_CHARS = 128
"""Longest accepted name, in characters."""


def _is_control(ch: str) -> bool:
    # Cc: C0/C1 controls (ESC, NUL, newline, DEL ...); Cf: format characters such as the bidi
    # overrides (U+202E) that make a terminal show text in another order than it is stored;
    # Zl/Zp: line and paragraph separators; Cs: lone surrogates and the non-characters U+FFFE and
    # U+FFFF, which neither UTF-8 nor an XML document can carry.
    return unicodedata.category(ch) in ("Cc", "Cf", "Zl", "Zp", "Cs") or ch in "\ufffe\uffff"


def name_problem(name: object) -> str | None:
    """Why ``name`` is not an acceptable name, or ``None`` when it is."""
    if not isinstance(name, str):
        return f"is a {type(name).__name__}, not a string"
    if not name:
        return "is empty"
    if len(name) > MAX_NAME_CHARS:
        return f"has {len(name)} characters (at most {MAX_NAME_CHARS})"
    if name in (".", ".."):
        return "is '.' or '..'"
    if "/" in name:
        return "contains '/'"
    if any(_is_control(ch) for ch in name):
        return "contains a control character (or one UTF-8 and XML cannot carry)"
    if name != name.strip():
        return "starts or ends with white space"
    return None


LONG_WORD = 240
"""A one-line message shows a run of non-space characters longer than this (a 5000-character name or
path echoed back) shortened in its middle by :func:`shortened`."""
_LONG_WORD = re.compile(rf"\S{{{LONG_WORD + 1},}}")


def shortened(text: str) -> str:
    """``text`` with every run of non-space characters longer than :data:`LONG_WORD` cut in its middle
    (``aaaa...[4870 characters]...aaaa``), so that an echoed input never buries the reason after it."""

    def cut(m: re.Match[str]) -> str:
        word = m.group(0)
        head, tail = 120, 60
        return f"{word[:head]}...[{len(word) - head - tail} characters]...{word[-tail:]}"

    return _LONG_WORD.sub(cut, text)


def printable(text: str) -> str:
    """``text`` with every control character shown as an escape (``\\x1b``, ``\\n``, ``\\u202e``),
    for terminals and one-line messages; printable text is returned unchanged."""
    if not any(_is_control(ch) for ch in text):
        return text
    return "".join(ch.encode("unicode_escape").decode("ascii") if _is_control(ch) else ch for ch in text)
