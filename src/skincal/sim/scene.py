"""Obstacle scenes for proximity (time-of-flight) simulation: primitives in the robot base frame.

An :class:`Obstacle` is a rigid group of primitives (sphere, capsule, box, plane) with a fixed
orientation ``R_base_obs`` whose origin either stays at ``p_base_obs`` or follows a
:class:`TimeTable` (piecewise-linear positions over time). In MuJoCo each obstacle is a mocap body
(:meth:`Scene.add_to_mjcf`); :meth:`Scene.ray_distance` is the same scene in closed form (numpy),
for the analytic simulator and as an independent check of MuJoCo's rangefinder.

Primitive sizes follow MuJoCo: sphere ``(r,)``; capsule ``(r, h)`` (segment from ``-h`` to ``+h``
along the local z axis); box ``(hx, hy, hz)`` half extents; plane ``(hx, hy)`` half extents of a
rectangle in the local xy plane (0 = unbounded), seen from its +z side. All in m.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike

from skincal.data.interp import interp_rows
from skincal.errors import ConfigError
from skincal.kinematics.transforms import FloatArray, quat_wxyz_from_matrix, rot_z
from skincal.sim.mjcf import mjcf_floats
from skincal.skin.tof import finite_array

KINDS = {"sphere": 1, "capsule": 2, "box": 3, "plane": 2}
"""Primitive kinds and the number of size entries each takes."""


@dataclass(frozen=True)
class Primitive:
    """One shape of an obstacle, posed in the obstacle's frame (``p_obs_prim`` m, ``R_obs_prim``)."""

    kind: str
    size: FloatArray
    p_obs_prim: FloatArray = field(default_factory=lambda: np.zeros(3))
    R_obs_prim: FloatArray = field(default_factory=lambda: np.eye(3))

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ConfigError(f"obstacle primitive kind must be one of {', '.join(KINDS)}, got '{self.kind}'")
        size = finite_array(self.size, f"{self.kind} size (m)", (KINDS[self.kind],))
        if np.any(size < 0) or (self.kind != "plane" and np.any(size[:1] <= 0)):
            raise ConfigError(f"{self.kind} size must be positive m, got {size.tolist()}")
        object.__setattr__(self, "size", size)
        object.__setattr__(self, "p_obs_prim", finite_array(self.p_obs_prim, "primitive position (m)", (3,)))
        R = finite_array(self.R_obs_prim, "primitive rotation", (3, 3))
        if np.abs(R.T @ R - np.eye(3)).max() > 1e-6 or np.linalg.det(R) < 0:
            raise ConfigError("primitive rotation is not a proper rotation matrix")
        object.__setattr__(self, "R_obs_prim", R)


@dataclass(frozen=True)
class TimeTable:
    """Piecewise-linear obstacle positions: ``t`` ``(K,)`` s strictly increasing, ``p_base`` ``(K, 3)`` m.

    Before ``t[0]`` and after ``t[-1]`` the obstacle rests at the first / last position.
    """

    t: FloatArray
    p_base: FloatArray

    def __post_init__(self) -> None:
        t = np.array(self.t, dtype=float)
        if t.ndim != 1 or t.size < 1 or not np.all(np.isfinite(t)) or np.any(np.diff(t) <= 0):
            raise ConfigError("obstacle time table: t must be a finite, strictly increasing (K,) array in s")
        object.__setattr__(self, "t", finite_array(t, "time table t (s)", t.shape))
        object.__setattr__(self, "p_base", finite_array(self.p_base, "time table p_base (m)", (t.size, 3)))

    def at(self, t: ArrayLike) -> FloatArray:
        """Positions ``(M, 3)`` at times ``t`` ``(M,)``, linear interpolation."""
        t = np.atleast_1d(np.asarray(t, dtype=float))
        return interp_rows(t, self.t, self.p_base)


@dataclass(frozen=True)
class Obstacle:
    """A rigid group of primitives; its frame is at ``p_base_obs`` (or follows ``path``), rotated by ``R_base_obs``.

    ``body_regions``: for a person, the ISO/TS 15066 body region of each primitive (names of
    :data:`skincal.control.body_regions.BODY_REGIONS`, one per primitive, checked there); ``()``: not a
    person (a post, a table)."""

    name: str
    primitives: tuple[Primitive, ...]
    p_base_obs: FloatArray = field(default_factory=lambda: np.zeros(3))
    R_base_obs: FloatArray = field(default_factory=lambda: np.eye(3))
    path: TimeTable | None = None
    body_regions: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        if not self.name or not self.primitives:
            raise ConfigError("an obstacle needs a name and at least one primitive")
        object.__setattr__(self, "primitives", tuple(self.primitives))
        object.__setattr__(self, "body_regions", tuple(str(r) for r in self.body_regions))
        if self.body_regions and len(self.body_regions) != len(self.primitives):
            raise ConfigError(
                f"obstacle '{self.name}': {len(self.body_regions)} body regions for {len(self.primitives)} primitives"
            )
        object.__setattr__(
            self, "p_base_obs", finite_array(self.p_base_obs, f"obstacle '{self.name}' position (m)", (3,))
        )
        object.__setattr__(
            self, "R_base_obs", finite_array(self.R_base_obs, f"obstacle '{self.name}' rotation", (3, 3))
        )

    def positions(self, t: ArrayLike) -> FloatArray:
        """Origin of the obstacle frame in the base frame at times ``t`` ``(M,)``: ``(M, 3)`` m."""
        t = np.atleast_1d(np.asarray(t, dtype=float))
        return self.path.at(t) if self.path is not None else np.broadcast_to(self.p_base_obs, (t.size, 3)).copy()


@dataclass(frozen=True)
class Scene:
    """A set of obstacles with unique names."""

    obstacles: tuple[Obstacle, ...] = ()

    def __post_init__(self) -> None:
        object.__setattr__(self, "obstacles", tuple(self.obstacles))
        names = [o.name for o in self.obstacles]
        if len(set(names)) != len(names):
            raise ConfigError(f"scene obstacle names must be unique, got {names}")

    @staticmethod
    def body_name(obstacle: str) -> str:
        """MuJoCo mocap body name of an obstacle."""
        return f"obstacle/{obstacle}"

    def add_to_mjcf(self, worldbody: ET.Element) -> None:
        """Append one mocap body per obstacle (geoms non-colliding, massless) to an MJCF ``worldbody``."""
        for obs in self.obstacles:
            body = ET.SubElement(
                worldbody,
                "body",
                {
                    "name": self.body_name(obs.name),
                    "mocap": "true",
                    "pos": mjcf_floats(obs.p_base_obs),
                    "quat": mjcf_floats(quat_wxyz_from_matrix(obs.R_base_obs)),
                },
            )
            for k, prim in enumerate(obs.primitives):
                ET.SubElement(
                    body,
                    "geom",
                    {
                        "name": f"{self.body_name(obs.name)}/{k}",
                        "type": prim.kind,
                        "size": mjcf_floats(prim.size if prim.kind != "plane" else [*prim.size, 1.0]),
                        "pos": mjcf_floats(prim.p_obs_prim),
                        "quat": mjcf_floats(quat_wxyz_from_matrix(prim.R_obs_prim)),
                        "contype": "0",
                        "conaffinity": "0",
                        "mass": "0",
                        "rgba": "0.8 0.5 0.3 0.6",
                    },
                )

    def mocap_positions(self, t: ArrayLike) -> FloatArray:
        """Obstacle origins ``(M, n_obstacles, 3)`` at times ``t`` ``(M,)`` (mocap order = obstacle order)."""
        t = np.atleast_1d(np.asarray(t, dtype=float))
        if not self.obstacles:
            return np.zeros((t.size, 0, 3))
        return np.stack([o.positions(t) for o in self.obstacles], axis=1)

    def tof_primitives(self, t: ArrayLike | None = None) -> list:
        """The scene as :mod:`skincal.skin.tof` solids in the base frame (for ``tof_range`` and the
        analytic simulator): fixed ``(3,)`` centres when ``t`` is ``None`` (obstacles at ``p_base_obs``),
        else ``(M, 3)`` centres at times ``t`` ``(M,)`` s. Only unbounded planes convert (to half-spaces)."""
        from skincal.skin import tof

        out: list = []
        for obs in self.obstacles:
            p_obs = obs.p_base_obs if t is None else obs.positions(t)
            for prim in obs.primitives:
                R = obs.R_base_obs @ prim.R_obs_prim
                c = p_obs + obs.R_base_obs @ prim.p_obs_prim
                if prim.kind == "sphere":
                    out.append(tof.Sphere(c, prim.size[0]))
                elif prim.kind == "capsule":
                    half = prim.size[1] * R[:, 2]
                    out.append(tof.Capsule(c - half, c + half, prim.size[0]))
                elif prim.kind == "box":
                    out.append(tof.Box(c, prim.size, R))
                elif np.any(prim.size > 0):
                    raise ConfigError(f"obstacle '{obs.name}': a bounded plane has no ToF half-space equivalent")
                else:
                    out.append(tof.Plane(c, R[:, 2]))
        return out

    def ray_distance(self, origin: ArrayLike, direction: ArrayLike, t: ArrayLike = 0.0) -> FloatArray:
        """Closed-form distance along rays to the nearest obstacle surface, ``(M,)`` m, NaN = no hit.

        ``origin`` ``(M, 3)`` m and unit ``direction`` ``(M, 3)`` in the base frame, ``t`` ``(M,)`` or a
        scalar, s. Each primitive is intersected in its own frame (``o' = R^T (o - c)``, ``d' = R^T d``);
        the smallest non-negative root counts (the exit point when the ray starts inside a solid).
        """
        o = np.atleast_2d(np.asarray(origin, dtype=float))
        d = np.atleast_2d(np.asarray(direction, dtype=float))
        t = np.broadcast_to(np.asarray(t, dtype=float), (o.shape[0],))
        best = np.full(o.shape[0], np.inf)
        for obs in self.obstacles:
            p_obs = obs.positions(t)
            for prim in obs.primitives:
                R = obs.R_base_obs @ prim.R_obs_prim
                c = p_obs + obs.R_base_obs @ prim.p_obs_prim
                best = np.minimum(best, _ray_primitive(prim, (o - c) @ R, d @ R))
        return np.where(np.isfinite(best), best, np.nan)


# ---------------------------------------------------------------------------------------------- ray casts
def _smallest_nonneg(*roots: FloatArray) -> FloatArray:
    s = np.stack(roots)
    s = np.where(np.isfinite(s) & (s >= 0), s, np.inf)
    return s.min(axis=0)


def _ray_sphere(o: FloatArray, d: FloatArray, r: float) -> tuple[FloatArray, FloatArray]:
    """Roots of ``|o + s d|^2 = r^2`` (``|d| = 1``); NaN where the ray misses."""
    b = np.einsum("ij,ij->i", o, d)
    disc = b * b - (np.einsum("ij,ij->i", o, o) - r * r)
    sq = np.sqrt(np.where(disc >= 0, disc, np.nan))
    return -b - sq, -b + sq


def _ray_primitive(prim: Primitive, o: FloatArray, d: FloatArray) -> FloatArray:
    """Distance ``(M,)`` along rays in the primitive's frame, ``inf`` = no hit."""
    with np.errstate(divide="ignore", invalid="ignore"):
        if prim.kind == "sphere":
            return _smallest_nonneg(*_ray_sphere(o, d, prim.size[0]))
        if prim.kind == "plane":
            s = -o[:, 2] / d[:, 2]
            hit = (o[:, 2] > 0) & (d[:, 2] < 0)  # seen from the +z side only, as MuJoCo's plane
            x = o + s[:, None] * d
            for k in range(2):
                if prim.size[k] > 0:
                    hit &= np.abs(x[:, k]) <= prim.size[k]
            return np.where(hit, s, np.inf)
        if prim.kind == "box":
            h = prim.size
            s1, s2 = (-h - o) / d, (h - o) / d
            s_near = np.nanmax(np.minimum(s1, s2), axis=1)
            s_far = np.nanmin(np.maximum(s1, s2), axis=1)
            inside_slab = np.all(np.abs(o) <= h, axis=1)
            parallel_miss = np.any((d == 0) & (np.abs(o) > h), axis=1)
            s = np.where(s_near >= 0, s_near, np.where(inside_slab, s_far, np.inf))
            return np.where((s_near <= s_far) & ~parallel_miss, s, np.inf)
        # capsule: the infinite cylinder part limited to |z| <= h, and the two end spheres
        r, h = prim.size
        a = d[:, 0] ** 2 + d[:, 1] ** 2
        b = o[:, 0] * d[:, 0] + o[:, 1] * d[:, 1]
        disc = b * b - a * (o[:, 0] ** 2 + o[:, 1] ** 2 - r * r)
        sq = np.sqrt(np.where(disc >= 0, disc, np.nan))
        roots = [(-b - sq) / a, (-b + sq) / a]
        roots = [np.where(np.abs(o[:, 2] + s * d[:, 2]) <= h, s, np.nan) for s in roots]
        for zc in (-h, h):
            roots += list(_ray_sphere(o - np.array([0.0, 0.0, zc]), d, r))
        return _smallest_nonneg(*roots)


# ---------------------------------------------------------------------------------------------- presets
def human(
    name: str = "human",
    position: ArrayLike = (0.9, 0.0, 0.0),
    yaw: float = np.pi,
    height: float = 1.75,
    path: TimeTable | None = None,
    body_region: str | None = None,
) -> Obstacle:
    """A standing person of capsules (torso, head, upper/lower arms, legs), feet at ``position``.

    The person faces its local +x, turned by ``yaw`` (rad) about the base z axis (``pi``: facing a
    robot at the origin from +x). Proportions scale with ``height`` (m). Body regions
    (:data:`HUMAN_REGIONS`: chest, skull, upper arms, forearms, thighs), or ``body_region`` for every part.
    """
    s = height / 1.75
    down = np.eye(3)

    def cap(r: float, z0: float, z1: float, y: float = 0.0, x: float = 0.0) -> Primitive:
        return Primitive("capsule", [r * s, 0.5 * (z1 - z0) * s], [x * s, y * s, 0.5 * (z0 + z1) * s], down)

    prims = (
        cap(0.15, 1.05, 1.35),  # torso
        Primitive("sphere", [0.11 * s], [0.0, 0.0, 1.62 * s]),  # head
        cap(0.05, 1.12, 1.42, y=0.22),
        cap(0.05, 1.12, 1.42, y=-0.22),  # upper arms
        cap(0.045, 0.82, 1.10, y=0.22, x=0.05),
        cap(0.045, 0.82, 1.10, y=-0.22, x=0.05),  # forearms
        cap(0.08, 0.10, 0.88, y=0.10),
        cap(0.08, 0.10, 0.88, y=-0.10),  # legs
    )
    regions = HUMAN_REGIONS if body_region is None else (body_region,) * len(prims)
    return Obstacle(name, prims, position, rot_z(yaw), path, regions)


HUMAN_REGIONS = ("chest", "skull", "upper_arm", "upper_arm", "forearm", "forearm", "thigh", "thigh")
"""ISO/TS 15066 body regions of :func:`human`'s parts, in its order (torso, head, two upper arms, two
forearms, two legs)."""


def table(
    name: str = "table",
    centre: ArrayLike = (0.6, 0.0, 0.0),
    size: Sequence[float] = (0.8, 1.2),
    height: float = 0.75,
    thickness: float = 0.04,
) -> Obstacle:
    """A table top (box ``size`` x, y m, top at ``height`` m) on four legs, centred over ``centre``."""
    hx, hy = 0.5 * size[0], 0.5 * size[1]
    top = Primitive("box", [hx, hy, 0.5 * thickness], [0.0, 0.0, height - 0.5 * thickness])
    legs = tuple(
        Primitive(
            "box",
            [0.025, 0.025, 0.5 * (height - thickness)],
            [sx * (hx - 0.05), sy * (hy - 0.05), 0.5 * (height - thickness)],
        )
        for sx in (-1, 1)
        for sy in (-1, 1)
    )
    return Obstacle(name, (top, *legs), centre)


def wall(
    name: str = "wall",
    distance: float = 1.0,
    yaw: float = 0.0,
    width: float = 4.0,
    height: float = 2.5,
    thickness: float = 0.1,
) -> Obstacle:
    """A wall (box) whose near face is ``distance`` m from the base z axis, in the direction ``yaw`` (rad)."""
    centre = distance + 0.5 * thickness
    R = rot_z(yaw)
    return Obstacle(
        name,
        (Primitive("box", [0.5 * thickness, 0.5 * width, 0.5 * height], [0, 0, 0.5 * height]),),
        R @ np.array([centre, 0.0, 0.0]),
        R,
    )
