"""The live meter: per skin unit, how far its calibration is from the target while data arrive.

Drawn from the streaming calibrator's per-unit status (:class:`skincal.calib.online.UnitStatus`, read
by attribute only, so this module imports no calibrator): the unit's best link so far and the
evidence for it, the largest position and rotation std against the target, the samples absorbed,
the joint whose motion would help most and what is missing. :func:`meter_table` is the rich table
(``skincal calibrate --follow``, ``skincal record --live`` on a terminal); :func:`meter_line` is the
one-line form printed on a non-terminal (a pipe, a CI log).

Every name and note comes from a file or a device: control characters are shown escaped
(:func:`skincal.names.printable`) and rich markup is neutralised, so a unit named ``[blink]x`` or
``su\\x1b[2J`` shows as stored and cannot restyle or clear the terminal.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np
from rich.markup import escape
from rich.table import Table

from skincal.names import printable

REACHED_STYLE = "green"
OPEN_STYLE = "yellow"
UNKNOWN_STYLE = "red"


def cell_text(text: object) -> str:
    """``text`` safe for a rich cell or markup string: control characters escaped, markup neutralised."""
    return escape(printable(str(text)))


def worst_std(values: Any) -> float:
    """The largest component of a std vector (``inf`` when any component is undetermined or missing)."""
    if values is None:
        return math.inf
    arr = np.asarray(values, dtype=float).ravel()
    if arr.size == 0 or not np.all(np.isfinite(arr)):
        return math.inf
    return float(arr.max())


def _std_cell(value: float, target: float, scale: float, digits: int) -> str:
    if not math.isfinite(value):
        return f"[{UNKNOWN_STYLE}]undetermined[/]"
    style = REACHED_STYLE if value <= target else OPEN_STYLE
    return f"[{style}]{scale * value:.{digits}f}[/]"


def _link_cell(status: Any) -> str:
    if status.link is None:
        return f"[{UNKNOWN_STYLE}]?[/]"
    margin = float(status.link_margin)
    if not math.isfinite(margin):
        return str(int(status.link))
    return f"{int(status.link)} (x{margin:.1f})"


def _state_cell(status: Any) -> str:
    if status.reached:
        return f"[{REACHED_STYLE}]at target[/]"
    return cell_text(status.missing or "collecting")


def counts(statuses: Mapping[str, Any]) -> tuple[int, int]:
    """``(units at the target, units)``."""
    return sum(1 for s in statuses.values() if s.reached), len(statuses)


def meter_table(
    statuses: Mapping[str, Any],
    target_position_m: float,
    target_rotation_deg: float,
    t_data: float,
    t_end: float | None = None,
    title: str = "skincal live",
    notes: tuple[str, ...] = (),
) -> Table:
    """The meter as a rich table: one row per unit (in the order of ``statuses``).

    Args:
        statuses: unit name -> the calibrator's status of that unit.
        target_position_m, target_rotation_deg: the target on every axis, m and deg.
        t_data: data time followed so far, s; ``t_end``: the data's end when known (a replay).
        title: the table title's first words (escaped here); ``notes``: lines of the caption (escaped).
    """
    reached, total = counts(statuses)
    span = f"{t_data:.1f} s" if t_end is None else f"{t_data:.1f} / {t_end:.1f} s"
    table = Table(
        title=f"{cell_text(title)}: {reached}/{total} units at target "
        f"({target_position_m * 1e3:g} mm, {target_rotation_deg:g} deg); data {span}",
        title_justify="left",
    )
    for col in ("unit", "link", "pos std mm", "rot std deg", "samples (moving)", "move",
                "missing"):  # fmt: skip
        table.add_column(col, justify="left" if col in ("unit", "missing") else "right")
    for name, s in statuses.items():
        table.add_row(
            cell_text(name),
            _link_cell(s),
            _std_cell(worst_std(s.position_std_m), target_position_m, 1e3, 3),
            _std_cell(worst_std(s.rotation_std_deg), target_rotation_deg, 1.0, 4),
            f"{int(s.samples)} ({int(s.moving_samples)})",
            "-" if s.best_joint is None or s.reached else f"joint {int(s.best_joint) + 1}",
            _state_cell(s),
        )
    if notes:
        table.caption = "\n".join(cell_text(n) for n in notes)
        table.caption_justify = "left"
    return table


def meter_line(
    statuses: Mapping[str, Any],
    target_position_m: float,
    target_rotation_deg: float,
    t_data: float,
    t_end: float | None = None,
) -> str:
    """The meter in one plain line (no markup; names escaped by :func:`printable`): the units at the
    target and the unit furthest from it in position and in rotation."""
    reached, total = counts(statuses)
    span = f"{t_data:.1f} s" if t_end is None else f"{t_data:.1f}/{t_end:.1f} s"
    parts = [f"data {span}: {reached}/{total} units at target"]
    for label, attr, scale, unit, digits in (
        ("pos", "position_std_m", 1e3, "mm", 3),
        ("rot", "rotation_std_deg", 1.0, "deg", 4),
    ):
        open_units = {n: worst_std(getattr(s, attr)) for n, s in statuses.items() if not s.reached}
        if not open_units:
            continue
        name = max(open_units, key=lambda n: open_units[n])
        value = open_units[name]
        shown = "undetermined" if not math.isfinite(value) else f"{scale * value:.{digits}f} {unit}"
        parts.append(f"worst {label} std {shown} ({printable(str(name))})")
    return "; ".join(parts)
