"""MuJoCo simulator: the same :class:`~skincal.data.dataset.Dataset` as :func:`skincal.sim.analytic.simulate`,
with the sensor physics from an independent engine.

The sensor models, clocks, joint stream and dataset are :func:`skincal.sim.common.simulate_units`,
shared with the analytic simulator (so one seed gives the same stamps, errors and noise in both,
draw for draw); this module supplies the true signals: the specific force ``f = R_base_su^T (a - g)``
and rate ``R_base_su^T w`` from MuJoCo's ``accelerometer`` and ``gyro`` at the unit's site, the
nearest ToF target from MuJoCo's rangefinders, and the joint motion of the mode below.

Modes:

* ``"kinematic"`` (default): at each instant the state is imposed, ``(q, qd, qdd) =
  trajectory.evaluate(t)``, and ``mj_inverse`` evaluates the sensors with that ``qacc`` (unlike
  ``mj_forward``, which would overwrite ``qacc`` with the free-motion acceleration). The true
  joint motion is the trajectory's (``ideal`` joint model: its own samples).
* ``"dynamic"``: the robot is simulated at 1 kHz (semi-implicit Euler) under gravity with one
  velocity servo per joint, ``tau = kv (u - qd)``, commanded ``u = qd_ref(t) + kp (q_ref(t) - q)``,
  and, like the real robot's controller, gravity compensation. The true joint motion is the state
  the robot actually reached (``q``, ``qd`` and the acceleration undergone over each step as
  ``qdd``) linearly interpolated between the 1 kHz steps (``ideal`` joint model: at the
  trajectory's sample times); IMU readings are linearly interpolated between the 1 kHz steps,
  range readings take the latest step (zero-order hold). The tracking error is what a real
  controller adds to the data.

Time-of-flight: with a :class:`~skincal.sim.scene.Scene`, each unit gets a ToF stream at
``tof_model.rate_hz``, measured by MuJoCo rangefinders (one per ToF cone ray) against the obstacles
(mocap bodies following their time tables) and the robot's own other links.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from skincal.data.dataset import Dataset
from skincal.data.interp import hold_rows, interp_rows
from skincal.errors import ConfigError
from skincal.kinematics.chain import GRAVITY_BASE, SerialChain
from skincal.kinematics.transforms import FloatArray
from skincal.protocol import Trajectory
from skincal.sim.common import check_session, simulate_units, tof_model_or_default
from skincal.sim.joint_states import JointStateModel
from skincal.sim.mujoco_model import SensorIndex, build_model, require_mujoco
from skincal.sim.scene import Scene
from skincal.skin.clock import ClockModel
from skincal.skin.imu import ImuModel
from skincal.skin.pose import SkinUnitPose
from skincal.skin.tof import TofModel, cone_directions

MODES = ("kinematic", "dynamic")

SERVO_TIME_CONSTANT = 0.01
"""Velocity-servo time constant, s: ``kv_j = M_jj(q0) / tau`` (100 rad/s bandwidth at 1 kHz)."""

POSITION_GAIN = 20.0
"""Outer position-loop gain ``kp`` of the dynamic mode's velocity command, 1/s."""


@dataclass(frozen=True)
class SensorTrace:
    """Sensor readings of every unit at instants ``t`` ``(M,)`` s: ``accel``/``gyro`` ``(M, U, 3)``
    (SU frame, m/s^2 and rad/s), ``range`` ``(M, U, K)`` m per ToF ray (NaN = nothing hit)."""

    t: FloatArray
    accel: FloatArray
    gyro: FloatArray
    range: FloatArray


def _read(data: Any, idx: SensorIndex) -> tuple[FloatArray, FloatArray, FloatArray]:
    s = data.sensordata
    return s[idx.accel], s[idx.gyro], s[idx.range]


def _empty_trace(t: FloatArray, idx: SensorIndex) -> SensorTrace:
    U, K = idx.range.shape
    M = t.size
    return SensorTrace(t, np.empty((M, U, 3)), np.empty((M, U, 3)), np.empty((M, U, K)))


def _no_hit_to_nan(trace: SensorTrace) -> SensorTrace:
    trace.range[trace.range < 0] = np.nan
    return trace


def kinematic_playback(
    model: Any, idx: SensorIndex, trajectory: Trajectory, t: FloatArray, scene: Scene | None = None
) -> SensorTrace:
    """Sensors at instants ``t`` ``(M,)`` s with ``q, qd, qdd = trajectory.evaluate(t)`` imposed (``mj_inverse``)."""
    mujoco = require_mujoco()
    t = np.asarray(t, dtype=float)
    q, qd, qdd = trajectory.evaluate(t)
    mocap = scene.mocap_positions(t) if scene is not None and scene.obstacles else None
    data = mujoco.MjData(model)
    out = _empty_trace(t, idx)
    for m in range(t.size):  # MuJoCo evaluates one state per call
        data.qpos[:], data.qvel[:], data.qacc[:] = q[m], qd[m], qdd[m]
        if mocap is not None:
            data.mocap_pos[:] = mocap[m]
        mujoco.mj_inverse(model, data)
        out.accel[m], out.gyro[m], out.range[m] = _read(data, idx)
    return _no_hit_to_nan(out)


@dataclass(frozen=True)
class ServoRun:
    """A dynamic run on the 1 kHz grid ``t`` ``(S,)``: actual ``q``, ``qd``, ``qdd`` ``(S, n)``,
    the reference ``q_ref``, ``qd_ref`` ``(S, n)`` and the sensors (MuJoCo's, at each step's state)."""

    t: FloatArray
    q: FloatArray
    qd: FloatArray
    qdd: FloatArray
    q_ref: FloatArray
    qd_ref: FloatArray
    sensors: SensorTrace


def servo_gains(model: Any, q0: FloatArray, time_constant: float = SERVO_TIME_CONSTANT) -> FloatArray:
    """Velocity gains ``kv_j = M_jj(q0) / time_constant`` (N m s/rad) from MuJoCo's mass matrix at ``q0``."""
    mujoco = require_mujoco()
    data = mujoco.MjData(model)
    data.qpos[:] = q0
    mujoco.mj_forward(model, data)
    M = np.zeros((model.nv, model.nv))
    try:
        mujoco.mj_fullM(model, data, M)  # MuJoCo >= 3.3
    except TypeError:  # pragma: no cover - older signature (m, dst, qM)
        mujoco.mj_fullM(model, M, data.qM)
    return np.diag(M) / time_constant


def servo_run(
    model: Any,
    idx: SensorIndex,
    trajectory: Trajectory,
    t_end: float,
    scene: Scene | None = None,
    position_gain: float = POSITION_GAIN,
) -> ServoRun:
    """Simulate the velocity-servoed robot from ``trajectory``'s start state to ``t_end`` s.

    ``model`` must have one velocity actuator per joint (``build_model(..., velocity_gain=...)``).
    Each step records the state, then ``mj_step`` integrates it by ``model.opt.timestep``; the
    acceleration actually undergone over the step, ``(qvel_{k+1} - qvel_k) / dt``, is recorded and
    the sensors are read at the recorded state with it imposed (``mj_inverse``).
    """
    mujoco = require_mujoco()
    n = model.nq
    if model.nu != n:
        raise ConfigError(f"servo_run needs {n} velocity actuators in the model, found {model.nu}")
    dt = float(model.opt.timestep)
    t0 = float(trajectory.knots[0])
    t = t0 + dt * np.arange(int(np.floor((t_end - t0) / dt + 1e-9)) + 1)
    q_ref, qd_ref, _ = trajectory.evaluate(t)
    mocap = scene.mocap_positions(t) if scene is not None and scene.obstacles else None
    data = mujoco.MjData(model)
    data.qpos[:], data.qvel[:] = q_ref[0], qd_ref[0]
    S = t.size
    q, qd, qdd = np.empty((S, n)), np.empty((S, n)), np.empty((S, n))
    sensors = _empty_trace(t, idx)
    probe = mujoco.MjData(model)
    for k in range(S):  # the physics is sequential
        q[k], qd[k] = data.qpos, data.qvel
        data.ctrl[:] = qd_ref[k] + position_gain * (q_ref[k] - data.qpos)
        if mocap is not None:
            data.mocap_pos[:] = mocap[k]
            probe.mocap_pos[:] = mocap[k]
        mujoco.mj_step(model, data)
        # The acceleration the robot actually undergoes over the step. With the implicit(fast)
        # integrator the actuators' velocity gains are integrated implicitly, so data.qacc (and
        # the accelerometers MuJoCo computes from it) differs from (qvel_{k+1} - qvel_k) / dt;
        # the sensors are therefore read at the recorded state with this acceleration imposed.
        qdd[k] = (data.qvel - qd[k]) / dt
        probe.qpos[:], probe.qvel[:], probe.qacc[:] = q[k], qd[k], qdd[k]
        mujoco.mj_inverse(model, probe)
        sensors.accel[k], sensors.gyro[k], sensors.range[k] = _read(probe, idx)
    return ServoRun(t, q, qd, qdd, q_ref, qd_ref, _no_hit_to_nan(sensors))


def simulate_mujoco(
    chain: SerialChain,
    placements: Mapping[str, SkinUnitPose],
    trajectory: Trajectory,
    imu_model: ImuModel,
    rng: np.random.Generator,
    *,
    mode: str = "kinematic",
    scene: Scene | None = None,
    tof_model: TofModel | None = None,
    gravity: FloatArray = GRAVITY_BASE,
    description: str = "",
    position_gain: float = POSITION_GAIN,
    model_options: Mapping[str, Any] | None = None,
    joint_model: JointStateModel | None = None,
    clock_model: ClockModel | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> Dataset:
    """Simulate a calibration session with MuJoCo (see the module docstring).

    Args:
        chain, placements, trajectory, imu_model, rng: as :func:`skincal.sim.analytic.simulate`.
        mode: ``"kinematic"`` (imposed motion) or ``"dynamic"`` (velocity servos under gravity).
        scene: obstacles; when given, every unit also gets a ToF stream.
        tof_model: :class:`skincal.skin.tof.TofModel` (default: VL53L1X defaults).
        gravity: ``(3,)`` base-frame gravity, m/s^2.
        description: stored in the dataset.
        position_gain: ``kp`` of the dynamic mode's velocity command, 1/s.
        model_options: extra keyword arguments of :func:`build_model` (e.g. ``link_radius``).
        joint_model: how the robot reports its joint states (default: ``ideal``).
        clock_model: the units' clock type (default: ``ideal``).
        progress: called as ``progress(done, total)`` after each unit's sensor model.
    """
    if mode not in MODES:
        raise ConfigError(f"simulate_mujoco: mode must be one of {', '.join(MODES)}, got '{mode}'")
    check_session("simulate_mujoco", chain, placements, trajectory)
    gravity = np.asarray(gravity, dtype=float)
    directions = None
    if scene is not None:
        tof_model = tof_model_or_default(tof_model)
        directions = cone_directions(tof_model.fov_deg, tof_model.n_rays)
    options = dict(model_options or {})
    units = list(placements)
    t0, t1 = float(trajectory.t[0]), float(trajectory.t[-1])

    kv = None
    if mode == "dynamic":
        probe = build_model(chain, placements, scene=scene, gravity=gravity, range_directions=directions, **options)
        kv = servo_gains(probe, trajectory.evaluate([t0])[0][0])
    model = build_model(
        chain,
        placements,
        scene=scene,
        gravity=gravity,
        range_directions=directions,
        velocity_gain=kv,
        gravity_compensation=mode == "dynamic",
        **options,
    )
    idx = SensorIndex.of(model, units, None if directions is None else len(directions))

    run = None
    if mode == "kinematic":
        motion = trajectory.evaluate
    else:
        run = servo_run(model, idx, trajectory, t1, scene, position_gain)

        def motion(t: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
            return interp_rows(t, run.t, run.q), interp_rows(t, run.t, run.qd), interp_rows(t, run.t, run.qdd)

    def imu_truth(u: int, t: FloatArray) -> tuple[FloatArray, FloatArray]:
        if run is None:
            trace = kinematic_playback(model, idx, trajectory, t, scene)
            return trace.accel[:, u], trace.gyro[:, u]
        return interp_rows(t, run.t, run.sensors.accel[:, u]), interp_rows(t, run.t, run.sensors.gyro[:, u])

    def tof_truth(u: int, t: FloatArray) -> FloatArray:
        if run is None:
            rays = kinematic_playback(model, idx, trajectory, t, scene).range[:, u]
        else:
            rays = hold_rows(t, run.t, run.sensors.range[:, u])
        return np.where(np.isnan(rays), np.inf, rays).min(axis=1)  # (M, K) per ray, NaN = hit nothing

    return simulate_units(
        chain, placements, trajectory, imu_model, rng, imu_truth=imu_truth, joint_motion=motion,
        tof_truth=None if scene is None else tof_truth, tof_model=tof_model, gravity=gravity,
        description=description, joint_model=joint_model, clock_model=clock_model, progress=progress,
    )  # fmt: skip
