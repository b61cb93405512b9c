"""Benchmark of the moved-unit monitor (issue 16; ``benchmarks/bench_monitor.py``): false alarms over
simulated hours of normal work, detection delays and pose errors of 5 mm / 2 deg knocks, on the work sessions
of :mod:`skincal.workflows.monitoring`. All figures SIMULATED."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from skincal.calib.metrics import pose_errors
from skincal.skin.pose import SkinUnitPose
from skincal.workflows.monitoring import (
    knocked_dataset,
    monitor_batch,
    monitor_online,
    motion_time,
    simulate_session,
    work_session,
)

KNOCKS = (("5 mm", 0.005, 0.0), ("2 deg", 0.0, 2.0))
"""The knocks of the issue's target: (label, translation m, rotation deg)."""


def knock_case(
    session,
    unit: str,
    translation_m: float,
    rotation_deg: float,
    t_knock: float,
    seed: int = 0,
    online: bool = False,
    **monitor: Any,
) -> dict[str, Any]:
    """One knocked session watched by :func:`monitor_batch` (``online``: :func:`monitor_online`, the
    streaming calibrator re-estimating the unit): the detection delay (wall and motion time of the unit's
    link after the knock), the change-time error, both poses' errors against the truth and the alarms of
    the other units."""
    ds = knocked_dataset(session, unit, t_knock, translation_m, rotation_deg, seed)
    run = monitor_online(ds, **monitor) if online else monitor_batch(ds, **monitor)
    truth = ds.truth_sensor[unit]
    link = session.placements[unit].link
    as_pose = lambda T: SkinUnitPose(link, np.asarray(T)[:3, :3], np.asarray(T)[:3, 3])  # noqa: E731
    mine = [e for e in run.events if e["unit"] == unit and e["t_detected_s"] >= t_knock]
    early = [e for e in run.events if e["unit"] == unit and e["t_detected_s"] < t_knock]
    out: dict[str, Any] = {
        "unit": unit, "link": link, "translation_m": translation_m, "rotation_deg": rotation_deg, "t_knock_s": t_knock,
        "calibrator": "online" if online else "mle",
        "detected": bool(mine), "false_alarms_before_knock": len(early),
        "other_units_alarms": sum(e["unit"] != unit for e in run.events),
    }  # fmt: skip
    if mine:
        e = mine[0]
        before = after = (float("nan"), float("nan"), float("nan"))  # mm, deg, quaternion distance
        if "T_link_su_before" in e:
            before = pose_errors(None, None, as_pose(e["T_link_su_before"]), as_pose(truth["knock_T_link_su_before"]))
        if "T_link_su_after" in e:
            after = pose_errors(None, None, as_pose(e["T_link_su_after"]), as_pose(truth["knock_T_link_su_after"]))
        out.update(
            delay_s=e["t_detected_s"] - t_knock,
            delay_motion_s=motion_time(ds, link, t_knock, e["t_detected_s"]),
            t_change_error_s=e["t_change_s"] - t_knock,
            before_mm=before[0], before_deg=before[1], after_mm=after[0], after_deg=after[1],
        )  # fmt: skip
    return out


def bench_monitor(
    noises: Sequence[str] = ("realistic", "real"),
    hours: float = 1.0,
    kind: str = "teleop",
    robot: str = "panda",
    units: Sequence[str] | None = None,
    online_units: Sequence[str] = ("su4",),
    knock_duration_s: float = 420.0,
    t_knock: float = 300.0,
    seed: int = 0,
    progress: Callable[[str], None] | None = None,
) -> dict[str, Any]:
    """The issue's targets for a moved unit: per IMU preset, the false alarms over ``hours`` of normal
    work (6 units, controller joint states) and, per knock of :data:`KNOCKS` and unit, the detection
    delay and both poses' errors (:func:`knock_case`; ``online_units`` also with the streaming
    calibrator). Costs (wall time, peak memory) included."""
    import resource
    import time

    say = progress or (lambda _text: None)
    doc: dict[str, Any] = {"robot": robot, "kind": kind, "hours": hours, "seed": seed, "false_alarms": {}, "knocks": []}
    for noise in noises:
        say(f"{noise}: {hours:g} h of normal work")
        start = time.perf_counter()
        session = work_session(robot, noise, kind, 3600.0 * hours, seed, rate_hz=500.0)
        ds = simulate_session(session, seed)
        simulated = time.perf_counter()
        run = monitor_batch(ds)
        done = time.perf_counter()
        doc["false_alarms"][noise] = {
            "duration_s": float(ds.joint_states.t[-1] - ds.joint_states.t[0]),
            "units": len(ds.units),
            "watched_unit_s": float(sum(run.watched_s.values())),
            "alarms": [{"unit": a.unit, "t_detected_s": a.t_detected, "statistic": a.statistic} for a in run.alarms],
            "thresholds": {k: v for k, v in run.thresholds.items()},
            "simulate_s": simulated - start,
            "monitor_s": done - simulated,
        }
        del ds, run
        session = work_session(robot, noise, kind, knock_duration_s, seed + 1)
        for label, dm, ddeg in KNOCKS:
            for unit in units or list(session.placements):
                say(f"{noise}: {label} knock of {unit}")
                case = knock_case(session, unit, dm, ddeg, t_knock, seed + 1)
                doc["knocks"].append({"imu": noise, "knock": label, **case})
            for unit in online_units:
                say(f"{noise}: {label} knock of {unit}, streaming calibrator")
                case = knock_case(session, unit, dm, ddeg, t_knock, seed + 1, online=True)
                doc["knocks"].append({"imu": noise, "knock": label, **case})
    doc["peak_rss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    return doc
