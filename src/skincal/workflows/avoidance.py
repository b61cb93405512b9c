"""Closed loop in MuJoCo: 1 kHz control, skin sensed at 50 Hz through MuJoCo rangefinders.

Two sets of unit poses take part: the TRUE poses place the rangefinder sites in the simulated robot
(what the sensors really see); the BELIEVED poses (a calibration result, the truth, or a degraded
truth) are what perception uses to turn readings into obstacle points. The difference is what bad
calibration costs.

Per step ``k`` (``t = k dt``, ``dt = 1 ms``):

1. obstacles move (mocap bodies along their time tables);
2. units whose turn it is (each unit reads every ``1 / rate_hz`` s, phases staggered over the units)
   read their range: MuJoCo rangefinders along the ToF cone rays at the current ``q``, nearest hit
   among the obstacles (the robot's own capsule hull is hidden from the rays, see below),
   then :meth:`~skincal.skin.tof.TofModel.measure` (window, noise, rounding: the simulators' model
   and random stream); perception gets the reading with the joint state of its instant;
3. the controller solves its QP with the live filtered points and the task reference;
4. ``mode="kinematic"`` (default): the robot integrates the commanded velocity, ``q <- q + qd dt`` (an
   ideal velocity interface, as a Panda under joint-velocity control at 1 kHz); ``mode="torque"``: the
   command is tracked with joint torques by :class:`skincal.sim.dynamics.TorqueRobot` in the same MuJoCo
   model (gravity and inertia from the model, torques clipped at the effort limits); the robot speed in
   ``S_p`` is then the measured joint velocity as far as the previous command accounts for it, plus a
   tracking tolerance (:func:`skincal.control.separation.separation_speed`: a tracking transient does not
   make ``S_p`` jump).

**Retreat and resume** (``resume=True``): the reference runs on a task clock ``tau`` instead of ``t``.
While the nearest perceived point is within the protective separation ``S_p`` of the step plus
``resume_band`` (m), the clock's rate ramps down to 0 (the reference stops where it is and its
velocity feed-forward with it; the controller keeps the distance, backing away when the person keeps
coming); once free it ramps back to 1, each ramp taking ``RAMP_S``. The task time lost is then how far
the clock lags behind the run without a person (:func:`skincal.control.iso_metrics.task_time_lost`).
Without ``resume`` the reference runs on ``t`` (the legacy loop, unchanged).
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from skincal.control.effective_mass import MassMatrix
from skincal.control.iso_metrics import TERMS
from skincal.control.qp import AvoidanceController, ControllerConfig
from skincal.control.separation import separation_speed
from skincal.errors import ConfigError
from skincal.kinematics.chain import SerialChain
from skincal.kinematics.geometry import DEFAULT_LINK_RADIUS
from skincal.kinematics.transforms import FloatArray
from skincal.perception.body import RobotBody
from skincal.perception.config import PerceptionConfig
from skincal.perception.tracker import ProximityTracker
from skincal.perception.uncertainty import SkinUncertainty
from skincal.sim.mujoco_model import SensorIndex, build_model, link_body_ids, require_mujoco
from skincal.sim.scenarios import Scenario
from skincal.skin.pose import SkinUnitPose
from skincal.skin.tof import TofModel, cone_directions, get_tof_model

RAMP_S = 0.2
"""Time the task clock takes to stop or to get back to full rate, s."""
RESUME_BAND = 0.1
"""Default band beyond ``S_p`` within which the task clock pauses, m."""
MODES = ("kinematic", "torque")


@dataclass(frozen=True)
class RunLog:
    """Everything one closed-loop run recorded.

    Attributes:
        scenario: the scenario run.
        t: ``(S,)`` control instants, s.
        q: ``(S, n)`` joint angles at each instant (before the step), rad.
        qd: ``(S, n)`` commanded joint velocities, rad/s.
        x, x_des: ``(S, 3)`` flange position and reference, base frame, m.
        feasible: ``(S,)`` the QP had a solution (else the least-violating retreat was commanded).
        violation: ``(S,)`` obstacle-row violation of the command, m/s.
        n_obstacles: ``(S,)`` obstacle rows in the QP.
        min_distance: ``(S,)`` smallest perceived distance to the padded robot, m (inf: none).
        solve_time_s: ``(S,)`` QP solver time; step_time_s ``(S,)`` whole controller step (perception
            query, QP set-up and solve); loop_time_s ``(S,)`` the whole loop iteration incl. sensing.
        units: unit names (true placement order); tof_t, tof_range: ``(M, U)`` reading instants (s)
            and readings (m, NaN = none) of each unit.
        margin: ``(S,)`` the protective separation ``S_p`` of the nearest point at each step (m; the
            fixed critical distance when the controller has no separation model).
        terms: the parts of ``margin`` (``S_h, S_r, S_s, C, Z_d, Z_r``), each ``(S,)`` m, NaN where no
            point was perceived; empty without a separation model.
        task_time: ``(S,)`` the task clock, s (``t`` without resume).
        protective_stop: ``(S,)`` the controller commanded its protective (safe) stop.
        mode: ``kinematic`` or ``torque``.
        sp_inside: ``(S,)`` perceived points inside their ``S_p`` at the step (with a separation model).
        sp_excess: ``(S,)`` over those points, the largest of the robot point's ACTUAL speed toward the
            point over the step (``n_i^T J_i (q_{k+1} - q_k) / dt``) less the speed the point allows
            (:attr:`skincal.control.qp.StepResult.inside_allowed`), m/s; ``-inf`` where none is inside.
        sp_approach: ``(S,)`` the largest actual speed toward those points, m/s (``-inf``: none inside).
    """

    scenario: Scenario
    t: FloatArray
    q: FloatArray
    qd: FloatArray
    x: FloatArray
    x_des: FloatArray
    feasible: np.ndarray
    violation: FloatArray
    n_obstacles: np.ndarray
    min_distance: FloatArray
    solve_time_s: FloatArray
    step_time_s: FloatArray
    loop_time_s: FloatArray
    units: tuple[str, ...]
    tof_t: FloatArray
    tof_range: FloatArray
    margin: FloatArray | None = None
    terms: dict[str, FloatArray] = field(default_factory=dict)
    task_time: FloatArray | None = None
    protective_stop: np.ndarray | None = None
    mode: str = "kinematic"
    sp_inside: np.ndarray | None = None
    sp_excess: FloatArray | None = None
    sp_approach: FloatArray | None = None

    @property
    def tracking_error(self) -> FloatArray:
        """``(S,)`` flange position error ``|x_des - x|``, m."""
        return np.linalg.norm(self.x_des - self.x, axis=1)


def run_scenario(
    chain: SerialChain,
    scenario: Scenario,
    true_poses: Mapping[str, SkinUnitPose],
    believed_poses: Mapping[str, SkinUnitPose],
    rng: np.random.Generator,
    *,
    controller: ControllerConfig = ControllerConfig(),
    perception: PerceptionConfig = PerceptionConfig(),
    tof_model: TofModel | None = None,
    link_radius: float = DEFAULT_LINK_RADIUS,
    uncertainty: SkinUncertainty | None = None,
    resume: bool = False,
    resume_band: float = RESUME_BAND,
    mode: str = "kinematic",
    torque: object | None = None,
    mass_matrix: MassMatrix | None = None,
) -> RunLog:
    """Run ``scenario`` in closed loop (see the module docstring) and log it.

    ``believed_poses`` may lack units (their readings are then unused) but not name unknown ones.
    ``tof_model``: default the VL53L1X preset (27 deg cone of 37 rays, 5 mm + 0.5 % noise).
    ``uncertainty``: the believed poses' covariances behind each point's ``cov`` (perception's default
    when None). ``resume``: the task clock of the module docstring. ``mode``: ``kinematic`` or ``torque``
    (``torque``: a :class:`skincal.sim.dynamics.TorqueConfig`, default its defaults). ``mass_matrix``: the
    robot's joint-space inertia ``q -> M(q)`` for a controller with power and force limiting
    (``controller.pfl``; default :func:`robot_mass_matrix`).
    """
    if mode not in MODES:
        raise ConfigError(f"unknown mode '{mode}' (use {' or '.join(MODES)})")
    if not (np.isfinite(resume_band) and resume_band >= 0):
        raise ConfigError(f"resume band must be a non-negative number of m, got {resume_band}")
    mujoco = require_mujoco()
    unknown = set(believed_poses) - set(true_poses)
    if unknown:
        raise ConfigError(f"calibrated unit(s) {', '.join(sorted(unknown))} are not on the simulated robot")
    tof_model = tof_model if tof_model is not None else get_tof_model("vl53l1x")
    dt = controller.dt
    units = tuple(true_poses)
    rays = cone_directions(tof_model.fov_deg, tof_model.n_rays)
    geometry = dict(scene=scenario.scene, range_directions=rays, board_geoms=False, link_radius=link_radius)
    if mode == "kinematic":
        model = build_model(chain, true_poses, **geometry)
        model.opt.timestep = dt
    else:  # motors, published inertials and limits (the model's own timestep, a divisor of dt)
        from skincal.sim.dynamics import torque_model

        model = torque_model(chain, true_poses, **geometry)
    # Rays ignore transparent geoms: hide the robot's own capsule hull from the rangefinders (a unit
    # near a joint sits inside the neighbouring link's capsule, which the real arm does not have).
    robot_geoms = np.isin(model.geom_bodyid, link_body_ids(model, chain.n_joints))
    model.geom_rgba[robot_geoms, 3] = 0.0
    idx = SensorIndex.of(model, units, len(rays))
    S = int(round(scenario.duration / dt))
    t = dt * np.arange(S)
    n = chain.n_joints
    q = scenario.q0.astype(float).copy()
    robot, qd, qd_cmd = None, np.zeros(n), np.zeros(n)
    if mode == "torque":
        from skincal.sim.dynamics import TorqueConfig, TorqueRobot

        robot = TorqueRobot(chain, model, torque if torque is not None else TorqueConfig(), q0=q)
        data = robot.data
    else:
        data = mujoco.MjData(model)
    task = scenario.task
    if not resume:
        x_des, xd_des = task.at(t)
    else:
        x_des, xd_des = np.empty((S, 3)), np.empty((S, 3))
    mocap = scenario.scene.mocap_positions(t) if scenario.scene.obstacles else None
    period = max(1, int(round(1.0 / (tof_model.rate_hz * dt))))
    phase = (np.arange(len(units)) * period) // max(len(units), 1)
    M = S // period + 1
    tof_t = np.full((M, len(units)), np.nan)
    tof_range = np.full((M, len(units)), np.nan)
    count = np.zeros(len(units), dtype=int)

    body = RobotBody.of(chain, link_radius)
    tracker = ProximityTracker(chain, dict(believed_poses), perception, body, uncertainty)
    if controller.pfl is not None and mass_matrix is None:
        mass_matrix = robot.mass_matrix if robot is not None else robot_mass_matrix(chain)
    ctl = AvoidanceController(chain, controller, body, q_posture=scenario.q0, mass_matrix=mass_matrix)
    fixed_margin = float(controller.critical)
    margin = np.full(S, fixed_margin)
    separation = getattr(controller, "separation", None)
    separated = separation is not None
    terms = {k: np.full(S, np.nan) for k in TERMS} if separated else {}
    if separated:  # before any point is seen: S_p of a still robot and an exactly known point
        from skincal.control.separation import protective_separation

        still = float(protective_separation(separation, np.zeros(1), None, np.zeros(1)).total[0])
    task_time = t if not resume else np.zeros(S)
    lag, rate, dr = 0.0, 1.0, dt / RAMP_S  # tau = t - lag: exactly t while the clock never slowed
    log_q, log_qd, log_x = np.empty((S, n)), np.empty((S, n)), np.empty((S, 3))
    feasible = np.ones(S, dtype=bool)
    violation, min_dist = np.zeros(S), np.full(S, np.inf)
    n_obs = np.zeros(S, dtype=int)
    solve_t, step_t, loop_t = np.zeros(S), np.zeros(S), np.zeros(S)
    sp_inside = np.zeros(S, dtype=int)
    sp_excess, sp_approach = np.full(S, -np.inf), np.full(S, -np.inf)
    for k in range(S):  # the closed loop is sequential
        t0 = time.perf_counter()
        reading = np.flatnonzero((k - phase) % period == 0)
        if reading.size:
            if robot is None:
                data.qpos[:] = q
            if mocap is not None:
                data.mocap_pos[:] = mocap[k]
            mujoco.mj_fwdPosition(model, data)
            mujoco.mj_sensorPos(model, data)
            hits = data.sensordata[idx.range[reading]]  # (R, K), -1 = no hit
            nearest = np.where(hits < 0, np.inf, hits).min(axis=1)
            r = tof_model.measure(nearest, rng)
            tof_t[count[reading], reading] = t[k]
            tof_range[count[reading], reading] = r
            count[reading] += 1
            tracker.update(t[k], q, {units[u]: float(ru) for u, ru in zip(reading, r, strict=True)})
        t1 = time.perf_counter()
        pts = tracker.points(t[k])
        if resume:
            task_time[k] = t[k] - lag
            xk, vk = task.at(task_time[k])
            x_des[k], xd_des[k] = xk[0], rate * vk[0]
        if robot is None:
            res = ctl.step(q, x_des[k], xd_des[k], pts)
        else:  # S_p from the measured speed, as far as the command tracked accounts for it
            res = ctl.step(q, x_des[k], xd_des[k], pts, separation_speed(qd, qd_cmd), qd_prev=qd_cmd)
            qd_cmd = res.qd
        step_t[k] = time.perf_counter() - t1
        log_q[k], log_qd[k], log_x[k] = q, res.qd, res.x
        feasible[k], violation[k], n_obs[k] = res.feasible, res.violation, res.n_obstacles
        min_dist[k], solve_t[k] = res.min_distance, res.solve_time_s
        if separated:
            # a step without any point keeps the last margin (the person is still where it was last seen)
            m_k = float(getattr(res, "margin", np.nan))
            margin[k] = m_k if np.isfinite(m_k) else margin[k - 1] if k else still
            parts = getattr(res, "terms", None)
            if parts is not None and np.size(parts.S_h):
                i = _binding(parts, res)
                for name in TERMS:
                    terms[name][k] = float(np.asarray(getattr(parts, name)).reshape(-1)[i])
        if resume:
            near = res.min_distance < margin[k] + resume_band
            rate = max(rate - dr, 0.0) if near else min(rate + dr, 1.0)
            lag += (1.0 - rate) * dt
        q_before = q
        if robot is None:
            q = q + res.qd * dt
        else:
            robot.step(res.qd, dt)
            q, qd = robot.q, robot.qd
        rows = getattr(res, "inside_rows", None)
        if rows is not None and rows.shape[0]:  # the standard's criterion on the motion the robot made
            speed = rows @ ((q - q_before) / dt)
            sp_inside[k] = rows.shape[0]
            sp_approach[k] = float(speed.max())
            sp_excess[k] = float(np.max(speed - res.inside_allowed))
        loop_t[k] = time.perf_counter() - t0
    return RunLog(
        scenario,
        t,
        log_q,
        log_qd,
        log_x,
        x_des,
        feasible,
        violation,
        n_obs,
        min_dist,
        solve_t,
        step_t,
        loop_t,
        units,
        tof_t[: count.max()],
        tof_range[: count.max()],
        margin,
        terms,
        task_time,
        ~feasible,
        mode,
        sp_inside if separated else None,
        sp_excess if separated else None,
        sp_approach if separated else None,
    )


def robot_mass_matrix(chain: SerialChain) -> MassMatrix:
    """``q -> M(q)`` ``(n, n)``: the joint-space inertia of the torque robot's MuJoCo model (the published
    inertials of the Panda, UR5e, iiwa14 or a URDF's own, rotor armature included: what
    :class:`skincal.sim.dynamics.TorqueRobot` simulates), by ``mj_fullM``."""
    from skincal.sim.dynamics import torque_model
    from skincal.sim.mujoco_model import full_mass_matrix

    mujoco = require_mujoco()
    model = torque_model(chain)
    data = mujoco.MjData(model)
    n = chain.n_joints

    def mass_matrix(q: FloatArray) -> FloatArray:
        data.qpos[:n] = q
        mujoco.mj_fwdPosition(model, data)
        return full_mass_matrix(model, data)[:n, :n]

    return mass_matrix


def _binding(parts, res) -> int:
    """Index of the point whose terms the step's margin is: the one whose ``S_p`` is the step's margin."""
    total = np.asarray(parts.total, dtype=float).reshape(-1)
    return int(np.argmin(np.abs(total - getattr(res, "margin", total.max()))))


def simulated_skin(placement: str, chain) -> dict:
    """The true unit poses of the skin the avoidance loop simulates: ``ring`` (dense) or ``paper`` (Table II)."""
    from skincal.workflows.session import make_placements

    if placement not in ("ring", "paper"):
        raise ConfigError(f"unknown placement '{placement}' (use ring or paper)")
    return make_placements(chain, placement, None, None)


def believed_poses(true_poses: dict, result: Path | None, degrade: str | None, blind: bool, seed: int):
    """The poses the controller believes and their label: a result file's, degraded truth (``degrade``
    ``'METRES,DEGREES'``, seeded by ``seed + 1``), none (``blind``), or truth."""
    poses, label, _ = believed_skin(true_poses, result, degrade, blind, seed)
    return poses, label


def degraded_uncertainty(units, position_m: float, angle_deg: float) -> SkinUncertainty:
    """The pose covariance a ``position_m`` / ``angle_deg`` degradation (:func:`degrade_poses`: that
    length in a uniformly random direction) has: per link axis std ``position_m / sqrt(3)`` and
    ``angle_deg / sqrt(3)`` (the degraded std reported and given to perception)."""
    std = np.array([position_m / np.sqrt(3)] * 3 + [np.radians(angle_deg) / np.sqrt(3)] * 3)
    return SkinUncertainty({u: np.diag(std**2) for u in units})


def believed_skin(true_poses: dict, result: Path | None, degrade: str | None, blind: bool, seed: int):
    """``(poses, label, uncertainty)``: :func:`believed_poses` and the poses' covariances (a result's
    own, the degradation's, perception's assumed std for the truth; ``None``: perception's default)."""
    chosen = [x for x in (result is not None, degrade is not None, blind) if x]
    if len(chosen) > 1:
        raise ConfigError("give at most one of --result, --degrade, --blind (--truth is the default)")
    if blind:
        return {}, "blind (no perception)", None
    if result is not None:
        from skincal.data.result import read_result

        res = read_result(result)
        unknown = sorted(set(res.units) - set(true_poses))
        if unknown:
            raise ConfigError(
                f"result {result.name} has unit(s) {', '.join(unknown[:5])} that the simulated skin lacks "
                "(calibrate a dataset of the same --placement)"
            )
        moved = [u for u, r in res.units.items() if r.pose.link != true_poses[u].link]
        if moved:
            raise ConfigError(
                f"result {result.name} puts {', '.join(moved[:5])} on other links than the simulated skin "
                "(was it calibrated from a dataset of another --placement?)"
            )
        poses = {u: r.pose for u, r in res.units.items()}
        return poses, f"result {result.name} ({res.method})", SkinUncertainty.from_result(res)
    if degrade is not None:
        from skincal.sim.scenarios import degrade_poses

        try:
            pos, ang = (float(x) for x in degrade.split(","))
        except ValueError:
            raise ConfigError(f"--degrade must be 'METRES,DEGREES' (e.g. 0.05,5), got '{degrade}'") from None
        if not (np.isfinite(pos) and np.isfinite(ang)):
            raise ConfigError(f"--degrade must be finite 'METRES,DEGREES', got '{degrade}'")
        poses = degrade_poses(true_poses, pos, ang, np.random.default_rng(seed + 1))
        return poses, f"truth degraded {pos} m/{ang} deg", degraded_uncertainty(poses, pos, ang)
    return dict(true_poses), "truth", None
