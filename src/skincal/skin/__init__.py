"""Skin units: their pose on the chain, the paper's DH form, placements and sensor models."""

from skincal.skin.imu import (
    IMU_PRESETS,
    ImuErrors,
    ImuModel,
    angular_rate,
    apply_imu_model,
    draw_imu_errors,
    get_imu_model,
    sample_instants,
    specific_force,
    true_sample_times,
)
from skincal.skin.placement import PAPER_TABLE_II, paper_placement, random_placement
from skincal.skin.pose import DH6_NAMES, SkinUnitPose, dh6_from_transform, dh6_to_transform

__all__ = [
    "DH6_NAMES",
    "IMU_PRESETS",
    "PAPER_TABLE_II",
    "ImuErrors",
    "ImuModel",
    "SkinUnitPose",
    "angular_rate",
    "apply_imu_model",
    "dh6_from_transform",
    "dh6_to_transform",
    "draw_imu_errors",
    "get_imu_model",
    "paper_placement",
    "random_placement",
    "sample_instants",
    "specific_force",
    "true_sample_times",
]
