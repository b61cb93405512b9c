"""Stopping model of a robot measured on its torque-level simulation (:mod:`skincal.sim.dynamics`).

One stop (ISO 10218-1 Annex B style, stop category 2): the torque robot runs at a constant joint
velocity ``lambda d`` (direction ``d``: ``"all"`` joints at the same fraction of their velocity limits,
or one joint alone), ``lambda`` chosen so that the fastest point of the robot's capsules moves at the
test speed ``v`` m/s when the stop is commanded at configuration ``q0``; it has run there for
``settle_s`` to be in steady state. The controller then commands zero velocity every control period;
the reference brakes at the acceleration limits along the path (:class:`~skincal.sim.dynamics.TorqueRobot`)
and the torque loop follows it within the torque limits. Measured:

* ``T_s``: from the stop command until every joint speed stays below ``rest_speed`` rad/s;
* ``S_s``: the largest displacement of any point of the capsules (:func:`~skincal.kinematics.geometry.link_capsules`)
  from where it was at the stop command, over the whole stop (overshoot included). A capsule point
  ``p + r u`` of a link that moved by ``(R, t)`` is displaced by at most ``|R p + t - p| + 2 r sin(theta / 2)``
  (``theta`` the link's rotation angle), and the first term is largest at a segment end (a convex
  function of the point along the segment): those are what is evaluated, an upper bound tight to the
  rounding of the sphere.

The speed of a stop is the same kind of bound: ``max |v(end)| + r |omega|`` over the capsules.
:func:`measure_stopping` takes, at each test speed, the worst time and distance over the configurations
and directions it tries (those at which the speed is reachable within the velocity limits) and returns the
:class:`~skincal.control.separation.StoppingModel` table. With the reference braking every joint at once,
``T_s = lambda max_i |d_i| / a_i``: a folded arm (more joint speed for the same point speed) stops later
and farther, so besides a random sample of configurations :func:`stopping_runs` simulates the ones of a
larger screened sample that need the most joint speed for each test speed (measured: no stop from 100
fresh random configurations at 1.1 m/s exceeded the panda / ur5e / iiwa14 tables; the largest came to
0.63 / 0.97 / 0.98 of the table's distance). The table is a worst case of a sample, not a proof.

Reaction time ``T_r`` (the model's ``reaction_time_s``) = one control period + the sensing latency
(default one ToF period, 20 ms at the VL53L1X's 50 Hz: a reading is up to one period old).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from skincal.errors import ConfigError
from skincal.kinematics.chain import SerialChain
from skincal.kinematics.geometry import DEFAULT_LINK_RADIUS, link_capsules
from skincal.kinematics.transforms import FloatArray
from skincal.sim.dynamics import TorqueConfig, TorqueRobot

DEFAULT_SPEEDS = (0.25, 0.5, 0.75, 1.0, 1.25, 1.5)
"""Test speeds of the fastest robot point, m/s (ISO/TS 15066 tables go to about 1.5 m/s)."""

CONTROL_PERIOD_S = 0.001
"""Control period of the avoidance loop, s (1 kHz)."""

SENSING_LATENCY_S = 0.02
"""Default sensing latency, s: one period of the VL53L1X ToF at 50 Hz (:mod:`skincal.skin.tof`)."""

REST_SPEED = 1e-3
"""Joint speed below which the robot counts as stopped, rad/s."""


@dataclass(frozen=True)
class StopRun:
    """One measured stop.

    Attributes:
        target: the test speed asked for, m/s.
        q0: ``(n,)`` configuration at the stop command.
        direction: ``"all"`` or the 1-based joint moved alone.
        speed: fastest capsule point's speed at the stop command, m/s.
        time: ``T_s``, s.
        distance: ``S_s``, m.
        joint_distance: largest joint travel after the stop command, rad.
        saturated: the torque limits were hit during the stop.
    """

    target: float
    q0: FloatArray
    direction: str | int
    speed: float
    time: float
    distance: float
    joint_distance: float
    saturated: bool


class LinkSegments:
    """Segment ends ``(C, 2, 3)`` in their link frames, their links and radii, for speed/displacement."""

    def __init__(self, chain: SerialChain, link_radius: float | FloatArray) -> None:
        caps = [c for c in link_capsules(chain, link_radius) if c.link >= 1]
        self.chain = chain
        self.link = np.array([c.link for c in caps])
        self.ends = np.array([[c.p0, c.p1] for c in caps])
        self.radius = np.array([c.radius for c in caps])

    def speed(self, q: FloatArray, qd: FloatArray) -> float:
        """Largest point speed of the capsules at ``(q, qd)``, m/s (bound, module docstring)."""
        return float(self.speeds(q[None], qd[None])[0])

    def speeds(self, q: FloatArray, qd: FloatArray) -> FloatArray:
        """:meth:`speed` of ``N`` states ``(N, n)`` at once, ``(N,)``."""
        motion = self.chain.link_motion(q, qd, np.zeros_like(q))
        T = motion.T_base_link[:, self.link]  # (N, C, 4, 4)
        w = motion.omega[:, self.link]  # (N, C, 3)
        r = np.einsum("ncij,cej->ncei", T[..., :3, :3], self.ends)  # (N, C, 2, 3) from the link origins
        v = motion.v_origin[:, self.link][:, :, None, :] + np.cross(w[:, :, None, :], r)
        fastest = np.linalg.norm(v, axis=3).max(axis=2) + self.radius * np.linalg.norm(w, axis=2)
        return fastest.max(axis=1)

    def displacement(self, q: FloatArray) -> float:
        """Largest displacement of a capsule point over configurations ``q`` ``(S, n)`` from ``q[0]``, m."""
        T = self.chain.link_frames(q)[:, self.link]  # (S, C, 4, 4)
        x = np.einsum("scij,cej->scei", T[..., :3, :3], self.ends) + T[:, :, None, :3, 3]
        moved = np.linalg.norm(x - x[:1], axis=3).max(axis=2)  # (S, C)
        R0 = T[0, :, :3, :3]
        rel = np.einsum("scij,ckj->scik", T[..., :3, :3], R0)  # R(t) R(0)^T
        cos = np.clip((np.trace(rel, axis1=2, axis2=3) - 1.0) / 2.0, -1.0, 1.0)
        chord = 2.0 * np.sin(np.arccos(cos) / 2.0)
        return float(np.max(moved + self.radius * chord))


DEFAULT_CONFIGURATIONS = 16
"""Configurations a stopping table is measured at by default (the worst over them is kept)."""

DEFAULT_SCREEN = 2000
"""Configurations screened (kinematics only) for the worst case at each speed, see :func:`stopping_runs`."""

WORST_PER_SPEED = 2
"""Screened configurations simulated per test speed and direction."""


def default_configurations(chain: SerialChain, count: int = DEFAULT_CONFIGURATIONS, seed: int = 0) -> FloatArray:
    """``count`` configurations ``(count, n)`` uniform in the central 60 % of the joint ranges (+-pi for
    a continuous joint), so a stop from full speed stays clear of the limits."""
    from skincal.protocol.limits import position_bounds

    n = chain.n_joints
    lo, hi = position_bounds(chain)
    mid, half = (lo + hi) / 2, 0.3 * (hi - lo)
    return np.random.default_rng(seed).uniform(mid - half, mid + half, size=(count, n))


def _direction(robot: TorqueRobot, direction: str | int) -> FloatArray:
    limit = np.where(np.isfinite(robot.velocity_limit), robot.velocity_limit, 1.0)
    if direction == "all":
        return limit
    if isinstance(direction, (int, np.integer)) and 1 <= direction <= robot.n:
        d = np.zeros(robot.n)
        d[direction - 1] = limit[direction - 1]
        return d
    raise ConfigError(f"stop direction must be 'all' or a joint 1..{robot.n}, got {direction!r}")


def stop_once(
    robot: TorqueRobot,
    q0: ArrayLike,
    speed: float,
    direction: str | int = "all",
    *,
    dt: float = CONTROL_PERIOD_S,
    settle_s: float = 0.05,
    timeout_s: float = 3.0,
    rest_speed: float = REST_SPEED,
    link_radius: float | FloatArray = DEFAULT_LINK_RADIUS,
    capsules: LinkSegments | None = None,
) -> StopRun | None:
    """One stop from ``speed`` m/s at ``q0`` (module docstring); ``None`` when that speed needs more
    than the velocity limits in this direction."""
    caps = capsules if capsules is not None else LinkSegments(robot.chain, link_radius)
    q0 = np.asarray(q0, dtype=float)
    d = _direction(robot, direction)
    unit = caps.speed(q0, d)
    if unit <= 0:
        return None
    lam = float(speed) / unit
    if lam > 1.0 + 1e-12:
        return None
    qd = lam * d
    robot.reset(q0 - qd * settle_s, qd)
    for _ in range(int(round(settle_s / dt))):
        robot.step(qd, dt)
    q_stop, v_stop = robot.q, caps.speed(robot.q, robot.qd)
    qs, saturated, moving_until = [q_stop], False, 0.0
    zero = np.zeros(robot.n)
    for k in range(1, int(round(timeout_s / dt)) + 1):
        robot.step(zero, dt)
        qs.append(robot.q)
        saturated |= bool(robot.saturated.any())
        if np.max(np.abs(robot.qd)) > rest_speed:
            moving_until = k * dt
        elif k * dt - moving_until > 0.05 and not np.any(robot.qd_ref):
            break
    else:
        raise ConfigError(f"robot '{robot.chain.name}' did not come to rest within {timeout_s} s of the stop command")
    q_run = np.array(qs)
    return StopRun(
        target=float(speed),
        q0=q_stop,
        direction=direction,
        speed=v_stop,
        time=moving_until,
        distance=caps.displacement(q_run),
        joint_distance=float(np.abs(q_run - q_stop).max()),
        saturated=saturated,
    )


def stopping_runs(
    chain: SerialChain,
    speeds: Sequence[float] = DEFAULT_SPEEDS,
    *,
    configurations: ArrayLike | None = None,
    n_configurations: int = DEFAULT_CONFIGURATIONS,
    seed: int = 0,
    directions: Sequence[str | int] = ("all",),
    config: TorqueConfig = TorqueConfig(),  # noqa: B008 - frozen, immutable default
    robot: TorqueRobot | None = None,
    dt: float = CONTROL_PERIOD_S,
    link_radius: float | FloatArray = DEFAULT_LINK_RADIUS,
    screen: int = DEFAULT_SCREEN,
) -> list[StopRun]:
    """Every reachable stop of ``speeds`` x ``configurations`` (default ``n_configurations`` of
    :func:`default_configurations` with ``seed``) x ``directions``, plus the likely worst cases: of
    ``screen`` more configurations (seed ``seed + 1``), per speed and direction the
    :data:`WORST_PER_SPEED` whose speed per unit of ``lambda`` is the smallest that still reaches the test
    speed (the reference brakes in ``T_s = lambda max_i |d_i| / a_i``, so the most joint speed per point
    speed stops latest and farthest; kinematics only, no simulation, to choose them)."""
    v = np.asarray(speeds, dtype=float)
    if v.ndim != 1 or v.size == 0 or not np.all(np.isfinite(v) & (v > 0)) or np.any(np.diff(v) <= 0):
        raise ConfigError("stopping speeds must be positive, finite and ascending (m/s)")
    qs = (
        default_configurations(chain, n_configurations, seed)
        if configurations is None
        else np.atleast_2d(np.asarray(configurations, float))
    )
    robot = robot if robot is not None else TorqueRobot(chain, config=config)
    caps = LinkSegments(chain, link_radius)
    plan = [(q0, direction, float(speed)) for q0 in qs for direction in directions for speed in v]
    if screen > 0:
        candidates = default_configurations(chain, int(screen), seed + 1)
        for direction in directions:
            d = _direction(robot, direction)
            unit = caps.speeds(candidates, np.broadcast_to(d, candidates.shape))
            order = np.argsort(unit)
            for speed in v:
                reach = order[unit[order] >= speed * (1 + 1e-9)]
                plan += [(candidates[i], direction, float(speed)) for i in reach[:WORST_PER_SPEED]]
    runs = []
    for q0, direction, speed in plan:
        run = stop_once(robot, q0, speed, direction, dt=dt, capsules=caps)
        if run is not None:
            runs.append(run)
    return runs


def measure_stopping(
    chain: SerialChain,
    speeds: Sequence[float] = DEFAULT_SPEEDS,
    *,
    configurations: ArrayLike | None = None,
    n_configurations: int = DEFAULT_CONFIGURATIONS,
    seed: int = 0,
    directions: Sequence[str | int] = ("all",),
    config: TorqueConfig = TorqueConfig(),  # noqa: B008 - frozen, immutable default
    robot: TorqueRobot | None = None,
    dt: float = CONTROL_PERIOD_S,
    sensing_latency_s: float = SENSING_LATENCY_S,
    link_radius: float | FloatArray = DEFAULT_LINK_RADIUS,
    screen: int = DEFAULT_SCREEN,
):  # -> StoppingModel (imported lazily: control.separation is another part's module)
    """The measured :class:`~skincal.control.separation.StoppingModel` of ``chain`` (module docstring):
    at each of ``speeds`` the worst ``T_s`` and ``S_s`` over the stops of :func:`stopping_runs`; speeds
    reachable in none of them end the table. ``reaction_time_s = dt + sensing_latency_s``."""
    from skincal.control.separation import StoppingModel

    runs = stopping_runs(
        chain, speeds, configurations=configurations, n_configurations=n_configurations, seed=seed,
        directions=directions, config=config, robot=robot, dt=dt, link_radius=link_radius, screen=screen,
    )  # fmt: skip
    v, times, dists = [0.0], [0.0], [0.0]
    for speed in np.asarray(speeds, dtype=float):
        mine = [r for r in runs if r.target == speed]
        if not mine:
            break
        v.append(float(speed))
        times.append(max(r.time for r in mine))
        dists.append(max(r.distance for r in mine))
    if len(v) < 2:
        raise ConfigError(f"robot '{chain.name}': no test speed is reachable within its velocity limits")
    # a worst case over a finite sample: keep the table monotone as the model requires
    return StoppingModel(
        speeds=np.array(v),
        times=np.maximum.accumulate(times),
        distances=np.maximum.accumulate(dists),
        reaction_time_s=float(dt) + float(sensing_latency_s),
    )


def stopping_table(
    robots: Sequence[str] = ("panda", "ur5e", "iiwa14"), speeds: Sequence[float] = DEFAULT_SPEEDS, **kwargs
) -> str:
    """Text table of the measured stopping models of preset ``robots`` (for the avoidance benchmark):
    one row per robot and speed, ``T_s`` ms and ``S_s`` mm; ``kwargs`` go to :func:`measure_stopping`."""
    from skincal.kinematics.presets import get_robot

    lines = [f"{'robot':<8} {'v m/s':>6} {'T_s ms':>7} {'S_s mm':>7}   (T_r ms)"]
    for name in robots:
        model = measure_stopping(get_robot(name), speeds, **kwargs)
        for v, t, s in zip(model.speeds[1:], model.times[1:], model.distances[1:], strict=True):
            lines.append(f"{name:<8} {v:>6.2f} {1e3 * t:>7.0f} {1e3 * s:>7.1f}   ({1e3 * model.reaction_time_s:.0f})")
    return "\n".join(lines)
