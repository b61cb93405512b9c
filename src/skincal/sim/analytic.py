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

Steps 1, 3 (the sensor models), 4 and the joint stream are :func:`skincal.sim.common.simulate_units`,
shared with the MuJoCo simulator; this module supplies the exact kinematics (:func:`unit_kinematics`)
and the closed-form ToF cast (:func:`skincal.skin.tof.nearest_in_cone`).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence

import numpy as np

from skincal.data.dataset import Dataset
from skincal.kinematics.chain import GRAVITY_BASE, SerialChain
from skincal.protocol import Trajectory
from skincal.sim.common import check_session, simulate_units, tof_model_or_default
from skincal.sim.joint_states import JointStateModel
from skincal.skin.clock import ClockModel
from skincal.skin.imu import ImuModel, angular_rate, specific_force
from skincal.skin.pose import SkinUnitPose
from skincal.skin.tof import TofModel, nearest_in_cone


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
    tof_model: TofModel | None = None,
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
    check_session("simulate", chain, placements, trajectory)
    gravity = np.asarray(gravity, dtype=float)
    poses = list(placements.values())
    tof_model = tof_model_or_default(tof_model)

    def imu_truth(u: int, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        f_su, w_su, _, _ = unit_kinematics(chain, poses[u], trajectory, t, gravity)
        return f_su, w_su

    def tof_truth(u: int, t: np.ndarray) -> np.ndarray:
        _, _, x_base, R_base_su = unit_kinematics(chain, poses[u], trajectory, t)
        return nearest_in_cone(x_base, R_base_su, scene, tof_model)

    return simulate_units(
        chain, placements, trajectory, imu_model, rng, imu_truth=imu_truth, joint_motion=trajectory.evaluate,
        tof_truth=None if scene is None else tof_truth, tof_model=tof_model, gravity=gravity,
        description=description, joint_model=joint_model, clock_model=clock_model, progress=progress,
    )  # fmt: skip
