"""Shared preprocessing of a dataset for every calibration method.

Real robots report ``q`` and ``qd`` on their own clock; IMUs sample on theirs. This module
estimates joint accelerations, interpolates the joint states to each IMU sample instant, tags
every IMU sample with its protocol segment and averages the static segments.

Frames: accelerometer samples are specific force in the unit frame (``f = R_base_su^T (a - g)``);
joint states are in rad, rad/s, rad/s^2; times in s on the dataset's common clock.

One job per module: :mod:`~skincal.calib.preprocess.conditioning` (the joint stream conditioned),
:mod:`~skincal.calib.preprocess.interpolate` (interpolated to the IMU instants),
:mod:`~skincal.calib.preprocess.samples` (a unit's samples tagged and gathered, static means),
:mod:`~skincal.calib.preprocess.screening` (readings screened, units checked); the names are re-exported here.
"""

from __future__ import annotations

from skincal.calib.preprocess.conditioning import (
    DEFAULT_QDD_WINDOW_S,
    POSITION_POLYORDER,
    condition_joint_stream,
    estimate_qdd,
    is_low_rate,
    joint_noise,
    regular_grid,
    white_noise_std,
)
from skincal.calib.preprocess.interpolate import JointInterpolator, joint_states_at
from skincal.calib.preprocess.samples import UnitSamples, static_means, tag_segments, unit_samples
from skincal.calib.preprocess.screening import check_accel_units, check_gyro_units, screen_channels, screen_readings

__all__ = [
    "DEFAULT_QDD_WINDOW_S",
    "JointInterpolator",
    "POSITION_POLYORDER",
    "UnitSamples",
    "check_accel_units",
    "check_gyro_units",
    "condition_joint_stream",
    "estimate_qdd",
    "is_low_rate",
    "joint_noise",
    "joint_states_at",
    "regular_grid",
    "screen_channels",
    "screen_readings",
    "static_means",
    "tag_segments",
    "unit_samples",
    "white_noise_std",
]
