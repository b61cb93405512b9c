"""Proximity perception: time-of-flight readings + calibrated unit poses -> obstacle points in the base frame."""

from skincal.perception.body import (
    BodyProximity,
    RobotBody,
    body_proximity,
    closest_on_segments,
    segment_distance,
)
from skincal.perception.config import PerceptionConfig
from skincal.perception.points import (
    ObstaclePoints,
    interpolate_joints,
    points_from_streams,
    unit_points,
    unit_rays,
    valid_ranges,
)
from skincal.perception.tracker import ProximityTracker, ray_velocity
from skincal.perception.uncertainty import (
    SkinUncertainty,
    assumed_pose_covariance,
    point_covariance,
    pose_jacobian,
    reading_covariance,
    unit_pose_covariance,
)

__all__ = [
    "BodyProximity",
    "ObstaclePoints",
    "PerceptionConfig",
    "ProximityTracker",
    "RobotBody",
    "SkinUncertainty",
    "assumed_pose_covariance",
    "body_proximity",
    "closest_on_segments",
    "interpolate_joints",
    "point_covariance",
    "points_from_streams",
    "pose_jacobian",
    "ray_velocity",
    "reading_covariance",
    "segment_distance",
    "unit_points",
    "unit_pose_covariance",
    "unit_rays",
    "valid_ranges",
]
