"""The streaming calibrator on drifting and re-synced clocks against the batch ``mle`` (issue 25's target):
``benchmarks/bench_streaming_clock.py``.

One job per cell (robot, protocol, clock preset, seed): a session from
:func:`skincal.workflows.session.make_session` as a user makes it with ``skincal simulate`` (the paper's six
units, ``realistic`` IMUs, the preset's joint states, the ``--clock`` preset), simulated analytically; then

* ``mle``: :func:`skincal.calib.calibrate` of the whole dataset;
* ``online``: :func:`skincal.workflows.live.follow_dataset` as ``skincal calibrate --follow --speed 0`` runs
  it, but to the data's end (no stop at the target).

Per calibrator: the mean position (mm) and rotation (deg) errors over the units (:func:`skincal.calib.evaluate`),
and per unit ``z_max = max_i |e_i| / std_i`` over the three position axes and the three rotation axes
(``e_rot = log(R_est R_true^T)``, the link axes of the reported std) and whether the unit carries a warning.
The target: ``online / mle <= 1.1`` for the mean errors of each (robot, protocol, clock) over its seeds, and
no unit with ``z_max > 3`` without a warning. All figures are of SIMULATED sessions.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from skincal.bench.harness import RunInfo
from skincal.bench.options import STREAMING_CLOCK
from skincal.errors import ConfigError

RATIO_TARGET = 1.1
"""The stream's mean error may be at most this times ``mle``'s."""
Z_TARGET = 3.0
"""A unit whose error exceeds this many reported std on an axis must carry a warning."""
ROBOTS = ("panda", "ur5e")
PROTOCOLS = ("fast", "paper-sim")
CLOCKS = ("wifi", "wifi-resync")


@dataclass(frozen=True)
class StreamingClockConfig:
    """The matrix: every robot x protocol x clock x seed (the options of ``benchmarks/bench_streaming_clock.py``)."""

    robots: tuple[str, ...] = ROBOTS
    protocols: tuple[str, ...] = PROTOCOLS
    clocks: tuple[str, ...] = CLOCKS
    seeds: tuple[int, ...] = (0, 1, 2)
    noise: str = "realistic"


@dataclass(frozen=True)
class StreamingClockJob:
    """One cell of the matrix."""

    robot: str
    protocol: str
    clock: str
    seed: int
    noise: str = "realistic"


def _split(text: str, known: tuple[str, ...] | None, what: str) -> tuple[str, ...]:
    items = tuple(s.strip() for s in text.split(",") if s.strip())
    if not items:
        raise ConfigError(f"--{what}: give at least one")
    bad = [s for s in items if known is not None and s not in known]
    if bad:
        raise ConfigError(f"--{what}: unknown '{bad[0]}' (known: {', '.join(known or ())})")
    return items


def config_from_options(values: Mapping[str, Any]) -> StreamingClockConfig:
    """The config of the parsed :data:`~skincal.bench.options.STREAMING_CLOCK` options (``quick``: the fast
    protocol and seed 0 only)."""
    protocols = _split(values["protocols"], PROTOCOLS, "protocols")
    seeds = tuple(int(s) for s in values["seeds"])
    if values["quick"]:
        protocols, seeds = ("fast",), seeds[:1]
    return StreamingClockConfig(
        _split(values["robots"], None, "robots"), protocols, _split(values["clocks"], None, "clocks"), seeds,
        values["noise"],
    )  # fmt: skip


def unit_figures(result: Any, ds: Any) -> dict[str, dict[str, Any]]:
    """Per unit of ``result``: position (mm) and rotation (deg) errors, ``z_max`` (module docstring; None without
    a std), the link found right and the warnings."""
    from scipy.spatial.transform import Rotation

    from skincal.calib import evaluate

    ev = evaluate(result, ds)
    out: dict[str, dict[str, Any]] = {}
    for name, unit in result.units.items():
        truth, e = ds.truth[name], ev.units[name]
        z: list[float] = []
        if unit.pose.link == truth.link:
            if unit.position_std_m is not None:
                z += list(np.abs(unit.pose.p_link_su - truth.p_link_su) / np.asarray(unit.position_std_m))
            if unit.rotation_std_deg is not None:
                rot = np.degrees(Rotation.from_matrix(unit.pose.R_link_su @ truth.R_link_su.T).as_rotvec())
                z += list(np.abs(rot) / np.asarray(unit.rotation_std_deg))
        z = [v for v in z if np.isfinite(v)]
        out[name] = {
            "position_error_mm": float(e.position_error_mm),
            "rotation_error_deg": float(e.rotation_error_deg),
            "link_right": unit.pose.link == truth.link,
            "z_max": float(max(z)) if z else None,
            "warnings": list(unit.warnings),
        }
    return out


def run_cell(job: StreamingClockJob) -> dict[str, Any]:
    """Simulate one cell's session, calibrate it with ``mle`` and with the stream to the data's end."""
    import time

    from skincal.calib import calibrate
    from skincal.sim import simulate
    from skincal.workflows.live import follow_dataset
    from skincal.workflows.session import make_session

    ds = simulate(make_session(job.robot, "paper", None, job.noise, job.protocol, job.seed, clock=job.clock),
                  "analytic")  # fmt: skip
    t = time.perf_counter()
    mle = calibrate(ds, "mle")
    mle_s = time.perf_counter() - t
    t = time.perf_counter()
    online = follow_dataset(ds, speed=None, stop_at_target=False).result
    online_s = time.perf_counter() - t
    record: dict[str, Any] = {
        "robot": job.robot, "protocol": job.protocol, "clock": job.clock, "seed": job.seed,
        "data_s": round(float(ds.duration), 1), "mle_s": round(mle_s, 2), "online_s": round(online_s, 2),
        "clock_drift_ppm": {u: float(s["clock_drift_ppm"]) for u, s in ds.truth_sensor.items()
                            if "clock_drift_ppm" in s},
    }  # fmt: skip
    for key, result in (("mle", mle), ("online", online)):
        units = unit_figures(result, ds)
        missing = sorted(set(ds.truth) - set(units))
        record[key] = {
            "position_mm": float(np.mean([u["position_error_mm"] for u in units.values()])),
            "rotation_deg": float(np.mean([u["rotation_error_deg"] for u in units.values()])),
            "units": units,
            "missing": missing,
            "z_max": max((u["z_max"] for u in units.values() if u["z_max"] is not None), default=None),
            "unwarned_beyond": sorted(n for n, u in units.items() if (u["z_max"] or 0.0) > Z_TARGET
                                      and not u["warnings"]),
        }  # fmt: skip
    return record


def summarise(records: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per (robot, protocol, clock): the mean errors of both over the seeds, their ratios (online / mle), the
    largest ``z_max`` of the stream, its unwarned units beyond :data:`Z_TARGET` and the verdict."""
    groups: dict[tuple[str, str, str], list[dict[str, Any]]] = {}
    for r in records:
        groups.setdefault((r["robot"], r["protocol"], r["clock"]), []).append(r)
    out = []
    for (robot, protocol, clock), rows in groups.items():
        row: dict[str, Any] = {"robot": robot, "protocol": protocol, "clock": clock, "seeds": [r["seed"] for r in rows]}
        for kind in ("position_mm", "rotation_deg"):
            m = float(np.mean([r["mle"][kind] for r in rows]))
            o = float(np.mean([r["online"][kind] for r in rows]))
            row[kind] = {"mle": m, "online": o, "ratio": o / m if m > 0 else float("inf")}
        row["online_z_max"] = max((r["online"]["z_max"] or 0.0) for r in rows)
        row["unwarned_beyond"] = [f"seed {r['seed']} {u}" for r in rows for u in r["online"]["unwarned_beyond"]]
        row["missing"] = [f"seed {r['seed']} {u}" for r in rows for u in r["online"]["missing"]]
        row["meets_target"] = (
            row["position_mm"]["ratio"] <= RATIO_TARGET and row["rotation_deg"]["ratio"] <= RATIO_TARGET
            and not row["unwarned_beyond"] and not row["missing"]
        )  # fmt: skip
        out.append(row)
    return out


class StreamingClockHarness:
    """The benchmark as a :class:`~skincal.bench.harness.Harness`: one job per cell."""

    options = STREAMING_CLOCK
    run_job = staticmethod(run_cell)

    def config(self, values: Mapping[str, Any]) -> StreamingClockConfig:
        """:func:`config_from_options`."""
        return config_from_options(values)

    def jobs(self, config: StreamingClockConfig) -> list[StreamingClockJob]:
        """Every cell; the fast protocol's first (the paper-sim sessions are 11 min of data)."""
        c = config
        return [StreamingClockJob(r, p, k, s, c.noise)
                for p in c.protocols for r in c.robots for k in c.clocks for s in c.seeds]  # fmt: skip

    def summary(self, config: StreamingClockConfig, records: list[dict[str, Any]], run: RunInfo) -> dict[str, Any]:
        """``{"simulated": true, "cells": records, "groups": summarise(records), "all_meet_target", ...}``."""
        groups = summarise(records)
        return {"simulated": True, "ratio_target": RATIO_TARGET, "z_target": Z_TARGET, "cells": records,
                "groups": groups, "all_meet_target": all(g["meets_target"] for g in groups),
                "wall_time_s": round(run.wall_time_s, 1)}  # fmt: skip

    def report(self, config: StreamingClockConfig, doc: Mapping[str, Any], run: RunInfo) -> list[Any]:
        """The per-cell table and the per-group verdicts."""
        from rich.table import Table

        table = Table(title=f"streaming vs mle, {config.noise} IMUs, paper units, SIMULATED")
        for col in ("robot", "protocol", "clock", "seed", "mle mm", "online mm", "ratio", "mle deg", "online deg",
                    "ratio", "max err/std", "unwarned > 3 std"):  # fmt: skip
            table.add_column(col)
        for r in doc["cells"]:
            m, o = r["mle"], r["online"]
            table.add_row(
                r["robot"], r["protocol"], r["clock"], str(r["seed"]), f"{m['position_mm']:.3f}",
                f"{o['position_mm']:.3f}", f"{o['position_mm'] / m['position_mm']:.2f}", f"{m['rotation_deg']:.4f}",
                f"{o['rotation_deg']:.4f}", f"{o['rotation_deg'] / m['rotation_deg']:.2f}",
                "-" if o["z_max"] is None else f"{o['z_max']:.1f}",
                ",".join(o["unwarned_beyond"] + o["missing"]) or "-",
            )  # fmt: skip
        lines: list[Any] = [table]
        for g in doc["groups"]:
            p, q = g["position_mm"], g["rotation_deg"]
            lines.append(
                f"{g['robot']} {g['protocol']} {g['clock']} (seeds {','.join(map(str, g['seeds']))}): position "
                f"{p['online']:.3f}/{p['mle']:.3f} mm = {p['ratio']:.2f}x, rotation {q['online']:.4f}/{q['mle']:.4f} "
                f"deg = {q['ratio']:.2f}x, max err/std {g['online_z_max']:.1f}, unwarned beyond {Z_TARGET:g} std: "
                f"{', '.join(g['unwarned_beyond']) or 'none'}: {'meets' if g['meets_target'] else 'MISSES'} the target"
            )
        lines.append(f"wall time {run.wall_time_s:.0f} s")
        return lines


HARNESS = StreamingClockHarness()
