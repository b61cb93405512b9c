"""Simple collision/surface geometry of a chain: capsules along the link polylines.

A link of a general (URDF) chain is the polyline from the point of its own joint through its frame
origin to the point of the next joint (the flange for the last link).

A DH link is a polyline between consecutive joint axes. In modified DH, link ``k`` (fixed to DH
frame {k}) runs from the origin of frame {k} along ``x_k`` by ``a_{k+1}`` and then along
``z_{k+1}`` by ``d_{k+1}`` to the origin of frame {k+1}; the last link runs to the flange. In
standard DH, link ``k`` runs from the origin of frame {k-1} along ``z_{k-1}`` by ``d_k`` and then
along ``x_k`` by ``a_k`` to the origin of frame {k}. Link 0 is the fixed base. Each straight piece
becomes a capsule (a zero-length piece is a sphere) of the given radius, expressed in the link's
own frame so that it moves with the link.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from skincal.kinematics.chain import SerialChain
from skincal.kinematics.transforms import FloatArray, invert, modified_dh, standard_dh

DEFAULT_LINK_RADIUS = 0.06
"""Capsule radius of a link when none is given, m (the Panda's links are 5-7 cm in radius)."""


@dataclass(frozen=True)
class Capsule:
    """A capsule fixed to ``link`` (0 = base): the set of points within ``radius`` (m) of the
    segment ``p0``-``p1`` given in that link's frame."""

    link: int
    p0: FloatArray
    p1: FloatArray
    radius: float

    @property
    def length(self) -> float:
        """Length of the core segment, m."""
        return float(np.linalg.norm(self.p1 - self.p0))


def _dh_step(chain: SerialChain, row: int) -> FloatArray:
    theta, d, a, alpha = chain.dh[row]
    step = modified_dh if chain.convention == "modified" else standard_dh
    return step(theta, d, a, alpha)


def link_capsules(chain: SerialChain, radius: float | FloatArray = DEFAULT_LINK_RADIUS) -> list[Capsule]:
    """Capsules of links 0..n (base included), each in its own link frame.

    ``radius``: one radius for all links or ``(n + 1,)`` per link, m. Pieces shorter than 1 mm are
    merged into their neighbours; a link with no length at all is one sphere at its frame origin.
    """
    n = chain.n_joints
    radii = np.broadcast_to(np.asarray(radius, dtype=float), (n + 1,))
    polylines: list[list[FloatArray]] = [[] for _ in range(n + 1)]
    zero = np.zeros(3)
    if chain.dh is None:
        # General chain: link k runs from joint k's point (on its axis, fixed in link k) through its
        # frame origin to joint k+1's point; the last link to the flange; the base to joint 1.
        for k in range(n + 1):
            start = invert(chain.T_joint_link[k - 1])[:3, 3] if k >= 1 else zero
            end = chain.T_parent_joint[k][:3, 3] if k < n else chain.T_link_flange[:3, 3]
            polylines[k] = [start, zero, end]
    elif chain.convention == "modified":
        # Link k (0..n-1) ends at frame {k+1}: T_{k,k+1} = Rx(alpha) Tx(a) Rz(theta) Tz(d).
        for k in range(n):
            _, d, a, alpha = chain.dh[k]
            corner = np.array([a, 0.0, 0.0])
            end = _dh_step(chain, k)[:3, 3]
            polylines[k] = [zero, corner, end]
        polylines[n] = [zero, chain.T_link_flange[:3, 3]]
    else:
        # Link k (1..n) spans frame {k-1} -> {k}; in frame {k}: T_{k-1,k}^-1 maps {k-1} points.
        polylines[0] = [zero]
        for k in range(1, n + 1):
            _, d, a, alpha = chain.dh[k - 1]
            T_k_prev = invert(_dh_step(chain, k - 1))  # pose of {k-1} in {k}, independent of q_k
            start = T_k_prev[:3, 3]
            corner = T_k_prev[:3, :3] @ np.array([0.0, 0.0, d]) + start
            polylines[k] = [start, corner, zero]
        polylines[n] = polylines[n] + [chain.T_link_flange[:3, 3]]
    capsules: list[Capsule] = []
    for link, pts in enumerate(polylines):
        kept = [pts[0]]
        for p in pts[1:]:
            if np.linalg.norm(p - kept[-1]) > 1e-3:
                kept.append(p)
        if len(kept) == 1:
            capsules.append(Capsule(link, kept[0].copy(), kept[0].copy(), float(radii[link])))
        for p0, p1 in zip(kept[:-1], kept[1:], strict=True):
            capsules.append(Capsule(link, p0.copy(), p1.copy(), float(radii[link])))
    return capsules


def capsule_frame(capsule: Capsule) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Unit axis ``p0 -> p1`` (``+z`` of the link frame for a sphere) and an orthonormal pair ``(u, v)``
    perpendicular to it, ``v = axis x u``; each ``(3,)`` in the capsule's link frame."""
    L = capsule.length
    axis = (capsule.p1 - capsule.p0) / L if L > 0 else np.array([0.0, 0.0, 1.0])
    helper = np.array([1.0, 0.0, 0.0]) if abs(axis[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    u = np.cross(axis, helper)
    u /= np.linalg.norm(u)
    return axis, u, np.cross(axis, u)


def sample_capsule_surface(capsule: Capsule, rng: np.random.Generator, size: int) -> tuple[FloatArray, FloatArray]:
    """Points uniformly distributed (by area) on a capsule's surface and the outward unit normals.

    Returns ``(points, normals)``, each ``(size, 3)`` in the capsule's link frame.
    """
    r, L = capsule.radius, capsule.length
    axis, u, v = capsule_frame(capsule)
    side_area, cap_area = 2 * np.pi * r * L, 4 * np.pi * r * r
    on_side = rng.random(size) < side_area / (side_area + cap_area)
    phi = rng.uniform(0.0, 2 * np.pi, size)
    radial = np.cos(phi)[:, None] * u + np.sin(phi)[:, None] * v
    s = rng.uniform(0.0, L, size)
    side_pts = capsule.p0 + s[:, None] * axis + r * radial
    # Hemispherical end caps: a uniform direction on the sphere, put on the end it points to.
    dirs = rng.normal(size=(size, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    centre = np.where((dirs @ axis >= 0)[:, None], capsule.p1, capsule.p0)
    cap_pts = centre + r * dirs
    points = np.where(on_side[:, None], side_pts, cap_pts)
    normals = np.where(on_side[:, None], radial, dirs)
    return points, normals
