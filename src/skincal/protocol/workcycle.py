"""Everyday robot motion: a pick-and-place cycle and a teleoperation-like random smooth motion.

Both are :class:`~skincal.protocol.trajectory.Trajectory` objects (exact piecewise form, sampled at
``rate_hz``), so the simulators take them like a protocol: ``Session(chain, placements,
work_cycle(chain, "pick-place", rng), ...)``. Neither excites one joint at a time: several joints
move together, as in a robot's daily work, and the calibration has to make do with it (issue 16).

The motion is a list of *waypoints* ``q_k`` joined by quintic pieces. At a waypoint the robot either
**rests** (zero velocity and acceleration, for ``rest_s`` s: a gripper closing at the pick, opening at
the place, an operator's pause) or **passes through** with the velocity

    v_k = lambda_k (q_{k+1} - q_{k-1}) / (T_{k-1} + T_k),     lambda_k in [0, 1]

(a Catmull-Rom tangent, zero acceleration), so that position, velocity and acceleration are
continuous. A piece from ``(x0, v0, 0)`` to ``(x1, v1, 0)`` over ``T`` s is the quintic of
:func:`via_quintic_coef`; ``T`` is :func:`skincal.protocol.limits.move_duration` of the rest-to-rest
move at a peak speed drawn per piece (``config.speed_range`` times ``move_speed``, capped at each
joint's velocity limit, lengthened for the acceleration bounds).

Limits and collisions: every waypoint lies in the position limits shrunk by ``limit_margin`` and is
collision-free (:mod:`skincal.protocol.collision`); every rest-to-rest move between two waypoints is
collision-free (checked every :data:`~skincal.protocol.collision.CHECK_STEP_S`). A piece with
pass-through velocities that leaves the limits (position, velocity, acceleration bounds) or collides
is replaced by the rest-to-rest move (its end velocities set to zero, which may also change its
neighbours: repeated until every piece passes). The sampled trajectory is checked once more as a whole,
like :func:`~skincal.protocol.trajectory.build_trajectory`.

Segments: every rest gives a STATIC segment (its middle, ``settle_s`` kept from either end); there
are no DYNAMIC segments (no single joint is excited), so calibration uses the joint data for the rest.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from skincal.data.dataset import STATIC, Segments
from skincal.errors import ConfigError, ProtocolError
from skincal.kinematics.chain import SerialChain
from skincal.kinematics.transforms import FloatArray
from skincal.protocol.config import ProtocolConfig
from skincal.protocol.limits import acceleration_bounds, check_limits, move_duration, position_bounds
from skincal.protocol.motion import eval_piece, hold_coef, quintic_move_samples
from skincal.protocol.trajectory import Trajectory

WORK_CYCLES = ("pick-place", "teleop")
"""Names of the everyday motions of :func:`work_cycle`."""

MAX_DRAWS = 200
"""Draws allowed per waypoint (or per pick/place layout) before giving up (limits, collisions)."""


@dataclass(frozen=True)
class WorkCycleConfig:
    """Parameters of an everyday motion.

    Attributes:
        duration_s: the motion lasts at least this long, s (it ends at a rest).
        rate_hz: sampling rate of the robot stream, Hz.
        move_speed: peak joint speed of a move, rad/s, before the per-piece draw of ``speed_range`` (capped
            at each joint's velocity limit; brisk moves are what make a unit's position observable).
        speed_range: each piece's peak speed is ``move_speed`` times a uniform draw in this range.
        min_move_s: shortest piece, s.
        limit_margin: distance kept from every joint position limit, rad.
        settle_s: time at either end of a rest that is not part of its STATIC segment, s.
        pick_rest_s, place_rest_s: rests at the pick and at the place (gripper), s.
        approach_rad: size of the joint offset from a pick/place pose to its approach pose, rad.
        jitter_rad: the pick and place poses vary by this much (std per joint) from cycle to cycle, rad.
        step_rad: teleoperation: std of a waypoint's step from the previous one per joint, rad.
        pause_probability: teleoperation: probability that the operator pauses at a waypoint.
        pause_range_s: teleoperation: a pause lasts a uniform draw in this range, s.
        tangent_range: the pass-through factor ``lambda_k`` is drawn uniformly in this range.
    """

    duration_s: float = 60.0
    rate_hz: float = 1000.0
    move_speed: float = 2.0
    speed_range: tuple[float, float] = (0.4, 1.0)
    min_move_s: float = 0.6
    limit_margin: float = 0.1
    settle_s: float = 0.25
    pick_rest_s: float = 1.5
    place_rest_s: float = 1.5
    approach_rad: float = 0.3
    jitter_rad: float = 0.05
    step_rad: float = 0.35
    pause_probability: float = 0.3
    pause_range_s: tuple[float, float] = (0.8, 3.0)
    tangent_range: tuple[float, float] = (0.3, 1.0)

    def __post_init__(self) -> None:
        for key in ("duration_s", "rate_hz", "move_speed", "min_move_s", "pick_rest_s", "place_rest_s"):
            value = getattr(self, key)
            if not (isinstance(value, (int, float, np.number)) and np.isfinite(value) and value > 0):
                raise ConfigError(f"work cycle: {key} must be a positive number, got {value!r}")
        for key in ("limit_margin", "settle_s", "approach_rad", "jitter_rad", "step_rad"):
            value = getattr(self, key)
            if not (isinstance(value, (int, float, np.number)) and np.isfinite(value) and value >= 0):
                raise ConfigError(f"work cycle: {key} must be a non-negative number, got {value!r}")
        if not 0 <= self.pause_probability <= 1:
            raise ConfigError(f"work cycle: pause_probability must be in [0, 1], got {self.pause_probability!r}")
        for key, lo_min in (("speed_range", 0.0), ("pause_range_s", 0.0), ("tangent_range", 0.0)):
            lo, hi = getattr(self, key)
            if not (np.isfinite(lo) and np.isfinite(hi) and lo_min <= lo <= hi) or (key != "tangent_range" and lo <= 0):
                raise ConfigError(f"work cycle: {key} must be an increasing pair of positive numbers, got {(lo, hi)!r}")
        if self.tangent_range[1] > 1:
            raise ConfigError(f"work cycle: tangent_range must lie in [0, 1], got {self.tangent_range!r}")


def via_quintic_coef(x0: FloatArray, v0: FloatArray, x1: FloatArray, v1: FloatArray, T: float) -> FloatArray:
    """Quintic ``(n, 6)`` from ``(x0, v0, 0)`` to ``(x1, v1, 0)`` in ``T`` s (ascending powers).

    With ``h = x1 - x0 - v0 T`` and ``dv = v1 - v0``: ``c3 = (10 h - 4 dv T) / T^3``,
    ``c4 = (-15 h + 7 dv T) / T^4``, ``c5 = (6 h - 3 dv T) / T^5``.
    """
    x0, v0, x1, v1 = (np.asarray(a, dtype=float) for a in (x0, v0, x1, v1))
    h = x1 - x0 - v0 * T
    dv = v1 - v0
    zero = np.zeros_like(x0)
    return np.stack(
        [x0, v0, zero, (10 * h - 4 * dv * T) / T**3, (-15 * h + 7 * dv * T) / T**4, (6 * h - 3 * dv * T) / T**5],
        axis=-1,
    )


class _Planner:
    """Waypoint checks and piece timing shared by both motions."""

    def __init__(self, chain: SerialChain, cfg: WorkCycleConfig, rng: np.random.Generator, name: str) -> None:
        from skincal.protocol.collision import CHECK_STEP_S, CollisionModel

        self.chain, self.cfg, self.rng, self.name = chain, cfg, rng, name
        self.step = CHECK_STEP_S
        self.model = CollisionModel(chain)
        lower, upper = position_bounds(chain)
        self.lo, self.hi = lower + cfg.limit_margin, upper - cfg.limit_margin
        if np.any(self.lo >= self.hi):
            j = int(np.argmax(self.lo >= self.hi))
            raise ProtocolError(
                f"robot '{chain.name}': joint {j + 1} has no range left within margin {cfg.limit_margin} rad"
            )
        self.protocol = ProtocolConfig(
            name=name, rate_hz=cfg.rate_hz, limit_margin=cfg.limit_margin, move_speed=cfg.move_speed,
            min_move_duration=cfg.min_move_s, excited_joints=(), collision_check=True,
        )  # fmt: skip
        self.amax = acceleration_bounds(chain, self.protocol)
        self.vmax = chain.velocity_limit

    def inside(self, q: FloatArray) -> bool:
        return bool(np.all(q >= self.lo) and np.all(q <= self.hi))

    def pose_ok(self, q: FloatArray) -> bool:
        return self.inside(q) and bool(self.model.free(q[None])[0])

    def move_ok(self, a: FloatArray, b: FloatArray) -> bool:
        T = move_duration(self.chain, self.protocol, a, b)
        return bool(self.model.free(quintic_move_samples(a, b, T, self.step)).all())

    def random_pose(self) -> FloatArray:
        for _ in range(MAX_DRAWS):
            q = self.rng.uniform(self.lo, self.hi)
            if self.pose_ok(q):
                return q
        raise self.failure("no collision-free pose")

    def failure(self, what: str) -> ProtocolError:
        return ProtocolError(
            f"robot '{self.chain.name}', work cycle '{self.name}': {what} found in {MAX_DRAWS} draws "
            f"(every draw left the limits or collided with the robot itself or the floor)"
        )

    def duration(self, a: FloatArray, b: FloatArray) -> float:
        lo, hi = self.cfg.speed_range
        protocol = replace(self.protocol, move_speed=self.cfg.move_speed * float(self.rng.uniform(lo, hi)))
        return move_duration(self.chain, protocol, a, b)

    def piece_ok(self, coef: FloatArray, T: float) -> bool:
        tau = np.append(np.arange(0.0, T, self.step / 5), T)
        n = self.chain.n_joints
        q, qd, qdd = eval_piece(coef, np.zeros(n), np.zeros(n), tau)
        if np.any(q < self.lo - 1e-9) or np.any(q > self.hi + 1e-9):
            return False
        if self.vmax is not None and np.any(np.abs(qd) > self.vmax * (1 + 1e-9)):
            return False
        if np.any(np.abs(qdd) > self.amax * (1 + 1e-9)):
            return False
        return bool(self.model.free(q[::5]).all())


def _lay_out(planner: _Planner, waypoints: list[FloatArray], rests: list[float], durations: list[float]) -> Trajectory:
    """The trajectory through ``waypoints`` (rest ``rests[k]`` s at waypoint ``k``; 0 = pass through), the
    piece from waypoint ``k`` to ``k + 1`` lasting ``durations[k]`` s.

    The first and last waypoints are rests (given a rest of at least ``min_move_s`` when 0)."""
    cfg, chain, rng = planner.cfg, planner.chain, planner.rng
    K = len(waypoints)
    Q = np.array(waypoints, dtype=float)
    rest = np.array(rests, dtype=float)
    rest[0], rest[-1] = max(rest[0], cfg.min_move_s), max(rest[-1], cfg.min_move_s)
    T = np.array(durations, dtype=float)
    lam = rng.uniform(*cfg.tangent_range, size=K)
    V = np.zeros_like(Q)
    for k in range(1, K - 1):
        if rest[k] == 0:
            V[k] = lam[k] * (Q[k + 1] - Q[k - 1]) / (T[k - 1] + T[k])
    ok = np.zeros(K - 1, dtype=bool)
    while not ok.all():  # a failing piece becomes rest-to-rest (always feasible: checked moves)
        for k in np.flatnonzero(~ok):
            coef = via_quintic_coef(Q[k], V[k], Q[k + 1], V[k + 1], float(T[k]))
            if planner.piece_ok(coef, float(T[k])):
                ok[k] = True
            elif np.any(V[k]) or np.any(V[k + 1]):
                V[k] = 0.0
                V[k + 1] = 0.0
                ok[max(k - 1, 0) : k + 2] = False
                break
            else:
                raise ProtocolError(
                    f"robot '{chain.name}', work cycle '{planner.name}': move {k + 1} leaves the limits"
                )
    n = chain.n_joints
    durations, coefs, segments, rest_poses = [], [], [], []
    now = 0.0
    for k in range(K):
        if rest[k] > 0:
            durations.append(float(rest[k]))
            coefs.append(hold_coef(Q[k]))
            settle = min(cfg.settle_s, 0.25 * rest[k])
            segments.append((now + settle, now + rest[k] - settle, STATIC, len(rest_poses), -1))
            rest_poses.append(Q[k])
            now += float(rest[k])
        if k < K - 1:
            durations.append(float(T[k]))
            coefs.append(via_quintic_coef(Q[k], V[k], Q[k + 1], V[k + 1], float(T[k])))
            now += float(T[k])
    knots = np.concatenate([[0.0], np.cumsum(durations)])
    seg = np.array(segments, dtype=float).reshape(-1, 5)
    traj = Trajectory(
        t=np.empty(0), q=np.empty((0, n)), qd=np.empty((0, n)), qdd=np.empty((0, n)),
        segments=Segments(seg[:, 0], seg[:, 1], seg[:, 2].astype(np.int8), seg[:, 3].astype(np.int32),
                          seg[:, 4].astype(np.int32)),
        config=replace(planner.protocol, n_poses=len(rest_poses)),
        poses=np.array(rest_poses), knots=knots, coef=np.array(coefs),
        sine_amplitude=np.zeros((len(coefs), n)), sine_omega=np.zeros((len(coefs), n)), robot=chain.name,
    )  # fmt: skip
    t = np.arange(int(np.floor(knots[-1] * cfg.rate_hz + 1e-9)) + 1) / cfg.rate_hz
    q, qd, qdd = traj.evaluate(t)
    check_limits(chain, t, q, qd, margin=cfg.limit_margin - 1e-9, qdd=qdd, acceleration_limit=planner.amax)
    from skincal.protocol.collision import check_motion

    t_check = np.append(np.arange(0.0, traj.duration, planner.step), traj.duration)
    check_motion(
        planner.model, t_check, traj.evaluate(t_check)[0], f"robot '{chain.name}', work cycle '{planner.name}': "
    )
    return replace(traj, t=t, q=q, qd=qd, qdd=qdd)


def _approach(planner: _Planner, q: FloatArray) -> FloatArray | None:
    """An approach pose ``approach_rad`` away from ``q`` (random direction over the first joints but the
    first), reachable by a collision-free move; None when none is found in a few draws."""
    n = planner.chain.n_joints
    for _ in range(20):
        d = np.zeros(n)
        d[1 : min(n, 4)] = planner.rng.normal(size=min(n, 4) - 1)
        if n == 1:
            d[0] = 1.0
        a = q + planner.cfg.approach_rad * d / np.linalg.norm(d)
        if planner.pose_ok(a) and planner.move_ok(a, q):
            return a
    return None


def pick_and_place(
    chain: SerialChain, rng: np.random.Generator, config: WorkCycleConfig = WorkCycleConfig()
) -> Trajectory:
    """Repeated pick-and-place cycles: home, approach the pick, pick (rest ``pick_rest_s``), back to the
    approach, approach the place, place (rest ``place_rest_s``), back, home (a short rest); the pick and
    place poses vary by ``jitter_rad`` per cycle. Lasts at least ``config.duration_s``."""
    planner = _Planner(chain, config, rng, "pick-place")
    for _ in range(MAX_DRAWS):
        home, pick, place = planner.random_pose(), planner.random_pose(), planner.random_pose()
        a_pick, a_place = _approach(planner, pick), _approach(planner, place)
        if a_pick is None or a_place is None:
            continue
        if planner.move_ok(home, a_pick) and planner.move_ok(a_pick, a_place) and planner.move_ok(a_place, home):
            break
    else:
        raise planner.failure("no collision-free pick-and-place layout")
    waypoints, rests, durations = [home], [config.min_move_s], []
    elapsed = config.min_move_s
    while elapsed < config.duration_s:
        cycle = []
        for _ in range(MAX_DRAWS):
            dp, dq = (rng.normal(scale=config.jitter_rad, size=chain.n_joints) for _ in range(2))
            p, q = pick + dp, place + dq
            if planner.pose_ok(p) and planner.pose_ok(q) and planner.move_ok(a_pick, p) and planner.move_ok(a_place, q):
                cycle = [(a_pick, 0.0), (p, config.pick_rest_s), (a_pick, 0.0), (a_place, 0.0),
                         (q, config.place_rest_s), (a_place, 0.0), (home, config.min_move_s)]  # fmt: skip
                break
        if not cycle:
            raise planner.failure("no collision-free pick or place pose near the layout")
        for q, r in cycle:
            durations.append(planner.duration(waypoints[-1], q))
            elapsed += durations[-1] + r
            waypoints.append(q)
            rests.append(r)
    return _lay_out(planner, waypoints, rests, durations)


def teleoperation(
    chain: SerialChain, rng: np.random.Generator, config: WorkCycleConfig = WorkCycleConfig()
) -> Trajectory:
    """A teleoperation-like random smooth motion: a random walk of waypoints (steps of ``step_rad`` std per
    joint, each reachable by a collision-free move), passed through smoothly, with pauses of
    ``pause_range_s`` s at a waypoint with probability ``pause_probability``. Lasts at least
    ``config.duration_s``."""
    planner = _Planner(chain, config, rng, "teleop")
    waypoints, rests, durations = [planner.random_pose()], [config.min_move_s], []
    elapsed = config.min_move_s
    while elapsed < config.duration_s:
        prev = waypoints[-1]
        for _ in range(MAX_DRAWS):
            q = prev + rng.normal(scale=config.step_rad, size=chain.n_joints)
            if planner.pose_ok(q) and planner.move_ok(prev, q):
                break
        else:
            raise planner.failure("no collision-free next waypoint")
        pause = float(rng.uniform(*config.pause_range_s)) if rng.uniform() < config.pause_probability else 0.0
        durations.append(planner.duration(prev, q))
        elapsed += durations[-1] + pause
        waypoints.append(q)
        rests.append(pause)
    rests[-1] = max(rests[-1], config.min_move_s)
    return _lay_out(planner, waypoints, rests, durations)


def work_cycle(
    chain: SerialChain, kind: str, rng: np.random.Generator, config: WorkCycleConfig = WorkCycleConfig()
) -> Trajectory:
    """The everyday motion ``kind`` (one of :data:`WORK_CYCLES`) for ``chain``."""
    if kind == "pick-place":
        return pick_and_place(chain, rng, config)
    if kind == "teleop":
        return teleoperation(chain, rng, config)
    raise ConfigError(f"unknown work cycle '{kind}' (use {' or '.join(WORK_CYCLES)})")
