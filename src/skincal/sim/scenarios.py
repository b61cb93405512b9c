"""Human-approach scenarios for the avoidance controller: the robot's start, its task, and who comes close.

A scenario is a YAML/JSON file (format below); the shipped ones live in
``skincal/sim/scenario_files/`` (package data) and are named by their stem (``skincal avoid --scenario hand``),
any other file by its path (``--scenario my.yaml``). Positions are given in the robot's base axes,
either absolute or relative to a point of the robot at its start configuration (``relative_to``), so one
file works on every robot.

The robot's named points and its start configuration are :mod:`skincal.kinematics.points`
(:func:`~skincal.kinematics.points.robot_points`, :func:`~skincal.kinematics.points.start_configuration`);
the flange's task (``circle`` or ``pick-place``) is :mod:`skincal.protocol.flange`.

Scenario file (every key optional unless said; lengths m, times s, speeds m/s)::

    name: hand                     # default: the file's stem
    description: a hand reaches into the end effector's path
    human_speed: 2.0               # v_h of ISO 13855 for the protective separation (1.6 walking, 2.0 hand)
    duration: 20                   # run length; default: when the last person has left + `after`
    after: 4.0                     # default 4
    people:                        # moving obstacles, at most 16
      - name: hand                 # required, unique (skincal.names rule)
        shape: sphere              # sphere (radius) | capsule (radius, length, axis) | human (height)
        radius: 0.05
        speed: 0.3                 # speed of every leg without its own (skincal avoid --speed overrides it)
        relative_to: flange        # base (default) | flange | shoulder | elbow | wrist | upper_arm | forearm
                                   # | {joint: k} | {link: k}: that point at the start configuration
        floor: false               # true: the z of the waypoints is absolute (feet on the floor); human: true
        start: 1.0                 # instant the first leg starts (default 0) ...
        arrive: {waypoint: 2, at: 7.0}  # ... or: the instant waypoint k (1-based) is reached
        body_region: hand          # ISO/TS 15066 body region (skincal.control.body_regions); default by
                                   # shape: sphere hand, capsule forearm, human per part (chest, skull, ...)
        waypoints:                 # at least 1, at most 256
          - {p: [0.645, -1.657, 0.433]}
          - {p: [0.033, -0.310, 0.187], hold: 3.0}   # hold: s to stay once there
          - {p: [0.645, -1.657, 0.433], speed: 0.5}  # this leg's own speed
    obstacles:                     # static, at most 16: sphere | capsule, with p (and relative_to, floor)
      - {name: post, shape: capsule, radius: 0.05, length: 1.0, axis: [0, 0, 1], p: [0.6, 0.4, 0.5]}

A human is :func:`skincal.sim.scene.human` (capsules and a sphere), feet on the waypoints, facing the
direction of its first leg. Each scenario has ``t_leave``, the instant the last person reaches its last
waypoint (and its hold ends): the tracking error should recover after it.

The four legacy scenarios (issue 7) are files that reproduce the former Python definitions on the Panda
(their points written relative to the flange at ``Q_START``): ``arm`` (a forearm along su4's line of
sight onto the robot's forearm at 0.3 m/s), ``hand`` (a hand along su6's line of sight into the space
the flange sweeps, 0.3 m/s), ``walk`` (a standing person at 0.8 m/s diagonally close past the flange),
``fast`` (``hand`` at 1 m/s); ``none`` is nobody. The issue-17 approaches: ``elbow`` (a hand onto the
elbow from behind and below, 1.0 m/s), ``lower`` (a forearm lowered onto the upper arm from above,
0.8 m/s), ``pinch`` (two hands closing on the wrist from both sides, 0.5 m/s), ``walk-at`` (a person
walking straight at the flange at 1.6 m/s and stopping in front of it).
"""

from __future__ import annotations

from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from skincal.errors import ConfigError
from skincal.kinematics.chain import SerialChain
from skincal.kinematics.points import robot_points, start_configuration
from skincal.kinematics.transforms import FloatArray
from skincal.names import name_problem, printable
from skincal.protocol.flange import Circle, PickPlace, make_task
from skincal.sim.scene import Obstacle, Primitive, Scene, TimeTable, human

MAX_FILE_BYTES = 1 << 20
"""Largest scenario file, bytes (16 people x 256 waypoints fit in 0.3 MB; a YAML parser needs ~100 s for 16 MB)."""
MAX_OBJECTS = 16
MAX_WAYPOINTS = 256
MAX_DURATION = 300.0
"""Longest run, s (the loop keeps every obstacle's position at every 1 ms step: 16 x 300 s is 115 MB)."""
MIN_DURATION = 0.02
"""Shortest run, s: one period of the simulated ToF (a shorter run never reads the skin; below one 1 ms
control step it has no step at all)."""
MAX_COORD = 100.0
MAX_SPEED = 10.0
MAX_SIZE = 5.0


# ---------------------------------------------------------------------------------------------- scenarios
@dataclass(frozen=True)
class Scenario:
    """One closed-loop run: start configuration, task, obstacles, duration and when the person has left.

    Attributes:
        name, description: labels.
        q0: ``(n,)`` start configuration, rad.
        task: the flange reference (:class:`Circle` or :class:`PickPlace`).
        scene: obstacles with their time tables.
        duration: s.
        t_leave: instant (s) after which nobody is near any more (``0`` when nobody comes).
        human_speed: ``v_h`` (m/s) the protective separation assumes for this scenario's people.
        source: the file it was read from.
    """

    name: str
    description: str
    q0: FloatArray
    task: Circle | PickPlace
    scene: Scene
    duration: float
    t_leave: float
    human_speed: float = 1.6
    source: str = ""

    @property
    def circle(self) -> Circle | PickPlace:
        """The task (legacy name)."""
        return self.task

    def without_people(self) -> Scenario:
        """The same run with nobody (the reference run of the task time lost)."""
        from dataclasses import replace

        return replace(self, name=f"{self.name} (nobody)", scene=Scene(()))


def scenario_dir() -> Path:
    """The folder of the shipped scenario files."""
    return Path(str(resources.files("skincal.sim") / "scenario_files"))


def shipped_scenarios() -> tuple[str, ...]:
    """Names of the shipped scenario files (stems), sorted."""
    return tuple(sorted(p.stem for p in scenario_dir().glob("*.yaml")))


class _Fields:
    """Reads one mapping of a scenario file, naming ``where`` (e.g. ``people[0]``) in every error."""

    def __init__(self, source: str, where: str, value: Any, known: tuple[str, ...]) -> None:
        self.source, self.where = source, where
        if not isinstance(value, dict):
            self.fail(f"must be a mapping, got {type(value).__name__}")
        for key in value:
            if key not in known:
                shown = printable(str(key))[:60]
                self.fail(f"unknown key (known: {', '.join(known)})", key=shown)
        self.value = value

    def path(self, key: str | None) -> str:
        if key is None:
            return self.where or "top level"
        return f"{self.where}.{key}" if self.where else key

    def fail(self, message: str, key: str | None = None) -> None:
        raise ConfigError(f"{self.source}: {self.path(key)}: {message}")

    def has(self, key: str) -> bool:
        return key in self.value

    def number(self, key: str, default: float | None = None, lo: float = -np.inf, hi: float = np.inf,
               open_lo: bool = False) -> float:  # fmt: skip
        if key not in self.value:
            if default is None:
                self.fail("is required", key)
            return float(default)
        v = self.value[key]
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            self.fail(f"must be a number, got {type(v).__name__}", key)
        v = float(v)
        if not np.isfinite(v) or v < lo or v > hi or (open_lo and v <= lo):
            rng = f"{'(' if open_lo else '['}{lo:g}, {hi:g}]"
            self.fail(f"must be a finite number in {rng}, got {v!r}", key)
        return v

    def vector(self, key: str, required: bool = True) -> FloatArray | None:
        if key not in self.value:
            if required:
                self.fail("is required", key)
            return None
        v = self.value[key]
        if not (isinstance(v, list) and len(v) == 3 and all(isinstance(x, (int, float)) and not isinstance(x, bool)
                                                             for x in v)):  # fmt: skip
            self.fail("must be a list of 3 numbers", key)
        a = np.array(v, dtype=float)
        if not np.all(np.isfinite(a)) or np.abs(a).max() > MAX_COORD:
            self.fail(f"must be finite numbers within +-{MAX_COORD:g} m, got {v}", key)
        return a

    def text(self, key: str, default: str | None = None) -> str:
        if key not in self.value:
            if default is None:
                self.fail("is required", key)
            return default
        v = self.value[key]
        if not isinstance(v, str):
            self.fail(f"must be a string, got {type(v).__name__}", key)
        return v

    def flag(self, key: str, default: bool) -> bool:
        v = self.value.get(key, default)
        if not isinstance(v, bool):
            self.fail(f"must be true or false, got {printable(str(v))[:40]}", key)
        return v

    def items(self, key: str, most: int) -> list:
        v = self.value.get(key, [])
        if not isinstance(v, list):
            self.fail(f"must be a list, got {type(v).__name__}", key)
        if len(v) > most:
            self.fail(f"has {len(v)} entries (at most {most})", key)
        return v


_TOP = ("name", "description", "human_speed", "duration", "after", "people", "obstacles")
_PERSON = ("name", "shape", "radius", "length", "axis", "height", "speed", "relative_to", "floor", "start", "arrive",
           "waypoints", "body_region")  # fmt: skip
DEFAULT_REGIONS = {"sphere": "hand", "capsule": "forearm"}
"""ISO/TS 15066 body region of a person part without ``body_region``, by shape (a ``human``'s parts:
:data:`skincal.sim.scene.HUMAN_REGIONS`)."""
_OBSTACLE = ("name", "shape", "radius", "length", "axis", "p", "relative_to", "floor")
_WAYPOINT = ("p", "hold", "speed")


def _anchor(f: _Fields, points: dict[str, FloatArray], chain: SerialChain, q0: FloatArray) -> FloatArray:
    ref = f.value.get("relative_to", "base")
    if isinstance(ref, str):
        if ref not in points:
            known = ", ".join(points)
            f.fail(
                f"unknown robot point '{printable(ref)[:40]}' (use {known}, {{joint: k}} or {{link: k}})", "relative_to"
            )
        return points[ref]
    if isinstance(ref, dict) and len(ref) == 1:
        ((kind, k),) = ref.items()
        n = chain.n_joints
        if kind in ("joint", "link") and isinstance(k, int) and not isinstance(k, bool):
            lo = 1 if kind == "joint" else 0
            if not lo <= k <= n:
                f.fail(f"{kind} {k} does not exist on '{chain.name}' ({lo}..{n})", "relative_to")
            T = chain.link_frames(q0)[0]
            return chain.joint_axes(T[None])[0][0][k - 1] if kind == "joint" else T[k, :3, 3].copy()
    f.fail("must be a robot point name, {joint: k} or {link: k}", "relative_to")
    raise AssertionError  # unreachable


def _place(f: _Fields, p: FloatArray, anchor: FloatArray, floor: bool) -> FloatArray:
    out = p + anchor
    if floor:
        out[2] = p[2]
    return out


def _shape(f: _Fields, person: bool) -> tuple[Primitive, ...] | None:
    shape = f.text("shape")
    kinds = ("sphere", "capsule", "human") if person else ("sphere", "capsule")
    if shape not in kinds:
        f.fail(f"must be one of {', '.join(kinds)}, got '{printable(shape)[:40]}'", "shape")
    extra = {"sphere": ("length", "axis", "height"), "capsule": ("height",), "human": ("radius", "length", "axis")}
    for key in extra[shape]:
        if f.has(key):
            f.fail(f"does not apply to a {shape}", key)
    if shape == "human":
        f.number("height", 1.75, 0.5, 2.5)
        return None
    r = f.number("radius", None, 0.0, MAX_SIZE, open_lo=True)
    if shape == "sphere":
        return (Primitive("sphere", [r]),)
    length = f.number("length", None, 0.0, 2 * MAX_SIZE, open_lo=True)
    axis = f.vector("axis", required=False)
    axis = np.array([0.0, 0.0, 1.0]) if axis is None else axis
    if np.linalg.norm(axis) < 1e-9:
        f.fail("must not be zero", "axis")
    from skincal.skin.placement import frame_from_normal

    z = axis / np.linalg.norm(axis)
    R = frame_from_normal(z[None], np.zeros(1))[0]
    if np.allclose(z, [1.0, 0.0, 0.0]):  # the legacy forearm's exact rotation (about y by 90 deg)
        R = np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]])
    return (Primitive("capsule", [r, 0.5 * length], [0.0, 0.0, 0.0], R),)


def _person(
    f: _Fields, chain: SerialChain, q0: FloatArray, points: dict, speed_override: float | None
) -> tuple[Obstacle, float]:
    name = f.text("name")
    problem = name_problem(name)
    if problem:
        f.fail(f"{printable(name)[:40]!r} {problem}", "name")
    prims = _shape(f, person=True)
    is_human = prims is None
    region = None
    if f.has("body_region"):
        region = f.text("body_region")
        problem = name_problem(region)
        if problem:
            f.fail(f"{printable(region)[:40]!r} {problem}", "body_region")
    speed = f.number("speed", 1.0, 0.0, MAX_SPEED, open_lo=True)
    if speed_override is not None:
        speed = speed_override
    anchor = _anchor(f, points, chain, q0)
    floor = f.flag("floor", is_human)
    raw = f.items("waypoints", MAX_WAYPOINTS)
    if not raw:
        f.fail("needs at least one waypoint", "waypoints")
    pts, holds, legs = [], [], []
    for i, w in enumerate(raw):
        wf = _Fields(f.source, f"{f.path('waypoints')}[{i}]", w, _WAYPOINT)
        pts.append(_place(f, wf.vector("p"), anchor, floor))
        holds.append(wf.number("hold", 0.0, 0.0, MAX_DURATION))
        legs.append(wf.number("speed", speed, 0.0, MAX_SPEED, open_lo=True) if i > 0 else speed)
        if i == 0 and wf.has("speed"):
            wf.fail("the first waypoint has no leg to it", "speed")
    leg_time = [0.0] + [float(np.linalg.norm(pts[i] - pts[i - 1])) / legs[i] for i in range(1, len(pts))]
    if f.has("start") and f.has("arrive"):
        f.fail("give start or arrive, not both", "arrive")
    t0 = f.number("start", 0.0, -MAX_DURATION, MAX_DURATION)
    if f.has("arrive"):
        af = _Fields(f.source, f.path("arrive"), f.value["arrive"], ("waypoint", "at"))
        k = af.number("waypoint", None, 1, len(pts))
        if k != int(k):
            af.fail("must be a whole waypoint number", "waypoint")
        k = int(k) - 1
        at = af.number("at", None, 0.0, MAX_DURATION)
        t0 = at - sum(leg_time[1 : k + 1]) - sum(holds[:k])
    # time table: rest at the first point until t0 (plus its hold), then leg by leg with the holds
    table_t, table_p = [], []
    t = t0 + holds[0]
    if t > 0:
        table_t.append(0.0)
        table_p.append(pts[0])
    table_t.append(t)
    table_p.append(pts[0])
    for i in range(1, len(pts)):
        if leg_time[i] <= 0:
            f.fail(f"waypoint {i + 1} is where waypoint {i} is (a leg of zero length)", "waypoints")
        t += leg_time[i]
        table_t.append(t)
        table_p.append(pts[i])
        if holds[i] > 0:
            t += holds[i]
            table_t.append(t)
            table_p.append(pts[i])
    if t > MAX_DURATION:
        f.fail(f"the last waypoint is reached at {t:.1f} s (at most {MAX_DURATION:g} s)", "waypoints")
    path = TimeTable(table_t, np.array(table_p)) if len(table_t) > 1 else None
    if is_human:
        step = next((pts[i] - pts[0] for i in range(1, len(pts)) if np.linalg.norm((pts[i] - pts[0])[:2]) > 1e-9), None)
        yaw = float(np.arctan2(step[1], step[0])) if step is not None else np.pi
        height = f.number("height", 1.75, 0.5, 2.5)
        return human(name, pts[0], yaw, height, path, region), t
    region = region if region is not None else DEFAULT_REGIONS[prims[0].kind]
    return Obstacle(name, prims, pts[0], path=path, body_regions=(region,)), t


def _static(f: _Fields, chain: SerialChain, q0: FloatArray, points: dict) -> Obstacle:
    name = f.text("name")
    problem = name_problem(name)
    if problem:
        f.fail(f"{printable(name)[:40]!r} {problem}", "name")
    prims = _shape(f, person=False)
    p = _place(f, f.vector("p"), _anchor(f, points, chain, q0), f.flag("floor", False))
    return Obstacle(name, prims, p)


def parse_scenario(
    spec: Any,
    source: str,
    chain: SerialChain,
    *,
    default_name: str = "scenario",
    speed: float | None = None,
    duration: float | None = None,
    task: str = "circle",
    q0: ArrayLike | None = None,
) -> Scenario:
    """The :class:`Scenario` of a parsed scenario file ``spec`` (module docstring) for ``chain``.

    ``speed`` (m/s) overrides every person's ``speed``, ``duration`` (s) the run length; ``q0`` the start
    configuration (default :func:`start_configuration`). A bad field is a one-line :class:`ConfigError`
    naming ``source`` and the field.
    """
    if speed is not None and not (np.isfinite(speed) and 0 < speed <= MAX_SPEED):
        raise ConfigError(f"--speed must be in (0, {MAX_SPEED:g}] m/s, got {speed}")
    f = _Fields(source, "", spec, _TOP)
    name = f.text("name", default_name)
    problem = name_problem(name)
    if problem:
        f.fail(f"{printable(name)[:40]!r} {problem}", "name")
    text = f.text("description", "")
    v_h = f.number("human_speed", 1.6, 0.0, MAX_SPEED, open_lo=True)
    after = f.number("after", 4.0, 0.0, MAX_DURATION)
    q0 = start_configuration(chain) if q0 is None else chain.check_q(q0)[0]
    points = robot_points(chain, q0)
    people, t_leave = [], 0.0
    for i, item in enumerate(f.items("people", MAX_OBJECTS)):
        obs, t_end = _person(_Fields(source, f"people[{i}]", item, _PERSON), chain, q0, points, speed)
        people.append(obs)
        t_leave = max(t_leave, t_end)
    static = [_static(_Fields(source, f"obstacles[{i}]", item, _OBSTACLE), chain, q0, points)
              for i, item in enumerate(f.items("obstacles", MAX_OBJECTS))]  # fmt: skip
    if len(people) + len(static) > MAX_OBJECTS:
        f.fail(f"{len(people)} people and {len(static)} obstacles: at most {MAX_OBJECTS} in all", "obstacles")
    names = [o.name for o in people + static]
    if len(set(names)) != len(names):
        f.fail(f"names must be unique, got {', '.join(printable(n)[:40] for n in names)}", "people")
    T = f.number("duration", t_leave + after if people else 5.0, MIN_DURATION, MAX_DURATION)
    if duration is not None:
        if not (np.isfinite(duration) and MIN_DURATION <= duration <= MAX_DURATION):
            raise ConfigError(f"scenario duration must be in [{MIN_DURATION:g}, {MAX_DURATION:g}] s, got {duration}")
        T = float(duration)
    if T > MAX_DURATION:
        f.fail(f"the run would last {T:.1f} s (at most {MAX_DURATION:g} s)", "duration")
    start = points["flange"]
    return Scenario(name, text, np.asarray(q0, dtype=float), make_task(task, start), Scene(tuple(people + static)),
                    T, t_leave, v_h, source)  # fmt: skip


def load_scenario(
    path: str | Path,
    chain: SerialChain,
    *,
    speed: float | None = None,
    duration: float | None = None,
    task: str = "circle",
    q0: ArrayLike | None = None,
) -> Scenario:
    """Read a scenario file (YAML or JSON, through the guarded :mod:`skincal.io.jsonio` readers)."""
    from skincal.io.jsonio import parse_json, parse_yaml, read_text

    path = Path(path)
    parse = parse_json if path.suffix.lower() == ".json" else parse_yaml
    spec = parse(read_text(path, "scenario file", ConfigError, max_bytes=MAX_FILE_BYTES), str(path), ConfigError)
    return parse_scenario(spec, str(path), chain, default_name=path.stem, speed=speed, duration=duration, task=task,
                          q0=q0)  # fmt: skip


def get_scenario(
    name: str,
    chain: SerialChain,
    duration: float | None = None,
    *,
    speed: float | None = None,
    task: str = "circle",
    q0: ArrayLike | None = None,
) -> Scenario:
    """A shipped scenario by name (:func:`shipped_scenarios`) or a scenario file by path, for ``chain``."""
    shipped = shipped_scenarios()
    if name in shipped:
        path = scenario_dir() / f"{name}.yaml"
    elif Path(name).suffix.lower() in (".yaml", ".yml", ".json"):
        path = Path(name)
    else:
        raise ConfigError(
            f"unknown scenario '{printable(name)[:60]}' (shipped: {', '.join(shipped)}; or a .yaml/.json file)"
        )
    return load_scenario(path, chain, speed=speed, duration=duration, task=task, q0=q0)


def degrade_poses(poses: dict, position_m: float, angle_deg: float, rng: np.random.Generator) -> dict:
    """Mis-calibrated copies of ``poses`` (name -> :class:`SkinUnitPose`): each unit's position moved by
    exactly ``position_m`` m in a random direction and its orientation turned by exactly ``angle_deg``
    about a random axis (link frame), seeded by ``rng``."""
    from scipy.spatial.transform import Rotation

    from skincal.skin.pose import SkinUnitPose

    if position_m < 0 or angle_deg < 0:
        raise ConfigError(f"degradation must be non-negative, got {position_m} m, {angle_deg} deg")
    if position_m > MAX_SIZE or angle_deg > 180.0:  # 1e308 m overflowed to a non-finite pose (exit 2, 3 lines)
        raise ConfigError(f"degradation must be at most {MAX_SIZE:g} m, 180 deg, got {position_m} m, {angle_deg} deg")
    out = {}
    for name, pose in poses.items():
        d = rng.normal(size=3)
        axis = rng.normal(size=3)
        R_err = Rotation.from_rotvec(np.deg2rad(angle_deg) * axis / np.linalg.norm(axis)).as_matrix()
        out[name] = SkinUnitPose(pose.link, R_err @ pose.R_link_su, pose.p_link_su + position_m * d / np.linalg.norm(d))
    return out
