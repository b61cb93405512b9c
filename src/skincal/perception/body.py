"""The robot body as link capsules in the base frame, and closed-form distances to it.

The body is :func:`skincal.kinematics.geometry.link_capsules`: per link a few capsules (segment
``p0``-``p1`` in the link frame, radius ``r``). At joint angles ``q`` each capsule is moved to the base
frame {0}: ``a = T_base_link(q) p0``, ``b = T_base_link(q) p1``.

Distances (all closed form, m):

* point-segment: ``s* = clip((x - a).(b - a) / |b - a|^2, 0, 1)``, closest point ``c = a + s* (b - a)``;
  the distance from ``x`` to the capsule surface is ``|x - c| - r`` (negative inside).
* segment-segment (Ericson, *Real-Time Collision Detection* 5.1.9): minimise
  ``|a1 + s u - a2 - t v|`` over ``s, t`` in [0, 1] by solving the 2x2 normal equations and clamping.
  Capsule-capsule distance is that minus both radii; capsule-sphere is a zero-length second segment.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from skincal.kinematics.chain import SerialChain
from skincal.kinematics.geometry import DEFAULT_LINK_RADIUS, Capsule, link_capsules
from skincal.kinematics.transforms import FloatArray

_EPS = 1e-12


@dataclass(frozen=True)
class RobotBody:
    """Link capsules of a chain, stacked for vectorised distance queries.

    Attributes:
        chain: the robot.
        link: ``(C,)`` 1-based link of each capsule (0 = base).
        p0_link, p1_link: ``(C, 3)`` segment ends in their link frames, m.
        radius: ``(C,)`` capsule radii, m.
    """

    chain: SerialChain
    link: np.ndarray
    p0_link: FloatArray
    p1_link: FloatArray
    radius: FloatArray

    @classmethod
    def of(
        cls, chain: SerialChain, radius: float | FloatArray = DEFAULT_LINK_RADIUS, capsules: Sequence[Capsule] = ()
    ) -> RobotBody:
        """The body of ``chain`` from :func:`link_capsules` (``radius`` m, one or ``(n + 1,)``), or given capsules."""
        caps = list(capsules) or link_capsules(chain, radius)
        return cls(
            chain=chain,
            link=np.array([c.link for c in caps], dtype=int),
            p0_link=np.array([c.p0 for c in caps], dtype=float),
            p1_link=np.array([c.p1 for c in caps], dtype=float),
            radius=np.array([c.radius for c in caps], dtype=float),
        )

    def inflated(self, margin: float) -> RobotBody:
        """The same body with every radius grown by ``margin`` m (a safety padding)."""
        return RobotBody(self.chain, self.link, self.p0_link, self.p1_link, self.radius + float(margin))

    def segments(self, T_base_link: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Capsule segment ends in the base frame, ``(N, C, 3)`` each, from ``T_base_link`` ``(N, n + 1, 4, 4)``."""
        T = T_base_link[:, self.link]  # (N, C, 4, 4)
        R, p = T[..., :3, :3], T[..., :3, 3]
        a = np.einsum("ncij,cj->nci", R, self.p0_link) + p
        b = np.einsum("ncij,cj->nci", R, self.p1_link) + p
        return a, b


def closest_on_segments(x: FloatArray, a: FloatArray, b: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Closest points on segments ``a``-``b`` to points ``x`` (all broadcast, ``(..., 3)``).

    Returns ``(c, s)``: closest points ``(..., 3)`` and segment parameters ``s`` in [0, 1] ``(...)``.
    """
    ab = b - a
    denom = np.einsum("...i,...i->...", ab, ab)
    s = np.einsum("...i,...i->...", x - a, ab) / np.maximum(denom, _EPS)
    s = np.clip(np.where(denom > _EPS, s, 0.0), 0.0, 1.0)
    return a + s[..., None] * ab, s


@dataclass(frozen=True)
class BodyProximity:
    """The closest robot point to each of ``K`` query points (one robot configuration).

    Attributes:
        distance: ``(K,)`` distance from the query point to the robot surface, m (negative inside).
        capsule: ``(K,)`` index of the closest capsule.
        link: ``(K,)`` link of that capsule (0 = base).
        p_base_robot: ``(K, 3)`` closest point on the capsule's core segment, base frame, m.
        normal: ``(K, 3)`` unit vector from that robot point to the query point (base frame).
    """

    distance: FloatArray
    capsule: np.ndarray
    link: np.ndarray
    p_base_robot: FloatArray
    normal: FloatArray


def body_proximity(body: RobotBody, T_base_link: FloatArray, points: ArrayLike, group: int = 1) -> BodyProximity:
    """Closest capsule and point of the robot at one configuration to each point ``(K, 3)`` (base frame, m).

    ``T_base_link``: ``(1, n + 1, 4, 4)`` or ``(n + 1, 4, 4)``. Distance ``d = |x - c| - r`` minimised
    over the capsules; the normal is ``(x - c) / |x - c|`` (any unit vector if ``x`` lies on the segment).
    ``group > 1``: the points come in consecutive groups of that many (e.g. the possible places of one
    reading, :func:`skincal.control.constraints.cap_candidates`) and the answer has one entry per group,
    the point of the group nearest to the robot (the first of equals): ``K / group`` entries.
    """
    T = np.asarray(T_base_link, dtype=float)
    T = T[None] if T.ndim == 3 else T
    x = np.asarray(points, dtype=float).reshape(-1, 3)
    K = x.shape[0]
    a, b = body.segments(T[:1])
    a, ab = a[0], b[0] - a[0]  # (C, 3)
    if a.shape[0] == 0:
        best = np.zeros(K // group, dtype=int)
        return BodyProximity(
            np.full(best.size, np.inf),
            best,
            body.link[best],
            np.zeros((best.size, 3)),
            np.tile([0.0, 0.0, 1.0], (best.size, 1)),
        )
    # :func:`closest_on_segments` on (C, K) arrays, after the dot product per component (long inner loops
    # for the many points of the control loop; the same operations in the same order, so the same numbers)
    denom = np.einsum("...i,...i->...", ab, ab)[:, None]
    x_a = (x.reshape(1, -1) - np.tile(a, (1, K))).reshape(-1, K, 3)  # x - a, (C, K, 3), by long rows
    s = np.einsum("...i,...i->...", x_a, ab[:, None, :]) / np.maximum(denom, _EPS)
    s = np.clip(np.where(denom > _EPS, s, 0.0), 0.0, 1.0)  # (C, K)
    gap = [x[:, j][None, :] - (a[:, j][:, None] + s * ab[:, j][:, None]) for j in range(3)]  # (C, K) each
    dist = np.sqrt(gap[0] * gap[0] + gap[1] * gap[1] + gap[2] * gap[2]) - body.radius[:, None]
    best = np.argmin(dist, axis=0)
    k = np.arange(K)
    if group > 1:  # the nearest point of each group, then only those
        k = np.argmin(dist[best, k].reshape(-1, group), axis=1) + group * np.arange(K // group)
        best = best[k]
    g = np.stack([gj[best, k] for gj in gap], axis=1)
    sb = s[best, k][:, None]
    c = a[best] + sb * ab[best]
    norm = np.linalg.norm(g, axis=-1, keepdims=True)
    normal = np.where(norm > _EPS, g / np.maximum(norm, _EPS), np.array([0.0, 0.0, 1.0]))
    return BodyProximity(dist[best, k], best, body.link[best], c, normal)


def segment_distance(a1: FloatArray, b1: FloatArray, a2: FloatArray, b2: FloatArray) -> FloatArray:
    """Distance between segments ``a1``-``b1`` and ``a2``-``b2`` (broadcast ``(..., 3)``), m.

    Closed form (Ericson 5.1.9): ``s = clip((b f - c e) / (a e - b^2))``, ``t = (b s + f) / e`` then
    clamp ``t`` and recompute ``s``, with ``u = b1 - a1``, ``v = b2 - a2``, ``w = a1 - a2``,
    ``a = u.u``, ``b = u.v``, ``c = u.w``, ``e = v.v``, ``f = v.w``. Zero-length segments are points.
    """
    u, v, w = b1 - a1, b2 - a2, a1 - a2
    s, t_clamped = _segment_parameters(u, v, w)
    gap = w + s[..., None] * u - t_clamped[..., None] * v
    return np.linalg.norm(gap, axis=-1)


def segment_closest_points(
    a1: FloatArray, b1: FloatArray, a2: FloatArray, b2: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """The closest points ``(c1, c2)`` (``(..., 3)`` each, m) of segments ``a1``-``b1`` and ``a2``-``b2``
    (broadcast): :func:`segment_distance`'s parameters, ``c1 = a1 + s u``, ``c2 = a2 + t v``."""
    u, v, w = b1 - a1, b2 - a2, a1 - a2
    s, t = _segment_parameters(u, v, w)
    return a1 + s[..., None] * u, a2 + t[..., None] * v


def _segment_parameters(u: FloatArray, v: FloatArray, w: FloatArray) -> tuple[FloatArray, FloatArray]:
    """``(s, t)`` in [0, 1] of the closest points of segments ``a1 + s u`` and ``a2 + t v``, ``w = a1 - a2``
    (:func:`segment_distance`)."""

    def dot(p: FloatArray, q: FloatArray) -> FloatArray:
        return np.einsum("...i,...i->...", p, q)

    a, b, c, e, f = dot(u, u), dot(u, v), dot(u, w), dot(v, v), dot(v, w)
    a_ok, e_ok = a > _EPS, e > _EPS
    denom = a * e - b * b
    s = np.where(denom > _EPS * np.maximum(a * e, _EPS), (b * f - c * e) / np.where(denom > 0, denom, 1.0), 0.0)
    s = np.clip(np.where(a_ok & e_ok, s, np.where(a_ok, -c / np.where(a_ok, a, 1.0), 0.0)), 0.0, 1.0)
    t = np.where(e_ok, (b * s + f) / np.where(e_ok, e, 1.0), 0.0)
    t_clamped = np.clip(t, 0.0, 1.0)
    s_re = np.clip(np.where(a_ok, (b * t_clamped - c) / np.where(a_ok, a, 1.0), 0.0), 0.0, 1.0)
    s = np.where((t != t_clamped) & e_ok, s_re, s)
    return s, t_clamped

