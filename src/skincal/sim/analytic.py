"""The analytic simulator: exact kinematics, each sensor on its own clock, sensor model on top.

For every unit ``k`` on link ``n`` with pose ``T_link_su = (R, p)``:

1. the IMU samples at its own instants (rate, random phase, jitter, drops):
   ``t_true = t_nominal - latency`` with ``t_nominal`` its stamps on a perfect clock;
2. the motion is evaluated exactly there: ``q, qd, qdd = trajectory.evaluate(t_true)``; the unit's
   acceleration ``a_base`` and the link's angular velocity ``w_base`` come from
   :meth:`SerialChain.link_motion`; ``R_base_su = R_base_link(q) R``;
3. the true specific force ``f = R_base_su^T (a_base - g_base)`` and rate ``w = R_base_su^T w_base``
   go through :func:`skincal.skin.imu.apply_imu_model` (scale, misalignment, bias, noise,
   quantisation, saturation);
4. the unit's own clock (:mod:`skincal.skin.clock`, drawn once per unit) stamps the samples:
   ``t_stamp = t_nominal + tau(t_true) + jitter``, quantised; with the ``ideal`` clock
   ``t_stamp = t_nominal``.

The robot stream is the true motion as the robot reports it
(:func:`skincal.sim.joint_states.apply_joint_state_model`); the ``ideal`` joint model gives the
trajectory at its own rate (1 kHz by default) with exact ``q, qd, qdd``. Time-of-flight streams
are simulated when a scene is given (on the true time base).

Random streams: each unit draws its IMU errors, instants, noise (and ToF) from its own child of
``rng``, then its clock from a child of that; the joint stream draws from another child of ``rng``
spawned after the units'. So the IMU streams of a seed do not change with the joint model, and
with the ``ideal`` clock they are those of the simulator before clock models, bit for bit.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence

import numpy as np

from skincal.data.dataset import Dataset, ImuStream, TofStream
from skincal.errors import ConfigError
from skincal.kinematics.chain import GRAVITY_BASE, SerialChain
from skincal.protocol import Trajectory
from skincal.sim.joint_states import JointStateModel, apply_joint_state_model
from skincal.skin.clock import ClockModel, UnitClock, draw_clock, stamp_samples
from skincal.skin.imu import (
    ImuErrors,
    ImuModel,
    angular_rate,
    apply_imu_model,
    draw_imu_errors,
    sample_instants,
    specific_force,
    true_sample_times,
)
from skincal.skin.pose import SkinUnitPose


def unit_kinematics(
    chain: SerialChain, pose: SkinUnitPose, trajectory: Trajectory, t: np.ndarray, gravity: np.ndarray = GRAVITY_BASE
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """True specific force ``(M, 3)`` and angular rate ``(M, 3)`` in the unit frame at instants ``t``,
    with the unit's base-frame position ``(M, 3)`` and orientation ``R_base_su`` ``(M, 3, 3)``."""
    q, qd, qdd = trajectory.evaluate(t)
    motion = chain.link_motion(q, qd, qdd, upto=pose.link)
    x_base, _, a_base = motion.point(pose.link, pose.p_link_su)
    R_base_su = motion.T_base_link[:, pose.link, :3, :3] @ pose.R_link_su
    f_su = specific_force(a_base, R_base_su, gravity)
    w_su = angular_rate(motion.omega[:, pose.link], R_base_su)
    return f_su, w_su, x_base, R_base_su


def simulate(
    chain: SerialChain,
    placements: Mapping[str, SkinUnitPose],
    trajectory: Trajectory,
    imu_model: ImuModel,
    rng: np.random.Generator,
    *,
    tof_model=None,
    scene: Sequence | None = None,
    gravity: np.ndarray = GRAVITY_BASE,
    description: str = "",
    joint_model: JointStateModel | None = None,
    clock_model: ClockModel | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> Dataset:
    """Simulate a calibration session (see module docstring).

    Args:
        chain: the robot.
        placements: true unit poses by name.
        trajectory: the protocol motion (:func:`skincal.protocol.build_trajectory`).
        imu_model: sensor model (:func:`skincal.skin.imu.get_imu_model`).
        rng: random generator; each unit draws from its own child generator.
        tof_model, scene: time-of-flight model and obstacle primitives (base frame); when a scene
            is given, each unit also gets a ToF stream at ``tof_model.rate_hz``.
        gravity: ``(3,)`` base-frame gravity, m/s^2.
        description: stored in the dataset.
        joint_model: how the robot reports its joint states (default: ``ideal``).
        clock_model: the units' clock type (default: ``ideal``).
        progress: called as ``progress(done, total)`` after each unit.
    """
    if not placements:
        raise ConfigError("simulate: no skin units to simulate")
    for pose in placements.values():
        chain.check_link(pose.link)
    gravity = np.asarray(gravity, dtype=float)
    t0, t1 = float(trajectory.t[0]), float(trajectory.t[-1])
    imu: dict[str, ImuStream] = {}
    tof: dict[str, TofStream] = {}
    truth_sensor: dict[str, dict[str, np.ndarray | float]] = {}
    for (name, pose), unit_rng in zip(placements.items(), rng.spawn(len(placements)), strict=True):
        errors = draw_imu_errors(imu_model, unit_rng)
        t_stamp = sample_instants(imu_model, t0 + errors.latency_s, t1 + min(errors.latency_s, 0.0), unit_rng)
        t_true = true_sample_times(t_stamp, errors)
        inside = (t_true >= t0) & (t_true <= t1)
        t_stamp, t_true = t_stamp[inside], t_true[inside]
        f_su, w_su, _, _ = unit_kinematics(chain, pose, trajectory, t_true, gravity)
        accel, gyro = apply_imu_model(imu_model, errors, f_su, w_su, unit_rng)
        if scene is not None:
            tof[name] = _simulate_tof(chain, pose, trajectory, tof_model, scene, unit_rng, t0, t1)
        clock, t_stamp, keep = unit_clock_stamps(clock_model, unit_rng, t_stamp, t_true, t0)
        imu[name] = ImuStream(t=t_stamp, accel=accel[keep], gyro=gyro[keep])
        truth_sensor[name] = sensor_truth(errors, clock)
        if progress is not None:
            progress(len(imu), len(placements))
    joints = apply_joint_state_model(
        joint_model or JointStateModel(), trajectory.evaluate, trajectory.t, rng.spawn(1)[0]
    )
    return Dataset(
        robot=chain,
        joints=joints,
        imu=imu,
        tof=tof,
        segments=trajectory.segments,
        truth=dict(placements),
        truth_sensor=truth_sensor,
        gravity=gravity,
        description=description,
    )


def unit_clock_stamps(
    clock_model: ClockModel | None,
    unit_rng: np.random.Generator,
    t_nominal: np.ndarray,
    t_true: np.ndarray,
    t0: float,
) -> tuple[UnitClock, np.ndarray, np.ndarray]:
    """One unit's clock, drawn from a child of ``unit_rng`` (so the unit's other draws are untouched),
    and its stamps of samples at physical instants ``t_true`` ``(M,)`` s with perfect-clock stamps
    ``t_nominal``: ``(clock, t_stamp (K,), keep (M,) bool)`` (:func:`skincal.skin.clock.stamp_samples`)."""
    model = clock_model or ClockModel()
    clock_rng = unit_rng.spawn(1)[0]
    clock = draw_clock(model, clock_rng)
    t_stamp, keep = stamp_samples(model, clock, t_nominal, t_true, t0, clock_rng)
    return clock, t_stamp, keep


def sensor_truth(errors: ImuErrors, clock: UnitClock | None = None) -> dict[str, np.ndarray | float]:
    """The ``Dataset.truth_sensor`` entry of one unit's drawn IMU errors and clock.

    ``time_offset_s`` = latency + clock offset (the stamp error right after a re-sync, or at the
    session start of a free-running clock); ``clock_drift_ppm``; ``clock_resync_period_s`` only
    when the clock is re-synced (a dataset attribute must be finite).
    """
    clock = clock or UnitClock()
    truth: dict[str, np.ndarray | float] = {
        "accel_bias": errors.accel_bias,
        "accel_scale": errors.accel_scale,
        "accel_misalignment": errors.accel_misalignment,
        "gyro_bias": errors.gyro_bias,
        "time_offset_s": float(errors.latency_s) + clock.offset_s,
        "clock_drift_ppm": clock.drift_ppm,
    }
    if np.isfinite(clock.resync_period_s):
        truth["clock_resync_period_s"] = clock.resync_period_s
    return truth


def tof_instants(t0: float, t1: float, rate_hz: float, rng: np.random.Generator) -> np.ndarray:
    """A ToF sensor's sample instants over ``[t0, t1]``: its rate with a random phase, s."""
    phase = rng.uniform(0.0, 1.0 / rate_hz)
    return t0 + phase + np.arange(int(np.floor((t1 - t0 - phase) * rate_hz)) + 1) / rate_hz


def _simulate_tof(chain, pose, trajectory, tof_model, scene, rng, t0: float, t1: float) -> TofStream:
    from skincal.skin.tof import TofModel, tof_range

    model = tof_model if tof_model is not None else TofModel()
    t = tof_instants(t0, t1, model.rate_hz, rng)
    _, _, x_base, R_base_su = unit_kinematics(chain, pose, trajectory, t)
    return TofStream(t=t, range=tof_range(x_base, R_base_su, scene, model, rng))
