"""The obstacle-avoidance controller: one quadratic program per control step (paper Sec. V-C).

Per step, with the flange position ``x`` (base frame), its ``3 x n`` position Jacobian ``J`` and the
reference ``x_des``, ``xdot_des``::

    minimise   1/2 qd^T (J^T J + lambda I) qd - (J^T xdot_cmd + lambda qd_post)^T qd
    subject to lb <= qd <= ub                       (velocity limits; position limits over one step)
               n_i^T J_i qd <= b(d_i) + min(n_i^T v_i, 0)   for every obstacle point i
                                       (velocity-aware, cone-aware: :mod:`skincal.control.constraints`)

with ``xdot_cmd = xdot_des + K (x_des - x)`` (feed-forward plus proportional feedback, ``K`` in 1/s)
and an optional weak posture velocity ``qd_post = K_post (q_post - q)`` inside the damping term
(``K_post = 0`` gives exactly the paper's objective). Solved with :func:`qpsolvers.solve_qp`
(DAQP by default).

Infeasible QP (a person inside the critical distance or ``S_p`` coming faster than the arm can back away,
or obstacles on opposite sides of a link): the controller never relaxes the obstacle rows silently. It
commands the *least-violating retreat*, lexicographically: first the smallest violation of the rows, then,
among the commands that reach it, the stillest,

    min 1/2 (eps |qd|^2 + |s|^2)  s.t.  G qd - s <= h, s >= 0, lb <= qd <= ub,   eps = 1e-6

(``eps`` only breaks ties: with it tiny the squared violation is the least possible up to ``O(eps)``), and
flags the step ``feasible = False`` with the violation ``max s`` (m/s). A row that asks to back away faster
than the joint limits allow is thus driven at the limits' pace away from its point (a still point inside
the margin: the arm retreats as fast as it can, not as little as it can); two points pinching a link make
the arm escape along any direction that opens both gaps (their normals not exactly opposite); the arm
stands still only where every motion violates more (exactly opposite points, a point by the base it has
no lever on). The former stop (``eps = 1``: as still as possible, the violation traded against motion 1:1)
held the arm where a person arrived (issue 17: ``elbow``, ``lower``, ``pinch``). A feasible QP is solved as
before, bit for bit. With ``ControllerConfig.stop_never_approaches`` (``--margin iso``/``iso-pfl``, issue 28)
the slack of every row is capped, ``s_i <= max(-h_i, 0)``: a row that asks to back away may be violated
only down to standing still (``n_i^T J_i qd <= 0``), any other row not at all (violating one let the retreat
from the others approach its point past its ``S_p``: ``walk-at``, simulated); always feasible, ``qd = 0``
meets it: the standard's protective stop when the person comes faster than the arm can back away.

Protective separation (``ControllerConfig.separation`` set, ISO/TS 15066 speed and separation
monitoring, :mod:`skincal.control.separation`): the critical distance of each obstacle row is the point's
own ``S_p,i = S_h + S_r + S_s + C + Z_d + Z_r`` computed at every step from

* ``Z_d,i = sigma_level sqrt(n_i^T Cov_i n_i)``: the point's position covariance (``ObstaclePoints.cov``)
  along its normal;
* ``v_r,i = n_i^T J_i qd``: the robot point's speed toward the obstacle point under the command being
  solved for, at least its present speed ``n_i^T J_i qd_now`` when the measured joint velocity is passed to
  :meth:`AvoidanceController.step` (torque mode), for ``S_r``, ``S_s`` and ``T_s``;
* ``v_h,i = max(v_h, a_i)``, ``a_i = max(-n_i^T v_i, 0)``: the design human speed, or the point's measured
  approach speed when larger;

and the row keeps the ramp's shape, shifted to ``S_p`` and taken at the robot's own speed: the gap may close
at most at ``b(d - S_p(v_r))``, ``b(x) = v_max tanh(x / w)`` with the fixed ramp width
``w = (notice - critical) / atanh(0.99)``,

    n_i^T J_i qd + a_i <= b(d_i - S_p,i(max(n_i^T J_i qd, n_i^T J_i qd_now)))

i.e. ``n_i^T J_i qd <= u_i*``, the fixed point of :func:`skincal.control.separation.allowed_approach_speed`
(from a precomputed table, :class:`~skincal.control.separation.ApproachSpeedTable`, never above it). Using
``S_p`` of the previous command instead (explicit) makes the margin chatter from step to step (robot fast ->
large ``S_p`` -> retreat -> small ``S_p`` -> fast approach ...): measured 0.23 <-> 1.03 m on alternate steps.
Below ``S_p`` the bound is negative, so the robot backs away. ``separation = None`` is the fixed critical
distance, unchanged.

Power and force limiting (``ControllerConfig.pfl`` a body region, ``skincal avoid --margin iso-pfl``;
ISO/TS 15066 Annex A, :mod:`skincal.control.body_regions`): speed and separation monitoring alone asks the
robot point never to move toward a person inside ``S_p``; with PFL it may, up to the transient speed limit
of the body region at its effective mass along the row's normal (:mod:`skincal.control.effective_mass`,
``M_eff,i = 1 / (g_i M(q)^-1 g_i^T)`` with ``g_i = n_i^T J_i``), as long as the point is not touching
(``d_i > 0``; touching, the separation row holds, so the robot never presses: no quasi-static contact;
a region where transient contact is not permitted, the head, keeps the separation row too)::

    n_i^T J_i qd <= max(u_i*, min(pfl_share F_T / sqrt(mu_i k), v_max)),   mu_i = (1/m_H + 1/M_eff,i)^-1
"""

from __future__ import annotations

import functools
import time
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import ArrayLike

from skincal.control.body_regions import BodyRegion, pfl_speed_limit
from skincal.control.constraints import (
    FrameCache,
    approach_speed_bound,
    approach_speed_slope,
    cap_candidates,
    joint_velocity_bounds,
    obstacle_geometry,
    obstacle_rows,
    ramp_width,
)
from skincal.control.effective_mass import MassMatrix, effective_mass
from skincal.control.separation import (
    ApproachSpeedTable,
    SeparationParams,
    SeparationTerms,
    protective_separation,
)
from skincal.errors import ConfigError
from skincal.kinematics.chain import SerialChain
from skincal.kinematics.transforms import FloatArray
from skincal.perception.body import RobotBody
from skincal.perception.points import ObstaclePoints

_STOP_EPS = 1e-6
"""Weight of stillness against the squared row violation in the least-violating retreat (module docstring)."""
_FEAS_TOL = 1e-6


@dataclass(frozen=True)
class ControllerConfig:
    """Controller parameters; SI units.

    Attributes:
        dt: control period, s (1 kHz).
        damping: ``lambda`` of the objective, m^2 (regularises singular ``J``).
        gain: ``K``, feedback gain on the Cartesian position error, 1/s.
        posture_gain: ``K_post``, pull toward ``q_post`` inside the damping term, 1/s (0 = off).
        critical, notice: distances (m) where the approach bound is zero / saturates. The paper's
            0.12 / 0.3 m are for a still robot-mounted demo; here the critical distance is the clearance
            to keep (0.2 m) plus 5 cm for what the skin cannot see in time (the part of a person
            outside every cone, the 50 Hz sampling and filter lag; measured in
            ``benchmarks/bench_avoid.py``: with 0.2 m the walk-past came to 0.196 m), and the notice
            distance the demo's 1 m reaction range.
        v_max: largest allowed approach speed, m/s (paper: 0.3); an approaching obstacle's own speed
            comes on top (the velocity-aware row), up to the joint velocity limits.
        padding: the robot model used for distances is the link capsules grown by this, m (a small
            allowance for the capsule model, not a margin for perception errors: those come from
            the cone-aware placement and the velocity-aware rows).
        n_rim: rim points of a reading's cone cap tried for the nearest possible target (0: axis only).
        velocity_scale: fraction of the joint velocity limits used.
        limit_margin: keep this far inside the joint position limits, rad.
        solver: a :mod:`qpsolvers` backend name.
        separation: ISO/TS 15066 protective separation per point instead of the fixed ``critical``
            (module docstring; ``critical`` and ``notice`` then only set the ramp width); None: the
            fixed critical distance.
        pfl: with ``separation``, the body region (ISO/TS 15066 Annex A) every obstacle point is taken to
            be: a point inside ``S_p`` but not touching may be approached at up to ``pfl_share`` of the
            region's transient speed limit at the robot point's effective mass (power and force
            limiting, module docstring; needs the controller's ``mass_matrix``); None: pure speed and
            separation monitoring.
        pfl_share: the share of the Annex A speed limit the controller allows itself (the rest covers
            perception and tracking errors).
        sp_buffer: the obstacle rows' ramp reaches zero this far outside each point's ``S_p``, m (``S_p``
            itself, logged and judged, is unchanged): room for a drive whose actual speed lags the command
            (torque mode) to come to rest before ``S_p`` (speed scaling before the protective separation).
        stop_never_approaches: in the least-violating retreat, a row that asks to back away (``h_i < 0``)
            may be violated only down to standing still, never to approaching (``n_i^T J_i qd <= 0``), and
            a row that allows an approach not at all: the protective stop of speed and separation
            monitoring (module docstring). False: the legacy retreat, which may approach one point to back
            away from others.
        acceleration_limit: ``(n,)`` joint acceleration limits of the drive the command goes to, rad/s^2 (a
            torque-level robot whose reference velocity moves toward the command at most at these,
            :class:`skincal.sim.dynamics.TorqueRobot`): each command stays within ``a_j dt`` of the previous
            one (``qd_prev`` of :meth:`AvoidanceController.step`), so the drive reaches it within the step and
            the obstacle rows hold on the velocity the robot actually has (module docstring). None: an ideal
            velocity interface (kinematic).
        all_directions: with ``separation``, a robot point near a perceived point (its bound below
            ``TANGENT_SHARE v_max``) moves across the normal no faster than the row lets it move toward the
            point, ``|t_k^T J_i qd| <= u_i`` for two tangents ``t_k`` while ``u_i >= 0`` (:func:`_sideways_rows`):
            the speed ``v_r`` of ``S_p`` toward a part of the person the skin has not seen yet, in any direction,
            scaled down before ``S_p`` is reached.
        feedback_speed: the feedback term ``K (x_des - x)`` is scaled down to at most this norm, m/s (None: not
            capped). After a retreat the flange is far off its reference and ``K = 10/s`` would bring it back at
            up to 1.8 m/s (``hand`` on the Panda, torque, with ``--resume``; simulated), a speed an acceleration
            limited drive cannot take back within a step when a part of the person is then first seen. Not used
            by ``skincal avoid`` yet: capped at 0.5 m/s it cut that run's steps approaching inside ``S_p`` from
            220 to 5 (``pinch``: 334 to 204) but gave ``arm`` (torque, 7 s, no ``--resume``) one (simulated).
    """

    dt: float = 0.001
    damping: float = 1e-3
    gain: float = 10.0
    posture_gain: float = 0.0
    critical: float = 0.25
    notice: float = 1.0
    v_max: float = 1.0
    padding: float = 0.02
    n_rim: int = 6
    velocity_scale: float = 1.0
    limit_margin: float = 0.05
    solver: str = "daqp"
    separation: SeparationParams | None = None
    pfl: BodyRegion | None = None
    pfl_share: float = 0.5
    sp_buffer: float = 0.0
    stop_never_approaches: bool = False
    acceleration_limit: tuple[float, ...] | None = None
    all_directions: bool = False
    feedback_speed: float | None = None

    def __post_init__(self) -> None:
        if self.pfl is not None and (self.separation is None or not isinstance(self.pfl, BodyRegion)):
            raise ConfigError("controller: pfl needs a BodyRegion and a separation model")
        if not (0 < self.pfl_share <= 1):
            raise ConfigError(f"controller: pfl_share must be in (0, 1], got {self.pfl_share}")
        if self.acceleration_limit is not None:
            acc = np.asarray(self.acceleration_limit, dtype=float)
            if acc.ndim != 1 or not np.all(np.isfinite(acc) & (acc > 0)):
                raise ConfigError("controller: acceleration_limit must be finite positive numbers (rad/s^2)")
            object.__setattr__(self, "acceleration_limit", tuple(float(a) for a in acc))
        if self.separation is not None and not isinstance(self.separation, SeparationParams):
            raise ConfigError(f"controller: separation must be SeparationParams or None, got {self.separation!r}")
        if not (0 < self.critical < self.notice):
            raise ConfigError(f"controller: need 0 < critical < notice (m), got {self.critical}, {self.notice}")
        if self.feedback_speed is not None and not self.feedback_speed > 0:
            raise ConfigError(f"controller: feedback_speed must be positive, got {self.feedback_speed}")
        for name in ("dt", "damping", "v_max", "velocity_scale"):
            if not getattr(self, name) > 0:
                raise ConfigError(f"controller: {name} must be positive, got {getattr(self, name)}")
        for name in ("gain", "posture_gain", "padding", "limit_margin", "n_rim", "sp_buffer"):
            if not getattr(self, name) >= 0:
                raise ConfigError(f"controller: {name} must be non-negative, got {getattr(self, name)}")


@dataclass(frozen=True)
class StepResult:
    """One control step.

    Attributes:
        qd: ``(n,)`` commanded joint velocities, rad/s.
        feasible: False when the QP had no solution and the least-violating retreat was commanded.
        violation: largest obstacle-row violation of ``qd``, m/s (0 when feasible).
        solve_time_s: time inside the QP solver call(s), s.
        n_obstacles: number of obstacle rows.
        min_distance: smallest distance of an obstacle point to the padded robot surface, m (inf if none).
        x: ``(3,)`` flange position at this step, base frame, m.
        margin: the critical distance of the most critical point (smallest ``d_i - S_p,i``), m: its
            ``S_p`` with ``separation``, else the fixed ``critical``; NaN without obstacle points.
        terms: with ``separation``, every point's ``S_p`` terms (:class:`SeparationTerms`, ``(K,)``
            each, in the order of the points); None otherwise.
        clearance: ``min_i (d_i - S_p,i)`` (or ``min d_i - critical``), m; inf without points
            (negative: inside the protective separation).
        inside_rows: with ``separation``, the rows ``n_i^T J_i`` ``(m, n)`` of the points inside their ``S_p``
            (``d_i < S_p,i``) at this step, for the standard's criterion on the robot's actual motion
            (:func:`skincal.control.iso_metrics.iso_criteria`); None otherwise.
        inside_allowed: ``(m,)`` the speed each of those points allows the robot toward it, m/s: 0 (speed
            and separation monitoring) or, with ``pfl``, the full Annex A limit at the row's effective mass.
    """

    qd: FloatArray
    feasible: bool
    violation: float
    solve_time_s: float
    n_obstacles: int
    min_distance: float
    x: FloatArray
    margin: float = float("nan")
    terms: SeparationTerms | None = None
    clearance: float = float("inf")
    inside_rows: FloatArray | None = None
    inside_allowed: FloatArray | None = None


@dataclass(frozen=True)
class QpProblem:
    """The QP of one step: ``min 1/2 qd^T P qd + c^T qd  s.t.  G qd <= h, lb <= qd <= ub``.

    ``distance`` ``(K,)``: every point's distance to the padded robot, m; ``critical`` ``(K,)``: the
    critical distance of each (``S_p,i`` or the fixed one), m; ``terms``: the ``S_p`` terms or None."""

    P: FloatArray
    c: FloatArray
    G: FloatArray
    h: FloatArray
    lb: FloatArray
    ub: FloatArray
    x: FloatArray
    distance: FloatArray
    critical: FloatArray | None = None
    terms: SeparationTerms | None = None
    separation_inputs: SeparationInputs | None = None
    free_box: tuple[FloatArray, FloatArray] | None = None


@dataclass(frozen=True)
class SeparationInputs:
    """Per point ``(K,)``: what ``S_p`` is computed from (module docstring).

    Attributes:
        G: ``(K, n)`` rows ``n_i^T J_i`` (all points, before void rows are dropped).
        v_now: the robot point's present speed toward the point, m/s.
        v_h: the point's measured approach speed, m/s.
        z_d: ``Z_d``, m.
    """

    G: FloatArray
    v_now: FloatArray
    v_h: FloatArray
    z_d: FloatArray


TANGENT_SHARE = 0.9
"""With ``ControllerConfig.all_directions``, the rows across the normal are added where the normal row's bound is
below this share of ``v_max`` (inside the ramp: a person near)."""


def _sideways_rows(
    chain: SerialChain, T: FloatArray, prox, h_all: FloatArray, below: float
) -> tuple[FloatArray, FloatArray]:
    """Rows ``+-t_k^T J_i`` ``(4 m, n)`` and bounds ``h_i`` ``(4 m,)`` for the ``m`` points whose bound is
    ``0 <= h_i < below`` (near, not inside the margin: inside it the normal row asks for a retreat and the way
    out may be sideways, ``pinch``): ``t_1, t_2`` unit vectors across the normal ``n_i`` (base frame). With the
    normal row they bound the robot point's speed toward any direction ``e`` by ``sqrt(3) h_i``
    (``e^T v <= |e.n| n^T v + |e.t_1| |t_1^T v| + |e.t_2| |t_2^T v|``)."""
    near = np.flatnonzero((h_all >= 0) & (h_all < below))
    if near.size == 0:
        return np.zeros((0, chain.n_joints)), np.zeros(0)
    normal = prox.normal[near]
    helper = np.where(np.abs(normal[:, :1]) < 0.9, np.array([[1.0, 0.0, 0.0]]), np.array([[0.0, 1.0, 0.0]]))
    t1 = np.cross(normal, helper)
    t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
    t2 = np.cross(normal, t1)
    J = chain.point_jacobians(T, prox.link[near], prox.p_base_robot[near])  # (m, 3, n)
    rows = np.concatenate([np.einsum("ki,kij->kj", t, J) for t in (t1, t2)])
    bound = np.tile(h_all[near], 2)
    return np.vstack([rows, -rows]), np.concatenate([bound, bound])


def drive_bounds(
    lb: FloatArray, ub: FloatArray, qd_prev: ArrayLike, acceleration: ArrayLike, dt: float
) -> tuple[FloatArray, FloatArray]:
    """The box ``lb <= qd <= ub`` ``(n,)`` rad/s narrowed to what an acceleration-limited drive reaches from the
    previous command ``qd_prev`` within one control period ``dt``,

        lb' = clip(lb, qd_prev - a dt, qd_prev + a dt),   ub' = clip(ub, qd_prev - a dt, qd_prev + a dt)

    (``a`` ``(n,)`` rad/s^2; a position bound that asks for more braking than ``a`` allows gives the strongest
    braking the drive has). Without it, the drive's reference moves toward a command far away at the limit of
    its slowest joint along the whole joint-space change (stop category 2 keeps the path), so a retreat command
    that also swings joints the retreat does not need (the tracking objective's choice) reverses the approach
    at a fraction of the drive's deceleration: measured in ``fast`` on the Panda, torque mode, a 2.6 rad/s
    change led by joint 5 (15 rad/s^2, 0.17 s) while the speed toward a hand inside ``S_p`` fell by 1 mm/s
    per ms (simulated)."""
    prev = np.asarray(qd_prev, dtype=float).reshape(-1)
    step = np.asarray(acceleration, dtype=float).reshape(-1) * float(dt)
    lo, hi = prev - step, prev + step
    return np.clip(lb, lo, hi), np.clip(ub, lo, hi)


@functools.lru_cache(maxsize=8)
def _speed_table(params: SeparationParams, v_max: float, width: float) -> ApproachSpeedTable:
    """The allowed-speed table of a separation model and ramp (built once, 0.1-0.2 s, shared by controllers)."""

    def ramp(gap: FloatArray) -> tuple[FloatArray, FloatArray]:
        """The approach bound ``b`` (m/s) at ``gap = d - S_p`` (m) and its slope ``db/dgap`` (1/s)."""
        b = approach_speed_bound(gap, 0.0, float("inf"), v_max, width)  # (notice unused: the width is given)
        return b, approach_speed_slope(gap, v_max, width)

    return ApproachSpeedTable(params, ramp)


class AvoidanceController:
    """Cartesian flange tracking with obstacle approach-velocity constraints (see the module docstring)."""

    def __init__(
        self,
        chain: SerialChain,
        config: ControllerConfig = ControllerConfig(),
        body: RobotBody | None = None,
        q_posture: ArrayLike | None = None,
        mass_matrix: MassMatrix | None = None,
    ) -> None:
        import qpsolvers

        if config.solver not in qpsolvers.available_solvers:
            raise ConfigError(f"QP solver '{config.solver}' is not available (have: {qpsolvers.available_solvers})")
        self.chain = chain
        self.config = config
        self.body = (body if body is not None else RobotBody.of(chain)).inflated(config.padding)
        self.q_posture = None if q_posture is None else np.asarray(q_posture, dtype=float)
        if config.pfl is not None and mass_matrix is None:
            raise ConfigError("controller: power and force limiting (pfl) needs the robot's mass_matrix")
        self.mass_matrix = mass_matrix
        self._flange = chain.T_link_flange[:3, 3]
        self._frames = FrameCache(chain)
        self._width = ramp_width(config.critical, config.notice)
        self._speeds = None if config.separation is None else _speed_table(config.separation, config.v_max, self._width)

    def problem(
        self,
        q: ArrayLike,
        x_des: ArrayLike,
        xd_des: ArrayLike,
        points: ArrayLike | ObstaclePoints,
        qd_now: ArrayLike | None = None,
        qd_prev: ArrayLike | None = None,
        *,
        _terms: bool = True,
    ) -> QpProblem:
        """Assemble the QP at joint angles ``q`` ``(n,)`` for reference ``x_des``, ``xd_des`` ``(3,)`` (m, m/s)
        and obstacle points: :class:`ObstaclePoints` (velocities, cone spread and covariances used) or
        still points ``(K, 3)`` exactly where given (base frame, m). ``qd_now`` ``(n,)``: the robot's
        measured joint velocity, rad/s, a floor for the speed in ``S_p`` (with ``separation``; default None:
        the robot moves as commanded, an ideal velocity interface). ``qd_prev`` ``(n,)``: the previous command,
        rad/s; with ``acceleration_limit`` the box bounds are narrowed to ``qd_prev +- a dt`` (:func:`drive_bounds`).
        (``_terms=False``: with ``separation``,
        ``critical`` and ``terms`` are left None; :meth:`step` computes them at the command's speed.)"""
        cfg = self.config
        q = np.asarray(q, dtype=float).reshape(-1)
        n = self.chain.n_joints
        T = self._frames.frames(q)
        x = T[n, :3, :3] @ self._flange + T[n, :3, 3]
        J = self.chain.point_jacobians(T, [n], x)[0]
        feedback = cfg.gain * (np.asarray(x_des, dtype=float) - x)
        if cfg.feedback_speed is not None:  # the way back to the reference at most at this speed
            norm = float(np.linalg.norm(feedback))
            if norm > cfg.feedback_speed:
                feedback *= cfg.feedback_speed / norm
        xd_cmd = np.asarray(xd_des, dtype=float) + feedback
        P = J.T @ J + cfg.damping * np.eye(n)
        c = -J.T @ xd_cmd
        if cfg.posture_gain > 0 and self.q_posture is not None:
            c -= cfg.damping * cfg.posture_gain * (self.q_posture - q)
        acc = cfg.acceleration_limit
        lb, ub = joint_velocity_bounds(self.chain, q, cfg.dt, cfg.velocity_scale, cfg.limit_margin, acc)
        free_box = None
        if acc is not None and qd_prev is not None:
            free_box = (lb, ub)
            lb, ub = drive_bounds(lb, ub, qd_prev, acc, cfg.dt)
        obs = points if isinstance(points, ObstaclePoints) else ObstaclePoints.still(points)
        pts = obs.positions
        if pts.shape[0]:
            cand = None
            if cfg.n_rim > 0 and np.any(obs.spread > 0):
                cand = cap_candidates(pts, obs.axes, obs.ranges, obs.spread, int(cfg.n_rim))
            terms, sep_in = None, None
            if cfg.separation is None:
                rows = obstacle_rows(self.body, T, pts, cfg.critical, cfg.notice, cfg.v_max, obs.velocities, cand)
                G_all, h_all, dist = rows.G, rows.h, rows.distance
                crit = np.full(dist.shape, cfg.critical)
            else:
                prox, G_all = obstacle_geometry(self.body, T, pts, cand)
                v_obs = np.einsum("ki,ki->k", prox.normal, obs.velocities)  # > 0: the point moves away
                var = np.einsum("ki,kij,kj->k", prox.normal, obs.cov, prox.normal)
                moving = qd_now is not None
                v_now = G_all @ np.asarray(qd_now, dtype=float).reshape(n) if moving else np.zeros(len(pts))
                sep_in = SeparationInputs(
                    G_all, v_now, -v_obs, cfg.separation.sigma_level * np.sqrt(np.maximum(var, 0.0))
                )
                if _terms:
                    terms = protective_separation(cfg.separation, sep_in.v_now, sep_in.v_h, sep_in.z_d)
                    crit = terms.total
                else:
                    terms, crit = None, None
                dist = prox.distance
                assert self._speeds is not None
                v_allowed = self._speeds(
                    dist - cfg.sp_buffer, sep_in.v_now if moving else None, sep_in.v_h, sep_in.z_d
                )  # fmt: skip
                h_all = v_allowed  # the point's own approach is in it (the velocity-aware row)
                if cfg.pfl is not None and self.mass_matrix is not None:
                    # PFL: short of touching, up to the Annex A speed at the point's effective mass
                    # (a region with no transient contact permitted, v = 0, keeps the separation row)
                    v_pfl = cfg.pfl_share * pfl_speed_limit(cfg.pfl, effective_mass(G_all, self.mass_matrix(q)))
                    pfl = (dist > 0) & (v_pfl > 0)
                    h_all = np.where(pfl, np.maximum(h_all, np.minimum(v_pfl, cfg.v_max)), h_all)
            # A row with no lever on the robot (point at the base) and a non-negative bound is void.
            keep = (np.abs(G_all).max(axis=1) > 1e-9) | (h_all < 0)
            G, h = G_all[keep], h_all[keep]
            if cfg.all_directions and cfg.separation is not None:
                G_t, h_t = _sideways_rows(self.chain, T, prox, h_all, TANGENT_SHARE * cfg.v_max)
                G, h = np.vstack([G, G_t]), np.concatenate([h, h_t])
        else:
            G, h, dist, crit, terms = np.zeros((0, n)), np.zeros(0), np.zeros(0), np.zeros(0), None
            sep_in = None
        return QpProblem(P, c, G, h, lb, ub, x, dist, crit, terms, sep_in, free_box)

    def solve(self, prob: QpProblem) -> tuple[FloatArray, bool, float, float]:
        """``(qd, feasible, violation, solve_time_s)`` of a problem; the least-violating retreat when infeasible.

        With the drive's box (``prob.free_box`` set: :func:`drive_bounds`) in two stages: the command of an ideal
        velocity interface ``qd*`` (the same QP in the box without the drive's step limit), then the command the drive
        reaches within the step nearest to it joint by joint, ``min 1/2 |qd - qd*|^2`` s.t. the obstacle rows and the
        drive's box: every joint moves toward ``qd*`` at up to its acceleration limit. Solving the tracking objective in
        the drive's box directly instead picks its corners, and the redundant arm's null-space speed, which that
        objective leaves almost free (``damping``), grew at the limits step after step: in ``hand`` on the Panda
        (torque) joints 1, 3 and 6 reached 1.3-2.2 rad/s with the flange nearly still, sweeping a link toward the
        hand at 0.25 m/s when it was first seen inside ``S_p`` (simulated). An infeasible first stage goes straight
        to the least-violating retreat in the drive's box."""
        if prob.free_box is None:
            return self._solve_qp(prob)
        free = replace(prob, lb=prob.free_box[0], ub=prob.free_box[1], free_box=None)
        ideal, feasible, _, t_ideal = self._solve_qp(free, retreat=False)
        if not feasible:
            qd, violation, t_stop = self._safe_stop(prob)
            return qd, False, violation, t_ideal + t_stop
        n = prob.P.shape[0]
        near = replace(prob, P=np.eye(n), c=-ideal, free_box=None)
        qd, feasible, violation, elapsed = self._solve_qp(near)
        return qd, feasible, violation, t_ideal + elapsed

    def _solve_qp(self, prob: QpProblem, retreat: bool = True) -> tuple[FloatArray, bool, float, float]:
        """One QP solve; infeasible: the least-violating retreat (``retreat``) or ``(nan, False, nan, t)``."""
        import qpsolvers

        G = prob.G if prob.G.shape[0] else None
        h = prob.h if prob.G.shape[0] else None
        t0 = time.perf_counter()
        qd = qpsolvers.solve_qp(prob.P, prob.c, G, h, lb=prob.lb, ub=prob.ub, solver=self.config.solver)
        elapsed = time.perf_counter() - t0
        if qd is not None and (G is None or np.max(G @ qd - h) <= _FEAS_TOL * max(1.0, np.abs(h).max())):
            return qd, True, 0.0, elapsed
        if not retreat:
            return np.full(prob.P.shape[0], np.nan), False, float("nan"), elapsed
        qd, violation, t_stop = self._safe_stop(prob)
        return qd, False, violation, elapsed + t_stop

    def _safe_stop(self, prob: QpProblem) -> tuple[FloatArray, float, float]:
        import qpsolvers

        n, K = prob.P.shape[0], prob.G.shape[0]
        P = np.diag(np.concatenate([np.full(n, _STOP_EPS), np.ones(K)]))
        G = np.hstack([prob.G, -np.eye(K)])
        lb = np.concatenate([prob.lb, np.zeros(K)])
        slack_ub = np.full(K, np.inf)
        capped = self.config.stop_never_approaches
        if capped:  # a retreat row violated at most down to a stop (or the slowest approach the box allows)
            slowest = np.minimum(prob.G * prob.lb, prob.G * prob.ub).sum(axis=1)  # min of G_i qd over the box
            slack_ub = np.maximum(np.maximum(-prob.h, 0.0), slowest - prob.h)
        ub = np.concatenate([prob.ub, slack_ub])
        t0 = time.perf_counter()
        z = qpsolvers.solve_qp(P, np.zeros(n + K), G, prob.h, lb=lb, ub=ub, solver=self.config.solver)
        if z is None and capped:  # rows that cannot all brake at once in the box: the plain least violation
            ub[n:] = np.inf
            z = qpsolvers.solve_qp(P, np.zeros(n + K), G, prob.h, lb=lb, ub=ub, solver=self.config.solver)
        elapsed = time.perf_counter() - t0
        if z is None:  # cannot happen for consistent bounds; as near standing still as the box allows
            qd = np.clip(np.zeros(n), prob.lb, prob.ub)
        else:
            qd = z[:n]
        violation = float(np.max(prob.G @ qd - prob.h, initial=0.0))
        return qd, max(violation, 0.0), elapsed

    def step(
        self,
        q: ArrayLike,
        x_des: ArrayLike,
        xd_des: ArrayLike,
        points: ArrayLike | ObstaclePoints,
        qd_now: ArrayLike | None = None,
        qd_prev: ArrayLike | None = None,
    ) -> StepResult:
        """Joint velocities for this step (see :meth:`problem`)."""
        prob = self.problem(q, x_des, xd_des, points, qd_now, qd_prev, _terms=False)
        qd, feasible, violation, elapsed = self.solve(prob)
        d_min = float(prob.distance.min()) if prob.distance.size else float("inf")
        margin, clearance = float("nan"), float("inf")
        terms, critical = prob.terms, prob.critical
        if prob.separation_inputs is not None and self.config.separation is not None:
            # S_p as the step leaves it: at the commanded speed, or the present one when larger
            s = prob.separation_inputs
            terms = protective_separation(self.config.separation, np.maximum(s.G @ qd, s.v_now), s.v_h, s.z_d)
            critical = terms.total
        inside_rows = inside_allowed = None
        if prob.distance.size and critical is not None:
            gap = prob.distance - critical
            i = int(np.argmin(gap))
            margin, clearance = float(critical[i]), float(gap[i])
            if prob.separation_inputs is not None:
                inside_rows = prob.separation_inputs.G[gap < 0]
                inside_allowed = np.zeros(inside_rows.shape[0])
                if self.config.pfl is not None and self.mass_matrix is not None and inside_rows.shape[0]:
                    m_eff = effective_mass(inside_rows, self.mass_matrix(np.asarray(q, dtype=float).reshape(-1)))
                    inside_allowed = pfl_speed_limit(self.config.pfl, m_eff)
        return StepResult(
            qd, feasible, violation, elapsed, int(prob.G.shape[0]), d_min, prob.x, margin, terms, clearance,
            inside_rows, inside_allowed,
        )  # fmt: skip
