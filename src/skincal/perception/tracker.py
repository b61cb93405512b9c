"""Streaming perception for the controller: per-unit tracks with velocity, and a short point memory.

Each unit ``u`` reads a range ``r`` at instant ``t`` with the robot at ``q(t)``; the reading becomes
the base-frame point ``p = o + r a`` (``o``, ``a``: the unit's origin and +z axis, ``T_base_su =
T_base_link(q) T_link_su`` from the believed pose). Per unit the tracker keeps the recent points:

* **position**: component-wise median of the last ``window`` points, stamped with their median
  instant ``t_ref``;
* **velocity** along the ray: least-squares slope ``v`` of the points over the last ``rate_window_s``
  (base frame, so the unit's own motion is compensated), projected on the newest axis,
  ``v_ray = (a^T v) a`` (the cone's lateral jitter is not a velocity), clipped to ``max_speed``;
* published at ``t_now`` as ``p_ref + v_ray min(t_now - t_ref, predict_s)``, the displacement capped
  at ``coast_m`` (the filter and the 50 Hz sampling delay the point, a 1 m/s hand moves 4 cm in
  40 ms; and a target that slips out of the narrow cone keeps coming for a while).

**Memory.** A unit that stops seeing its target (nothing, or a farther target) only says the
target is no longer in its 27 deg cone: the reported target may lie anywhere in the cone, so a
target at the edge leaves it as soon as the unit turns a little or the robot backs away. That is
no evidence the obstacle has gone, so the point is kept (coasting as above, then still) until
``memory_s`` after its last reading; a departing person is followed out by
the readings themselves (tracking reaches ``max_range`` beyond the notice distance). A track whose
unit jumps to a different target (range ``jump`` m off the prediction) is kept the same way as a
memory point (at most ``n_memory``, oldest replaced), cleared when a new reading of any unit lands
on it (within ``jump``) or after ``memory_s``.

**Free space.** The other units' readings also clear points: a unit that reads range ``r`` (or
nothing within ``max_range``) has seen nothing nearer in its cone, so a memory point, or a stale
track of another unit (no reading of its own for ``max_age_s``), lying inside that cone nearer than
``r - jump`` is gone and dropped (:meth:`ProximityTracker._carve`). With a dense skin a person who
leaves is thus forgotten as soon as a cone sweeps the place, not ``memory_s`` later.

Every published point carries the cone's lateral uncertainty ``spread = r sin(fov / 2)``: the
VL53L1X reports the nearest target *anywhere* in its cone, so the target lies on the spherical cap of
radius ``r`` about the unit, not necessarily on its axis (the controller takes the cap point nearest to
the robot, :func:`skincal.control.constraints.obstacle_rows`).

**Covariance.** Every point also carries its position covariance ``cov`` (base frame, m^2,
:mod:`skincal.perception.uncertainty`: the unit's pose covariance, the ToF noise, the joint noise),
that of the track's NEWEST reading (the median filter only narrows the ToF part, and the calibration
part is the same bias for every reading of a unit, so the newest reading's is a fair and slightly
cautious figure); an extrapolated point keeps it (the velocity's own error is not added), a memory
point keeps the covariance it had when remembered.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
from numpy.typing import ArrayLike

from skincal.kinematics.chain import SerialChain
from skincal.perception.body import RobotBody, body_proximity
from skincal.perception.config import PerceptionConfig
from skincal.perception.points import ObstaclePoints, valid_ranges
from skincal.perception.uncertainty import SkinUncertainty, reading_covariance
from skincal.skin.pose import SkinUnitPose

_BUFFER = 12
"""Readings kept per unit (enough for the median window and ``rate_window_s`` at 50 Hz)."""


def ray_velocity(t: ArrayLike, p: ArrayLike, axis: ArrayLike) -> np.ndarray:
    """Velocity along ``axis`` ``(3,)`` of points ``p`` ``(M, 3)`` at instants ``t`` ``(M,)``: the
    least-squares slope ``v = sum (t - t_mean)(p - p_mean) / sum (t - t_mean)^2`` projected,
    ``(a^T v) a``, m/s (zero for fewer than 3 points)."""
    t = np.asarray(t, dtype=float)
    p = np.asarray(p, dtype=float)
    a = np.asarray(axis, dtype=float)
    if t.size < 3:
        return np.zeros(3)
    dt = t - t.mean()
    v = dt @ (p - p.mean(axis=0)) / max(float(dt @ dt), 1e-12)
    return float(v @ a) * a


class ProximityTracker:
    """Readings of all units at one instant in (:meth:`update`), live obstacle points out (:meth:`points`).

    ``uncertainty``: the units' pose covariances, the ToF and joint noise behind each point's ``cov``
    (default: none known, so every unit gets the assumed std of ``config``).
    """

    def __init__(
        self,
        chain: SerialChain,
        poses: Mapping[str, SkinUnitPose],
        config: PerceptionConfig = PerceptionConfig(),
        body: RobotBody | None = None,
        uncertainty: SkinUncertainty | None = None,
    ) -> None:
        self.chain = chain
        self.uncertainty = uncertainty if uncertainty is not None else SkinUncertainty()
        self.poses = dict(poses)
        self.config = config
        self.body = body if body is not None else RobotBody.of(chain)
        self.units = tuple(self.poses)
        U = len(self.units)
        self._half = np.deg2rad(config.fov_deg) / 2
        self._links = np.array([self.poses[u].link for u in self.units], dtype=int)
        self._T_link_su = np.stack([self.poses[u].T_link_su for u in self.units]) if U else np.zeros((0, 4, 4))
        self._pose_cov = self.uncertainty.unit_covariances(self.units, config)  # (U, 6, 6)
        self._cov = np.zeros((U, 3, 3))  # covariance of each track's newest reading, m^2
        self._bt = np.full((U, _BUFFER), -np.inf)  # reading instants, s (-inf = empty slot)
        self._bp = np.full((U, _BUFFER, 3), np.nan)  # points, base frame, m
        self._br = np.full((U, _BUFFER), np.nan)  # ranges, m
        # filtered track of each unit (refreshed on every valid reading)
        self._pos = np.full((U, 3), np.nan)
        self._vel = np.zeros((U, 3))
        self._axis = np.zeros((U, 3))
        self._range = np.full(U, np.nan)
        self._t_ref = np.full(U, -np.inf)
        self._t_last = np.full(U, -np.inf)
        # memory points (tracks a unit jumped away from)
        M = int(config.n_memory)
        self._mp = np.full((M, 3), np.nan)
        self._mt = np.full(M, -np.inf)
        self._mr = np.full(M, np.nan)
        self._ma = np.zeros((M, 3))
        self._mu = [""] * M
        self._mc = np.zeros((M, 3, 3))

    # ------------------------------------------------------------------ update
    def update(self, t: float, q: ArrayLike, ranges: Mapping[str, float]) -> None:
        """Add the readings ``unit -> range`` (m, NaN = none) taken at instant ``t`` s with joints ``q`` ``(n,)``."""
        idx = np.array([self.units.index(u) for u in ranges if u in self.poses], dtype=int)
        if idx.size == 0:
            return
        cfg = self.config
        r = np.array([ranges[self.units[i]] for i in idx], dtype=float)
        T = self.chain.link_frames(q)[0]
        T_base_su = T[self._links[idx]] @ self._T_link_su[idx]
        o, a = T_base_su[:, :3, 3], T_base_su[:, :3, 2]
        ok = valid_ranges(r, cfg)
        p = o + np.where(ok, r, 0.0)[:, None] * a
        is_self = np.zeros(idx.size, dtype=bool)
        if np.any(ok):
            is_self[ok] = body_proximity(self.body, T, p[ok]).distance <= cfg.self_margin
        self._clear_memory(t, o, a, r, ok & ~is_self)
        # free space seen along each cone: up to the reading, up to max_range when there was none
        nothing = np.isnan(r) | (r > cfg.max_range)
        self._carve(t, idx, o, a, np.where(ok, r, np.where(nothing, cfg.max_range, 0.0)))
        new = np.flatnonzero(ok & ~is_self)
        if new.size:
            u = idx[new]
            cov = reading_covariance(
                self.chain,
                T,
                self._links[u],
                self._T_link_su[u, :3, :3],
                r[new],
                p[new],
                self._pose_cov[u],
                self.uncertainty,
            )
        for j, k in enumerate(new):  # a few units per instant (the robot itself is no news)
            self._add(int(idx[k]), t, p[k], r[k], o[k], a[k])
            self._cov[idx[k]] = cov[j]

    def _add(self, i: int, t: float, p: np.ndarray, r: float, o: np.ndarray, a: np.ndarray) -> None:
        cfg = self.config
        if np.isfinite(self._t_last[i]):
            pred = self._pos[i] + self._vel[i] * min(t - self._t_ref[i], cfg.predict_s)
            if abs(r - np.linalg.norm(pred - o)) > cfg.jump:  # another target (lateral shifts are the cone's)
                self._remember(i)
                self._drop(i)
        self._bt[i] = np.roll(self._bt[i], -1)
        self._bp[i] = np.roll(self._bp[i], -1, axis=0)
        self._br[i] = np.roll(self._br[i], -1)
        self._bt[i, -1], self._bp[i, -1], self._br[i, -1] = t, p, r
        recent = np.isfinite(self._bt[i]) & (t - self._bt[i] <= cfg.max_age_s)
        last = np.flatnonzero(recent)[-int(cfg.window) :]
        self._pos[i] = np.median(self._bp[i, last], axis=0)
        self._range[i] = float(np.median(self._br[i, last]))
        self._t_ref[i] = float(np.median(self._bt[i, last]))
        rate = recent & (t - self._bt[i] <= cfg.rate_window_s + 1e-9)
        v = ray_velocity(self._bt[i, rate], self._bp[i, rate], a)
        speed = np.linalg.norm(v)
        self._vel[i] = v if speed <= cfg.max_speed else v * (cfg.max_speed / speed)
        self._axis[i], self._t_last[i] = a, t

    def _drop(self, i: int) -> None:
        self._bt[i] = -np.inf
        self._t_last[i] = self._t_ref[i] = -np.inf
        self._vel[i] = 0.0

    def _remember(self, i: int) -> None:
        slot = int(np.argmin(self._mt))
        self._mp[slot], self._mt[slot], self._mr[slot] = self._pos[i], self._t_last[i], self._range[i]
        self._ma[slot], self._mu[slot] = self._axis[i], self.units[i]
        self._mc[slot] = self._cov[i]

    def _clear_memory(self, t: float, o: np.ndarray, a: np.ndarray, r: np.ndarray, ok: np.ndarray) -> None:
        """Forget expired memory points and those a new reading lands on (within ``jump``)."""
        cfg = self.config
        live = np.isfinite(self._mt) & (t - self._mt <= cfg.memory_s)
        self._mt[~live] = -np.inf
        if not np.any(live) or not np.any(ok):
            return
        p = o[ok] + r[ok, None] * a[ok]
        covered = np.any(np.linalg.norm(self._mp[live][:, None, :] - p[None], axis=-1) <= cfg.jump, axis=1)
        self._mt[np.flatnonzero(live)[covered]] = -np.inf

    def _carve(self, t: float, idx: np.ndarray, o: np.ndarray, a: np.ndarray, free: np.ndarray) -> None:
        """Free-space evidence: unit ``idx[k]`` (origin ``o[k]``, axis ``a[k]``) saw nothing nearer than
        ``free[k]`` m in its cone. A memory point, or another unit's stale track (no reading of its own
        for ``max_age_s``), lying inside that cone (angle to the axis < fov / 2) nearer than
        ``free[k] - jump`` is contradicted (the sensor reports the nearest target in its cone) and dropped.
        A unit's own track is left alone: when its target leaves the cone it is still near the cone."""
        cfg = self.config
        if not np.any(free > cfg.jump):
            return

        def inside(p: np.ndarray) -> np.ndarray:  # (K, 3) -> (K, R): in reading k's free cone
            d = p[:, None, :] - o[None]
            dist = np.linalg.norm(d, axis=-1)
            cos = np.einsum("krj,rj->kr", d, a) / np.maximum(dist, 1e-12)
            return (cos > np.cos(self._half)) & (dist < free[None] - cfg.jump)

        mem = np.flatnonzero(np.isfinite(self._mt))
        if mem.size:
            self._mt[mem[inside(self._mp[mem]).any(axis=1)]] = -np.inf
        stale = np.flatnonzero(np.isfinite(self._t_last) & (t - self._t_last > cfg.max_age_s))
        if stale.size:
            hit = inside(self._pos[stale])
            hit &= stale[:, None] != idx[None, :]
            for i in stale[hit.any(axis=1)]:
                self._drop(int(i))

    # ------------------------------------------------------------------ output
    def points(self, t_now: float) -> ObstaclePoints:
        """Live points at ``t_now`` s: unit tracks (extrapolated along their ray velocity, see the module
        docstring) and memory points (still)."""
        cfg = self.config
        alive = np.isfinite(self._t_last) & (t_now - self._t_last <= cfg.memory_s)
        age = np.clip(np.where(alive, t_now - self._t_ref, 0.0), 0.0, cfg.predict_s)
        shift = self._vel * age[:, None]
        norm = np.linalg.norm(shift, axis=1, keepdims=True)
        shift = np.where(norm > cfg.coast_m, shift * cfg.coast_m / np.maximum(norm, 1e-12), shift)
        moving = (t_now - self._t_ref <= cfg.predict_s)[:, None] & (norm <= cfg.coast_m)
        vel = np.where(moving, self._vel, 0.0)
        pos = self._pos + shift
        mem = np.isfinite(self._mt) & (t_now - self._mt <= cfg.memory_s)
        units = tuple(u for u, k in zip(self.units, alive, strict=True) if k) + tuple(
            u for u, k in zip(self._mu, mem, strict=True) if k
        )
        ranges = np.concatenate([self._range[alive], self._mr[mem]])
        return ObstaclePoints(
            positions=np.concatenate([pos[alive], self._mp[mem]]),
            units=units,
            stamps=np.concatenate([self._t_last[alive], self._mt[mem]]),
            ranges=ranges,
            velocities=np.concatenate([vel[alive], np.zeros((int(mem.sum()), 3))]),
            axes=np.concatenate([self._axis[alive], self._ma[mem]]),
            spread=ranges * np.sin(self._half),
            cov=np.concatenate([self._cov[alive], self._mc[mem]]),
        )
