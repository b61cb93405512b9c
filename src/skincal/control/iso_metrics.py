"""Metrics of a closed-loop avoidance run as functions of arrays: clearance, contacts, tracking error and
recovery, ISO/TS 15066 margins, QP timing.

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

Every function takes arrays (instants ``t`` ``(S,)`` s, configurations ``q`` ``(S, n)`` rad, errors m) and
the obstacle solids as a function of time (``solids_at(t) -> [skin.tof solids]``, base frame): no
simulator. A run of the MuJoCo experiment is summarised by :func:`skincal.workflows.experiment.summarize`.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, dataclass

import numpy as np

from skincal.errors import ConfigError
from skincal.kinematics.transforms import FloatArray
from skincal.perception.body import RobotBody, segment_distance
from skincal.skin import tof

RECOVERY_THRESHOLD = 0.005
"""Tracking error below which the task counts as recovered, m."""
NEAR_BAND = 0.5
"""The person counts as near while the clearance is below ``S_p`` plus this, m."""
TERMS = ("S_h", "S_r", "S_s", "C", "Z_d", "Z_r")
"""The parts of ISO/TS 15066's protective separation distance ``S_p``, in its order."""

SolidsAt = Callable[[FloatArray], Sequence[object]]
"""``solids_at(t)``: the obstacle solids (:mod:`skincal.skin.tof` spheres and capsules, end points
``(M, 3)``) at instants ``t`` ``(M,)`` s."""

_CHUNK = 2000


def obstacle_segments(solids: Sequence[object], M: int) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Obstacle ``solids`` at ``M`` instants as segments: ends ``(M, P, 3)`` each and radii ``(P,)``, m.

    Spheres are zero-length segments; other solids (boxes, planes) are not supported here.
    """
    a, b, r = [], [], []
    for p in solids:
        if isinstance(p, tof.Sphere):
            a.append(p.center)
            b.append(p.center)
        elif isinstance(p, tof.Capsule):
            a.append(p.p0)
            b.append(p.p1)
        else:
            raise ConfigError(f"clearance: obstacle solid {type(p).__name__} is not supported (spheres and capsules)")
        r.append(float(np.asarray(p.radius)))
    if not a:
        return np.zeros((M, 0, 3)), np.zeros((M, 0, 3)), np.zeros(0)
    stack = lambda xs: np.stack([np.broadcast_to(x, (M, 3)) for x in xs], axis=1)  # noqa: E731
    return stack(a), stack(b), np.array(r)


def clearance(t: FloatArray, q: FloatArray, body: RobotBody, solids_at: SolidsAt | None) -> FloatArray:
    """``(S,)`` smallest distance between the robot capsules of ``body`` at ``q`` ``(S, n)`` and the obstacle
    solids at ``t`` ``(S,)``, m (inf: none; ``solids_at`` None: no obstacles)."""
    S = t.size
    out = np.full(S, np.inf)
    if solids_at is None:
        return out
    for k0 in range(0, S, _CHUNK):
        sl = slice(k0, min(S, k0 + _CHUNK))
        oa, ob, orad = obstacle_segments(solids_at(t[sl]), t[sl].size)
        if orad.size == 0:
            continue
        ra, rb = body.segments(body.chain.link_frames(q[sl]))  # (M, C, 3)
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


def task_time_lost(
    t: FloatArray,
    tracking_error: FloatArray,
    task_time: FloatArray | None,
    ref_t: FloatArray,
    ref_tracking_error: FloatArray,
    ref_task_time: FloatArray | None,
) -> float:
    """Task time lost by a run (``t`` ``(S,)`` s, ``tracking_error`` ``(S,)`` m, its task clock ``task_time``
    ``(S,)`` s or None) against a reference (the same run without a person, at least ``S`` steps), s.

    With the task clock (``resume``): how far the clock lags the reference's at the end. Without it
    (the reference runs on ``t``, so the task never waits): the extra time the flange is off its
    reference by more than :data:`RECOVERY_THRESHOLD`.
    """
    if ref_t.size < t.size:
        raise ConfigError(f"task time lost: a reference of {ref_t.size} steps is shorter than the run's {t.size}")
    dt = float(t[1] - t[0]) if t.size > 1 else 0.0
    clock = task_time if task_time is not None else t
    S = t.size  # a longer reference (the same run without a person, run longer) is cut to the run
    ref_clock = (ref_task_time if ref_task_time is not None else ref_t)[:S]
    if not np.array_equal(clock, t):  # the clock paused somewhere
        return float(max(ref_clock[-1] - clock[-1], 0.0))
    ref_off = np.sum(ref_tracking_error[:S] > RECOVERY_THRESHOLD)
    off = np.sum(tracking_error > RECOVERY_THRESHOLD) - ref_off
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


def summarize_run(
    *,
    scenario: str,
    poses: str,
    t: FloatArray,
    clear: FloatArray,
    margin: FloatArray,
    terms: Mapping[str, FloatArray],
    tracking_error: FloatArray,
    t_leave: float,
    protective_stop: np.ndarray,
    feasible: np.ndarray,
    n_obstacles: np.ndarray,
    solve_time_s: FloatArray,
    step_time_s: FloatArray,
    loop_time_s: FloatArray,
    task_time_lost_s: float = float("nan"),
    mode: str = "kinematic",
) -> AvoidMetrics:
    """All metrics of a run from its arrays (each ``(S,)``): the clearance (:func:`clearance`), the
    protective separation ``margin`` ``S_p`` and its ``terms`` per step (m), the flange's tracking error
    (m), the steps in protective stop, with a feasible QP, with obstacle rows, and the timings (s)."""
    gap = clear - margin
    finite = np.isfinite(gap)
    worst = int(np.argmin(np.where(finite, gap, np.inf))) if np.any(finite) else -1
    parts = None
    if worst >= 0 and terms:
        parts = {name: float(terms[name][worst]) for name in TERMS if name in terms}
    err = tracking_error
    dt = float(t[1] - t[0]) if t.size > 1 else 0.0
    ms = 1e3
    return AvoidMetrics(
        scenario=scenario,
        poses=poses,
        min_clearance_m=float(clear.min()),
        contacts=count_contacts(clear),
        contact_time_s=float(np.sum(clear < 0) * dt),
        max_tracking_error_m=float(err.max()),
        rms_tracking_error_m=float(np.sqrt(np.mean(err**2))),
        final_tracking_error_m=float(err[-1]),
        recovery_s=recovery_time(t, err, t_leave),
        active_time_s=float(np.sum(n_obstacles > 0) * dt),
        infeasible_steps=int(np.sum(~feasible)),
        qp_median_ms=float(np.median(solve_time_s) * ms),
        qp_p95_ms=float(np.percentile(solve_time_s, 95) * ms),
        step_median_ms=float(np.median(step_time_s) * ms),
        loop_median_ms=float(np.median(loop_time_s) * ms),
        loop_p95_ms=float(np.percentile(loop_time_s, 95) * ms),
        steps=int(t.size),
        min_clearance_minus_sp_m=float(gap[worst]) if worst >= 0 else float("inf"),
        steps_below_sp=int(np.sum(finite & (gap < 0))),
        margin_m=float(margin[worst]) if worst >= 0 else float("nan"),
        margin_max_m=float(np.nanmax(margin)) if np.any(np.isfinite(margin)) else float("nan"),
        margin_terms=parts,
        protective_stop_s=float(np.sum(protective_stop) * dt),
        near_time_s=float(np.sum(finite & (gap < NEAR_BAND)) * dt),
        task_time_lost_s=task_time_lost_s,
        mode=mode,
    )
