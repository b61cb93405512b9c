"""Reading the JSON and YAML files users hand to skincal, trusting nothing about them.

One place for the guards every such reader needs (result files, chain files, links files, topic
maps, trajectory files), so each reader only checks its own fields:

* the path must name a regular file (checked with ``stat`` before it is opened: ``/dev/zero`` would
  read forever and a FIFO would block), at most :data:`MAX_TEXT_BYTES` long;
* the text must be UTF-8;
* nesting at most :data:`MAX_DEPTH` levels (Python's parsers recurse: a file nested 100,000 deep
  otherwise ends in ``RecursionError``), counted before JSON is parsed;
* JSON: no duplicate keys (which one would win is parser-dependent), no ``NaN``/``Infinity``
  literals, no number that overflows a float (``1e400``), no integer of more than
  :data:`MAX_INT_DIGITS` digits;
* YAML: no duplicate keys, no anchors or aliases (``&a``/``*a``: an alias bomb expands
  exponentially in whatever walks the document).

Every problem raises the caller's error class (``DatasetError`` for data files, ``ConfigError``
for configuration) with one line ``<path>: <problem>``.
"""

from __future__ import annotations

import math
import os
import re
import stat
from pathlib import Path
from typing import Any

import numpy as np

from skincal.errors import DatasetError, SkincalError
from skincal.io.files import regular_file

MAX_TEXT_BYTES = 64 * 2**20
"""Largest JSON/YAML file read, bytes (64 MiB; skincal's own files are a few kB)."""
MAX_DEPTH = 64
"""Deepest nesting of arrays/objects (JSON) or sequences/mappings (YAML) accepted."""
MAX_INT_DIGITS = 40
"""Longest integer literal accepted in JSON, digits."""

def read_bytes(
    path: str | Path, what: str = "file", error: type[SkincalError] = DatasetError, max_bytes: int = MAX_TEXT_BYTES
) -> bytes:
    """The bytes of the regular file ``path`` (:func:`regular_file`), at most ``max_bytes`` of them."""
    size = regular_file(path, what, error)
    if size > max_bytes:
        raise error(f"{path}: is {size} bytes; a {what} may have at most {max_bytes} bytes")
    try:
        # O_NONBLOCK: should the path be swapped for a FIFO after the check, opening does not block
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_CLOEXEC", 0))
    except OSError as exc:
        raise error(f"{path}: cannot read {what} ({exc.strerror or exc})") from None
    with os.fdopen(fd, "rb") as fh:
        if not stat.S_ISREG(os.fstat(fh.fileno()).st_mode):
            raise error(f"{path}: is not a regular file, expected a {what}")
        try:
            data = fh.read(max_bytes + 1)
        except OSError as exc:
            raise error(f"{path}: cannot read {what} ({exc.strerror or exc})") from None
    if len(data) > max_bytes:
        raise error(f"{path}: a {what} may have at most {max_bytes} bytes")
    return data


def read_text(
    path: str | Path, what: str = "file", error: type[SkincalError] = DatasetError, max_bytes: int = MAX_TEXT_BYTES
) -> str:
    """The UTF-8 text of the regular file ``path`` (:func:`read_bytes`)."""
    try:
        return read_bytes(path, what, error, max_bytes).decode("utf-8")
    except UnicodeDecodeError as exc:
        raise error(f"{path}: not a text file (not valid UTF-8 at byte {exc.start})") from None


# ---------------------------------------------------------------------- JSON
_JSON_STRING = re.compile(r'"(?:[^"\\]|\\.)*"', re.DOTALL)
_DEPTH_CHUNK = 1 << 20


def json_depth(text: str) -> int:
    """Deepest nesting of ``[``/``{`` in JSON ``text``, brackets inside strings not counted
    (without recursion: works on any input, valid JSON or not)."""
    stripped = _JSON_STRING.sub("", text).encode("utf-8")
    depth = deepest = 0
    for start in range(0, len(stripped), _DEPTH_CHUNK):
        b = np.frombuffer(stripped, dtype=np.uint8, count=min(_DEPTH_CHUNK, len(stripped) - start), offset=start)
        step = ((b == 0x5B) | (b == 0x7B)).astype(np.int32) - ((b == 0x5D) | (b == 0x7D)).astype(np.int32)
        if not step.any():
            continue
        running = depth + np.cumsum(step)
        deepest = max(deepest, int(running.max()))
        depth = int(running[-1])
    return deepest


class _Refused(Exception):
    """A problem found by a parser hook; carries the message."""


def _pairs(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for key, value in pairs:
        if key in out:
            shown = key if len(key) <= 40 else key[:37] + "..."
            raise _Refused(f"has the key {shown!r} twice in one object")
        out[key] = value
    return out


def _constant(name: str) -> Any:
    raise _Refused(f"contains {name}, which is not valid JSON (use null)")


def _float(text: str) -> float:
    value = float(text)
    if not math.isfinite(value):
        raise _Refused(f"contains the number {text[:40]}, which is out of range for a float")
    return value


def _int(text: str) -> int:
    if len(text.lstrip("-")) > MAX_INT_DIGITS:
        raise _Refused(f"contains an integer of {len(text.lstrip('-'))} digits (at most {MAX_INT_DIGITS})")
    return int(text)


def parse_json(text: str, source: str, error: type[SkincalError] = DatasetError) -> Any:
    """Parse JSON ``text`` with the guards of this module; ``source`` starts every message."""
    import json

    depth = json_depth(text)
    if depth > MAX_DEPTH:
        raise error(f"{source}: nested {depth} levels deep (at most {MAX_DEPTH})")
    try:
        return json.loads(text, object_pairs_hook=_pairs, parse_constant=_constant, parse_float=_float, parse_int=_int)
    except _Refused as exc:
        raise error(f"{source}: {exc}") from None
    except json.JSONDecodeError as exc:
        raise error(f"{source}: not valid JSON (line {exc.lineno}, column {exc.colno}: {exc.msg})") from None
    except (RecursionError, ValueError) as exc:  # guards above should make these unreachable
        why = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise error(f"{source}: not valid JSON ({why})") from None


def load_json(path: str | Path, what: str = "JSON file", error: type[SkincalError] = DatasetError) -> Any:
    """Read and parse the JSON file ``path`` (regular file, size, UTF-8, depth, keys, numbers)."""
    return parse_json(read_text(path, what, error), str(path), error)


# ---------------------------------------------------------------------- YAML
_EXPONENT_FLOAT = re.compile(r"^[-+]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)[eE][-+]?[0-9]+$")
"""A float with an exponent and no dot (``5e-2``, ``-1E3``), YAML 1.2's core schema."""

def _strict_loader() -> type:
    import yaml

    class StrictLoader(yaml.SafeLoader):
        """``yaml.SafeLoader`` without aliases and duplicate keys, nesting limited to :data:`MAX_DEPTH`."""

        _depth = 0

        def compose_node(self, parent: Any, index: Any) -> Any:
            if self.check_event(yaml.AliasEvent):
                mark = self.peek_event().start_mark
                raise _Refused(f"uses a YAML alias (line {mark.line + 1}); anchors and aliases are not supported")
            self._depth += 1
            try:
                if self._depth > MAX_DEPTH:
                    mark = self.peek_event().start_mark
                    raise _Refused(f"is nested more than {MAX_DEPTH} levels deep (line {mark.line + 1})")
                return super().compose_node(parent, index)
            finally:
                self._depth -= 1

        def construct_mapping(self, node: Any, deep: bool = False) -> Any:
            seen: set = set()
            for key_node, _ in node.value:
                key = self.construct_object(key_node, deep=True)
                try:
                    duplicate = key in seen
                    seen.add(key)
                except TypeError:  # unhashable keys are the safe constructor's to refuse
                    continue
                if duplicate:
                    shown = repr(key) if len(repr(key)) <= 40 else repr(key)[:37] + "..."
                    raise _Refused(f"has the key {shown} twice in one mapping (line {key_node.start_mark.line + 1})")
            return super().construct_mapping(node, deep=deep)

    # YAML 1.1's float needs a dot ("5e-2" stayed the string '5e-2'); YAML 1.2 and JSON read it as 0.05.
    # Added after the 1.1 resolvers, so "1_000" stays an int and "1.5" a float as before.
    StrictLoader.add_implicit_resolver(
        "tag:yaml.org,2002:float", _EXPONENT_FLOAT, list("-+0123456789.")
    )
    return StrictLoader


def parse_yaml(text: str, source: str, error: type[SkincalError] = DatasetError) -> Any:
    """Parse YAML (or JSON) ``text`` safely with the guards of this module."""
    import yaml

    try:
        return yaml.load(text, Loader=_strict_loader())  # noqa: S506 - a SafeLoader subclass
    except _Refused as exc:
        raise error(f"{source}: {exc}") from None
    except yaml.YAMLError as exc:
        raise error(f"{source}: not valid YAML/JSON ({str(exc).splitlines()[0]})") from None
    except RecursionError:
        raise error(f"{source}: is nested too deeply") from None


def load_yaml(path: str | Path, what: str = "YAML file", error: type[SkincalError] = DatasetError) -> Any:
    """Read and parse the YAML (or JSON) file ``path`` (regular file, size, UTF-8, depth, keys, no aliases)."""
    return parse_yaml(read_text(path, what, error), str(path), error)
