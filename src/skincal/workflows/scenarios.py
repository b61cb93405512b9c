"""Human-approach scenarios for the avoidance controller: the task (a circle) and who comes close.

Robot: the Panda at ``Q_START``. The approach lines are laid out along the lines of sight of the
paper's Table II units (:func:`skincal.skin.placement.paper_placement`, one per link 2..7). At
``Q_START`` they look: su1 forward (+x) from low on the upper arm, su2 sideways (-y) from the upper
arm, su3 up, su4 sideways (+y) from the forearm, su5 backward from the wrist, su6 forward-right
(+x -y) from the hand. The skin the loop simulates is the caller's choice (``skincal avoid
--placement``): six 27 deg cones leave most directions unseen, so a person's leg or the far side of
an arm comes within about 0.1 m unnoticed (``arm`` 0.088 m, ``walk`` 0.111 m in
``benchmarks/bench_avoid.py --placement paper``); the default is the dense ring skin
(:func:`skincal.skin.placement.ring_placement`, 49 units), with which every scenario keeps 0.2 m.

Task (paper Sec. V-C): the flange tracks a circle of radius 0.1 m in the vertical y-z plane in front of
the robot, starting where the flange is at ``Q_START`` (period 5 s, 0.126 m/s).

Scenarios (all positions in the base frame, m; obstacles are :mod:`skincal.sim.scene` objects). Each
is built to discriminate: unavoided (a blind robot just tracking its circle) the person comes within
a few centimetres of the robot or touches it, and the approach runs along a unit's line of sight
(at the arrival instant ``T_ARRIVE``), so good perception can see it coming:

* ``none``: nobody; the task alone.
* ``arm``: a person's forearm (capsule, r = 4.5 cm) comes along su4's line of sight (+y) onto the
  robot's forearm at 0.3 m/s, holds 3 s and withdraws at 0.5 m/s.
* ``hand``: a hand (sphere, r = 5 cm) comes along su6's line of sight (+x -y) into the space the
  flange sweeps at 0.3 m/s, holds 3 s and withdraws: the task itself must give way.
* ``walk``: a standing person (:func:`skincal.sim.scene.human`) walks at 0.8 m/s diagonally from the
  front right, where su6 and su1 look, close past the flange and off to the left.
* ``fast``: the hand of ``hand`` at 1 m/s.

Each has ``t_leave``, the instant the person has fully left (the tracking error should recover after it).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from skincal.errors import ConfigError
from skincal.kinematics.chain import SerialChain
from skincal.kinematics.transforms import FloatArray
from skincal.sim.scene import Obstacle, Primitive, Scene, TimeTable, human

Q_START = np.array([0.0, -0.3, 0.0, -2.2, 0.0, 2.0, np.pi / 4])
"""Start configuration of the Panda, rad (flange about 0.47 m in front of the base, 0.52 m high)."""

SU6_VIEW = (np.array([0.466, -0.22, 0.686]), np.array([0.408, -0.898, 0.164]))
SU4_VIEW = (np.array([0.306, -0.02, 0.68]), np.array([0.329, 0.944, 0.034]))
"""Origin (m) and axis of su6 and su4 at ``T_ARRIVE`` while tracking the circle (base frame)."""
T_ARRIVE = 7.0
"""Instant the hand and the arm reach their hold points, s."""
HAND_FAR, HAND_NEAR = SU6_VIEW[0] + 1.6 * SU6_VIEW[1], SU6_VIEW[0] + 0.1 * SU6_VIEW[1]
"""The hand comes along su6's line of sight at arrival, into the space the flange sweeps, m."""
ARM_FAR, ARM_NEAR = SU4_VIEW[0] + 1.6 * SU4_VIEW[1], SU4_VIEW[0] + 0.12 * SU4_VIEW[1]
"""The person's forearm (centre of a capsule along x) comes along su4's line of sight onto the robot's forearm, m."""
WALK_PATH = np.array([[1.6, -1.9, 0.0], [0.74, -0.1, 0.0], [0.9, 1.8, 0.0]])
"""The walker's feet: start, closest pass, end, m."""


@dataclass(frozen=True)
class Circle:
    """Flange reference ``x(t) = center + radius (u cos(w t) + v sin(w t))``, ``w = 2 pi / period``.

    ``center``, ``u``, ``v``: ``(3,)`` base frame (``u``, ``v`` orthonormal), m; ``period`` s.
    """

    center: FloatArray
    radius: float
    u: FloatArray
    v: FloatArray
    period: float

    @classmethod
    def through(cls, start: ArrayLike, radius: float = 0.1, period: float = 5.0, plane: str = "yz") -> Circle:
        """The circle whose ``t = 0`` point is ``start`` ``(3,)`` m, in the vertical ``yz`` or flat ``xy`` plane."""
        axes = {
            "yz": (np.array([0.0, 1.0, 0.0]), np.array([0.0, 0.0, 1.0])),
            "xy": (np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0])),
        }
        if plane not in axes:
            raise ConfigError(f"circle plane must be 'yz' or 'xy', got '{plane}'")
        if radius <= 0 or period <= 0:
            raise ConfigError(f"circle needs radius > 0 m and period > 0 s, got {radius}, {period}")
        u, v = axes[plane]
        return cls(np.asarray(start, dtype=float) - radius * u, float(radius), u, v, float(period))

    def at(self, t: ArrayLike) -> tuple[FloatArray, FloatArray]:
        """Position ``(M, 3)`` m and velocity ``(M, 3)`` m/s at instants ``t`` ``(M,)`` s."""
        t = np.atleast_1d(np.asarray(t, dtype=float))[:, None]
        w = 2 * np.pi / self.period
        c, s = np.cos(w * t), np.sin(w * t)
        return self.center + self.radius * (c * self.u + s * self.v), self.radius * w * (-s * self.u + c * self.v)


@dataclass(frozen=True)
class Scenario:
    """One closed-loop run: start configuration, task, obstacles, duration and when the person has left.

    Attributes:
        name, description: labels.
        q0: ``(n,)`` start configuration, rad.
        circle: the flange reference.
        scene: obstacles with their time tables.
        duration: s.
        t_leave: instant (s) after which nobody is near any more (``0`` when nobody comes).
    """

    name: str
    description: str
    q0: FloatArray
    circle: Circle
    scene: Scene
    duration: float
    t_leave: float


def _mover(name: str, prims: tuple[Primitive, ...], waypoints: list[tuple[float, ArrayLike]]) -> Obstacle:
    t = [w[0] for w in waypoints]
    p = np.array([w[1] for w in waypoints], dtype=float)
    return Obstacle(name, prims, p[0], path=TimeTable(t, p))


def _approach(name: str, prims, far, near, t1: float, speed: float, hold: float) -> tuple[Obstacle, float]:
    """Come from ``far`` to ``near`` at ``speed`` m/s arriving at ``t1``, hold ``hold`` s, go back at 0.5 m/s."""
    far, near = np.asarray(far, dtype=float), np.asarray(near, dtype=float)
    L = float(np.linalg.norm(near - far))
    t_in = t1 - L / speed
    t2 = t1 + hold
    t3 = t2 + L / 0.5
    return _mover(name, prims, [(0.0, far), (t_in, far), (t1, near), (t2, near), (t3, far)]), t3


def _arm(chain: SerialChain, q0: FloatArray) -> tuple[Scene, float, float, str]:
    # A horizontal forearm along x, reaching in from +y (along su4's line of sight) to rest on the
    # robot's forearm (x ~ 0.1-0.35, z ~ 0.62-0.74): unavoided, it touches.
    prims = (Primitive("capsule", [0.045, 0.13], [0.0, 0.0, 0.0], _rot_y_90()),)
    arm, t_out = _approach("arm", prims, ARM_FAR, ARM_NEAR, T_ARRIVE, 0.3, 3.0)
    return Scene((arm,)), t_out, t_out + 4.0, "a person's forearm reaches onto the robot's forearm from +y (0.3 m/s)"


def _hand(chain: SerialChain, q0: FloatArray, speed: float = 0.3) -> tuple[Scene, float, float, str]:
    # Along su6's line of sight (it looks +x -y from the hand) into the flange's circle: unavoided, it touches.
    prims = (Primitive("sphere", [0.05]),)
    hand, t_out = _approach("hand", prims, HAND_FAR, HAND_NEAR, T_ARRIVE, speed, 3.0)
    return Scene((hand,)), t_out, t_out + 4.0, f"a hand reaches into the end effector's path at {speed} m/s"


def _walk(chain: SerialChain, q0: FloatArray) -> tuple[Scene, float, float, str]:
    # Diagonally from the front right (where su6 and su1 look) close past the flange, off to the left.
    t = [1.0, 1.0 + np.linalg.norm(WALK_PATH[1] - WALK_PATH[0]) / 0.8]
    t.append(t[1] + np.linalg.norm(WALK_PATH[2] - WALK_PATH[1]) / 0.8)
    heading = WALK_PATH[1] - WALK_PATH[0]
    person = human("walker", WALK_PATH[0], float(np.arctan2(heading[1], heading[0])), path=TimeTable(t, WALK_PATH))
    return Scene((person,)), t[-1], t[-1] + 4.0, "a person walks close past the robot's hand (0.8 m/s)"


def _none(chain: SerialChain, q0: FloatArray) -> tuple[Scene, float, float, str]:
    return Scene(()), 0.0, 5.0, "nobody near: the task alone"


def _rot_y_90() -> FloatArray:
    return np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]])


SCENARIOS: dict[str, Callable[[SerialChain, FloatArray], tuple[Scene, float, float, str]]] = {
    "none": _none,
    "arm": _arm,
    "hand": _hand,
    "walk": _walk,
    "fast": lambda chain, q0: _hand(chain, q0, speed=1.0),
}
"""Scenario builders by name: ``(chain, q0) -> (scene, t_leave, duration, description)``."""


def get_scenario(name: str, chain: SerialChain, duration: float | None = None) -> Scenario:
    """The scenario ``name`` (:data:`SCENARIOS`) for ``chain`` (the Panda: ``Q_START``), optionally shortened."""
    if name not in SCENARIOS:
        raise ConfigError(f"unknown scenario '{name}' (known: {', '.join(SCENARIOS)})")
    if chain.n_joints != Q_START.size:
        raise ConfigError(f"scenarios are set up for a 7-joint arm (the Panda), got '{chain.name}'")
    q0 = Q_START.copy()
    scene, t_leave, default_duration, text = SCENARIOS[name](chain, q0)
    start = chain.flange_pose(q0)[0, :3, 3]
    T = default_duration if duration is None else float(duration)
    if T <= 0:
        raise ConfigError(f"scenario duration must be positive s, got {T}")
    return Scenario(name, text, q0, Circle.through(start), scene, T, t_leave)


def degrade_poses(poses: dict, position_m: float, angle_deg: float, rng: np.random.Generator) -> dict:
    """Mis-calibrated copies of ``poses`` (name -> :class:`SkinUnitPose`): each unit's position moved by
    exactly ``position_m`` m in a random direction and its orientation turned by exactly ``angle_deg``
    about a random axis (link frame), seeded by ``rng``."""
    from scipy.spatial.transform import Rotation

    from skincal.skin.pose import SkinUnitPose

    if position_m < 0 or angle_deg < 0:
        raise ConfigError(f"degradation must be non-negative, got {position_m} m, {angle_deg} deg")
    out = {}
    for name, pose in poses.items():
        d = rng.normal(size=3)
        axis = rng.normal(size=3)
        R_err = Rotation.from_rotvec(np.deg2rad(angle_deg) * axis / np.linalg.norm(axis)).as_matrix()
        out[name] = SkinUnitPose(pose.link, R_err @ pose.R_link_su, pose.p_link_su + position_m * d / np.linalg.norm(d))
    return out
