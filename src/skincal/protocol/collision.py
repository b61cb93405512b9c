"""Collision check of a protocol motion with the chain's link capsules.

The robot is the set of capsules of :func:`skincal.kinematics.geometry.link_capsules` (each link's
polyline, radius :data:`LINK_RADIUS`). A configuration is *collision-free* when

* no capsule of link ``i`` intersects a capsule of a non-adjacent link ``j`` (``|i - j| >= 2``),
  except pairs that touch in every configuration because the links between them are shorter than
  the two radii (a wrist whose joint axes meet: e.g. the Panda's link 1 is a point, so links 0 and 2
  always touch); and
* no capsule of a link ``>= 2`` reaches below the floor plane ``z = floor_z`` of the base frame
  (default 0: links 0 and 1 stand on it; ``None``: no floor, e.g. an arm hanging from a torso).

Capsule-capsule distance = segment-segment distance - the two radii (:func:`segment_distance`,
vectorised). :func:`check_motion` samples a trajectory every :data:`CHECK_STEP_S` seconds.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from skincal.errors import ProtocolError
from skincal.kinematics.chain import SerialChain
from skincal.kinematics.geometry import link_capsules
from skincal.kinematics.transforms import FloatArray

LINK_RADIUS = 0.05
"""Capsule radius of every link in the collision check, m (a slim arm: the Panda's links are 5-7 cm
in radius, but its links' polylines run along the joint axes, inside the real link shells)."""
FLOOR_Z = 0.0
"""Height of the floor plane in the base frame, m."""
CHECK_STEP_S = 0.05
"""Sampling step of the collision check along a trajectory, s."""
_EPS = 1e-12


def segment_distance(p0: FloatArray, p1: FloatArray, q0: FloatArray, q1: FloatArray) -> FloatArray:
    """Shortest distance between segments ``p0-p1`` and ``q0-q1``; arrays ``(..., 3)`` broadcast, m.

    Closed form of the closest points (Ericson, *Real-Time Collision Detection*, 5.1.9), with
    degenerate (point) segments handled; returns ``(...)``.
    """
    p0, p1, q0, q1 = np.broadcast_arrays(*(np.asarray(x, dtype=float) for x in (p0, p1, q0, q1)))
    d1, d2, r = p1 - p0, q1 - q0, p0 - q0
    a = np.einsum("...k,...k->...", d1, d1)
    e = np.einsum("...k,...k->...", d2, d2)
    f = np.einsum("...k,...k->...", d2, r)
    c = np.einsum("...k,...k->...", d1, r)
    b = np.einsum("...k,...k->...", d1, d2)
    a_ok, e_ok = a > _EPS, e > _EPS
    safe_a, safe_e = np.where(a_ok, a, 1.0), np.where(e_ok, e, 1.0)
    # general case: both segments have length
    denom = a * e - b * b
    parallel = denom <= 1e-12 * np.maximum(a * e, _EPS)
    s = np.where(parallel, 0.0, np.clip((b * f - c * e) / np.where(parallel, 1.0, denom), 0.0, 1.0))
    t = (b * s + f) / safe_e
    s = np.where(t < 0, np.clip(-c / safe_a, 0.0, 1.0), np.where(t > 1, np.clip((b - c) / safe_a, 0.0, 1.0), s))
    t = np.clip(t, 0.0, 1.0)
    # first segment a point: s = 0, t from the projection; second a point: t = 0, s from the projection
    s = np.where(a_ok, np.where(e_ok, s, np.clip(-c / safe_a, 0.0, 1.0)), 0.0)
    t = np.where(e_ok, np.where(a_ok, t, np.clip(f / safe_e, 0.0, 1.0)), 0.0)
    closest = r + s[..., None] * d1 - t[..., None] * d2
    return np.linalg.norm(closest, axis=-1)


@dataclass(frozen=True)
class CollisionModel:
    """The capsules of ``chain`` and the pairs checked (module docstring)."""

    chain: SerialChain
    radius: float = LINK_RADIUS
    floor_z: float | None = FLOOR_Z

    @cached_property
    def capsules(self):
        return link_capsules(self.chain, self.radius)

    @cached_property
    def _arrays(self) -> tuple[np.ndarray, FloatArray, FloatArray, FloatArray]:
        caps = self.capsules
        link = np.array([c.link for c in caps])
        p0 = np.array([np.append(c.p0, 1.0) for c in caps])
        p1 = np.array([np.append(c.p1, 1.0) for c in caps])
        radius = np.array([c.radius for c in caps])
        return link, p0, p1, radius

    @cached_property
    def pairs(self) -> tuple[np.ndarray, np.ndarray]:
        """Indices ``(I, J)`` of the capsule pairs checked against each other."""
        link, _, _, radius = self._arrays
        n_links = self.chain.n_joints + 1
        length = np.zeros(n_links)
        for cap in self.capsules:
            length[cap.link] += cap.length
        I, J = [], []
        for i in range(len(link)):
            for j in range(i + 1, len(link)):
                li, lj = sorted((link[i], link[j]))
                if lj - li < 2:
                    continue
                # the links between touch both: always in contact when shorter than the two radii
                if length[li + 1 : lj].sum() < radius[i] + radius[j]:
                    continue
                I.append(i)
                J.append(j)
        return np.array(I, dtype=int), np.array(J, dtype=int)

    def endpoints(self, q: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Capsule end points in the base frame, each ``(N, C, 3)``, at configurations ``q`` ``(N, n)``."""
        link, p0, p1, _ = self._arrays
        frames = self.chain.link_frames(q)[:, link, :3, :]  # (N, C, 3, 4)
        return (frames @ p0[:, :, None])[..., 0], (frames @ p1[:, :, None])[..., 0]

    def clearance(self, q: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Per configuration ``(N,)``: the smallest capsule-capsule distance over the checked pairs and
        the smallest height of a capsule of a link ``>= 2`` above the floor, m (negative = collision)."""
        q = np.atleast_2d(np.asarray(q, dtype=float))
        link, _, _, radius = self._arrays
        a, b = self.endpoints(q)
        I, J = self.pairs
        if I.size:
            d = segment_distance(a[:, I], b[:, I], a[:, J], b[:, J]) - radius[I] - radius[J]
            pair_min = d.min(axis=1)
        else:
            pair_min = np.full(q.shape[0], np.inf)
        above = link >= 2
        if above.any() and self.floor_z is not None:
            z = np.minimum(a[:, above, 2], b[:, above, 2]) - radius[above] - self.floor_z
            floor_min = z.min(axis=1)
        else:
            floor_min = np.full(q.shape[0], np.inf)
        return pair_min, floor_min

    def free(self, q: FloatArray) -> np.ndarray:
        """``(N,)`` True where the configuration is collision-free."""
        pair_min, floor_min = self.clearance(q)
        return (pair_min > 0) & (floor_min > 0)

    def first_collision(self, q: FloatArray) -> tuple[int, str] | None:
        """Index of the first colliding configuration in ``q`` ``(N, n)`` and what collides, or ``None``."""
        q = np.atleast_2d(np.asarray(q, dtype=float))
        pair_min, floor_min = self.clearance(q)
        bad = np.flatnonzero((pair_min <= 0) | (floor_min <= 0))
        if bad.size == 0:
            return None
        k = int(bad[0])
        link, _, _, radius = self._arrays
        a, b = self.endpoints(q[k : k + 1])
        I, J = self.pairs
        if floor_min[k] <= 0:
            above = np.flatnonzero(link >= 2)
            z = np.minimum(a[0, above, 2], b[0, above, 2]) - radius[above] - self.floor_z
            return k, f"link {link[above[int(np.argmin(z))]]} reaches below the floor"
        d = segment_distance(a[0, I], b[0, I], a[0, J], b[0, J]) - radius[I] - radius[J]
        m = int(np.argmin(d))
        return k, f"links {link[I[m]]} and {link[J[m]]} collide"


def check_motion(model: CollisionModel, t: FloatArray, q: FloatArray, what: str = "") -> None:
    """Raise :class:`ProtocolError` at the first colliding configuration of ``q`` ``(N, n)`` at ``t``."""
    hit = model.first_collision(q)
    if hit is not None:
        k, reason = hit
        raise ProtocolError(f"{what}{reason} at t={float(t[k]):.2f} s (capsules of radius {model.radius} m)")
