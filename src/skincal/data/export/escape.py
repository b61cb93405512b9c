"""User text made safe for each export format by construction: numbers as exact literals, one-line
messages, XML comments, xacro attribute text, Python literals, CSV cells (the package docstring,
"Escaping by construction")."""

from __future__ import annotations

import ast
import json
import re
import xml.etree.ElementTree as ET
from typing import Any

from skincal.names import printable


def num(x: float) -> str:
    return repr(float(x) + 0.0)  # + 0.0: no "-0.0"


def nums(values) -> str:
    return " ".join(num(v) for v in values)


# ---------------------------------------------------------------------- names and escaping
def shown(text: str) -> str:
    """``text`` for a one-line message (:func:`printable`)."""
    return printable(text)


def comment_literal(text: str) -> str:
    """``text`` as a JSON string literal that can stand inside an XML (and xacro) comment: ASCII
    only (control characters and lone surrogates escaped), every ``-`` written ``\\u002d`` (no
    ``--`` and no trailing ``-``) and every ``$`` written ``\\u0024``; ``json.loads`` gives ``text``
    back."""
    return json.dumps(str(text), ensure_ascii=True).replace("-", "\\u002d").replace("$", "\\u0024")


def xml_comment(text: str) -> ET.Element[Any]:
    if "--" in text or text.endswith("-"):  # pragma: no cover - fixed text and comment_literal only
        raise AssertionError("an XML comment cannot hold '--'")
    return ET.Comment(f" {text} ")


def xacro_text(text: str) -> str:
    """``text`` as literal xacro attribute text: xacro reads ``${...}`` and ``$(...)`` as
    expressions and drops one ``$`` of a run of ``$`` before ``{`` or ``(``, so such a run gets one
    more ``$``."""
    return re.sub(r"\$+(?=[{(])", lambda m: "$" + m.group(0), text)


def py_literal(value: object) -> str:
    """``value`` (plain strings, numbers, lists, tuples and dicts of them) as a Python literal: its
    :func:`repr`, checked to read back equal with :func:`ast.literal_eval`."""
    text = repr(value)
    if ast.literal_eval(text) != value:  # pragma: no cover - repr of plain data always reads back
        raise AssertionError(f"not a plain literal: {text}")
    return text


_FORMULA_START = ("=", "+", "-", "@", "\t", "\r")


def csv_cell(text: str) -> str:
    """A CSV text cell a spreadsheet will not run as a formula: a leading ``'`` when ``text``
    starts with ``=``, ``+``, ``-``, ``@``, tab or CR."""
    return "'" + text if text.startswith(_FORMULA_START) else text


# ---------------------------------------------------------------------- YAML, JSON, CSV
def plain_float(value: float) -> float:
    return float(value) + 0.0  # + 0.0: no "-0.0"
