"""The protocol's joint trajectory: sampled arrays plus an exact piecewise closed form.

Timeline (paper Sec. II-A, IV), for each pose ``p = 0..P-1``::

    [move to pose p (p > 0)] rest | for each excited joint j: sine_j [stop_j] rest

* *move*: rest-to-rest quintic (zero velocity and acceleration at both ends); not a segment.
  Its duration is ``config.move_duration`` or, when ``None``, ``max(min_move_duration,
  15/8 max_j |dq_j| / min(move_speed, vmax_j))`` so that the peak speed is bounded, lengthened
  where needed for the acceleration bounds (:func:`skincal.protocol.limits.move_duration`).
* *rest*: ``rest_duration`` s at the pose; the middle ``static_duration`` s of the first rest at
  a pose is the STATIC segment (``(rest - static) / 2`` s of settling on either side, so that no
  sample of it touches the acceleration step where the first sine starts).
* *sine_j*: ``qd_j = A_j sin(2 pi f_j tau)`` for ``excite_duration`` s, all other joints held: the
  DYNAMIC segment. ``q_j`` reaches ``q0_j + A_j / (2 pi f_j) (1 - cos 2 pi f_j tau)``.
* *stop_j*: **deviation from the paper** (whose velocity controller simply stopped): when
  ``f_j * excite_duration`` is not a whole number of periods, the joint is still moving at the end
  of the sine, so a quintic Hermite brings it from its end state back to the pose with zero speed
  and acceleration (peak speed <= A_j, peak acceleration <= 2 pi f_j A_j; see
  :func:`skincal.protocol.motion.stop_duration`). With a whole number of periods there is no stop.

Position and velocity are continuous everywhere; the acceleration jumps where a sine starts (by
``2 pi f A``, as with the paper's velocity command) and where a whole-period sine ends.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from skincal.data.dataset import DYNAMIC, STATIC, JointStates, Segments
from skincal.errors import ConfigError
from skincal.kinematics.chain import SerialChain
from skincal.kinematics.transforms import FloatArray
from skincal.protocol.config import ProtocolConfig
from skincal.protocol.limits import (
    acceleration_bounds,
    check_amplitudes,
    check_limits,
    move_duration,
    sample_static_poses,
)
from skincal.protocol.motion import (
    eval_piece,
    hermite_quintic_coef,
    hold_coef,
    quintic_move_coef,
    sine_end_state,
    stop_duration,
)


@dataclass(frozen=True, eq=False)
class Trajectory:
    """A protocol trajectory sampled at ``config.rate_hz`` and its exact piecewise form.

    Attributes:
        t: ``(N,)`` sample times, s, from 0.
        q, qd, qdd: ``(N, n)`` joint positions (rad), velocities (rad/s), accelerations (rad/s^2).
        segments: STATIC / DYNAMIC segments (pose index, excited joint, -1 when static).
        config: the protocol parameters.
        poses: ``(P, n)`` static poses, rad.
        knots: ``(K + 1,)`` piece boundaries, s; piece ``k`` covers ``[knots[k], knots[k+1])``.
        coef: ``(K, n, 6)`` polynomial coefficients of every piece in local time (ascending powers).
        sine_amplitude: ``(K, n)`` position amplitude ``B = A / w`` of the sine term, rad.
        sine_omega: ``(K, n)`` angular frequency ``w = 2 pi f`` of the sine term, rad/s.
        robot: name of the chain it was built for.
    """

    t: FloatArray
    q: FloatArray
    qd: FloatArray
    qdd: FloatArray
    segments: Segments
    config: ProtocolConfig
    poses: FloatArray
    knots: FloatArray
    coef: FloatArray
    sine_amplitude: FloatArray
    sine_omega: FloatArray
    robot: str = ""

    @property
    def duration(self) -> float:
        """Total length, s."""
        return float(self.knots[-1] - self.knots[0])

    @property
    def n_joints(self) -> int:
        """Number of joints ``n``."""
        return int(self.coef.shape[1])

    def evaluate(self, t: ArrayLike) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Exact ``q, qd, qdd`` ``(M, n)`` at arbitrary times ``t`` ``(M,)`` s (any order).

        Piecewise closed form (:mod:`skincal.protocol.motion`); before 0 and after the end the
        robot rests at the first / last pose.
        """
        t = np.atleast_1d(np.asarray(t, dtype=float))
        if t.ndim != 1 or not np.all(np.isfinite(t)):
            raise ConfigError(f"trajectory.evaluate: t must be a finite (M,) array of seconds, got shape {t.shape}")
        n, K = self.n_joints, self.coef.shape[0]
        inside = (t >= self.knots[0]) & (t <= self.knots[-1])
        tc = np.clip(t, self.knots[0], self.knots[-1])
        piece = np.clip(np.searchsorted(self.knots, tc, side="right") - 1, 0, K - 1)
        order = np.argsort(piece, kind="stable")
        bounds = np.searchsorted(piece[order], np.arange(K + 1))
        q, qd, qdd = (np.empty((t.size, n)) for _ in range(3))
        for k in np.flatnonzero(np.diff(bounds)):  # loop over pieces, vectorised over their samples
            idx = order[bounds[k] : bounds[k + 1]]
            q[idx], qd[idx], qdd[idx] = eval_piece(
                self.coef[k], self.sine_amplitude[k], self.sine_omega[k], tc[idx] - self.knots[k]
            )
        qd[~inside] = 0.0
        qdd[~inside] = 0.0
        return q, qd, qdd

    def joint_states(self) -> JointStates:
        """The sampled stream as :class:`skincal.data.JointStates` (with ``qdd``)."""
        return JointStates(t=self.t, q=self.q, qd=self.qd, qdd=self.qdd)


class _Pieces:
    """Accumulates pieces and segments while the timeline is laid out."""

    def __init__(self, n: int) -> None:
        self.n = n
        self.durations: list[float] = []
        self.coef: list[FloatArray] = []
        self.B: list[FloatArray] = []
        self.w: list[FloatArray] = []
        self.now = 0.0
        self.segments: list[tuple[float, float, int, int, int]] = []

    def add(self, T: float, coef: FloatArray, B: FloatArray | None = None, w: FloatArray | None = None) -> float:
        start = self.now
        self.durations.append(float(T))
        self.coef.append(coef)
        self.B.append(np.zeros(self.n) if B is None else B)
        self.w.append(np.zeros(self.n) if w is None else w)
        self.now = start + float(T)
        return start


def _stop_durations(config: ProtocolConfig, n: int) -> FloatArray:
    A, f = config.amplitude_per_joint(n), config.frequency_per_joint(n)
    T = np.zeros(n)
    for j in config.joints_to_excite(n):
        T[j] = stop_duration(A[j], f[j], config.excite_duration, j)
    return T


def protocol_duration(config: ProtocolConfig, n_joints: int) -> float:
    """Length of the protocol in s for an ``n_joints`` robot.

    ``P (rest + sum_j (excite + stop_j + rest)) + (P - 1) move``, where ``move`` is
    ``config.move_duration`` or, for automatic moves (which depend on the poses), the lower bound
    ``config.min_move_duration``; :attr:`Trajectory.duration` is always exact.
    """
    joints = config.joints_to_excite(n_joints)
    stops = _stop_durations(config, n_joints)
    per_pose = config.rest_duration + sum(config.excite_duration + stops[j] + config.rest_duration for j in joints)
    move = config.move_duration if config.move_duration is not None else config.min_move_duration
    return config.n_poses * per_pose + (config.n_poses - 1) * move


def build_trajectory(
    chain: SerialChain,
    config: ProtocolConfig,
    rng: np.random.Generator | None = None,
    poses: ArrayLike | None = None,
    *,
    start: ArrayLike | None = None,
) -> Trajectory:
    """Lay out the protocol for ``chain``, sample it at ``config.rate_hz`` and check the limits.

    Static poses come from ``poses`` ``(P, n)`` rad, else ``config.poses``, else
    :func:`sample_static_poses` with ``rng``. ``start`` ``(n,)`` rad: where the robot rests before
    the motion; the motion then begins with the move from it to the first pose (no move when they
    are equal), so that a piece of motion can be appended to one that ended at ``start``
    (:func:`concatenate_trajectories`). Raises :class:`ProtocolError` if an amplitude exceeds
    a velocity limit, the motion leaves the margin-shrunk position limits or the acceleration bounds
    (:func:`skincal.protocol.limits.acceleration_bounds`), or -- with ``config.collision_check`` --
    collides with itself or the floor (:mod:`skincal.protocol.collision`, sampled every 50 ms);
    joint, links and time named. Fit a preset to a robot first with
    :func:`skincal.protocol.limits.fit_to_limits`.
    """
    n = chain.n_joints
    config = config.for_chain(chain)
    check_amplitudes(chain, config)
    if poses is None:
        poses = config.poses
    if poses is None:
        if rng is None:
            raise ConfigError("build_trajectory: give static poses (argument or config.poses) or an rng to sample them")
        poses = sample_static_poses(chain, config.n_poses, rng, config)
    poses = np.array(poses, dtype=float)
    if poses.ndim != 2 or poses.shape[1] != n or poses.shape[0] == 0 or not np.all(np.isfinite(poses)):
        raise ConfigError(f"protocol '{config.name}': poses must be a finite (P, {n}) array in rad, got {poses.shape}")
    A, f = config.amplitude_per_joint(n), config.frequency_per_joint(n)
    joints = config.joints_to_excite(n)
    stops = _stop_durations(config, n)
    D = config.excite_duration
    pieces = _Pieces(n)
    if start is not None:
        start = np.asarray(start, dtype=float)
        if start.shape != (n,) or not np.all(np.isfinite(start)):
            raise ConfigError(f"protocol '{config.name}': start must be a finite ({n},) configuration in rad")
    for p, q0 in enumerate(poses):
        q_prev = poses[p - 1] if p > 0 else start
        if q_prev is not None and (p > 0 or not np.array_equal(q_prev, q0)):
            T = move_duration(chain, config, q_prev, q0)
            pieces.add(T, quintic_move_coef(q_prev, q0, T))
        rest_start = pieces.add(config.rest_duration, hold_coef(q0))
        settle = 0.5 * (config.rest_duration - config.static_duration)
        pieces.segments.append((rest_start + settle, pieces.now - settle, STATIC, p, -1))
        for j in joints:
            w = np.zeros(n)
            B = np.zeros(n)
            w[j] = 2 * np.pi * f[j]
            B[j] = A[j] / w[j]
            start = pieces.add(D, hold_coef(q0), B, w)
            pieces.segments.append((start, pieces.now, DYNAMIC, p, j))
            if stops[j] > 0:
                dq, v0, a0 = sine_end_state(A[j], f[j], D)
                coef = hold_coef(q0)
                coef[j] = hermite_quintic_coef(q0[j] + dq, v0, a0, q0[j], stops[j])
                pieces.add(stops[j], coef)
            pieces.add(config.rest_duration, hold_coef(q0))
    knots = np.concatenate([[0.0], np.cumsum(pieces.durations)])
    seg = np.array(pieces.segments, dtype=float).reshape(-1, 5)
    segments = Segments(
        t_start=seg[:, 0],
        t_end=seg[:, 1],
        kind=seg[:, 2].astype(np.int8),
        pose=seg[:, 3].astype(np.int32),
        joint=seg[:, 4].astype(np.int32),
    )
    traj = Trajectory(
        t=np.empty(0),
        q=np.empty((0, n)),
        qd=np.empty((0, n)),
        qdd=np.empty((0, n)),
        segments=segments,
        config=config,
        poses=poses,
        knots=knots,
        coef=np.array(pieces.coef),
        sine_amplitude=np.array(pieces.B),
        sine_omega=np.array(pieces.w),
        robot=chain.name,
    )
    t = np.arange(int(np.floor(knots[-1] * config.rate_hz + 1e-9)) + 1) / config.rate_hz
    q, qd, qdd = traj.evaluate(t)
    check_limits(
        chain, t, q, qd, margin=config.limit_margin, qdd=qdd, acceleration_limit=acceleration_bounds(chain, config)
    )
    if config.collision_check:
        from skincal.protocol.collision import CHECK_STEP_S, CollisionModel, check_motion

        t_check = np.append(np.arange(0.0, traj.duration, CHECK_STEP_S), traj.duration)
        check_motion(CollisionModel(chain, floor_z=config.floor_z), t_check, traj.evaluate(t_check)[0],
                     f"robot '{chain.name}', protocol '{config.name}': ")  # fmt: skip
    return _with_samples(traj, t, q, qd, qdd)


def sampled_at(traj: Trajectory, rate_hz: float) -> Trajectory:
    """``traj`` sampled every ``1 / rate_hz`` s from its exact piecewise form (``config.rate_hz`` set to it):
    for a controller (100 Hz) or a simulator (1 kHz); the motion itself is unchanged."""
    from dataclasses import replace

    t = np.arange(int(np.floor(traj.duration * rate_hz + 1e-9)) + 1) / rate_hz
    q, qd, qdd = traj.evaluate(t)
    return replace(traj, t=t, q=q, qd=qd, qdd=qdd, config=replace(traj.config, rate_hz=float(rate_hz)))


def _with_samples(traj: Trajectory, t: FloatArray, q: FloatArray, qd: FloatArray, qdd: FloatArray) -> Trajectory:
    from dataclasses import replace

    return replace(traj, t=t, q=q, qd=qd, qdd=qdd)


def concatenate_trajectories(parts: list[Trajectory]) -> Trajectory:
    """One trajectory executing ``parts`` one after another (each starting where the previous ended,
    e.g. built with ``build_trajectory(..., start=previous_end)``), sampled at the first part's rate.

    Times, segments and pose indices of each part are shifted behind the previous ones; the config
    is the first part's. Raises :class:`ConfigError` when a part does not start at the configuration
    the previous one ended in (to 1e-9 rad) or the joint counts differ.
    """
    from dataclasses import replace

    if not parts:
        raise ConfigError("concatenate_trajectories: no trajectory given")
    n = parts[0].n_joints
    knots, coef, B, w, seg, poses = [np.zeros(1)], [], [], [], [], []
    offset, n_poses = 0.0, 0
    for k, part in enumerate(parts):
        if part.n_joints != n:
            raise ConfigError(f"concatenate_trajectories: part {k + 1} has {part.n_joints} joints, the first {n}")
        if k > 0:
            end = parts[k - 1].evaluate([parts[k - 1].knots[-1]])[0][0]
            begin = part.evaluate([part.knots[0]])[0][0]
            if not np.allclose(end, begin, rtol=0.0, atol=1e-9):
                raise ConfigError(f"concatenate_trajectories: part {k + 1} does not start where part {k} ends")
        shift = offset - float(part.knots[0])
        knots.append(part.knots[1:] + shift)
        coef.append(part.coef)
        B.append(part.sine_amplitude)
        w.append(part.sine_omega)
        s = part.segments
        seg.append((s.t_start + shift, s.t_end + shift, s.kind, s.pose + n_poses, s.joint))
        poses.append(part.poses)
        offset += part.duration
        n_poses += part.poses.shape[0]
    segments = Segments(*(np.concatenate([x[i] for x in seg]) for i in range(5)))
    traj = replace(
        parts[0], segments=segments, poses=np.concatenate(poses), knots=np.concatenate(knots),
        coef=np.concatenate(coef), sine_amplitude=np.concatenate(B), sine_omega=np.concatenate(w),
    )  # fmt: skip
    rate = traj.config.rate_hz
    t = np.arange(int(np.floor(offset * rate + 1e-9)) + 1) / rate
    return _with_samples(traj, t, *traj.evaluate(t))
