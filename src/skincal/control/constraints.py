"""Constraint rows of the avoidance QP: obstacle approach velocity and joint limits.

Obstacle constraint (paper Sec. V-C, after Escobedo et al. 2021): for obstacle point ``x_i`` let
``c_i`` be the closest point of the robot (on a link capsule's core segment, link ``l_i``),
``d_i = |x_i - c_i| - r`` the distance to the (padded) capsule surface and ``n_i = (x_i - c_i) / |x_i - c_i|``
the unit normal from robot to obstacle, all in the base frame. The robot point's velocity toward
the obstacle is ``n_i^T J_i qd`` with ``J_i`` the ``3 x n`` position Jacobian of ``c_i`` as a point
fixed to link ``l_i``; since ``d/dt d_i = -n_i^T J_i qd`` (envelope theorem: the closest point only
slides along the segment, perpendicular to ``n_i``), the row

    n_i^T J_i qd <= b(d_i)

bounds the approach speed by ``b(d_i)`` (:func:`approach_speed_bound`).

Moving obstacles (velocity-aware barrier): with the point's velocity ``v_i`` the gap changes as
``d/dt d_i = n_i^T v_i - n_i^T J_i qd``; asking ``d/dt d_i >= -b(d_i)`` gives

    n_i^T J_i qd <= b(d_i) + min(n_i^T v_i, 0)

(only an approaching point tightens the row; a receding one gives no licence to follow it).

Cone-aware placement: a reading ``r`` says the nearest target lies somewhere on the spherical cap of
radius ``r`` about the unit within the cone, i.e. up to ``spread = r sin(fov/2)`` off the axis point
``p``. The row uses the candidate nearest to the robot among ``p`` and ``n_rim`` rim points
``p + spread e_k - (r - sqrt(r^2 - spread^2)) a`` (``e_k`` unit vectors across the ray axis ``a``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from skincal.kinematics.chain import SerialChain, cross
from skincal.kinematics.transforms import FloatArray
from skincal.perception.body import BodyProximity, RobotBody, body_proximity

SATURATION = 0.99
"""Fraction of ``v_max`` the bound reaches at the notice distance."""


def approach_speed_bound(
    distance: ArrayLike, critical: float | ArrayLike, notice: float, v_max: float, width: float | None = None
) -> FloatArray:
    """Allowed approach speed ``b(d)`` [m/s] at distance ``d`` [m]: a smooth sigmoid (tanh) ramp,

        b(d) = v_max tanh((d - d_c) / w),    w = (d_n - d_c) / atanh(0.99),

    zero at the critical distance ``d_c``, 99 % of ``v_max`` at the notice distance ``d_n`` (and
    ``v_max`` beyond), negative below ``d_c`` (the robot must retreat, at up to ``v_max``).
    With the paper's values ``d_c = 0.12 m``, ``d_n = 0.3 m``, ``v_max = 0.3 m/s``.
    ``width``: ``w`` given (m) instead, e.g. with a per-point ``d_c`` ``(K,)`` (the protective separation
    ``S_p``, :mod:`skincal.control.separation`), the ramp keeps its shape and is shifted to start at it.
    """
    w = (notice - critical) / np.arctanh(SATURATION) if width is None else width
    return v_max * np.tanh((np.asarray(distance, dtype=float) - critical) / w)


def approach_speed_slope(gap: ArrayLike, v_max: float, width: float) -> FloatArray:
    """``db/dd`` of :func:`approach_speed_bound` at ``gap = d - d_c`` (m) for ramp ``width`` ``w``: ``(v_max / w)
    (1 - tanh^2(gap / w))``, 1/s."""
    t = np.tanh(np.asarray(gap, dtype=float) / width)
    return (v_max / width) * (1.0 - t * t)


def ramp_width(critical: float, notice: float) -> float:
    """``w`` of :func:`approach_speed_bound` for a critical and notice distance, m."""
    return float((notice - critical) / np.arctanh(SATURATION))


class FrameCache:
    """Link frames of one configuration, fast: all joint transforms at once
    (:meth:`SerialChain.joint_transforms`), then their running product.

    Same result as :meth:`SerialChain.link_frames` for one sample, without its batching overhead
    (the control loop evaluates one configuration per millisecond).
    """

    def __init__(self, chain: SerialChain) -> None:
        self.chain = chain

    def frames(self, q: ArrayLike) -> FloatArray:
        """``T_base_link`` ``(n + 1, 4, 4)`` at joint positions ``q`` ``(n,)`` (rad or m)."""
        steps = self.chain.joint_transforms(np.asarray(q, dtype=float).reshape(1, -1))[0]
        n = steps.shape[0]
        T = np.empty((n + 1, 4, 4))
        T[0] = np.eye(4)
        for i in range(n):
            T[i + 1] = T[i] @ steps[i]
        return T


@dataclass(frozen=True)
class ObstacleRows:
    """Obstacle constraints ``G qd <= h`` for ``K`` points.

    Attributes:
        G: ``(K, n)`` rows ``n_i^T J_i``.
        h: ``(K,)`` bounds ``b(d_i)``, m/s.
        distance: ``(K,)`` distance of each point to the padded robot surface, m.
        link: ``(K,)`` link of the closest robot point.
        normal: ``(K, 3)`` unit normals, robot -> obstacle, base frame.
        p_base_robot: ``(K, 3)`` closest robot points (on the capsule core segments), m.
    """

    G: FloatArray
    h: FloatArray
    distance: FloatArray
    link: np.ndarray
    normal: FloatArray
    p_base_robot: FloatArray


def cap_candidates(
    points: ArrayLike, axes: ArrayLike, ranges: ArrayLike, spread: ArrayLike, n_rim: int = 6
) -> FloatArray:
    """Where a cone reading's target may be: ``(K, 1 + n_rim, 3)`` candidates per point ``(K, 3)`` (m):
    the axis point and ``n_rim`` points on the rim of the cap (ray axes ``(K, 3)``, ranges ``(K,)`` m,
    lateral ``spread`` ``(K,)`` m). A point with zero spread repeats itself."""
    p = np.asarray(points, dtype=float).reshape(-1, 3)
    a = np.asarray(axes, dtype=float).reshape(-1, 3)
    r = np.asarray(ranges, dtype=float).reshape(-1)
    s = np.minimum(np.asarray(spread, dtype=float).reshape(-1), r)
    helper = np.where((np.abs(a[:, :1]) < 0.9), [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    e1 = cross(a, helper)
    e1 /= np.maximum(np.linalg.norm(e1, axis=1, keepdims=True), 1e-12)
    e2 = cross(a, e1)
    phi = 2 * np.pi * np.arange(n_rim) / max(n_rim, 1)
    # element-wise on (R, 3K) rows (long inner loops): rim = p + s (cos e1 + sin e2) - (r - sqrt(r^2 - s^2)) a
    K = p.shape[0]
    e = np.cos(phi)[:, None] * e1.reshape(1, -1) + np.sin(phi)[:, None] * e2.reshape(1, -1)
    back = (np.repeat(r - np.sqrt(np.maximum(r**2 - s**2, 0.0)), 3) * a.reshape(-1))[None, :]
    rim = p.reshape(1, -1) + np.repeat(s, 3)[None, :] * e - back
    out = np.empty((K, 1 + n_rim, 3))
    out[:, 0] = p
    out[:, 1:] = rim.reshape(n_rim, K, 3).transpose(1, 0, 2)
    return out


def obstacle_geometry(
    body: RobotBody, T_base_link: FloatArray, points: ArrayLike, candidates: ArrayLike | None = None
) -> tuple[BodyProximity, FloatArray]:
    """The closest robot point to each obstacle point ``(K, 3)`` (or to its candidate nearest the robot,
    ``candidates`` ``(K, C, 3)``) and the rows ``G = n_i^T J_i`` ``(K, n)`` at one configuration."""
    pts = np.asarray(points, dtype=float).reshape(-1, 3)
    K = pts.shape[0]
    if candidates is not None:
        cand = np.asarray(candidates, dtype=float).reshape(K, -1, 3)
        prox = body_proximity(body, T_base_link, cand.reshape(-1, 3), group=cand.shape[1])
    else:
        prox = body_proximity(body, T_base_link, pts)
    J = body.chain.point_jacobians(T_base_link, prox.link, prox.p_base_robot)
    return prox, np.einsum("ki,kij->kj", prox.normal, J)


def obstacle_bounds(
    prox: BodyProximity,
    critical: float | ArrayLike,
    notice: float,
    v_max: float,
    velocities: ArrayLike | None = None,
    width: float | None = None,
) -> FloatArray:
    """``(K,)`` right-hand sides ``b(d_i) + min(n_i^T v_i, 0)`` (m/s) of the rows of ``prox``
    (:func:`approach_speed_bound`; ``critical`` one distance or ``(K,)``)."""
    h = approach_speed_bound(prox.distance, critical, notice, v_max, width)
    if velocities is not None:
        K = prox.distance.shape[0]
        h = h + np.minimum(np.einsum("ki,ki->k", prox.normal, np.asarray(velocities, dtype=float).reshape(K, 3)), 0.0)
    return h


def obstacle_rows(
    body: RobotBody,
    T_base_link: FloatArray,
    points: ArrayLike,
    critical: float,
    notice: float,
    v_max: float,
    velocities: ArrayLike | None = None,
    candidates: ArrayLike | None = None,
) -> ObstacleRows:
    """One row ``n_i^T J_i qd <= b(d_i) + min(n_i^T v_i, 0)`` per obstacle point ``(K, 3)`` at one configuration.

    ``velocities``: ``(K, 3)`` point velocities, m/s (default still). ``candidates``: ``(K, C, 3)``
    possible positions of each point (:func:`cap_candidates`); the one nearest the robot makes the row.
    """
    prox, G = obstacle_geometry(body, T_base_link, points, candidates)
    h = obstacle_bounds(prox, critical, notice, v_max, velocities)
    return ObstacleRows(G, h, prox.distance, prox.link, prox.normal, prox.p_base_robot)


def joint_velocity_bounds(
    chain: SerialChain,
    q: ArrayLike,
    dt: float,
    scale: float = 1.0,
    margin: float = 0.0,
    acceleration: ArrayLike | None = None,
):
    """Box bounds ``lb <= qd <= ub`` ``(n,)`` [rad/s] from velocity limits and position limits over one step.

    ``ub = min(scale v_max, (q_upper - margin - q) / dt)``, ``lb = max(-scale v_max, (q_lower + margin - q) / dt)``,
    then widened to contain 0 (a joint already past a limit may stop or move back, never further).
    Joints without limits get ``+-inf`` (velocity) or no position term.

    ``acceleration`` ``(n,)`` rad/s^2: a drive that changes its velocity by at most ``a dt`` per step (torque mode)
    must also be able to stop before the limit, so with ``s = q_upper - margin - q >= 0`` left (and likewise below)

        ub <= sqrt((a dt / 2)^2 + 2 a s) - a dt / 2

    the speed from which braking at ``a`` (``v, v - a dt, ...`` each held for ``dt``: ``v^2 / (2 a) + v dt / 2``
    travelled) ends within ``s``. Without it the one-step bound lets the drive reach a limit at speed: ``lower`` on
    the Panda (torque, simulated) drove joint 2 into its stop at 2 rad/s (7.5 rad/s^2 needs 0.3 rad to brake).
    """
    q = np.asarray(q, dtype=float).reshape(-1)
    n = chain.n_joints
    v = np.full(n, np.inf) if chain.velocity_limit is None else scale * chain.velocity_limit
    lb, ub = -v.copy(), v.copy()
    if chain.joint_lower is not None and chain.joint_upper is not None:
        up, down = chain.joint_upper - margin - q, q - chain.joint_lower - margin
        ub = np.minimum(ub, up / dt)
        lb = np.maximum(lb, -down / dt)
        if acceleration is not None:
            a = np.asarray(acceleration, dtype=float).reshape(n)
            half = 0.5 * a * dt
            ub = np.minimum(ub, np.sqrt(half**2 + 2.0 * a * np.maximum(up, 0.0)) - half)
            lb = np.maximum(lb, half - np.sqrt(half**2 + 2.0 * a * np.maximum(down, 0.0)))
    return np.minimum(lb, 0.0), np.maximum(ub, 0.0)
