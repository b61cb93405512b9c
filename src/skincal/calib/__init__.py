"""Calibration of skin-unit poses behind one door: ``calibrate(dataset, method=...)``.

Methods (registered in :data:`METHODS`, one module each in :mod:`skincal.calib.methods`): ``mle``
(default), ``om`` and ``om-joint`` (the paper), ``mmm`` and ``mm`` (the paper's baselines). Shared
pieces: preprocessing of the joint and IMU streams, link discovery, metrics.
``calibrate_relative(dataset, reference)`` poses units in a reference unit's frame from the IMUs
alone (no joint states; :mod:`skincal.calib.imu_only`).
"""

from skincal.calib import methods as _methods  # noqa: F401  (registers every method, one module each)
from skincal.calib.api import METHODS, MethodSpec, UnitProblem, calibrate, register
from skincal.calib.imu_only import calibrate_relative, compare_with_joint_result
from skincal.calib.links import LinkAssignment, discover_link
from skincal.calib.metrics import evaluate, pose_errors
from skincal.calib.preprocess import (
    JointInterpolator,
    UnitSamples,
    estimate_qdd,
    joint_states_at,
    static_means,
    unit_samples,
)

__all__ = [
    "METHODS",
    "JointInterpolator",
    "LinkAssignment",
    "MethodSpec",
    "UnitProblem",
    "UnitSamples",
    "calibrate",
    "calibrate_relative",
    "compare_with_joint_result",
    "discover_link",
    "estimate_qdd",
    "evaluate",
    "joint_states_at",
    "pose_errors",
    "register",
    "static_means",
    "unit_samples",
]
