"""A calibration method's options: a frozen dataclass, parsed and checked in one place.

Each method declares its options as a frozen dataclass whose fields are ``bool``, ``int`` or
``float`` with a default (``MethodSpec.options``); :func:`parse_options` builds it from
``calibrate(..., **options)`` or from the CLI's ``--option key=value`` strings. An unknown name, a
value of the wrong type (``scale="false"`` is refused rather than read as ``True``), a non-finite
number or one outside the field's ``metadata`` bounds (``{"min": 0}``, ``{"max": 1}``) is a one-line
:class:`~skincal.errors.ConfigError` naming the method and the option, for every method alike.
"""

from __future__ import annotations

import dataclasses
import math
import typing
from collections.abc import Mapping
from typing import Any, TypeVar

from skincal.errors import ConfigError

T = TypeVar("T")

_TRUE = ("true", "yes", "on", "1")
_FALSE = ("false", "no", "off", "0")


class NoOptions:
    """The options of a method that takes none."""


INT_OPTION_MAX = 2**31 - 1
"""Largest magnitude of an integer option (the optimisers take C ``int``)."""


def _coerce(method: str, name: str, kind: type, value: object) -> bool | int | float:
    where = f"method '{method}': option {name}"
    if kind is bool:
        if isinstance(value, bool):
            return value
        if isinstance(value, str) and value.strip().lower() in _TRUE + _FALSE:
            return value.strip().lower() in _TRUE
        raise ConfigError(f"{where} expects true or false, got {value!r}")
    if isinstance(value, bool):  # True is an int to Python, not to a user
        raise ConfigError(f"{where} expects a number, got {value!r}")
    try:
        number = kind(value) if not isinstance(value, str) else kind(value.strip())
    except (TypeError, ValueError):
        raise ConfigError(f"{where} expects {'an integer' if kind is int else 'a number'}, got {value!r}") from None
    if kind is int and isinstance(value, float) and not value.is_integer():
        raise ConfigError(f"{where} expects an integer, got {value!r}")
    if not math.isfinite(number):
        raise ConfigError(f"{where} must be finite, got {value!r}")
    if kind is int and abs(number) > INT_OPTION_MAX:  # the optimisers take C ints
        raise ConfigError(f"{where} must be at most {INT_OPTION_MAX} in magnitude, got {value!r}")
    return number


def parse_options(cls: type[T], options: Mapping[str, object], method: str) -> T:
    """Build the options dataclass ``cls`` of ``method`` from ``options`` (see module docstring)."""
    if cls is NoOptions:
        if options:
            raise ConfigError(f"method '{method}' takes no options, got {', '.join(sorted(options))}")
        return cls()
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls)}  # type: ignore[arg-type]
    unknown = sorted(set(options) - set(fields))
    if unknown:
        raise ConfigError(f"unknown option(s) {', '.join(unknown)} for method '{method}' (known: {', '.join(fields)})")
    values: dict[str, Any] = {}
    for name, value in options.items():
        field = fields[name]
        number = _coerce(method, name, hints[name], value)
        low, high = field.metadata.get("min"), field.metadata.get("max")
        if (low is not None and number < low) or (high is not None and number > high):
            if high is None:
                bounds = "non-negative" if low == 0 else f"at least {low}"
            else:
                bounds = f"in [{low}, {high}]" if low is not None else f"at most {high}"
            raise ConfigError(f"method '{method}': option {name} must be {bounds}, got {value!r}")
        values[name] = number
    return cls(**values)


def parse_option_strings(items: list[str]) -> dict[str, str]:
    """``["scale=false", "maxeval_static=500"]`` (the CLI's repeatable ``--option``) as a dict;
    typing happens in :func:`parse_options`."""
    out: dict[str, str] = {}
    for item in items:
        name, sep, value = item.partition("=")
        if not sep or not name.strip():
            raise ConfigError(f"--option expects name=value, got {item!r}")
        if name.strip() in out:
            raise ConfigError(f"--option {name.strip()} given twice")
        out[name.strip()] = value
    return out
