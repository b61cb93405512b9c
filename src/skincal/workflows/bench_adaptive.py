"""Benchmark of the adaptive motion against the fixed ``fast`` protocol (issue 16, "the next best motion").

Per robot and seed, the same session (robot, 6 units of the ``paper`` placement, IMU, joint-state and
clock presets, and seed: the same unit poses and IMU errors) is calibrated by the streaming calibrator
two ways:

* **adaptive**: :func:`skincal.workflows.adaptive.run_simulated`, the loop choosing each segment until
  every unit's std is within the target; the robot motion time then, and the TRUE errors of the estimate;
* **fixed**: the ``fast`` protocol simulated whole and replayed into the streaming calibrator
  (:func:`skincal.calib.online.replay`); its full motion time, the data time at which every unit's std
  first reached the target (``None``: never), and the true errors at that point and at the end.

True errors are :func:`skincal.calib.metrics.evaluate` against the session's truth (worst unit).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

from skincal.workflows.live import Target, all_reached, make_calibrator


@dataclass(frozen=True)
class Row:
    """One robot and seed."""

    robot: str
    seed: int
    adaptive_s: float
    adaptive_reached: bool
    adaptive_segments: int
    adaptive_pos_mm: float
    adaptive_rot_deg: float
    adaptive_links_ok: bool
    adaptive_wall_s: float
    fixed_s: float
    fixed_reached_s: float | None
    fixed_reached_pos_mm: float | None
    fixed_reached_rot_deg: float | None
    fixed_end_pos_mm: float
    fixed_end_rot_deg: float


def worst(errors: dict[str, Any]) -> tuple[float, float, bool]:
    """Largest position error (mm), rotation error (deg) over the units, and whether every link is right
    (a unit the result lacks counts as inf / wrong)."""
    units = errors.get("units", {})
    if not units:
        return float("inf"), float("inf"), False
    pos = max(float(e["position_error_mm"]) for e in units.values())
    rot = max(float(e["rotation_error_deg"]) for e in units.values())
    links = all(e["link_estimated"] == e["link_true"] for e in units.values())
    return pos, rot, links


def run_fixed(robot: str, seed: int, noise: str, target: Target, joints: str = "auto") -> dict[str, Any]:
    """The ``fast`` protocol's session replayed into the streaming calibrator (module docstring)."""
    import copy

    from skincal.calib.metrics import evaluate
    from skincal.calib.online import replay
    from skincal.sim import simulate
    from skincal.workflows.session import make_session

    session = make_session(robot, "paper", None, noise, "fast", seed, joints=joints)
    ds = simulate(session)
    cal = make_calibrator(session.chain, list(session.placements), ds.gravity, target)
    t0 = float(ds.joint_states.t[0])
    seen: dict[str, Any] = {}

    def on_chunk(t: float) -> bool:
        if "t" not in seen and all_reached(cal.status()):
            probe = copy.deepcopy(cal)
            seen["t"] = t - t0
            seen["errors"] = evaluate(probe.result(), ds)
        return False

    replay(ds, cal, chunk_s=0.5, on_chunk=on_chunk)
    end = evaluate(cal.result(), ds)
    return {"duration_s": session.trajectory.duration, "reached_s": seen.get("t"), "at_reach": seen.get("errors"),
            "end": end}  # fmt: skip


def run_case(robot: str, seed: int, noise: str = "realistic", target: Target = Target(),
             max_motion_s: float = 180.0, joints: str = "auto") -> Row:  # fmt: skip
    """One robot and seed: the adaptive loop and the fixed protocol (module docstring)."""
    from skincal.workflows.adaptive import run_simulated

    wall = time.perf_counter()
    run = run_simulated(robot, "paper", None, noise, seed, joints=joints, target=target, max_motion_s=max_motion_s)
    wall = time.perf_counter() - wall
    pos, rot, links = worst(run.errors)
    fixed = run_fixed(robot, seed, noise, target, joints)
    fpos, frot, _ = worst(fixed["end"])
    rpos, rrot = (None, None) if fixed["at_reach"] is None else worst(fixed["at_reach"])[:2]
    return Row(robot, seed, run.motion_s, run.loop.reached, len(run.loop.segments), pos, rot, links, wall,
               fixed["duration_s"], fixed["reached_s"], rpos, rrot, fpos, frot)  # fmt: skip
