"""A cheap stand-in dataset for exercising the UDP path (emulator tests, benchmark): not physics.

Use :mod:`skincal.sim` for physically consistent data; here only shapes, rates and plausible
magnitudes matter.
"""

from __future__ import annotations

import numpy as np

from skincal.data.dataset import Dataset, ImuStream, JointStates, TofStream
from skincal.kinematics.chain import GRAVITY_BASE
from skincal.kinematics.presets import get_robot


def traffic_dataset(
    n_units: int,
    duration_s: float,
    rng: np.random.Generator,
    *,
    imu_hz: float = 100.0,
    tof_hz: float = 50.0,
    joint_hz: float = 100.0,
    robot: str = "panda",
) -> Dataset:
    """``n_units`` units ``su1..suN`` with IMU at ``imu_hz`` (accel ~ 9.81 m/s^2 along a random
    direction plus noise, gyro noise) and ToF at ``tof_hz`` (``tof_hz = 0``: none; ranges in
    0.05..2 m, 10 % NaN), joints at ``joint_hz`` (slow sinusoids), each stream with its own phase."""
    chain = get_robot(robot)
    n_j = chain.n_joints
    t_j = np.arange(0.0, duration_s, 1.0 / joint_hz)
    w = rng.uniform(0.2, 1.0, n_j)
    q = 0.3 * np.sin(np.outer(t_j, w))
    joints = JointStates(t_j, q, 0.3 * w * np.cos(np.outer(t_j, w)))
    imu, tof = {}, {}
    for k in range(1, n_units + 1):
        t = np.arange(rng.uniform(0, 1.0 / imu_hz), duration_s, 1.0 / imu_hz)
        up = rng.normal(size=3)
        up *= -GRAVITY_BASE[2] / np.linalg.norm(up)
        imu[f"su{k}"] = ImuStream(t, up + rng.normal(0, 0.02, (t.size, 3)), rng.normal(0, 0.01, (t.size, 3)))
        if tof_hz > 0:
            t_r = np.arange(rng.uniform(0, 1.0 / tof_hz), duration_s, 1.0 / tof_hz)
            r = rng.uniform(0.05, 2.0, t_r.size)
            r[rng.random(t_r.size) < 0.1] = np.nan
            tof[f"su{k}"] = TofStream(t_r, r)
    return Dataset(robot=chain, joints=joints, imu=imu, tof=tof, description="synthetic UDP traffic")
