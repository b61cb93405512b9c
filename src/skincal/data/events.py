"""Moved-unit events (``docs/interfaces.md``, "Moved units"): one :class:`MoveEvent` per unit that moved
on its link while the robot worked, the same in the dataset (``/events/<k>`` attrs) and in the result
(top-level ``events``).

An event holds ``unit``, ``t_change_s <= t_detected_s`` (s, joint clock), optionally ``link``, the rigid
poses ``T_link_su_before`` / ``T_link_su_after`` (``(4, 4)``, m), the monitor's ``statistic`` and
``threshold``, ``t_recalibrated_s`` (s) and further string or number fields (``extra``). It is checked
when built (:func:`move_event` from a mapping, one-line :class:`~skincal.errors.DatasetError` naming the
field) and :meth:`MoveEvent.fields` gives the file's fields back.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from skincal.errors import DatasetError
from skincal.kinematics.transforms import FloatArray
from skincal.names import name_problem

EVENT_TIMES = ("t_change_s", "t_detected_s")
EVENT_POSES = ("T_link_su_before", "T_link_su_after")
EVENT_NUMBERS = ("statistic", "threshold", "t_recalibrated_s")
MAX_POSITION_M = 1e3
"""Largest accepted position component of a unit (a result's positions, an event's poses), m: a skin
unit sits on a robot link, and numbers like ``1e308`` overflow every distance computed from them."""
_RIGID_TOL = 1e-6


def _short(value: object) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


@dataclass(frozen=True)
class MoveEvent:
    """A unit that moved on its link (knocked, peeled and re-stuck), noticed by the change monitor.

    Attributes:
        unit: the unit that moved (the one rule for names).
        t_change_s: estimated instant of the change, s, on the joint clock.
        t_detected_s: instant the monitor raised the alarm, s (``>= t_change_s``).
        link: the unit's link (a move keeps the link), or None.
        T_link_su_before, T_link_su_after: ``(4, 4)`` rigid poses before the change and re-calibrated
            after it (positions within :data:`MAX_POSITION_M` m), or None.
        statistic, threshold: the monitor's CUSUM value at the alarm and the unit's threshold, or None.
        t_recalibrated_s: end of the data the "after" pose was estimated from, s, or None.
        extra: further fields, name -> string or number (kept as they are).

    Raises:
        DatasetError: a field breaks the rules above (one line naming it).
    """

    unit: str
    t_change_s: float
    t_detected_s: float
    link: int | None = None
    T_link_su_before: FloatArray | None = None
    T_link_su_after: FloatArray | None = None
    statistic: float | None = None
    threshold: float | None = None
    t_recalibrated_s: float | None = None
    extra: Mapping[str, str | float] = field(default_factory=dict)

    def __post_init__(self) -> None:
        _check(self, "event")

    def fields(self) -> dict[str, Any]:
        """The event's fields as written to a file, given fields only (poses as ``(4, 4)`` arrays)."""
        out: dict[str, Any] = {"unit": self.unit, "t_change_s": self.t_change_s, "t_detected_s": self.t_detected_s}
        for key in ("statistic", "threshold", "link", "t_recalibrated_s", *EVENT_POSES):
            value = getattr(self, key)
            if value is not None:
                out[key] = value
        out.update(self.extra)
        return out


def move_event(event: Any, where: str) -> MoveEvent:
    """The :class:`MoveEvent` of a mapping of the file's fields (a ``None`` value: not given); ``where``
    starts the one-line :class:`DatasetError` (``events[0]``, ``/events/0``)."""
    if isinstance(event, MoveEvent):
        return event
    if not isinstance(event, Mapping):
        raise DatasetError(f"{where} must be an object, got {_short(event)}")
    named = ("unit", *EVENT_TIMES, *EVENT_NUMBERS, "link", *EVENT_POSES)
    extra = {k: v for k, v in event.items() if k not in named and v is not None}
    values = {k: event.get(k) for k in named}
    obj = object.__new__(MoveEvent)
    for key, value in {**values, "extra": extra}.items():
        object.__setattr__(obj, key, value)
    _check(obj, where)
    return obj


def _check(e: MoveEvent, where: str) -> None:
    """Check and normalise ``e`` in place (floats, an int link, read-only float poses, a plain extra)."""
    set_ = object.__setattr__
    problem = name_problem(e.unit) if isinstance(e.unit, str) else "is not a string"
    if problem is not None:
        raise DatasetError(f"{where}.unit {_short(e.unit)} is not a valid unit name: it {problem}")
    for key in EVENT_TIMES + EVENT_NUMBERS:
        value = getattr(e, key)
        if value is None and key not in EVENT_TIMES:
            continue
        if isinstance(value, bool) or not isinstance(value, int | float | np.integer | np.floating):
            raise DatasetError(f"{where}.{key} must be a number, got {_short(value)}")
        if not math.isfinite(float(value)):
            raise DatasetError(f"{where}.{key} must be finite, got {value}")
        set_(e, key, float(value))
    if e.t_change_s > e.t_detected_s:
        raise DatasetError(f"{where}: t_change_s {e.t_change_s} is after t_detected_s {e.t_detected_s}")
    link = e.link
    if link is not None:
        if isinstance(link, bool) or not isinstance(link, int | np.integer | float) or link != int(link) or link < 0:
            raise DatasetError(f"{where}.link must be an integer >= 0, got {_short(link)}")
        set_(e, "link", int(link))
    for key in EVENT_POSES:
        value = getattr(e, key)
        if value is None:
            continue
        try:
            T = np.array(value, dtype=float)
        except (TypeError, ValueError):
            raise DatasetError(f"{where}.{key} must be a (4, 4) array of numbers") from None
        if T.shape != (4, 4) or not np.all(np.isfinite(T)):
            raise DatasetError(f"{where}.{key} must be a finite (4, 4) array, got shape {T.shape}")
        R = T[:3, :3]
        rigid = np.allclose(T[3], [0, 0, 0, 1]) and np.allclose(R.T @ R, np.eye(3), atol=_RIGID_TOL)
        if not rigid or np.linalg.det(R) < 0 or np.abs(T[:3, 3]).max() > MAX_POSITION_M:
            raise DatasetError(f"{where}.{key} is not a rigid transform of a unit on a link")
        T.setflags(write=False)
        set_(e, key, T)
    if not isinstance(e.extra, Mapping):
        raise DatasetError(f"{where}: extra must be a mapping of field name -> string or number")
    for key, value in e.extra.items():
        if not isinstance(key, str) or not (isinstance(value, str) or (
            isinstance(value, int | float | np.integer | np.floating) and not isinstance(value, bool))):  # fmt: skip
            raise DatasetError(f"{where}.{key} must be a string or a number, got {_short(value)}")
    set_(e, "extra", dict(e.extra))


def check_events(events: Any, where: str, units: Any = None) -> tuple[MoveEvent, ...]:
    """A sequence of moved-unit events (:class:`MoveEvent` or mappings of their fields, :func:`move_event`);
    with ``units``, each event's unit must be one of them."""
    if not isinstance(events, list | tuple):
        raise DatasetError(f"{where} must be a list of events, got {_short(events)}")
    out = tuple(move_event(e, f"{where}[{i}]") for i, e in enumerate(events))
    if units is not None:
        for i, e in enumerate(out):
            if e.unit not in units:
                raise DatasetError(f"{where}[{i}].unit '{e.unit}' is not a unit of this file")
    return out
