"""Metrics of a closed-loop run: clearance, contacts, tracking error and recovery, QP timing.

Clearance at each control instant is the smallest surface-to-surface distance between the robot's
TRUE link capsules (no padding) and the obstacle solids, in closed form: capsule-capsule
``|seg1 - seg2| - r1 - r2`` and capsule-sphere (a zero-length segment), via
:func:`skincal.perception.body.segment_distance`. A contact is an interval of clearance < 0.

Like ISO/TS 15066 speed and separation monitoring, each run reports the minimum over time of
``clearance - S_p`` (``S_p`` the protective separation the controller used at that step, the fixed
critical distance for the legacy controller; >= 0 at every step is the standard's condition), the
parts of ``S_p`` at that step, the time in protective stop (steps where the controller commanded its
safe stop), the time the person is within ``S_p + 0.5 m`` (``NEAR_BAND``), and the task time lost
against the same run without a person (:func:`task_time_lost`).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from skincal.errors import ConfigError
from skincal.kinematics.transforms import FloatArray
from skincal.perception.body import RobotBody, segment_distance
from skincal.skin import tof
from skincal.workflows.avoidance import TERMS, RunLog

RECOVERY_THRESHOLD = 0.005
"""Tracking error below which the task counts as recovered, m."""
NEAR_BAND = 0.5
"""The person counts as near while the clearance is below ``S_p`` plus this, m."""

_CHUNK = 2000


def obstacle_segments(log: RunLog, t: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Obstacle solids at instants ``t`` ``(M,)`` as segments: ends ``(M, P, 3)`` each and radii ``(P,)``, m.

    Spheres are zero-length segments; other solids (boxes, planes) are not supported here.
    """
    prims = log.scenario.scene.tof_primitives(t) if log.scenario.scene.obstacles else []
    a, b, r = [], [], []
    for p in prims:
        if isinstance(p, tof.Sphere):
            a.append(p.center)
            b.append(p.center)
        elif isinstance(p, tof.Capsule):
            a.append(p.p0)
            b.append(p.p1)
        else:
            raise ConfigError(f"clearance: obstacle solid {type(p).__name__} is not supported (spheres and capsules)")
        r.append(float(np.asarray(p.radius)))
    M = np.atleast_1d(t).size
    if not a:
        return np.zeros((M, 0, 3)), np.zeros((M, 0, 3)), np.zeros(0)
    stack = lambda xs: np.stack([np.broadcast_to(x, (M, 3)) for x in xs], axis=1)  # noqa: E731
    return stack(a), stack(b), np.array(r)


def clearance(log: RunLog, body: RobotBody) -> FloatArray:
    """``(S,)`` smallest distance between the robot capsules and the obstacle solids at each step, m (inf: none)."""
    S = log.t.size
    out = np.full(S, np.inf)
    for k0 in range(0, S, _CHUNK):
        sl = slice(k0, min(S, k0 + _CHUNK))
        oa, ob, orad = obstacle_segments(log, log.t[sl])
        if orad.size == 0:
            continue
        ra, rb = body.segments(body.chain.link_frames(log.q[sl]))  # (M, C, 3)
        d = segment_distance(ra[:, :, None], rb[:, :, None], oa[:, None], ob[:, None])  # (M, C, P)
        d = d - body.radius[None, :, None] - orad[None, None, :]
        out[sl] = d.reshape(d.shape[0], -1).min(axis=1)
    return out


def count_contacts(clear: FloatArray) -> int:
    """Number of contact intervals (runs of clearance < 0)."""
    touching = np.concatenate([[False], clear < 0])
    return int(np.sum(touching[1:] & ~touching[:-1]))


def recovery_time(t: FloatArray, error: FloatArray, t_leave: float, threshold: float = RECOVERY_THRESHOLD) -> float:
    """Time after ``t_leave`` until the error falls below ``threshold`` for good, s (NaN: never; 0: never above)."""
    after = t >= t_leave
    if not np.any(after):
        return float("nan")
    above = np.flatnonzero(after & (error >= threshold))
    if above.size == 0:
        return 0.0
    last = above[-1]
    if last + 1 >= t.size:
        return float("nan")
    return float(t[last + 1] - t_leave)


def margin_of(log: RunLog) -> FloatArray:
    """``(S,)`` the protective separation ``S_p`` of each step, m."""
    return log.margin if log.margin is not None else np.full(log.t.size, np.nan)


def task_time_lost(log: RunLog, reference: RunLog) -> float:
    """Task time lost by ``log`` against ``reference`` (the same run without a person), s.

    With the task clock (``resume``): how far the clock lags the reference's at the end. Without it
    (the reference runs on ``t``, so the task never waits): the extra time the flange is off its
    reference by more than :data:`RECOVERY_THRESHOLD`.
    """
    if reference.t.size < log.t.size:
        raise ConfigError(
            f"task time lost: a reference of {reference.t.size} steps is shorter than the run's {log.t.size}"
        )
    dt = float(log.t[1] - log.t[0]) if log.t.size > 1 else 0.0
    clock = log.task_time if log.task_time is not None else log.t
    S = log.t.size  # a longer reference (the same run without a person, run longer) is cut to the run
    ref_clock = (reference.task_time if reference.task_time is not None else reference.t)[:S]
    if not np.array_equal(clock, log.t):  # the clock paused somewhere
        return float(max(ref_clock[-1] - clock[-1], 0.0))
    ref_off = np.sum(reference.tracking_error[:S] > RECOVERY_THRESHOLD)
    off = np.sum(log.tracking_error > RECOVERY_THRESHOLD) - ref_off
    return float(max(off, 0) * dt)


@dataclass(frozen=True)
class AvoidMetrics:
    """Summary of one run (lengths m, times s unless the name says ms)."""

    scenario: str
    poses: str
    min_clearance_m: float
    contacts: int
    contact_time_s: float
    max_tracking_error_m: float
    rms_tracking_error_m: float
    final_tracking_error_m: float
    recovery_s: float
    active_time_s: float
    infeasible_steps: int
    qp_median_ms: float
    qp_p95_ms: float
    step_median_ms: float
    loop_median_ms: float
    loop_p95_ms: float
    steps: int
    min_clearance_minus_sp_m: float = float("nan")
    steps_below_sp: int = 0
    margin_m: float = float("nan")
    margin_max_m: float = float("nan")
    margin_terms: dict | None = None
    protective_stop_s: float = 0.0
    near_time_s: float = 0.0
    task_time_lost_s: float = float("nan")
    mode: str = "kinematic"

    def to_dict(self) -> dict:
        """Plain JSON-ready dict (NaN/inf -> None)."""

        def plain(v):
            if isinstance(v, dict):
                return {k: plain(x) for k, x in v.items()}
            return None if isinstance(v, float) and not np.isfinite(v) else v

        return {k: plain(v) for k, v in asdict(self).items()}


def summarize(log: RunLog, body: RobotBody, poses: str = "", reference: RunLog | None = None) -> AvoidMetrics:
    """All metrics of a run; ``body`` is the TRUE robot geometry (as simulated); ``reference`` the same
    run without a person (for the task time lost; NaN without it)."""
    clear = clearance(log, body)
    sp = margin_of(log)
    gap = clear - sp
    finite = np.isfinite(gap)
    worst = int(np.argmin(np.where(finite, gap, np.inf))) if np.any(finite) else -1
    terms = None
    if worst >= 0 and log.terms:
        terms = {name: float(log.terms[name][worst]) for name in TERMS if name in log.terms}
    stop = log.protective_stop if log.protective_stop is not None else ~log.feasible
    err = log.tracking_error
    dt = float(log.t[1] - log.t[0]) if log.t.size > 1 else 0.0
    ms = 1e3
    return AvoidMetrics(
        scenario=log.scenario.name,
        poses=poses,
        min_clearance_m=float(clear.min()),
        contacts=count_contacts(clear),
        contact_time_s=float(np.sum(clear < 0) * dt),
        max_tracking_error_m=float(err.max()),
        rms_tracking_error_m=float(np.sqrt(np.mean(err**2))),
        final_tracking_error_m=float(err[-1]),
        recovery_s=recovery_time(log.t, err, log.scenario.t_leave),
        active_time_s=float(np.sum(log.n_obstacles > 0) * dt),
        infeasible_steps=int(np.sum(~log.feasible)),
        qp_median_ms=float(np.median(log.solve_time_s) * ms),
        qp_p95_ms=float(np.percentile(log.solve_time_s, 95) * ms),
        step_median_ms=float(np.median(log.step_time_s) * ms),
        loop_median_ms=float(np.median(log.loop_time_s) * ms),
        loop_p95_ms=float(np.percentile(log.loop_time_s, 95) * ms),
        steps=int(log.t.size),
        min_clearance_minus_sp_m=float(gap[worst]) if worst >= 0 else float("inf"),
        steps_below_sp=int(np.sum(finite & (gap < 0))),
        margin_m=float(sp[worst]) if worst >= 0 else float("nan"),
        margin_max_m=float(np.nanmax(sp)) if np.any(np.isfinite(sp)) else float("nan"),
        margin_terms=terms,
        protective_stop_s=float(np.sum(stop) * dt),
        near_time_s=float(np.sum(finite & (gap < NEAR_BAND)) * dt),
        task_time_lost_s=task_time_lost(log, reference) if reference is not None else float("nan"),
        mode=log.mode,
    )
