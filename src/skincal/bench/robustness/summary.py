"""The robustness benchmark's cells: the records of a cell summarised against its targets
(:func:`summarise_cell`, :func:`summarise`) and shown (:func:`robustness_table`, :func:`report`)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from skincal.bench.robustness.faults import FAULTS
from skincal.bench.robustness.job import RobustnessConfig


# --------------------------------------------------------------------------- summary
def targets(fault: str) -> dict[str, Any]:
    """The cell's targets: ``mean_position_error_mm`` (or ``None``), all links right, no silent error."""
    return {"mean_position_error_mm": FAULTS[fault].target_mean_mm, "links": "all", "silent_errors": 0}


def summarise_cell(records: Sequence[Mapping[str, Any]]) -> dict[str, Any]:
    """Statistics of one cell over its records (all seeds' units); see the module docstring.

    Means and maxima are over calibrated observable units; ``z_rms`` over every finite ``z`` of
    those with the right link; ``warned`` counts calibrated units with any warning, ``silent``
    the silent errors (:data:`SILENT_RULE`), ``beyond_3sigma`` the units wrong beyond their
    uncertainty by the same rule, warned or not. ``pass`` checks :func:`targets`.
    """
    first = records[0]
    units = [u for r in records for u in r["units"].values()]
    done = [u for u in units if u["calibrated"]]
    seen = [u for u in done if u["observable"]]
    pos = [u["position_error_mm"] for u in seen]
    rot = [u["rotation_error_deg"] for u in seen]
    z = [v for u in seen if u["z"] is not None for v in u["z"] if v is not None]
    links = sum(u["link_estimated"] == u["link_true"] for u in done)
    silent = [f"seed {r['seed']} {n}" for r in records for n, u in r["units"].items() if u.get("silent")]
    beyond = int(sum(bool(u.get("beyond_3sigma")) for u in done))
    cell: dict[str, Any] = {
        "robot": first["robot"],
        "backend": first["backend"],
        "fault": first["fault"],
        "seeds": sorted(r["seed"] for r in records),
        "mean_position_error_mm": float(np.mean(pos)) if pos else None,
        "max_position_error_mm": float(np.max(pos)) if pos else None,
        "mean_rotation_error_deg": float(np.mean(rot)) if rot else None,
        "max_rotation_error_deg": float(np.max(rot)) if rot else None,
        "links_correct": int(links),
        "units_total": len(units),
        "units_calibrated": len(done),
        "z_rms": float(np.sqrt(np.mean(np.square(z)))) if z else None,
        "warned": int(sum(bool(u["warnings"]) for u in done)),
        "beyond_3sigma": beyond,
        "silent": len(silent),
        "silent_units": silent,
        "errors": [r["error"] for r in records if r["error"]],
        "simulate_s": float(sum(r["simulate_s"] for r in records)),
        "calibrate_s": float(sum(r["calibrate_s"] for r in records)),
        "targets": targets(first["fault"]),
    }
    cell["failed_targets"] = failed_targets(cell)
    cell["pass"] = not cell["failed_targets"]
    return cell


def failed_targets(cell: Mapping[str, Any]) -> list[str]:
    """Which of the cell's targets it misses (short phrases; empty when it meets them all)."""
    out = []
    goal = cell["targets"]["mean_position_error_mm"]
    mean = cell["mean_position_error_mm"]
    if goal is not None and (mean is None or mean > goal):
        out.append(f"mean > {goal:g} mm")
    if cell["links_correct"] < cell["units_total"]:
        out.append("links")
    if cell["silent"]:
        out.append("silent")
    if cell["errors"]:
        out.append("crashed")
    return out


def summarise(config: RobustnessConfig, records: Sequence[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """One :func:`summarise_cell` per cell, in the configuration's order (robot, backend, fault)."""
    by_cell: dict[tuple[str, str, str], list[Mapping[str, Any]]] = {}
    for r in records:
        by_cell.setdefault((r["robot"], r["backend"], r["fault"]), []).append(r)
    return [
        summarise_cell(by_cell[(r, b, f)])
        for r in config.robots
        for b in config.backends
        for f in config.faults
        if (r, b, f) in by_cell
    ]


def _num(x: float | None, digits: int) -> str:
    return "-" if x is None else f"{x:.{digits}f}"


def robustness_table(config: RobustnessConfig, cells: list[dict[str, Any]]):
    """A rich table with one row per cell (robot, backend, fault)."""
    from rich.table import Table

    table = Table(
        title=f"robustness: mle, {config.protocol} protocol, {config.seeds} placement(s) of "
        f"{config.n_units} units per cell"
    )
    for col, justify in (
        ("robot", "left"), ("backend", "left"), ("fault", "left"), ("pos mean/max mm", "right"),
        ("rot mean/max deg", "right"), ("links", "right"), ("z rms", "right"), ("calibrated", "right"),
        ("warned", "right"), ("beyond", "right"), ("silent", "right"), ("targets", "left"),
    ):  # fmt: skip
        table.add_column(col, justify=justify, no_wrap=col in ("backend", "fault"))
    previous = None
    for c in cells:
        if previous is not None and (c["robot"], c["backend"]) != previous:
            table.add_section()
        previous = (c["robot"], c["backend"])
        n = c["units_total"]
        verdict = "ok" if c["pass"] else "[red]" + ", ".join(c["failed_targets"]) + "[/red]"
        table.add_row(
            c["robot"], c["backend"], c["fault"],
            f"{_num(c['mean_position_error_mm'], 3)} / {_num(c['max_position_error_mm'], 2)}",
            f"{_num(c['mean_rotation_error_deg'], 3)} / {_num(c['max_rotation_error_deg'], 2)}",
            f"{c['links_correct']}/{n}", _num(c["z_rms"], 2), f"{c['units_calibrated']}/{n}",
            str(c["warned"]), str(c["beyond_3sigma"]),
            ("[red]" + str(c["silent"]) + "[/red]") if c["silent"] else "0", verdict,
        )  # fmt: skip
    return table


LEGEND = (
    "errors of calibrated units (means over observable ones); z = position error / reported std per link axis; "
    "warned: units with any warning; beyond: units on a wrong link or beyond 3 sigma (any axis, or sum z^2 > "
    "chi2_3(0.9973)); silent: beyond and not warned. Targets: mean <= 0.3 mm (qd-*), <= 1 mm (imu-real, "
    "clock-*); all links right and no silent error in every cell."
)
"""What the table's columns mean, printed under it."""


def where(workers: int, dask: Any) -> str:
    """Where the jobs ran, for the summary line."""
    return f"dask {dask}" if dask else f"{workers} local process(es)"


def report(config: RobustnessConfig, doc: Mapping[str, Any]) -> list[Any]:
    """What the command prints after a run: the table, the legend and the summary line."""
    cells = doc["cells"]
    passed = sum(c["pass"] for c in cells)
    line = (
        f"{passed}/{len(cells)} cells meet their targets; {len(doc['records'])} jobs in {doc['wall_time_s']:.1f} s "
        f"wall ({where(doc['workers'] or 1, doc['dask'])})"
    )
    return [robustness_table(config, cells), LEGEND, line]
