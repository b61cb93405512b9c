"""Joint-limit checks of a protocol, fitting a protocol to a robot, and static-pose sampling.

Units follow the joint type: rad, rad/s, rad/s^2 for a revolute joint; m, m/s, m/s^2 for a
prismatic one (the excitation ``qd = A sin(2 pi f t)`` is the same model in either unit).

* Position limits are applied shrunk by ``config.limit_margin``. A joint without finite limits (a
  continuous joint, or a chain without limits) has its poses sampled in ``[-pi, pi]`` and is not
  position-checked.
* Velocity limits are the chain's symmetric ``velocity_limit``.
* Acceleration limits are the chain's ``acceleration_limit`` when it has them; otherwise the
  default bound of :func:`acceleration_bounds`: ``2 pi f_j v_j`` with the protocol's own frequency
  ``f_j`` and ``v_j`` the joint's velocity limit (its amplitude when it has none) -- the peak
  acceleration of a sine at that speed, so the excitation itself never exceeds it and the moves
  between poses are slowed down to stay below it.
"""

from __future__ import annotations

import numpy as np

from skincal.errors import ProtocolError
from skincal.kinematics.chain import SerialChain
from skincal.kinematics.transforms import FloatArray
from skincal.protocol.config import ProtocolConfig
from skincal.protocol.motion import excitation_envelope

_TOL = 1e-9


NO_LIMIT_BEYOND = 1e3
"""A position limit beyond this magnitude (rad or m) counts as none: URDFs write ``+-1e16`` for "no limit"."""


def position_bounds(chain: SerialChain) -> tuple[FloatArray, FloatArray]:
    """``(lower, upper)`` position limits ``(n,)``; ``[-pi, pi]`` where the chain has none or they
    are infinite (continuous joints) or beyond :data:`NO_LIMIT_BEYOND`."""
    n = chain.n_joints
    if chain.joint_lower is None or chain.joint_upper is None:
        return np.full(n, -np.pi), np.full(n, np.pi)
    lower = np.where(np.abs(chain.joint_lower) <= NO_LIMIT_BEYOND, chain.joint_lower, -np.pi)
    upper = np.where(np.abs(chain.joint_upper) <= NO_LIMIT_BEYOND, chain.joint_upper, np.pi)
    return lower, upper


def acceleration_bounds(chain: SerialChain, config: ProtocolConfig) -> FloatArray:
    """Acceleration bound ``(n,)`` of every joint: the chain's ``acceleration_limit``, else the default
    ``2 pi f_j max(v_j, A_j)`` (module docstring; ``v_j`` the velocity limit, ``A_j`` the amplitude)."""
    if chain.acceleration_limit is not None:
        return np.array(chain.acceleration_limit, dtype=float)
    n = chain.n_joints
    speed = config.amplitude_per_joint(n)
    if chain.velocity_limit is not None:
        speed = np.maximum(speed, chain.velocity_limit)
    return 2 * np.pi * config.frequency_per_joint(n) * speed


QUINTIC_PEAK_ACCEL = 10 / np.sqrt(3)
"""Peak acceleration of the rest-to-rest quintic is this times ``|dq| / T^2``."""


def move_duration(chain: SerialChain, config: ProtocolConfig, q_from: FloatArray, q_to: FloatArray) -> float:
    """Duration of the rest-to-rest quintic move between two poses, s.

    ``config.move_duration`` when set, else ``max(min_move_duration, 15/8 max_j |dq_j| / min(move_speed,
    vmax_j))`` so that the peak speed is bounded; in both cases lengthened where needed so that the
    peak acceleration ``10 / sqrt(3) |dq_j| / T^2`` stays within :func:`acceleration_bounds`.
    """
    dq = np.abs(np.asarray(q_to, dtype=float) - np.asarray(q_from, dtype=float))
    if config.move_duration is not None:
        T = config.move_duration
    else:
        speed = np.full(chain.n_joints, config.move_speed)
        if chain.velocity_limit is not None:
            speed = np.minimum(speed, chain.velocity_limit)
        T = max(config.min_move_duration, float(15 / 8 * np.max(dq / speed)))
    T_accel = float(np.sqrt(np.max(QUINTIC_PEAK_ACCEL * dq / acceleration_bounds(chain, config))))
    if T_accel > T:
        T = float(np.ceil(T_accel * 1000.0) / 1000.0)  # whole ms, at least the bound
    return T


def check_amplitudes(chain: SerialChain, config: ProtocolConfig) -> None:
    """Raise :class:`ProtocolError` if an excited joint's amplitude ``A_j`` exceeds its velocity limit."""
    if chain.velocity_limit is None:
        return
    A = config.amplitude_per_joint(chain.n_joints)
    for j in config.joints_to_excite(chain.n_joints):
        if A[j] > chain.velocity_limit[j] + _TOL:
            raise ProtocolError(
                f"joint {j + 1}: excitation amplitude {A[j]:.3f} rad/s exceeds the velocity limit "
                f"{chain.velocity_limit[j]:.3f} rad/s (protocol '{config.name}')"
            )


VELOCITY_CAP_FRACTION = 0.95
""":func:`fit_to_limits` caps excitation amplitudes at this fraction of each joint's velocity limit."""


def _per_joint_count(value: float | tuple[float, ...], n: int) -> tuple[float | tuple[float, ...], bool]:
    """A per-joint tuple of another length cut to ``n`` entries or extended with its last one."""
    if np.ndim(value) == 0 or len(value) == n:  # type: ignore[arg-type]
        return value, False
    vals = tuple(value)  # type: ignore[arg-type]
    return (vals[:n] if len(vals) > n else vals + (vals[-1],) * (n - len(vals))), True


def fit_to_limits(
    chain: SerialChain, config: ProtocolConfig, fraction: float = VELOCITY_CAP_FRACTION
) -> ProtocolConfig:
    """``config`` for ``chain``, every change said in ``config.notes`` (nothing is dropped silently).

    * robot-relative settings resolved (:meth:`ProtocolConfig.for_chain`);
    * per-joint amplitudes or frequencies given for another number of joints (``paper-real`` lists
      7) are cut to the robot's joints or extended with the last entry;
    * every excitation amplitude ``A_j`` is scaled down to at most ``fraction`` of the joint's velocity
      limit, ``fraction`` of its acceleration limit over ``2 pi f_j`` (peak acceleration of the sine)
      when the chain has acceleration limits, and so that the excursion of the excitation and its
      return (proportional to ``A_j``) takes at most ``fraction`` of the joint's position range
      shrunk by the margin (``[-pi, pi]`` for a continuous joint).
    """
    from dataclasses import replace

    config = config.for_chain(chain)
    n = chain.n_joints
    notes = list(config.notes)
    changes = {}
    for key in ("amplitude", "frequency"):
        value, changed = _per_joint_count(getattr(config, key), n)
        if changed:
            changes[key] = value
            notes.append(f"{key} given for {len(getattr(config, key))} joints, adapted to the robot's {n}")
    if changes:
        config = replace(config, **changes)
    A = config.amplitude_per_joint(n)
    f = config.frequency_per_joint(n)
    cap = np.full(n, np.inf)
    why = [""] * n
    if chain.velocity_limit is not None:
        cap = fraction * np.asarray(chain.velocity_limit, dtype=float)
        why = [f"{fraction:.0%} of the velocity limit"] * n
    if chain.acceleration_limit is not None:
        acc_cap = fraction * np.asarray(chain.acceleration_limit, dtype=float) / (2 * np.pi * f)
        for j in np.flatnonzero(acc_cap < cap):
            why[j] = f"{fraction:.0%} of the acceleration limit / (2 pi f)"
        cap = np.minimum(cap, acc_cap)
    lower, upper = position_bounds(chain)
    room = fraction * np.maximum(upper - lower - 2 * config.limit_margin, 0.0)
    excited = config.joints_to_excite(n)
    for j in excited:
        lo, hi = excitation_envelope(1.0, f[j], config.excite_duration, j)  # excursion per unit amplitude
        pos_cap = room[j] / (hi - lo) if hi > lo else np.inf
        if pos_cap < cap[j]:
            cap[j], why[j] = pos_cap, f"its excursion within {fraction:.0%} of the position range"
    unit = ["m/s" if chain.joint_type[j] == "prismatic" else "rad/s" for j in range(n)]
    scaled = A.copy()
    for j in excited:
        if A[j] > cap[j] * (1 + 1e-12):
            scaled[j] = cap[j]
            notes.append(f"joint {j + 1}: amplitude {A[j]:.4g} -> {cap[j]:.4g} {unit[j]} ({why[j]})")
    if not np.array_equal(scaled, A) or chain.velocity_limit is not None:
        config = replace(config, amplitude=tuple(float(a) for a in scaled))
    if notes != list(config.notes):
        config = replace(config, notes=tuple(notes))
    return config


def excursion_envelopes(chain: SerialChain, config: ProtocolConfig) -> tuple[FloatArray, FloatArray]:
    """Per joint, the lowest and highest offset from the pose reached while it is excited, ``(n,)`` rad.

    Joints that are not excited have ``(0, 0)``. See :func:`skincal.protocol.motion.excitation_envelope`.
    """
    n = chain.n_joints
    A, f = config.amplitude_per_joint(n), config.frequency_per_joint(n)
    lo, hi = np.zeros(n), np.zeros(n)
    for j in config.joints_to_excite(n):
        lo[j], hi[j] = excitation_envelope(A[j], f[j], config.excite_duration, j)
    return lo, hi


def pose_box(chain: SerialChain, config: ProtocolConfig) -> tuple[FloatArray, FloatArray]:
    """Per joint interval ``(n,)`` of static poses whose excitation stays within the margin-shrunk limits.

    ``q0 in [lower + margin - lo_j, upper - margin - hi_j]`` with ``(lo_j, hi_j)`` from
    :func:`excursion_envelopes`. Raises :class:`ProtocolError` naming a joint whose excursion does
    not fit at all.
    """
    lower, upper = position_bounds(chain)
    lo, hi = excursion_envelopes(chain, config)
    m = config.limit_margin
    box_lo, box_hi = lower + m - lo, upper - m - hi
    for j in range(chain.n_joints):
        if box_lo[j] > box_hi[j]:
            raise ProtocolError(
                f"joint {j + 1}: its excitation sweeps {hi[j] - lo[j]:.3f} rad but only "
                f"{upper[j] - lower[j] - 2 * m:.3f} rad lie within its limits [{lower[j]:.4f}, {upper[j]:.4f}] "
                f"with margin {m} rad (protocol '{config.name}': lower the amplitude or raise the frequency)"
            )
    return box_lo, box_hi


MAX_POSE_DRAWS = 200
"""Draws allowed per static pose before :func:`sample_static_poses` gives up (collision check)..."""
MAX_BACKTRACKS = 10
"""...or, with the uniform draw, draws the previous pose again (a pose no collision-free move leaves), at
most this many times per motion."""
DIVERSE_POOL = 20
"""Candidates drawn per static pose (in one batch) for ``pose_selection="diverse"``; batches are drawn
until :data:`DIVERSE_FEASIBLE` collision-free candidates per pose are available."""
DIVERSE_FEASIBLE = 5


class _PoseChecker:
    """Collision checks of a candidate pose: the pose, every excitation at it, the move to it."""

    def __init__(self, chain: SerialChain, config: ProtocolConfig) -> None:
        from skincal.protocol.collision import CHECK_STEP_S, CollisionModel
        from skincal.protocol.motion import excitation_offsets

        self.chain, self.config, self.step = chain, config, CHECK_STEP_S
        self.model = CollisionModel(chain, floor_z=config.floor_z)
        n = chain.n_joints
        A, f = config.amplitude_per_joint(n), config.frequency_per_joint(n)
        self.blocks = []  # (m_j, n) offsets of each excitation and its return
        for j in config.joints_to_excite(n):
            column = excitation_offsets(A[j], f[j], config.excite_duration, self.step, j)
            off = np.zeros((column.size, n))
            off[:, j] = column
            self.blocks.append(off)

    def static_ok(self, poses: FloatArray) -> np.ndarray:
        """``(K,)`` True where a pose and all its excitations are collision-free (checked in stages:
        the poses, then each excitation for the candidates still free)."""
        poses = np.atleast_2d(poses)
        ok = self.model.free(poses)
        for off in self.blocks:
            idx = np.flatnonzero(ok)
            if idx.size == 0:
                break
            q = (poses[idx, None, :] + off[None]).reshape(-1, poses.shape[1])
            ok[idx] = self.model.free(q).reshape(idx.size, off.shape[0]).all(axis=1)
        return ok

    def move_ok(self, q_from: FloatArray, q_to: FloatArray) -> bool:
        from skincal.protocol.motion import quintic_move_samples

        T = move_duration(self.chain, self.config, q_from, q_to)
        return bool(self.model.free(quintic_move_samples(q_from, q_to, T, self.step)).all())


def gravity_features(chain: SerialChain, poses: FloatArray) -> FloatArray:
    """Gravity direction in every link frame 1..n, flattened ``(K, 3 n)``."""
    R = chain.link_frames(poses)[:, 1:, :3, :3]
    return np.einsum("kiab,a->kib", R, np.array([0.0, 0.0, -1.0])).reshape(poses.shape[0], -1)


def sample_static_poses(
    chain: SerialChain, n_poses: int, rng: np.random.Generator, config: ProtocolConfig
) -> FloatArray:
    """``n_poses`` static poses ``(P, n)`` within :func:`pose_box` (seeded by ``rng``).

    Every pose leaves room for the full excitation of every excited joint, ``q0 + A / (2 pi f)
    (1 - cos 2 pi f t)`` and its return, within the limits shrunk by ``config.limit_margin``.

    * ``pose_selection="uniform"``: one uniform draw of all poses (exactly the draw of earlier
      versions); with ``collision_check`` each pose whose excitations or move from the previous pose
      collide (:mod:`skincal.protocol.collision`) is replaced by a fresh uniform draw, and a previous
      pose from which :data:`MAX_POSE_DRAWS` draws found no collision-free move is drawn again.
    * ``pose_selection="diverse"``: candidates are drawn uniformly (batches of :data:`DIVERSE_POOL`
      per pose, until :data:`DIVERSE_FEASIBLE` per pose are collision-free); the first one starts,
      and each next pose is the candidate whose gravity directions in the link frames 1..n lie
      farthest from those of every pose chosen so far (greedy farthest point: rotation, bias and
      scale of a unit need gravity in several directions of its link frame), among those reachable
      by a collision-free move.

    Raises :class:`ProtocolError` naming the robot and the protocol when no collision-free pose is
    found within :data:`MAX_POSE_DRAWS` draws per pose.
    """
    if n_poses < 1:
        raise ProtocolError(f"n_poses must be at least 1, got {n_poses}")
    P, n = int(n_poses), chain.n_joints
    box_lo, box_hi = pose_box(chain, config)
    if config.pose_selection == "diverse":
        return _diverse_poses(chain, P, rng, config, box_lo, box_hi)
    poses = rng.uniform(box_lo, box_hi, size=(P, n))
    if not config.collision_check:
        return poses
    check = _PoseChecker(chain, config)
    p, draws, back = 0, 1, 0
    while p < P:
        if check.static_ok(poses[p])[0] and (p == 0 or check.move_ok(poses[p - 1], poses[p])):
            p, draws = p + 1, 1
            continue
        if draws >= MAX_POSE_DRAWS:
            if p == 0 or back >= MAX_BACKTRACKS:
                raise _no_pose(chain, config, p)
            # no collision-free move leaves the previous pose: a dead end, drawn again (a draw that
            # succeeds without this step is the draw of earlier versions, draw for draw)
            p, draws, back = p - 1, 1, back + 1
        poses[p] = rng.uniform(box_lo, box_hi)
        draws += 1
    return poses


def _no_pose(chain: SerialChain, config: ProtocolConfig, p: int) -> ProtocolError:
    return ProtocolError(
        f"robot '{chain.name}', protocol '{config.name}': no collision-free static pose {p + 1} found in "
        f"{MAX_POSE_DRAWS} draws (every draw collided with the robot itself or the floor during its "
        f"excitation or move"
        + ("" if config.floor_z is None else f"; the floor is z = {config.floor_z:g} m of the base: --floor moves it")
        + ")"
    )


def _diverse_poses(
    chain: SerialChain, P: int, rng: np.random.Generator, config: ProtocolConfig, lo: FloatArray, hi: FloatArray
) -> FloatArray:
    check = _PoseChecker(chain, config) if config.collision_check else None
    n = chain.n_joints
    pool = np.zeros((0, n))
    drawn = 0

    def grow() -> None:
        nonlocal pool, drawn
        batch = rng.uniform(lo, hi, size=(DIVERSE_POOL * P, n))
        drawn += batch.shape[0]
        pool = np.concatenate([pool, batch if check is None else batch[check.static_ok(batch)]])

    while pool.shape[0] < DIVERSE_FEASIBLE * P and drawn < MAX_POSE_DRAWS * P:
        grow()
    if pool.shape[0] == 0:
        raise _no_pose(chain, config, 0)
    chosen = [0]
    while len(chosen) < P:
        feat = gravity_features(chain, pool)
        dist = np.min(np.sum((feat[:, None, :] - feat[chosen][None]) ** 2, axis=2), axis=1)
        dist[chosen] = -np.inf
        reachable = (
            int(k)
            for k in np.argsort(-dist, kind="stable")
            if dist[k] > -np.inf and (check is None or check.move_ok(pool[chosen[-1]], pool[k]))
        )
        nxt = next(reachable, None)
        if nxt is not None:
            chosen.append(nxt)
        elif drawn < MAX_POSE_DRAWS * P:
            grow()  # no candidate reachable from the last pose by a collision-free move: draw more
        else:
            raise _no_pose(chain, config, len(chosen))
    return pool[chosen]


def check_limits(
    chain: SerialChain,
    t: FloatArray,
    q: FloatArray,
    qd: FloatArray | None = None,
    margin: float = 0.0,
    qdd: FloatArray | None = None,
    acceleration_limit: FloatArray | None = None,
) -> None:
    """Raise :class:`ProtocolError` at the first sample outside the position, velocity or acceleration limits.

    ``t`` ``(N,)`` s, ``q``, ``qd`` and ``qdd`` ``(N, n)``; positions must lie in ``[lower + margin,
    upper - margin]`` (infinite limits are not checked), speeds within the chain's velocity limits,
    accelerations within ``acceleration_limit`` ``(n,)`` (default: the chain's, if any).
    """
    if qdd is not None:
        amax = chain.acceleration_limit if acceleration_limit is None else np.asarray(acceleration_limit)
        if amax is not None:
            bad = np.abs(qdd) > amax * (1 + 1e-9) + _TOL
            if bad.any():
                i, j = np.argwhere(bad)[0]
                raise ProtocolError(
                    f"joint {j + 1} would reach {qdd[i, j]:.4f} (rad or m)/s^2 at t={t[i]:.3f} s "
                    f"(acceleration limit {amax[j]:.4f})"
                )
    if chain.joint_lower is not None and chain.joint_upper is not None:
        lower, upper = chain.joint_lower + margin, chain.joint_upper - margin
        below = q < lower - _TOL
        above = q > upper + _TOL
        bad = below | above
        if bad.any():
            i, j = np.argwhere(bad)[0]
            limit = chain.joint_lower[j] if below[i, j] else chain.joint_upper[j]
            raise ProtocolError(
                f"joint {j + 1} would reach {q[i, j]:.4f} rad at t={t[i]:.3f} s "
                f"(limit {limit:.4f} rad, margin {margin} rad)"
            )
    if qd is not None and chain.velocity_limit is not None:
        bad = np.abs(qd) > chain.velocity_limit + _TOL
        if bad.any():
            i, j = np.argwhere(bad)[0]
            raise ProtocolError(
                f"joint {j + 1} would reach {qd[i, j]:.4f} rad/s at t={t[i]:.3f} s "
                f"(velocity limit {chain.velocity_limit[j]:.4f} rad/s)"
            )
