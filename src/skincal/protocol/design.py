"""The next best motion: which joint to excite, and where, for the most information per second.

From the robot's current configuration ``q_now`` the candidates are segments the robot can execute
(:func:`skincal.protocol.build_trajectory` with ``start=q_now``, one pose, one excited joint):

* *excite joint j here*: rest, ``qd_j = A_j sin(2 pi f_j t)`` for ``excite_duration`` s (amplitude and
  frequency of the segment protocol fitted to the robot, :func:`segment_config`), rest;
* *move, then excite joint j*: the rest-to-rest quintic move to a new rest pose, then the same. The
  new poses are drawn uniformly within the margin-shrunk position limits, collision-free, and the
  :attr:`DesignOptions.pose_candidates` whose gravity directions in the link frames lie farthest from
  those of the poses visited so far are kept (gravity diversity, as ``pose_selection="diverse"``).

A candidate is offered only when its excursion stays within the limits (:func:`excitable`); the chosen
one is built with every check of :func:`~skincal.protocol.build_trajectory` (limits at the protocol
rate, self-collision and floor), and the next best is taken when it fails.

Score (D-optimal, per second of motion)::

    score = sum_u w_u [log det(I_u + P + dI_u) - log det(I_u + P)] / duration

with ``I_u`` the unit's current information on its pose parameters ``[rotation (3, rad), position
(3, m)]`` (:meth:`OnlineCalibrator.information`), ``dI_u`` the information the candidate's motion would
add at the unit's current estimate (:meth:`OnlineCalibrator.pose_information_rate` of the motion
sampled every :attr:`DesignOptions.dt` s, scaled to the IMU rate, and divided by the factor the
calibrator inflates the unit's covariance by for correlated residuals, :func:`inflations`, as ``I_u``
is), ``P`` a weak prior (std :attr:`DesignOptions.prior_rotation_rad`, :attr:`DesignOptions.prior_position_m`)
that keeps the log det finite before a direction is observed,
and ``w_u = 1``, or :attr:`DesignOptions.reached_weight` for a unit whose std already reached its target.
The gain is invariant to the parameters' units (a log det ratio), so rad and m mix freely.

Units without a link or an estimate yet cannot be scored, and a unit whose link is still undecided
is scored on a guess; while there are any, the motion is chosen to find them (:func:`next_motion`):
the joint most of them name as ``best_joint`` (the calibrator names the joint that tells the links
apart), else the joint not yet excited nearest the tip; the D-optimal score picks among those.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Protocol

import numpy as np

from skincal.errors import ConfigError, ProtocolError
from skincal.kinematics.chain import SerialChain
from skincal.kinematics.transforms import FloatArray
from skincal.protocol import ProtocolConfig, Trajectory, build_trajectory, get_protocol
from skincal.protocol.limits import excursion_envelopes, fit_to_limits, pose_box, position_bounds

SEGMENT_PROTOCOL = "fast"
"""The protocol whose excitation (amplitude, frequency, duration, rests, move speed) a segment uses."""


@dataclass(frozen=True)
class DesignOptions:
    """How the next motion is chosen.

    Attributes:
        pose_candidates: new rest poses scored per decision (besides staying where the robot is).
        excite_s: length of a segment's excitation, s (``None``: the segment protocol's, 1 s): 2 s (four
            periods of ``fast``'s 2 Hz) reached the target sooner on the Panda (seeds 0-2: 30, 16, 15 s against
            40, 17, 25 s), the rests and moves around it weighing less.
        pose_pool: uniform draws the new poses are chosen from (gravity diversity).
        dt: step at which a candidate's motion is sampled for its information, s.
        imu_rate_hz: the units' sample rate: the information of the motion sampled every ``dt`` is scaled
            by ``dt * imu_rate_hz`` (information grows with the number of samples).
        reached_weight: weight of a unit whose std already reached the target (others weigh 1).
        by_distance: a unit not at the target weighs by how far it is from it (:func:`unit_weights`).
        prior_rotation_rad, prior_position_m: std of the weak prior regularising the log det.
    """

    pose_candidates: int = 4
    excite_s: float | None = 2.0
    pose_pool: int = 60
    dt: float = 0.02
    imu_rate_hz: float = 100.0
    reached_weight: float = 0.1
    by_distance: bool = True
    prior_rotation_rad: float = 1.0
    prior_position_m: float = 0.1

    def __post_init__(self) -> None:
        if self.pose_candidates < 0 or self.pose_pool < self.pose_candidates:
            raise ConfigError("DesignOptions: need 0 <= pose_candidates <= pose_pool")
        for name in ("dt", "imu_rate_hz", "prior_rotation_rad", "prior_position_m"):
            if not (np.isfinite(getattr(self, name)) and getattr(self, name) > 0):
                raise ConfigError(f"DesignOptions.{name} must be positive, got {getattr(self, name)!r}")
        if not (0.0 <= self.reached_weight <= 1.0):
            raise ConfigError(f"DesignOptions.reached_weight must be in [0, 1], got {self.reached_weight!r}")

    @property
    def prior(self) -> FloatArray:
        """``(6, 6)`` prior information ``diag(1/sigma^2)`` over ``[rotation (3), position (3)]``."""
        return np.diag([self.prior_rotation_rad**-2] * 3 + [self.prior_position_m**-2] * 3)


class Informed(Protocol):
    """What the design needs of the streaming calibrator (:class:`~skincal.calib.online.OnlineCalibrator`)."""

    def status(self) -> Mapping[str, object]: ...

    def information(self, unit: str) -> tuple[int, FloatArray]: ...

    def pose_information_rate(
        self, unit: str, link: int, q: FloatArray, qd: FloatArray, qdd: FloatArray, dt: float
    ) -> FloatArray: ...

    def result(self) -> object: ...


@dataclass(frozen=True)
class Candidate:
    """One possible next segment.

    Attributes:
        pose: ``(n,)`` rest pose of the segment, rad (the current configuration when it does not move).
        joint: 0-based excited joint.
        moves: whether the segment starts with a move to ``pose``.
        duration: length of the segment, s.
        gain: weighted D-optimal information gain over all units (nats).
        score: ``gain / duration``.
        trajectory: the segment, time from 0, starting at the robot's current configuration.
    """

    pose: FloatArray
    joint: int
    moves: bool
    duration: float
    gain: float
    score: float
    trajectory: Trajectory

    def describe(self) -> str:
        """One line: what the robot does."""
        where = "move to a new pose, then excite" if self.moves else "excite"
        return f"{where} joint {self.joint + 1} ({self.duration:.1f} s, gain {self.gain:.2f})"


def segment_config(
    chain: SerialChain, protocol: str | ProtocolConfig = SEGMENT_PROTOCOL, excite_s: float | None = None
) -> ProtocolConfig:
    """The segment protocol fitted to ``chain`` (:func:`~skincal.protocol.limits.fit_to_limits`), one pose,
    collision-checked; ``excite_s``: the excitation's length, s (default the protocol's)."""
    config = get_protocol(protocol) if isinstance(protocol, str) else protocol
    if excite_s is not None:
        config = replace(config, excite_duration=float(excite_s))
    return replace(fit_to_limits(chain, config), collision_check=True, n_poses=1, poses=None)


def d_optimal_gain(information: FloatArray, added: FloatArray, prior: FloatArray | None = None) -> float:
    """``log det(I + P + dI) - log det(I + P)`` (nats) for information ``I``, added ``dI`` and prior ``P``
    (all ``(k, k)`` symmetric; ``P`` defaults to 0, then ``I`` must be positive definite)."""
    base = np.asarray(information, dtype=float) + (0.0 if prior is None else np.asarray(prior, dtype=float))
    sign0, log0 = np.linalg.slogdet(base)
    sign1, log1 = np.linalg.slogdet(base + np.asarray(added, dtype=float))
    if sign0 <= 0 or sign1 <= 0:
        raise ConfigError("d_optimal_gain: the information (with the prior) is not positive definite")
    return float(log1 - log0)


def psd(M: FloatArray) -> FloatArray:
    """``M`` made a valid information matrix: symmetrised, negative eigenvalues (round-off of an inverse or
    a Schur complement) set to 0; a non-finite ``M`` (nothing known) is all zeros."""
    M = np.asarray(M, dtype=float)
    if not np.all(np.isfinite(M)):
        return np.zeros_like(M)
    M = 0.5 * (M + M.T)
    lam, V = np.linalg.eigh(M)
    if lam.min() >= 0:
        return M
    return (V * np.clip(lam, 0.0, None)) @ V.T


def excitable(chain: SerialChain, config: ProtocolConfig, q: FloatArray) -> np.ndarray:
    """``(K, n)`` bool: joint ``j`` may be excited at configuration ``q[k]`` (``(K, n)`` or ``(n,)``): every
    joint within the margin-shrunk limits and joint ``j``'s excursion too (:func:`~skincal.protocol.limits.pose_box`
    per joint)."""
    q = np.atleast_2d(np.asarray(q, dtype=float))
    lower, upper = position_bounds(chain)
    m = config.limit_margin
    lo, hi = excursion_envelopes(chain, replace(config, excited_joints=None))
    tol = 1e-9
    inside = np.all((q >= lower + m - tol) & (q <= upper - m + tol), axis=1)
    fits = (q >= lower + m - lo - tol) & (q <= upper - m - hi + tol)
    return inside[:, None] & fits


def build_segment(
    chain: SerialChain, config: ProtocolConfig, start: FloatArray, pose: FloatArray, joint: int, *, check: bool = True
) -> Trajectory:
    """The segment from ``start`` (move when ``pose`` differs), rest, excite ``joint``, rest; with ``check``
    every check of :func:`~skincal.protocol.build_trajectory` (limits, collision), else limits only."""
    seg = replace(config, excited_joints=(int(joint),), collision_check=bool(check and config.collision_check))
    return build_trajectory(chain, seg, poses=np.asarray(pose, dtype=float)[None], start=start)


def candidate_poses(
    chain: SerialChain, config: ProtocolConfig, visited: FloatArray, rng: np.random.Generator, options: DesignOptions
) -> FloatArray:
    """``(K, n)`` new rest poses: uniform draws within :func:`~skincal.protocol.limits.pose_box` (every
    joint's excitation fits there), collision-free, the ``K`` farthest (greedy) from the visited poses
    ``(V, n)`` in gravity directions."""
    from skincal.protocol.collision import CollisionModel

    if options.pose_candidates == 0:
        return np.zeros((0, chain.n_joints))
    lo, hi = pose_box(chain, replace(config, excited_joints=None))
    pool = rng.uniform(lo, hi, size=(options.pose_pool, chain.n_joints))
    pool = pool[CollisionModel(chain, floor_z=config.floor_z).free(pool)]
    if pool.shape[0] == 0:
        return pool
    from skincal.protocol.limits import gravity_features

    feat = gravity_features(chain, np.atleast_2d(np.asarray(pool, dtype=float)))
    ref = gravity_features(chain, np.atleast_2d(visited)) if len(visited) else np.zeros((0, feat.shape[1]))
    dist = np.full(pool.shape[0], np.inf)
    for r in ref:
        dist = np.minimum(dist, np.sum((feat - r) ** 2, axis=1))
    chosen: list[int] = []
    for _ in range(min(options.pose_candidates, pool.shape[0])):
        d = dist.copy()
        d[chosen] = -np.inf
        k = int(np.argmax(d))
        chosen.append(k)
        dist = np.minimum(dist, np.sum((feat - feat[k]) ** 2, axis=1))
    return pool[chosen]


def unit_weights(
    status: Mapping[str, object], reached_weight: float, target: tuple[float, float] | None = None
) -> dict[str, float]:
    """Per scorable unit (a link and an estimate), its weight: ``reached_weight`` once at target, else 1,
    or with ``target`` (position m, rotation deg) how far it is from it: ``log`` of its largest std over
    the target (position or rotation axis), within ``[FAR_WEIGHT_MIN, FAR_WEIGHT_MAX]`` (an undetermined
    axis counts as the maximum), so that the motion goes where the remaining std is."""
    out: dict[str, float] = {}
    for name, st in status.items():
        if getattr(st, "link", None) is None or getattr(st, "pose", None) is None:
            continue
        if getattr(st, "reached", False):
            out[name] = reached_weight
        elif target is None:
            out[name] = 1.0
        else:
            pos = float(np.max(getattr(st, "position_std_m", np.inf))) / target[0]
            rot = float(np.max(getattr(st, "rotation_std_deg", np.inf))) / target[1]
            far = np.log(max(pos, rot)) if np.isfinite(max(pos, rot)) else FAR_WEIGHT_MAX
            out[name] = float(np.clip(far, FAR_WEIGHT_MIN, FAR_WEIGHT_MAX))
    return out


FAR_WEIGHT_MIN = 0.25
FAR_WEIGHT_MAX = 3.0
"""Bounds of a unit's weight by its distance from the target (:func:`unit_weights`)."""


def calibrator_target(calibrator: Informed) -> tuple[float, float] | None:
    """The calibrator's target (position m, rotation deg) when it tells it (its ``options``)."""
    options = getattr(calibrator, "options", None)
    p, r = getattr(options, "target_position_m", None), getattr(options, "target_rotation_deg", None)
    return (float(p), float(r)) if isinstance(p, (int, float)) and isinstance(r, (int, float)) else None


def motion_gain(
    calibrator: Informed,
    trajectory: Trajectory,
    weights: Mapping[str, float],
    options: DesignOptions,
    current: Mapping[str, tuple[int | None, FloatArray]] | None = None,
    inflation: Mapping[str, float] | None = None,
) -> float:
    """Weighted D-optimal gain (module docstring) of executing ``trajectory`` for the units in ``weights``;
    ``current``: each unit's ``(link, information)`` (default: asked now); ``inflation``: per unit, the
    factor its calibrator inflates the covariance by for correlated residuals (default :func:`inflations`),
    which divides the predicted information too (it applies to the new data as to the old)."""
    t = np.arange(0.0, trajectory.duration, options.dt)
    q, qd, qdd = trajectory.evaluate(t)
    prior = options.prior
    factors = inflations(calibrator) if inflation is None else inflation
    gain = 0.0
    for unit, w in weights.items():
        if w <= 0:
            continue
        link, info = current[unit] if current is not None else _information(calibrator, unit)
        if link is None:
            continue
        try:
            added = calibrator.pose_information_rate(unit, link, q, qd, qdd, options.dt)
        except np.linalg.LinAlgError:  # a degenerate estimate: nothing to predict from
            continue
        scale = options.dt * options.imu_rate_hz / max(factors.get(unit, 1.0), 1.0)
        gain += w * d_optimal_gain(info, psd(added) * scale, prior)
    return gain


def inflations(calibrator: Informed) -> dict[str, float]:
    """Per unit, the calibrator's covariance inflation for correlated residuals (its result's
    ``residual_correlation``; 1 when it has none)."""
    try:
        units = getattr(calibrator.result(), "units", {})
    except np.linalg.LinAlgError:
        return {}
    out = {}
    for name, unit in units.items():
        value = getattr(unit, "extras", {}).get("residual_correlation")
        if isinstance(value, (int, float)) and np.isfinite(value) and value > 0:
            out[name] = float(value)
    return out


def information_now(calibrator: Informed) -> dict[str, tuple[int | None, FloatArray]]:
    """Every scorable unit's ``(link, information)`` now (:func:`psd`)."""
    return {u: _information(calibrator, u) for u in unit_weights(calibrator.status(), 1.0)}


def realized_gain(
    before: Mapping[str, tuple[int | None, FloatArray]],
    after: Mapping[str, tuple[int | None, FloatArray]],
    weights: Mapping[str, float],
    options: DesignOptions = DesignOptions(),
) -> float:
    """The weighted D-optimal gain the data actually gave between two :func:`information_now` (units
    scorable in both, on the same link; the prior of the prediction)."""
    gain = 0.0
    for unit, w in weights.items():
        if unit not in before or unit not in after or before[unit][0] != after[unit][0]:
            continue
        a, b = before[unit][1] + options.prior, after[unit][1] + options.prior
        gain += w * float(np.linalg.slogdet(b)[1] - np.linalg.slogdet(a)[1])
    return gain


def _information(calibrator: Informed, unit: str) -> tuple[int | None, FloatArray]:
    """The unit's link and current information (:func:`psd`); ``(None, 0)`` when its estimate is degenerate."""
    try:
        link, info = calibrator.information(unit)
    except np.linalg.LinAlgError:
        return None, np.zeros((6, 6))
    return link, psd(info)


def score_candidates(
    calibrator: Informed,
    chain: SerialChain,
    config: ProtocolConfig,
    q_now: FloatArray,
    poses: FloatArray,
    options: DesignOptions = DesignOptions(),
    joints: Sequence[int] | None = None,
    *,
    here: bool = True,
    discount: Mapping[int, float] | None = None,
) -> list[Candidate]:
    """Every feasible candidate (here unless not ``here``, and at each of ``poses`` ``(K, n)``; ``joints``:
    only these) scored, best first. Candidates are built without the collision check (:func:`next_motion`
    checks the chosen). ``discount``: per joint, a factor on the score of exciting it again here (see
    :func:`next_motion`)."""
    q_now = np.asarray(q_now, dtype=float)
    status = calibrator.status()
    weights = unit_weights(
        status, options.reached_weight, calibrator_target(calibrator) if options.by_distance else None
    )
    current = {u: _information(calibrator, u) for u in weights}
    factors = inflations(calibrator) if weights else {}
    sites = [q_now, *np.atleast_2d(poses)] if len(poses) else [q_now]
    ok = excitable(chain, config, np.array(sites))
    allowed = set(range(chain.n_joints) if joints is None else joints)
    out: list[Candidate] = []
    for k, pose in enumerate(sites):
        for j in range(chain.n_joints):
            if not ok[k, j] or j not in allowed or (k == 0 and not here):
                continue
            try:
                traj = build_segment(chain, config, q_now, pose, j, check=False)
            except ProtocolError:
                continue
            gain = motion_gain(calibrator, traj, weights, options, current, factors) if weights else 0.0
            score = gain / traj.duration * ((discount or {}).get(j, 1.0) if k == 0 else 1.0)
            out.append(Candidate(pose, j, k > 0, traj.duration, gain, score, traj))
    out.sort(key=lambda c: (-c.score, c.duration))  # equal scores (nothing to gain yet): the shortest first
    return out


def next_motion(
    calibrator: Informed,
    chain: SerialChain,
    q_now: FloatArray,
    rng: np.random.Generator,
    *,
    config: ProtocolConfig | None = None,
    visited: FloatArray | None = None,
    moved: Sequence[int] = (),
    options: DesignOptions = DesignOptions(),
    discount: Mapping[int, float] | None = None,
) -> Candidate:
    """The best next segment from ``q_now`` (module docstring), checked (limits, collision).

    Args:
        calibrator: the streaming calibrator (its status and information).
        chain: the robot.
        q_now: ``(n,)`` the robot's configuration (at rest), rad.
        rng: draws the candidate poses.
        config: the segment protocol (default :func:`segment_config`).
        visited: ``(V, n)`` rest poses visited so far (gravity diversity; default ``q_now`` only).
        moved: 0-based joints that have moved so far (excited, or in a move between poses).
        options: :class:`DesignOptions`.
        discount: per joint, the factor on the score of exciting it again at the current pose: what the
            last such excitation realised over what was predicted (:func:`realized_gain`), so that a
            motion whose information the calibrator does not turn into a smaller std is not repeated
            forever (the loop resets it after a move).

    Finding the units first: a unit is *unfound* while it has no link or estimate, its link is
    undecided, or it sits on link ``k < n`` while joint ``k + 1`` never moved (then every link from
    ``k`` on explains its data alike). While some are, the candidates excite only the joints they call
    for (:func:`finding_joints`), and while some joint never moved, only after a move to a new pose
    (a move turns every joint at once); the D-optimal score picks among those.

    Raises :class:`ProtocolError` when no candidate passes the checks.
    """
    config = config or segment_config(chain, excite_s=options.excite_s)
    q_now = np.asarray(q_now, dtype=float)
    visited = np.atleast_2d(q_now if visited is None else np.asarray(visited, dtype=float))
    status = calibrator.status()
    moved_set = {int(j) for j in moved}
    unfound = [st for st in status.values() if _unfound(st, moved_set, chain.n_joints)]
    joints: list[int] | None = None
    poses = candidate_poses(chain, config, visited, rng, options)
    here = True
    if unfound:
        joints = finding_joints(unfound, moved_set, chain.n_joints)
        here = len(moved_set) == chain.n_joints or poses.shape[0] == 0
    tries = [(joints, here)] + ([(None, True)] if joints is not None else [])
    for only, at_hand in tries:  # what finds the units; else (it cannot run from here) anything
        for cand in score_candidates(calibrator, chain, config, q_now, poses, options, only, here=at_hand,
                                     discount=discount):  # fmt: skip
            try:
                traj = build_segment(chain, config, q_now, cand.pose, cand.joint, check=True)
            except ProtocolError:
                continue
            return replace(cand, trajectory=traj)
    raise ProtocolError(
        f"robot '{chain.name}': no next motion within the limits and collision-free from the current configuration"
    )


def _unfound(st: object, moved: set[int], n: int) -> bool:
    """See :func:`next_motion`."""
    link = getattr(st, "link", None)
    return (
        link is None
        or getattr(st, "pose", None) is None
        or str(getattr(st, "missing", "")).startswith("link undecided")
        or (link < n and link not in moved)
    )


def finding_joints(unfound: Sequence[object], moved: set[int], n: int) -> list[int]:
    """The 0-based joints that find the ``unfound`` units: each unit's vote (joint ``k + 1`` for a unit
    on link ``k`` whose next joint never moved, else its ``best_joint``), the most voted ones; without
    votes the joints not yet moved (nearest the tip first), else all."""
    votes = []
    for st in unfound:
        link = getattr(st, "link", None)
        j = link if link is not None and link < n and link not in moved else getattr(st, "best_joint", None)
        if j is not None and 0 <= int(j) < n:
            votes.append(int(j))
    if votes:
        counts = np.bincount(votes, minlength=n)
        return [int(j) for j in np.flatnonzero(counts == counts.max())]
    fresh = [j for j in range(n - 1, -1, -1) if j not in moved]
    return fresh[:1] if fresh else list(range(n))
