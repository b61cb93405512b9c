"""Time-of-flight readings + calibrated unit poses + joint states -> obstacle points in the base frame.

Each reading ``r`` of unit ``u`` (pose ``T_link_su`` on link ``l``, the controller's *belief*, e.g. a
calibration result) at instant ``t`` becomes::

    p_base_obs = T_base_link(q(t)) T_link_su [0, 0, r, 1]^T

(the VL53L1X reports the nearest target in its 27 deg cone; the point is placed on the unit's +z
axis, so a target at the cone's edge is misplaced sideways by up to ``r tan(13.5 deg)``).
Joint states come at 1 kHz and readings at 50 Hz on their own clocks: ``q(t)`` is linearly
interpolated to each reading's instant (:func:`interpolate_joints`).

Validity (:func:`valid_ranges`): NaN (no target), outside ``[min_range, max_range]``, and readings
explained by the robot's own body (the point lies within ``self_margin`` of a link capsule).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from skincal.errors import ConfigError
from skincal.kinematics.chain import SerialChain
from skincal.kinematics.transforms import FloatArray
from skincal.perception.body import RobotBody, body_proximity, closest_on_segments
from skincal.skin.pose import SkinUnitPose


@dataclass(frozen=True)
class PerceptionConfig:
    """How readings become obstacle points; SI units.

    Attributes:
        min_range, max_range: readings outside this window are dropped, m. ``max_range`` is the
            avoidance threshold: the paper's demo reacts to targets within 1 m of a unit.
        self_margin: drop points closer than this to the robot's own link capsules, m.
        window: temporal filter length: per unit, the median of the last ``window`` valid points.
        max_age_s: a unit's point expires when its newest valid reading is older than this, s;
            older readings also leave the median window.
    """

    min_range: float = 0.01
    max_range: float = 1.0
    self_margin: float = 0.02
    window: int = 3
    max_age_s: float = 0.5

    def __post_init__(self) -> None:
        if not (0 <= self.min_range < self.max_range) or not np.isfinite(self.max_range):
            raise ConfigError(f"perception: need 0 <= min_range < max_range, got {self.min_range}, {self.max_range} m")
        if self.self_margin < 0 or self.max_age_s <= 0 or int(self.window) != self.window or self.window < 1:
            raise ConfigError("perception: self_margin >= 0 m, max_age_s > 0 s and an integer window >= 1 are needed")


@dataclass(frozen=True)
class ObstaclePoints:
    """Obstacle points in the base frame {0}.

    Attributes:
        positions: ``(K, 3)`` m.
        units: ``(K,)`` name of the unit that saw each point.
        stamps: ``(K,)`` reading instants, s (for filtered points: the newest reading used).
        ranges: ``(K,)`` the (filtered) range readings, m.
    """

    positions: FloatArray
    units: tuple[str, ...]
    stamps: FloatArray
    ranges: FloatArray

    @classmethod
    def empty(cls) -> ObstaclePoints:
        """No points."""
        return cls(np.zeros((0, 3)), (), np.zeros(0), np.zeros(0))

    def __len__(self) -> int:
        return int(self.positions.shape[0])


def interpolate_joints(t_joints: ArrayLike, q_joints: ArrayLike, t: ArrayLike) -> FloatArray:
    """Joint angles ``(M, n)`` at instants ``t`` ``(M,)`` s, linear between samples ``t_joints`` ``(N,)``.

    Instants outside the joint stream hold its first/last sample.
    """
    tj = np.asarray(t_joints, dtype=float)
    qj = np.asarray(q_joints, dtype=float)
    t = np.atleast_1d(np.asarray(t, dtype=float))
    if tj.ndim != 1 or qj.shape[:1] != tj.shape or np.any(np.diff(tj) <= 0):
        raise ConfigError("joint stream: t must be strictly increasing (N,) and q (N, n)")
    k = np.clip(np.searchsorted(tj, t, side="right") - 1, 0, max(tj.size - 2, 0))
    if tj.size == 1:
        return np.repeat(qj[:1], t.size, axis=0)
    w = np.clip((t - tj[k]) / (tj[k + 1] - tj[k]), 0.0, 1.0)[:, None]
    return (1.0 - w) * qj[k] + w * qj[k + 1]


def unit_rays(chain: SerialChain, pose: SkinUnitPose, q: ArrayLike) -> tuple[FloatArray, FloatArray]:
    """Origins and +z axes ``(M, 3)`` of a unit in the base frame at joint angles ``q`` ``(M, n)``:
    ``T_base_su = T_base_link(q) T_link_su``."""
    T = chain.link_frames(q, upto=chain.check_link(pose.link))[:, pose.link] @ pose.T_link_su
    return T[:, :3, 3], T[:, :3, 2]


def valid_ranges(ranges: ArrayLike, config: PerceptionConfig) -> np.ndarray:
    """``(M,)`` bool: the reading is finite and within ``[min_range, max_range]``."""
    r = np.asarray(ranges, dtype=float)
    with np.errstate(invalid="ignore"):
        return np.isfinite(r) & (r >= config.min_range) & (r <= config.max_range)


def not_self(body: RobotBody, q: FloatArray, points: FloatArray, margin: float) -> np.ndarray:
    """``(M,)`` bool: point ``m`` (base frame) is farther than ``margin`` m from the robot at ``q[m]``."""
    if points.shape[0] == 0:
        return np.zeros(0, dtype=bool)
    T = body.chain.link_frames(q)
    a, b = body.segments(T)  # (M, C, 3)
    c, _ = closest_on_segments(points[:, None, :], a, b)
    d = np.linalg.norm(points[:, None, :] - c, axis=-1) - body.radius
    return d.min(axis=1) > margin


def unit_points(
    chain: SerialChain,
    pose: SkinUnitPose,
    q: ArrayLike,
    ranges: ArrayLike,
    config: PerceptionConfig = PerceptionConfig(),
    body: RobotBody | None = None,
) -> tuple[FloatArray, np.ndarray]:
    """Points ``(M, 3)`` (base frame, m) of one unit's readings ``(M,)`` at joint angles ``(M, n)``, and
    their validity ``(M,)`` (range window and, when ``body`` is given, not the robot itself).
    Invalid rows hold NaN."""
    r = np.asarray(ranges, dtype=float)
    origin, axis = unit_rays(chain, pose, q)
    ok = valid_ranges(r, config)
    p = origin + np.where(ok, r, np.nan)[:, None] * axis
    if body is not None and np.any(ok):
        ok[ok] = not_self(body, chain.check_q(q)[ok], p[ok], config.self_margin)
        p[~ok] = np.nan
    return p, ok


def points_from_streams(
    chain: SerialChain,
    poses: Mapping[str, SkinUnitPose],
    t_joints: ArrayLike,
    q_joints: ArrayLike,
    tof: Mapping[str, tuple[ArrayLike, ArrayLike]],
    config: PerceptionConfig = PerceptionConfig(),
    body: RobotBody | None = None,
) -> ObstaclePoints:
    """Every valid reading of every unit as a point (no temporal filter), e.g. from a dataset.

    ``tof``: unit -> ``(t (M,) s, range (M,) m)`` (a :class:`skincal.data.dataset.TofStream` works via
    ``(s.t, s.range)``); units without a pose are an error. Joints ``(N,)``/``(N, n)`` are
    interpolated to each reading's instant. Points are sorted by stamp.
    """
    pos, units, stamps, rng_ = [], [], [], []
    for name, (t, r) in tof.items():
        if name not in poses:
            raise ConfigError(f"ToF stream of unit '{name}' has no calibrated pose")
        t = np.asarray(t, dtype=float)
        q = interpolate_joints(t_joints, q_joints, t)
        p, ok = unit_points(chain, poses[name], q, r, config, body)
        pos.append(p[ok])
        stamps.append(t[ok])
        rng_.append(np.asarray(r, dtype=float)[ok])
        units += [name] * int(ok.sum())
    if not pos:
        return ObstaclePoints.empty()
    stamps_all = np.concatenate(stamps)
    order = np.argsort(stamps_all, kind="stable")
    names = tuple(np.array(units, dtype=object)[order])
    return ObstaclePoints(np.concatenate(pos)[order], names, stamps_all[order], np.concatenate(rng_)[order])


class ProximityTracker:
    """Streaming perception: readings of all units at one instant in, filtered live points out.

    Per unit it keeps the last ``config.window`` valid points (base frame); :meth:`points` publishes,
    per unit, the component-wise median of those not older than ``max_age_s`` (none if all expired).
    """

    def __init__(
        self,
        chain: SerialChain,
        poses: Mapping[str, SkinUnitPose],
        config: PerceptionConfig = PerceptionConfig(),
        body: RobotBody | None = None,
    ) -> None:
        self.chain = chain
        self.poses = dict(poses)
        self.config = config
        self.body = body if body is not None else RobotBody.of(chain)
        self.units = tuple(self.poses)
        W = int(config.window)
        self._p = np.full((len(self.units), W, 3), np.nan)
        self._t = np.full((len(self.units), W), -np.inf)
        self._r = np.full((len(self.units), W), np.nan)
        self._links = np.array([self.poses[u].link for u in self.units], dtype=int)
        self._T_link_su = np.stack([self.poses[u].T_link_su for u in self.units]) if self.units else np.zeros((0, 4, 4))

    def update(self, t: float, q: ArrayLike, ranges: Mapping[str, float]) -> None:
        """Add the readings ``unit -> range`` (m, NaN = none) taken at instant ``t`` s with joints ``q`` ``(n,)``."""
        idx = [self.units.index(u) for u in ranges if u in self.poses]
        if not idx:
            return
        r = np.array([ranges[self.units[i]] for i in idx], dtype=float)
        ok = valid_ranges(r, self.config)
        if not np.any(ok):
            return
        T = self.chain.link_frames(q)[0]
        sel = np.array(idx)[ok]
        T_base_su = T[self._links[sel]] @ self._T_link_su[sel]
        p = T_base_su[:, :3, 3] + r[ok, None] * T_base_su[:, :3, 2]
        prox = body_proximity(self.body, T, p)
        keep = prox.distance > self.config.self_margin
        for i, pi, ri in zip(sel[keep], p[keep], r[ok][keep], strict=True):
            self._p[i] = np.roll(self._p[i], -1, axis=0)
            self._t[i] = np.roll(self._t[i], -1)
            self._r[i] = np.roll(self._r[i], -1)
            self._p[i, -1], self._t[i, -1], self._r[i, -1] = pi, t, ri

    def points(self, t_now: float) -> ObstaclePoints:
        """Live filtered points at ``t_now`` s: per unit the median of its unexpired window."""
        fresh = (t_now - self._t) <= self.config.max_age_s  # (U, W)
        live = fresh.any(axis=1)
        if not np.any(live):
            return ObstaclePoints.empty()
        p = np.where(fresh[live][..., None], self._p[live], np.nan)
        r = np.where(fresh[live], self._r[live], np.nan)
        return ObstaclePoints(
            np.nanmedian(p, axis=1),
            tuple(u for u, ok in zip(self.units, live, strict=True) if ok),
            self._t[live].max(axis=1),
            np.nanmedian(r, axis=1),
        )
