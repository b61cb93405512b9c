"""What every simulator does the same way; a backend supplies only the physics.

:func:`simulate_units` is the one pipeline from true signals to a :class:`~skincal.data.dataset.Dataset`.
A backend (:mod:`skincal.sim.analytic`, :mod:`skincal.sim.mujoco_backend`) hands it three functions:

* ``imu_truth(u, t)``: unit ``u``'s true specific force and angular rate ``(M, 3)`` in its frame at
  physical instants ``t`` ``(M,)`` s;
* ``tof_truth(u, t)`` (with a scene): unit ``u``'s true distance to the nearest target ``(M,)`` m
  (``inf``: nothing in view) at instants ``t``;
* ``joint_motion(t)``: the robot's true ``q, qd, qdd`` ``(M, n)`` at instants ``t``.

Per unit ``k`` (in placement order), all from its own child ``rng_k`` of ``rng``:

1. constant IMU errors (:func:`~skincal.skin.imu.draw_imu_errors`), perfect-clock stamps
   (:func:`~skincal.skin.imu.sample_instants`) and physical instants ``t_true = t_stamp - latency``,
   kept within the trajectory;
2. ``imu_truth`` at ``t_true`` through :func:`~skincal.skin.imu.apply_imu_model`;
3. with a scene: ToF instants (:func:`tof_instants`), ``tof_truth`` there, read through
   :meth:`~skincal.skin.tof.TofModel.measure`;
4. the unit's clock (:func:`unit_clock_stamps`, from a child of ``rng_k``) stamps the IMU samples;
   the drawn errors and clock are the unit's truth record (:func:`sensor_truth`).

Then the joint stream: :func:`~skincal.sim.joint_states.apply_joint_state_model` of ``joint_motion``
from a child of ``rng`` spawned after the units'.

Random streams (the contract of "same seed, same dataset, draw for draw" across backends): the
order above; every draw of a unit comes from its own generator, so a backend may evaluate its
physics in any order, and the IMU streams of a seed do not change with the joint model.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

from skincal.data.dataset import Dataset, ImuStream, TofStream
from skincal.errors import ConfigError
from skincal.kinematics.chain import SerialChain
from skincal.kinematics.transforms import FloatArray
from skincal.protocol import Trajectory
from skincal.sim.joint_states import JointStateModel, apply_joint_state_model
from skincal.skin.clock import ClockModel, UnitClock, draw_clock, stamp_samples
from skincal.skin.imu import ImuErrors, ImuModel, apply_imu_model, draw_imu_errors, sample_instants, true_sample_times
from skincal.skin.pose import SkinUnitPose
from skincal.skin.tof import TofModel

ImuTruth = Callable[[int, FloatArray], tuple[FloatArray, FloatArray]]
"""``imu_truth(u, t) -> (f_su, w_su)``: unit ``u``'s true specific force (m/s^2) and rate (rad/s), ``(M, 3)``."""
TofTruth = Callable[[int, FloatArray], FloatArray]
"""``tof_truth(u, t) -> (M,)``: unit ``u``'s true nearest-target distance, m (``inf``: none)."""
JointMotion = Callable[[FloatArray], tuple[FloatArray, FloatArray, FloatArray]]
"""``joint_motion(t) -> (q, qd, qdd)``: the robot's true motion, ``(M, n)`` each."""


def check_session(who: str, chain: SerialChain, placements: Mapping[str, SkinUnitPose], trajectory: Trajectory) -> None:
    """The inputs every simulator refuses the same way (:class:`ConfigError` naming ``who``)."""
    if not placements:
        raise ConfigError(f"{who}: no skin units to simulate")
    for pose in placements.values():
        chain.check_link(pose.link)
    if trajectory.n_joints != chain.n_joints:
        raise ConfigError(f"trajectory has {trajectory.n_joints} joints, robot '{chain.name}' has {chain.n_joints}")


def tof_model_or_default(tof_model: TofModel | None) -> TofModel:
    """The ToF model of a simulation: the given one, else :class:`~skincal.skin.tof.TofModel` defaults."""
    return tof_model if tof_model is not None else TofModel()


def simulate_units(
    chain: SerialChain,
    placements: Mapping[str, SkinUnitPose],
    trajectory: Trajectory,
    imu_model: ImuModel,
    rng: np.random.Generator,
    *,
    imu_truth: ImuTruth,
    joint_motion: JointMotion,
    tof_truth: TofTruth | None = None,
    tof_model: TofModel | None = None,
    gravity: FloatArray,
    description: str = "",
    joint_model: JointStateModel | None = None,
    clock_model: ClockModel | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> Dataset:
    """The dataset of a session from a backend's true signals (see the module docstring).

    Args:
        chain, placements, trajectory, imu_model, rng: the session (units in ``placements`` order).
        imu_truth, joint_motion, tof_truth: the backend's physics; no ToF streams without ``tof_truth``.
        tof_model: the ToF sensor type (default :class:`~skincal.skin.tof.TofModel`).
        gravity: ``(3,)`` base-frame gravity stored in the dataset, m/s^2.
        description, joint_model, clock_model: as :func:`skincal.sim.analytic.simulate`.
        progress: called as ``progress(done, total)`` after each unit.
    """
    t0, t1 = float(trajectory.t[0]), float(trajectory.t[-1])
    tof_model = tof_model_or_default(tof_model)
    imu: dict[str, ImuStream] = {}
    tof: dict[str, TofStream] = {}
    truth_sensor: dict[str, dict[str, Any]] = {}
    for u, (name, unit_rng) in enumerate(zip(placements, rng.spawn(len(placements)), strict=True)):
        errors = draw_imu_errors(imu_model, unit_rng)
        t_stamp = sample_instants(imu_model, t0 + errors.latency_s, t1 + min(errors.latency_s, 0.0), unit_rng)
        t_true = true_sample_times(t_stamp, errors)
        inside = (t_true >= t0) & (t_true <= t1)
        t_stamp, t_true = t_stamp[inside], t_true[inside]
        f_su, w_su = imu_truth(u, t_true)
        accel, gyro = apply_imu_model(imu_model, errors, f_su, w_su, unit_rng)
        if tof_truth is not None:
            t_tof = tof_instants(t0, t1, tof_model.rate_hz, unit_rng)
            tof[name] = TofStream(t=t_tof, range=tof_model.measure(tof_truth(u, t_tof), unit_rng))
        clock, t_stamp, keep = unit_clock_stamps(clock_model, unit_rng, t_stamp, t_true, t0)
        imu[name] = ImuStream(t=t_stamp, accel=accel[keep], gyro=gyro[keep])
        truth_sensor[name] = sensor_truth(errors, clock, t0)
        if progress is not None:
            progress(u + 1, len(placements))
    joints = apply_joint_state_model(joint_model or JointStateModel(), joint_motion, trajectory.t, rng.spawn(1)[0])
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
    ``t_nominal``: ``(clock, t_stamp (K,), keep (M,) bool)`` (:func:`skincal.skin.clock.stamp_samples`).
    A clock with gaps draws them over ``[t0, max(t_true)]``."""
    model = clock_model or ClockModel()
    clock_rng = unit_rng.spawn(1)[0]
    duration = float(np.max(t_true)) - t0 if np.size(t_true) else 0.0
    clock = draw_clock(model, clock_rng, duration)
    t_stamp, keep = stamp_samples(model, clock, t_nominal, t_true, t0, clock_rng)
    return clock, t_stamp, keep


def sensor_truth(
    errors: ImuErrors, clock: UnitClock | None = None, session_t0: float = 0.0
) -> dict[str, np.ndarray | float]:
    """The ``Dataset.truth_sensor`` entry of one unit's drawn IMU errors and clock.

    ``time_offset_s`` = latency + clock offset + the host's mean reception delay (the stamp error
    right after a re-sync, or at the session start of a free-running clock, before any gap's step);
    ``clock_drift_ppm``; ``clock_resync_period_s`` only when the clock is re-synced (a dataset
    attribute must be finite); only when the clock has gaps, ``clock_gap_start_s`` and
    ``clock_gap_end_s`` ``(G,)`` (physical instants, s) and ``clock_step_s`` ``(G,)`` (the stamp
    error changes by ``clock_step_s[j]`` from ``clock_gap_end_s[j]`` on), and only with host
    reception stamps ``clock_host_delay_mean_s``.
    """
    clock = clock or UnitClock()
    truth: dict[str, np.ndarray | float] = {
        "accel_bias": errors.accel_bias,
        "accel_scale": errors.accel_scale,
        "accel_misalignment": errors.accel_misalignment,
        "gyro_bias": errors.gyro_bias,
        "time_offset_s": float(errors.latency_s) + clock.offset_s + clock.delay_mean_s,
        "clock_drift_ppm": clock.drift_ppm,
    }
    if np.isfinite(clock.resync_period_s):
        truth["clock_resync_period_s"] = clock.resync_period_s
    if clock.gaps.size:
        t0 = session_t0
        truth["clock_gap_start_s"] = t0 + clock.gaps[:, 0]
        truth["clock_gap_end_s"] = t0 + clock.gaps[:, 0] + clock.gaps[:, 1]
        truth["clock_step_s"] = np.array(clock.gaps[:, 2])
    if clock.delay_mean_s:
        truth["clock_host_delay_mean_s"] = clock.delay_mean_s
    truth.update(errors.gyro_truth())
    return truth


def tof_instants(t0: float, t1: float, rate_hz: float, rng: np.random.Generator) -> np.ndarray:
    """A ToF sensor's sample instants over ``[t0, t1]``: its rate with a random phase, s."""
    phase = rng.uniform(0.0, 1.0 / rate_hz)
    return t0 + phase + np.arange(int(np.floor((t1 - t0 - phase) * rate_hz)) + 1) / rate_hz
