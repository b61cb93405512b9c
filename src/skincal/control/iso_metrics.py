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
simulator.

ISO/TS 15066's own criteria (:func:`iso_criteria`, issue 28): speed and separation monitoring asks that
whenever the separation is below ``S_p`` the robot is stopped or moving away: per step, the speed of the
TRUE robot point nearest the person toward it (the robot's actual joint velocity) must be <= 0 inside
``S_p`` (``ssm``), or <= the body region's transient speed limit at the point's effective mass (power and
force limiting, ``pfl``); every contact is judged against the region's Annex A limits
(:mod:`skincal.control.body_regions`) and split into robot-initiated and person-initiated.
A run of the MuJoCo experiment is summarised by :func:`skincal.workflows.experiment.summarize`.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import asdict, dataclass

import numpy as np

from skincal.control.body_regions import BodyRegion, contact_force, pfl_speed_limit, transfer_energy
from skincal.control.effective_mass import MassMatrix, effective_mass
from skincal.errors import ConfigError
from skincal.kinematics.stopping import StoppingModel
from skincal.kinematics.transforms import FloatArray
from skincal.perception.body import RobotBody, segment_closest_points, segment_distance
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


def _capsule_distances(t: FloatArray, q: FloatArray, body: RobotBody, solids_at: SolidsAt) -> Iterator[tuple]:
    """Per chunk of instants with solids: ``(sl, d, ra, rb, oa, ob)``, the surface distance
    ``d = |core_c - core_p| - r_c - r_p`` ``(M, C, P)`` of every robot capsule ``c`` and solid ``p`` (m) and
    their core segments (robot ``(M, C, 3)``, solids ``(M, P, 3)``, base frame)."""
    S = t.size
    for k0 in range(0, S, _CHUNK):
        sl = slice(k0, min(S, k0 + _CHUNK))
        oa, ob, orad = obstacle_segments(solids_at(t[sl]), t[sl].size)
        if orad.size == 0:
            continue
        ra, rb = body.segments(body.chain.link_frames(q[sl]))  # (M, C, 3)
        d = segment_distance(ra[:, :, None], rb[:, :, None], oa[:, None], ob[:, None])  # (M, C, P)
        yield sl, d - body.radius[None, :, None] - orad[None, None, :], ra, rb, oa, ob


def clearance(t: FloatArray, q: FloatArray, body: RobotBody, solids_at: SolidsAt | None) -> FloatArray:
    """``(S,)`` smallest distance between the robot capsules of ``body`` at ``q`` ``(S, n)`` and the obstacle
    solids at ``t`` ``(S,)``, m (inf: none; ``solids_at`` None: no obstacles)."""
    out = np.full(t.size, np.inf)
    if solids_at is None:
        return out
    for sl, d, *_ in _capsule_distances(t, q, body, solids_at):
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
    iso: dict | None = None
    """The ISO/TS 15066 criteria of the run (:meth:`IsoCriteria.summary`), None when not judged."""

    def to_dict(self) -> dict:
        """Plain JSON-ready dict (NaN/inf -> None)."""

        def plain(v):
            if isinstance(v, dict):
                return {k: plain(x) for k, x in v.items()}
            if isinstance(v, (list, tuple)):
                return [plain(x) for x in v]
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
    iso: IsoCriteria | None = None,
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
        iso=iso.summary() if iso is not None else None,
    )


# ------------------------------------------------------------------- ISO/TS 15066 criteria (issue 28)
APPROACH_TOLERANCE_MPS = 1e-3
"""Speed toward a person (m/s) below which a robot point counts as not approaching (numerical noise of the
finite-difference velocities; 1 mm/s)."""
CRITERIA = ("ssm", "pfl")
"""``ssm``: inside ``S_p`` the robot point nearest the person must not approach it (ISO/TS 15066 5.5.4);
``pfl``: it may, up to the body region's Annex A transient speed at its effective mass (5.5.5, Annex A)."""


@dataclass(frozen=True)
class NearestPairs:
    """Per control instant the nearest pair of a TRUE robot capsule and an obstacle solid (each ``(S,)`` or
    ``(S, 3)``; base frame, m).

    Attributes:
        clearance: surface-to-surface distance (:func:`clearance`; inf without solids).
        capsule: index of the robot capsule (``body``'s order; -1 without solids).
        solid: index of the obstacle solid (``solids_at``'s order; -1 without solids).
        p_robot: the robot's surface point facing the solid (core point + radius along ``normal``).
        normal: unit vector from the robot's core point to the solid's.
        p_solid: the solid's core point (on its segment).
    """

    clearance: FloatArray
    capsule: np.ndarray
    solid: np.ndarray
    p_robot: FloatArray
    normal: FloatArray
    p_solid: FloatArray


def nearest_pairs(t: FloatArray, q: FloatArray, body: RobotBody, solids_at: SolidsAt | None) -> NearestPairs:
    """:class:`NearestPairs` of the robot at ``q`` ``(S, n)`` and the solids at ``t`` ``(S,)``; the clearance
    is :func:`clearance`'s, number for number."""
    S = t.size
    out = NearestPairs(np.full(S, np.inf), np.full(S, -1), np.full(S, -1), np.zeros((S, 3)),
                       np.tile([0.0, 0.0, 1.0], (S, 1)), np.zeros((S, 3)))  # fmt: skip
    if solids_at is None:
        return out
    for sl, d, ra, rb, oa, ob in _capsule_distances(t, q, body, solids_at):
        M, C, P = d.shape
        flat = d.reshape(M, -1)
        best = np.argmin(flat, axis=1)
        cap, sol = best // P, best % P
        m = np.arange(M)
        c_r, c_h = segment_closest_points(ra[m, cap], rb[m, cap], oa[m, sol], ob[m, sol])
        g = c_h - c_r
        norm = np.linalg.norm(g, axis=1, keepdims=True)
        normal = np.where(norm > 1e-12, g / np.maximum(norm, 1e-12), np.array([0.0, 0.0, 1.0]))
        out.clearance[sl] = flat[m, best]
        out.capsule[sl], out.solid[sl] = cap, sol
        out.p_robot[sl] = c_r + body.radius[cap][:, None] * normal
        out.normal[sl], out.p_solid[sl] = normal, c_h
    return out


def approach_speeds(
    t: FloatArray, q: FloatArray, body: RobotBody, solids_at: SolidsAt | None, pairs: NearestPairs
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """``(v_robot, v_person, J_n)``: per instant ``(S,)`` the speed of the robot's surface point toward the
    nearest solid and of that solid toward the robot (m/s, > 0: approaching), and ``(S, n)`` the rows
    ``n^T J`` of the robot point (the robot's actual joint velocity: forward differences of ``q``, the
    last repeated; the solid's velocity: forward differences of its core point's ends over one step)."""
    S, n = q.shape
    Jn = np.zeros((S, n))
    v_r, v_h = np.zeros(S), np.zeros(S)
    if solids_at is None or S < 2:
        return v_r, v_h, Jn
    dt = float(t[1] - t[0])
    qd = np.empty_like(q)
    qd[:-1] = np.diff(q, axis=0) / dt
    qd[-1] = qd[-2]
    for k0 in range(0, S, _CHUNK):
        sl = slice(k0, min(S, k0 + _CHUNK))
        ok = pairs.capsule[sl] >= 0
        if not np.any(ok):
            continue
        idx = np.flatnonzero(ok) + k0
        T = body.chain.link_frames(q[idx])
        J = body.chain.point_jacobians(T, body.link[pairs.capsule[idx]], pairs.p_robot[idx])  # (M, 3, n)
        Jn[idx] = np.einsum("ki,kij->kj", pairs.normal[idx], J)
        v_r[idx] = np.einsum("kj,kj->k", Jn[idx], qd[idx])
        a0, b0, _ = obstacle_segments(solids_at(t[idx]), idx.size)
        a1, b1, _ = obstacle_segments(solids_at(t[idx] + dt), idx.size)
        m, s = np.arange(idx.size), pairs.solid[idx]
        vel = 0.5 * ((a1[m, s] - a0[m, s]) + (b1[m, s] - b0[m, s])) / dt  # translation of the solid
        v_h[idx] = -np.einsum("ki,ki->k", pairs.normal[idx], vel)
    return v_r, v_h, Jn


@dataclass(frozen=True)
class ContactEvent:
    """One contact (the first instant of a run of clearance < 0) judged by ISO/TS 15066 Annex A.

    Speeds are taken one step before the touch (the impact), m/s; masses kg; energies J; forces N.
    ``region`` None: an object, not a person (no contact is permitted; any approach is robot-initiated).
    ``robot_initiated``: the robot point moved toward the person faster than the allowed speed (0 for
    ``ssm``, the Annex A limit for ``pfl``); ``within_limits``: the robot's share of the contact (its own
    speed toward the person) is within the region's transient limit, ``v_robot <= v_limit`` (equivalently
    ``energy <= energy_limit``, ``force <= force_limit``); the person's own speed (``v_person``) is reported
    with ``energy_relative`` (the relative speed's energy) and is the person's doing. ``robot_approaching``:
    the robot point moved toward the person at all (faster than the tolerance): under ``pfl`` a contact may
    be that and still not robot-initiated (within the limit)."""

    t: float
    obstacle_solid: int
    region: str | None
    v_robot: float
    v_person: float
    m_robot: float
    v_limit: float
    energy: float
    energy_relative: float
    energy_limit: float
    force: float
    force_limit: float
    robot_initiated: bool
    within_limits: bool
    robot_approaching: bool = False


@dataclass(frozen=True)
class IsoCriteria:
    """The run against ISO/TS 15066's criteria (:func:`iso_criteria`); times s, speeds m/s.

    The standard's criterion is on the *measured* separation (its ``S_p`` has the intrusion distance ``C``
    and the sensing uncertainty ``Z_d`` for what the sensors miss): per perceived point inside its ``S_p``,
    the robot point's actual speed toward it. The same test against the TRUE geometry (the true nearest pair
    of robot and person, the step's ``S_p``) is stricter and reported beside it (``true_*``).

    Attributes:
        criterion: ``ssm`` or ``pfl`` (:data:`CRITERIA`).
        inside_sp_s: time some perceived point was inside its ``S_p``.
        violation_s: time inside ``S_p`` with the robot point approaching the point faster than allowed
            (must be 0).
        violation_steps: steps of it.
        max_approach_inside_sp_mps: the largest actual speed of a robot point toward a point inside ``S_p``.
        max_excess_mps: the largest amount by which that speed exceeded the allowed one (<= 0: none).
        true_inside_sp_s, true_violation_s, true_max_approach_mps: the same against the true geometry.
        contacts: the contacts (:class:`ContactEvent`, true geometry).
        passed: no violation (measured separation) and every contact within its limits.
        braking_s: of ``violation_s``, the time that is a stop in progress from the step the robot came inside
            ``S_p`` (:func:`braking_steps`; NaN without a stopping model). Reported, not excused: ``passed``
            does not use it.
    """

    criterion: str
    inside_sp_s: float
    violation_s: float
    violation_steps: int
    max_approach_inside_sp_mps: float
    max_excess_mps: float
    true_inside_sp_s: float
    true_violation_s: float
    true_max_approach_mps: float
    contacts: tuple[ContactEvent, ...]
    passed: bool
    braking_s: float = float("nan")

    def summary(self) -> dict:
        """The metrics' flat fields (JSON-ready): counts, peaks and the verdict."""
        c = self.contacts
        worst = max(c, key=lambda e: e.energy / e.energy_limit if e.energy_limit > 0 else np.inf, default=None)
        return {
            "iso_criterion": self.criterion,
            "inside_sp_s": self.inside_sp_s,
            "sp_violation_s": self.violation_s,
            "sp_violation_steps": self.violation_steps,
            "sp_violation_braking_s": self.braking_s,
            "max_approach_inside_sp_mps": self.max_approach_inside_sp_mps,
            "max_approach_excess_mps": self.max_excess_mps,
            "true_inside_sp_s": self.true_inside_sp_s,
            "true_sp_violation_s": self.true_violation_s,
            "true_max_approach_inside_sp_mps": self.true_max_approach_mps,
            "contacts_robot_initiated": sum(e.robot_initiated for e in c),
            "contacts_person_initiated": sum(not e.robot_initiated for e in c),
            "contacts_within_limits": sum(e.within_limits for e in c),
            "contacts_robot_approaching": sum(e.robot_approaching for e in c),
            "peak_contact_energy_j": worst.energy if worst is not None else 0.0,
            "peak_contact_energy_limit_j": worst.energy_limit if worst is not None else float("nan"),
            "peak_contact_force_n": max((e.force for e in c), default=0.0),
            "iso_pass": self.passed,
            "contact_events": [asdict(e) for e in c],
        }


def iso_criteria(
    t: FloatArray,
    q: FloatArray,
    body: RobotBody,
    solids_at: SolidsAt | None,
    margin: FloatArray,
    regions: Sequence[object | None],
    mass_matrix: MassMatrix | None,
    criterion: str = "ssm",
    tolerance: float = APPROACH_TOLERANCE_MPS,
    measured: tuple[np.ndarray, FloatArray, FloatArray] | None = None,
    stopping: StoppingModel | None = None,
) -> IsoCriteria:
    """A run (instants ``t`` ``(S,)``, configurations ``q`` ``(S, n)``, the step's ``S_p`` ``margin`` ``(S,)``)
    against ISO/TS 15066: at each step the TRUE nearest pair of robot and solid (:func:`nearest_pairs`), the
    robot point's speed toward it (:func:`approach_speeds`), inside ``S_p`` at most 0 (``ssm``) or the body
    region's Annex A speed at the point's effective mass (``pfl``; :mod:`skincal.control.body_regions`,
    :mod:`skincal.control.effective_mass`), plus ``tolerance``; every contact judged (:class:`ContactEvent`).

    ``regions``: per solid (``solids_at``'s order) its :class:`~skincal.control.body_regions.BodyRegion` or
    None (an object). ``mass_matrix``: ``q -> M(q)`` ``(n, n)`` (None: effective mass unknown, taken as
    infinite: the most cautious limit). ``measured``: per step ``(inside, approach, excess)`` ``(S,)`` each:
    the number of perceived points inside their ``S_p``, the robot's largest actual speed toward them and
    its largest excess over their allowed speed, m/s (:class:`skincal.workflows.avoidance.RunLog`'s
    ``sp_*``); the standard's criterion. None: the true-geometry test is the criterion. ``stopping``: the
    robot's stopping model, for the share of the violation that is a stop in progress (:func:`braking_steps`)."""
    if criterion not in CRITERIA:
        raise ConfigError(f"unknown ISO criterion '{criterion}' (use {' or '.join(CRITERIA)})")
    S = t.size
    dt = float(t[1] - t[0]) if S > 1 else 0.0
    pairs = nearest_pairs(t, q, body, solids_at)
    v_r, v_h, Jn = approach_speeds(t, q, body, solids_at, pairs)
    inside = np.isfinite(pairs.clearance) & (pairs.clearance < margin)
    touching = np.concatenate([[False], pairs.clearance < 0])
    onsets = np.flatnonzero(touching[1:] & ~touching[:-1])
    impact = np.maximum(onsets - 1, 0)
    need = np.union1d(np.flatnonzero(inside), impact)

    def m_eff(k: int) -> float:
        if mass_matrix is None:
            return float("inf")
        return float(effective_mass(Jn[k][None], mass_matrix(q[k]))[0])

    masses = {int(k): m_eff(int(k)) for k in need} if criterion == "pfl" or onsets.size else {}

    def limit(k: int) -> tuple[float, BodyRegion | None]:
        region = regions[pairs.solid[k]] if pairs.solid[k] >= 0 else None
        if not isinstance(region, BodyRegion):
            return 0.0, None
        return float(pfl_speed_limit(region, masses.get(k, float("inf")))), region

    allowed = np.zeros(S)
    if criterion == "pfl":
        for k in np.flatnonzero(inside):
            allowed[k] = limit(int(k))[0]
    bad = inside & (v_r > allowed + tolerance)
    events = []
    for k0, k in zip(onsets, impact, strict=True):
        k = int(k)
        v_lim, region = limit(k)
        v_allowed = v_lim if criterion == "pfl" else 0.0
        vr, vh, mr = float(v_r[k]), float(v_h[k]), masses.get(k, float("inf"))
        if region is None:
            energy = e_rel = e_lim = force = f_lim = float("nan")
        else:
            energy = float(transfer_energy(region, mr, vr))
            e_rel = float(transfer_energy(region, mr, vr + max(vh, 0.0)))
            e_lim, force = region.transient_energy, float(contact_force(region, mr, vr))
            f_lim = region.transient_force or 0.0
        events.append(ContactEvent(
            float(t[k0]), int(pairs.solid[k]), None if region is None else region.name, vr, vh, mr, v_lim, energy,
            e_rel, e_lim, force, f_lim, vr > v_allowed + tolerance, vr <= v_lim + tolerance, vr > tolerance,
        ))  # fmt: skip
    excess = v_r - allowed
    true_approach = float(v_r[inside].max()) if np.any(inside) else 0.0
    if measured is None:
        m_inside, m_bad = inside, bad
        m_approach, m_excess = true_approach, float(excess[inside].max()) if np.any(inside) else float("-inf")
    else:
        m_inside = np.asarray(measured[0]) > 0
        m_bad = m_inside & (np.asarray(measured[2]) > tolerance)
        m_approach = float(np.max(measured[1][m_inside])) if np.any(m_inside) else 0.0
        m_excess = float(np.max(measured[2][m_inside])) if np.any(m_inside) else float("-inf")
    braking = float("nan")
    if stopping is not None:
        speed = measured[1] if measured is not None else np.where(inside, v_r, -np.inf)
        braking = float(np.sum(braking_steps(m_inside, m_bad, np.asarray(speed, dtype=float), dt, stopping)) * dt)
    return IsoCriteria(
        braking_s=braking,
        criterion=criterion,
        inside_sp_s=float(np.sum(m_inside) * dt),
        violation_s=float(np.sum(m_bad) * dt),
        violation_steps=int(np.sum(m_bad)),
        max_approach_inside_sp_mps=m_approach,
        max_excess_mps=m_excess,
        true_inside_sp_s=float(np.sum(inside) * dt),
        true_violation_s=float(np.sum(bad) * dt),
        true_max_approach_mps=true_approach,
        contacts=tuple(events),
        passed=bool(not np.any(m_bad) and all(e.within_limits and not e.robot_initiated for e in events)),
    )


def braking_steps(
    inside: np.ndarray, bad: np.ndarray, approach: FloatArray, dt: float, stopping: StoppingModel
) -> np.ndarray:
    """``(S,)`` the violating steps (``bad``) that are a stop in progress: in a run of consecutive steps
    ``inside`` ``S_p`` entered at step ``k0`` with the robot approaching at ``v0 = approach[k0]`` (m/s), the
    steps ``k`` up to the first one that is not braking, where braking means the approach speed never above
    ``v0`` and ``t_k - t_k0 <= T_r + T_s(v0)`` of the stopping model. (What ``S_r + S_s`` of ``S_p`` budget
    for: ISO/TS 15066 asks the robot to initiate its stop when the separation falls below ``S_p``, and a
    drive cannot reverse at once; a point first perceived inside ``S_p``, a part the skin had not seen, is
    such an entry.)"""
    S = inside.size
    out = np.zeros(S, dtype=bool)
    k = 0
    while k < S:
        if not inside[k]:
            k += 1
            continue
        k0, v0 = k, float(approach[k])
        limit = stopping.reaction_time_s + float(stopping.stopping_time(max(v0, 0.0)))
        braking = True
        while k < S and inside[k]:
            braking = braking and approach[k] <= v0 + 1e-12 and (k - k0) * dt <= limit + 1e-12
            out[k] = braking and bad[k]
            k += 1
    return out
