"""Serial revolute chains from DH tables: presets, batched forward kinematics, point motion."""

from skincal.kinematics.chain import GRAVITY_BASE, LinkMotion, SerialChain, transform_points
from skincal.kinematics.presets import PRESETS, get_robot, load_chain, panda, sawyer, ur5e
from skincal.kinematics.transforms import (
    homogeneous,
    invert,
    matrix_from_quat_wxyz,
    modified_dh,
    nearest_rotation,
    quat_wxyz_from_matrix,
    quaternion_distance,
    rot_x,
    rot_z,
    rotation_angle,
    skew,
    standard_dh,
)

__all__ = [
    "GRAVITY_BASE",
    "PRESETS",
    "LinkMotion",
    "SerialChain",
    "get_robot",
    "homogeneous",
    "invert",
    "load_chain",
    "matrix_from_quat_wxyz",
    "modified_dh",
    "nearest_rotation",
    "panda",
    "quat_wxyz_from_matrix",
    "quaternion_distance",
    "rot_x",
    "rot_z",
    "rotation_angle",
    "sawyer",
    "skew",
    "standard_dh",
    "transform_points",
    "ur5e",
]
