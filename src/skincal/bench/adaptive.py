"""Benchmark of the adaptive motion against the fixed ``fast`` protocol (issue 16, "the next best motion").

Per robot and seed, the same session (robot, 6 units of the ``paper`` placement, IMU, joint-state and
clock presets, and seed: the same unit poses and IMU errors) is calibrated by the streaming calibrator
two ways:

* **adaptive**: :func:`skincal.workflows.adaptive.run_simulated`, the loop choosing each segment until
  every unit's std is within the target; the robot motion time then, and the TRUE errors of the estimate;
  with the true errors tracked after every segment, the motion time at which the worst unit's TRUE error
  first was within the target too (``None``: not before the loop stopped);
* **fixed**: the ``fast`` protocol simulated whole and replayed into the streaming calibrator
  (:func:`skincal.calib.online.replay`); its full motion time, the data time at which every unit's std
  first reached the target (``None``: never), the true errors at that point and at the end, and the data
  time at which the true errors were first within the target (checked every 2 s).

The fixed protocol's std is read from the stream as it is absorbed (the last ~1.5 s wait for later
samples), the adaptive loop's once the robot rests after a segment (everything absorbed); the fixed
times are thus late by up to ~1.5 s.

True errors are :func:`skincal.calib.metrics.evaluate` against the session's truth (worst unit).
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from skincal.bench.harness import RunInfo
from skincal.bench.options import ADAPTIVE
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
    adaptive_true_s: float | None
    fixed_s: float
    fixed_reached_s: float | None
    fixed_reached_pos_mm: float | None
    fixed_reached_rot_deg: float | None
    fixed_end_pos_mm: float
    fixed_end_rot_deg: float
    fixed_true_s: float | None


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


def first_within(history: list[tuple[float, dict[str, Any]]], target: Target) -> float | None:
    """The first time of ``(t, errors)`` pairs at which every unit's true error is within ``target``."""
    for t, errors in history:
        pos, rot, links = worst(errors)
        if links and pos <= target.position_m * 1e3 and rot <= target.rotation_deg:
            return float(t)
    return None


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
    history: list[tuple[float, dict[str, Any]]] = []

    def on_chunk(t: float) -> bool:
        if "t" not in seen and all_reached(cal.status()):
            probe = copy.deepcopy(cal)
            seen["t"] = t - t0
            seen["errors"] = evaluate(probe.result(), ds).to_dict()
        seen["chunks"] = seen.get("chunks", 0) + 1
        if "true" not in seen and seen["chunks"] % 4 == 0:  # the true error every 2 s of data
            done = copy.deepcopy(cal).result()
            if done.units:
                history.append((t - t0, evaluate(done, ds).to_dict()))
                if first_within(history[-1:], target) is not None:
                    seen["true"] = t - t0
        return False

    replay(ds, cal, chunk_s=0.5, on_chunk=on_chunk)
    end = evaluate(cal.result(), ds).to_dict()
    return {"duration_s": session.trajectory.duration, "reached_s": seen.get("t"), "at_reach": seen.get("errors"),
            "true_s": seen.get("true"), "end": end}  # fmt: skip


def run_case(robot: str, seed: int, noise: str = "realistic", target: Target = Target(),
             max_motion_s: float = 180.0, joints: str = "auto", std_factor: float = 1.0) -> Row:  # fmt: skip
    """One robot and seed: the adaptive loop and the fixed protocol (module docstring). ``std_factor``: the
    adaptive loop runs to ``std_factor`` times the target std (e.g. 0.5: on until the TRUE errors are likely
    within the target too); true errors are always judged against ``target``."""
    from skincal.workflows.adaptive import run_simulated

    loop_target = Target(target.position_m * std_factor, target.rotation_deg * std_factor)
    wall = time.perf_counter()
    run = run_simulated(robot, "paper", None, noise, seed, joints=joints, target=loop_target,
                        max_motion_s=max_motion_s, track_truth=True)  # fmt: skip
    wall = time.perf_counter() - wall
    pos, rot, links = worst(run.errors)
    true_s = first_within([(r.t_end, r.true_errors) for r in run.loop.segments if r.true_errors is not None], target)
    fixed = run_fixed(robot, seed, noise, target, joints)
    fpos, frot, _ = worst(fixed["end"])
    rpos, rrot = (None, None) if fixed["at_reach"] is None else worst(fixed["at_reach"])[:2]
    return Row(robot, seed, run.motion_s, run.loop.reached, len(run.loop.segments), pos, rot, links, wall, true_s,
               fixed["duration_s"], fixed["reached_s"], rpos, rrot, fpos, frot, fixed["true_s"])  # fmt: skip


@dataclass(frozen=True)
class AdaptiveConfig:
    """Robots x seeds of :func:`run_case` (the options of ``benchmarks/bench_adaptive.py``)."""

    robots: tuple[str, ...] = ("panda", "sawyer", "ur5e")
    seeds: tuple[int, ...] = (0,)
    noise: str = "realistic"
    target: Target = Target()
    max_motion_s: float = 180.0
    std_factor: float = 1.0


@dataclass(frozen=True)
class AdaptiveJob:
    """One robot and seed of an :class:`AdaptiveConfig`."""

    config: AdaptiveConfig
    robot: str
    seed: int


def run_adaptive_job(job: AdaptiveJob) -> Row:
    """:func:`run_case` of one job."""
    c = job.config
    return run_case(job.robot, job.seed, c.noise, c.target, c.max_motion_s, std_factor=c.std_factor)


def _f(x: float | None, fmt: str = ".1f") -> str:
    return "-" if x is None else format(x, fmt)


class AdaptiveHarness:
    """The adaptive-vs-fixed benchmark as a :class:`~skincal.bench.harness.Harness`: a :class:`Row` per
    robot and seed."""

    options = ADAPTIVE
    run_job = staticmethod(run_adaptive_job)

    def config(self, values: Mapping[str, Any]) -> AdaptiveConfig:
        """The configuration of the parsed options (``target`` as :func:`skincal.workflows.live.parse_target`)."""
        from skincal.workflows.live import parse_target

        v = values
        return AdaptiveConfig(tuple(v["robots"]), tuple(v["seeds"]), v["noise"], parse_target(v["target"]),
                              v["max_motion"], v["std_factor"])  # fmt: skip

    def jobs(self, config: AdaptiveConfig) -> list[AdaptiveJob]:
        """Robot-major, then seed."""
        return [AdaptiveJob(config, robot, seed) for robot in config.robots for seed in config.seeds]

    def summary(self, config: AdaptiveConfig, records: list[Row], run: RunInfo) -> dict[str, Any]:
        """``{"rows": the records}``."""
        return {"rows": records}

    def report(self, config: AdaptiveConfig, doc: Mapping[str, Any], run: RunInfo) -> list[Any]:
        """The table of motion times and true errors."""
        from rich.table import Table

        title = f"motion time to {config.target.text()} std, 6 units, {config.noise} IMUs, controller joint states"
        if config.std_factor != 1.0:
            title += f" (the adaptive loop to {config.std_factor:g} x that std)"
        table = Table(title=title)
        for col in ("robot", "seed", "adaptive [s]", "segments", "reached", "true err [mm / deg]", "links",
                    "true err in target at [s]", "fast [s]", "fast std at target [s]", "fast err there",
                    "fast true err in target at [s]", "fast err at end"):  # fmt: skip
            table.add_column(col)
        for r in doc["rows"]:
            table.add_row(
                r.robot, str(r.seed), f"{r.adaptive_s:.1f}", str(r.adaptive_segments),
                "yes" if r.adaptive_reached else "NO",
                f"{r.adaptive_pos_mm:.3f} / {r.adaptive_rot_deg:.4f}", "ok" if r.adaptive_links_ok else "WRONG",
                _f(r.adaptive_true_s), f"{r.fixed_s:.1f}", _f(r.fixed_reached_s),
                "-" if r.fixed_reached_pos_mm is None else
                f"{r.fixed_reached_pos_mm:.3f} / {r.fixed_reached_rot_deg:.4f}",
                _f(r.fixed_true_s),
                f"{r.fixed_end_pos_mm:.3f} / {r.fixed_end_rot_deg:.4f}",
            )  # fmt: skip
        return [table]


HARNESS = AdaptiveHarness()
