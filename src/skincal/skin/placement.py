"""Skin-unit placements: the paper's Table II set and random placements on the link surfaces.

Every placement is a ``dict[str, SkinUnitPose]`` keyed ``su1, su2, ...`` with poses in link frame
``link`` (DH frame {link}, ``docs/interfaces.md``), the unit's z axis pointing out of the link.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from skincal.errors import ConfigError
from skincal.kinematics.chain import SerialChain
from skincal.kinematics.geometry import (
    DEFAULT_LINK_RADIUS,
    Capsule,
    capsule_frame,
    link_capsules,
    sample_capsule_surface,
)
from skincal.kinematics.transforms import FloatArray, rot_z
from skincal.skin.pose import SkinUnitPose

PAPER_TABLE_II = np.array(
    [
        [1.571, 0.060, -1.571, 0.060, 0.0, 1.571],
        [0.000, -0.080, 0.000, 0.050, 0.0, 1.571],
        [-1.571, 0.080, 1.571, 0.060, 0.0, 1.571],
        [3.141, -0.100, 3.141, 0.100, 0.0, 1.571],
        [-1.571, 0.030, 1.571, 0.050, 0.0, 1.571],
        [1.571, 0.000, -1.571, 0.050, 0.0, 1.571],
    ]
)
"""Paper Table II, one of its four simulated sets: rows SU 1..6, columns
``[theta_v, d_v, theta_su, d_su, a_su, alpha_su]`` (rad, m; paper Eq. 1), as printed (3 decimals)."""


def paper_placement(chain: SerialChain) -> dict[str, SkinUnitPose]:
    """The paper's Table II placement: ``su1..su6`` from :data:`PAPER_TABLE_II` via ``from_dh6``.

    Reading of the table: its rows are labelled "SU k (joint k)", but the paper skips link 1 (an
    SU there is unobservable) and the authors' configuration has one SU per link 2..7, so SU ``k``
    is placed on link ``k + 1`` (links 2..7 of a 7-joint robot). On a shorter chain only the units
    whose link exists are returned (e.g. ``su1..su5`` on a 6-joint robot).
    """
    if chain.n_joints < 2:
        raise ConfigError(f"robot '{chain.name}': the paper placement needs at least 2 links (SU k on link k + 1)")
    return {
        f"su{k + 1}": SkinUnitPose.from_dh6(k + 2, PAPER_TABLE_II[k])
        for k in range(min(len(PAPER_TABLE_II), chain.n_joints - 1))
    }


def frame_from_normal(normal: FloatArray, yaw: FloatArray) -> FloatArray:
    """Rotations ``(N, 3, 3)`` whose z axis is ``normal`` ``(N, 3)`` (unit) and x axis is turned by ``yaw``.

    ``R = [x0, y0, n] Rz(yaw)`` where ``x0`` is a fixed unit vector perpendicular to ``n`` and
    ``y0 = n x x0``; ``yaw`` ``(N,)`` rad about the normal.
    """
    normal = np.asarray(normal, dtype=float)
    helper = np.where((np.abs(normal[:, 0]) < 0.9)[:, None], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0])
    x0 = helper - np.sum(helper * normal, axis=1, keepdims=True) * normal
    x0 /= np.linalg.norm(x0, axis=1, keepdims=True)
    y0 = np.cross(normal, x0)
    return np.stack([x0, y0, normal], axis=-1) @ rot_z(yaw)


def _capsule_area(c: Capsule) -> float:
    return 2 * np.pi * c.radius * c.length + 4 * np.pi * c.radius**2


def random_placement(
    chain: SerialChain,
    n_units: int,
    rng: np.random.Generator,
    links: Sequence[int] | None = None,
    radius: float | FloatArray = DEFAULT_LINK_RADIUS,
) -> dict[str, SkinUnitPose]:
    """``n_units`` units ``su1..suN`` at random points on the link capsule surfaces (seeded).

    Unit ``i`` (0-based) goes to ``links[i % len(links)]`` (round robin); ``links`` defaults to
    2..n (link 1 only if asked: an SU there is not fully observable). On its link a capsule of
    :func:`skincal.kinematics.geometry.link_capsules` (``radius`` m, one or ``(n + 1,)`` per link)
    is drawn with probability proportional to its area, then a point uniform on its surface: the
    unit's origin is that point, its z axis the outward normal, its yaw about z uniform in
    ``[0, 2 pi)``. Points where two capsules of a link overlap may lie inside the other one.
    """
    if not (isinstance(n_units, (int, np.integer)) and n_units >= 1):
        raise ConfigError(f"random placement: n_units must be a positive integer, got {n_units!r}")
    links = list(range(2, chain.n_joints + 1)) if links is None else [int(k) for k in links]
    if not links:
        raise ConfigError(f"robot '{chain.name}': no link to place units on (links 2..n is empty; pass links=[1])")
    for k in links:
        chain.check_link(k)
    capsules = link_capsules(chain, radius)
    by_link = {k: [c for c in capsules if c.link == k] for k in set(links)}
    units: dict[str, SkinUnitPose] = {}
    for i in range(int(n_units)):
        link = links[i % len(links)]
        caps = by_link[link]
        area = np.array([_capsule_area(c) for c in caps])
        cap = caps[rng.choice(len(caps), p=area / area.sum())]
        point, normal = sample_capsule_surface(cap, rng, 1)
        R = frame_from_normal(normal, rng.uniform(0.0, 2 * np.pi, 1))[0]
        units[f"su{i + 1}"] = SkinUnitPose(link, R, point[0])
    return units


def ring_placement(
    chain: SerialChain,
    per_ring: int = 6,
    spacing: float = 0.2,
    links: Sequence[int] | None = None,
    radius: float = DEFAULT_LINK_RADIUS,
    tip: bool = True,
) -> dict[str, SkinUnitPose]:
    """A dense whole-body skin: rings of units around the link capsules, z axis outward (deterministic).

    Every capsule of :func:`skincal.kinematics.geometry.link_capsules` on ``links`` (default 2..n)
    at least 5 cm long gets ``max(1, round(L / spacing))`` rings at ``s = L (k + 1/2) / rings`` along
    its axis; each ring has ``per_ring`` units on the surface (radius ``radius`` m) at azimuths
    ``phi_j = 2 pi j / per_ring``, successive rings turned by half a step so their cones interleave.
    ``tip`` adds one unit on the last link's end cap looking along the capsule's axis (the tool
    direction). Units are named ``su1, su2, ...`` link by link.
    """
    if int(per_ring) != per_ring or per_ring < 1 or not spacing > 0:
        raise ConfigError(f"ring placement: need an integer per_ring >= 1 and spacing > 0 m, got {per_ring}, {spacing}")
    links = list(range(2, chain.n_joints + 1)) if links is None else [int(k) for k in links]
    for k in links:
        chain.check_link(k)
    poses: list[SkinUnitPose] = []
    n_ring = 0
    ringed = [c for c in link_capsules(chain, radius) if c.link in links and c.length >= 0.05]
    for cap in ringed:
        axis, u, v = capsule_frame(cap)
        rings = max(1, int(round(cap.length / spacing)))
        for k in range(rings):
            centre = cap.p0 + cap.length * (k + 0.5) / rings * axis
            phi = 2 * np.pi * (np.arange(per_ring) + 0.5 * (n_ring % 2)) / per_ring
            normals = np.cos(phi)[:, None] * u + np.sin(phi)[:, None] * v
            R = frame_from_normal(normals, np.zeros(per_ring))
            poses += [SkinUnitPose(cap.link, R[j], centre + radius * normals[j]) for j in range(per_ring)]
            n_ring += 1
    last = [c for c in ringed if c.link == chain.n_joints]
    if tip and last:  # on the far end of the last link's last capsule, looking along it
        axis = capsule_frame(last[-1])[0]
        R = frame_from_normal(axis[None], np.zeros(1))[0]
        poses.append(SkinUnitPose(chain.n_joints, R, last[-1].p1 + radius * axis))
    if not poses:
        raise ConfigError(f"robot '{chain.name}': no capsule of 5 cm or more on links {links} to put rings on")
    return {f"su{i + 1}": p for i, p in enumerate(poses)}
