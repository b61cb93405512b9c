"""Named points of a robot and the start configuration of the avoidance task, from the kinematics alone.

:func:`robot_points`: ``base``, ``flange``, ``shoulder`` (joint 2's point), ``wrist`` (joint ``n - 1``'s),
``elbow`` (the point of the link axes' polyline between them farthest from the shoulder-wrist line),
``upper_arm`` and ``forearm`` (midpoints), base frame, m. Scenario files place people relative to them
(:mod:`skincal.sim.scenarios`).

:func:`start_configuration`: the Panda preset starts at ``Q_START`` (the legacy configuration, flange
about 0.47 m in front of the base and 0.52 m high, the tool pointing down). Any other chain gets a
configuration computed from its kinematics alone: the flange at ``0.5 R`` in front of its shoulder (joint
2) and ``0.2 R`` above it (``R`` the chain's reach from the shoulder), the tool pointing down where the
chain allows it, the elbow above the shoulder-flange line, inside the joint limits less 0.15 rad, and of
the solutions from 24 seeded starts the one with the best-conditioned position Jacobian (largest smallest
singular value).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from skincal.errors import ConfigError
from skincal.kinematics.chain import SerialChain
from skincal.kinematics.geometry import link_capsules
from skincal.kinematics.presets import panda
from skincal.kinematics.transforms import FloatArray

Q_START = np.array([0.0, -0.3, 0.0, -2.2, 0.0, 2.0, np.pi / 4])
"""Start configuration of the Panda, rad (flange about 0.47 m in front of the base, 0.52 m high)."""


def joint_box(chain: SerialChain, margin: float = 0.15) -> tuple[FloatArray, FloatArray]:
    """``(lo, hi)`` ``(n,)`` rad: the joint limits (clipped to +-pi) less ``margin`` rad, at most a quarter
    of each range, the box the start configuration is sought in."""
    n = chain.n_joints
    lo = np.full(n, -np.pi) if chain.joint_lower is None else np.maximum(chain.joint_lower, -np.pi)
    hi = np.full(n, np.pi) if chain.joint_upper is None else np.minimum(chain.joint_upper, np.pi)
    m = np.minimum(margin, 0.25 * (hi - lo))
    return lo + m, hi - m


def robot_points(chain: SerialChain, q: ArrayLike) -> dict[str, FloatArray]:
    """Named points ``(3,)`` of the robot at ``q`` (base frame, m): ``base``, ``flange``, ``shoulder``
    (joint 2's point), ``wrist`` (joint ``n - 1``'s), ``elbow`` (the point of the link axes' polyline
    between them farthest from the shoulder-wrist line), ``upper_arm`` and ``forearm`` (midpoints)."""
    q = np.asarray(q, dtype=float)
    n = chain.n_joints
    T = chain.link_frames(q)[0]
    c = chain.joint_axes(T[None])[0][0]
    shoulder = c[min(1, n - 1)]
    wrist = c[max(n - 2, 0)]
    ends = [T[cp.link, :3, :3] @ p + T[cp.link, :3, 3] for cp in link_capsules(chain) for p in (cp.p0, cp.p1)]
    cand = np.array(ends + list(c))
    axis = wrist - shoulder
    L = float(np.linalg.norm(axis))
    if L > 1e-9:
        rel = cand - shoulder
        s = np.clip(rel @ axis / L**2, 0.0, 1.0)
        # only points beside the middle of the shoulder-wrist segment count as the elbow
        d = np.where((s > 0.05) & (s < 0.95), np.linalg.norm(rel - s[:, None] * axis, axis=1), -1.0)
        elbow = cand[int(np.argmax(d))] if d.max() > 0 else 0.5 * (shoulder + wrist)
    else:
        elbow = shoulder.copy()
    flange = (T[n] @ chain.T_link_flange)[:3, 3]
    return {
        "base": np.zeros(3),
        "flange": flange,
        "shoulder": shoulder,
        "elbow": elbow,
        "wrist": wrist,
        "upper_arm": 0.5 * (shoulder + elbow),
        "forearm": 0.5 * (elbow + wrist),
    }


def _is_panda(chain: SerialChain) -> bool:
    return chain.n_joints == 7 and chain.same_motion(panda())


def start_configuration(chain: SerialChain) -> FloatArray:
    """The start configuration ``(n,)`` rad of ``chain`` (module docstring): ``Q_START`` on the Panda,
    else computed (seeded, deterministic)."""
    if _is_panda(chain):
        return Q_START.copy()
    from scipy.optimize import least_squares

    n = chain.n_joints
    if n < 3:
        raise ConfigError(f"robot '{chain.name}': an avoidance task needs at least 3 joints, got {n}")
    rng = np.random.default_rng(0)
    lo, hi = joint_box(chain)
    mid = 0.5 * (lo + hi)
    shoulder = chain.joint_axes(chain.link_frames(mid))[0][0][1]
    reach = float(np.linalg.norm(chain.flange_pose(rng.uniform(lo, hi, (2000, n)))[:, :3, 3] - shoulder, axis=1).max())
    target = shoulder + np.array([0.5 * reach, 0.0, 0.2 * reach])
    down = np.array([0.0, 0.0, -1.0])

    def residual(q: FloatArray) -> FloatArray:
        T = chain.flange_pose(q)[0]
        return np.concatenate([10.0 * (T[:3, 3] - target), 0.5 * (T[:3, 2] - down), 0.05 * (q - mid) / (hi - lo)])

    best, best_score = None, -np.inf
    for q_init in rng.uniform(lo, hi, size=(24, n)):
        q = least_squares(residual, q_init, bounds=(lo, hi)).x
        if np.linalg.norm(chain.flange_pose(q)[0, :3, 3] - target) > 1e-3:
            continue
        pts = robot_points(chain, q)
        line = pts["wrist"] - pts["shoulder"]
        s = float(np.clip((pts["elbow"] - pts["shoulder"]) @ line / max(line @ line, 1e-12), 0, 1))
        elbow_up = pts["elbow"][2] > pts["shoulder"][2] + s * line[2]
        J = chain.point_jacobian(q, n, chain.T_link_flange[:3, 3])[:3]
        score = float(np.linalg.svd(J, compute_uv=False).min()) + (1.0 if elbow_up else 0.0)
        if score > best_score:
            best, best_score = q, score
    if best is None:
        raise ConfigError(f"robot '{chain.name}': found no start configuration with the flange in front of the base")
    return best
