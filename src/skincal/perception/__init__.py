"""Proximity perception: time-of-flight readings + calibrated unit poses -> obstacle points in the base frame."""

from skincal.perception.body import BodyProximity, RobotBody, body_proximity, closest_on_segments, segment_distance
from skincal.perception.points import (
    ObstaclePoints,
    PerceptionConfig,
    interpolate_joints,
    points_from_streams,
    unit_points,
    unit_rays,
    valid_ranges,
)
from skincal.perception.tracker import ProximityTracker, ray_velocity

__all__ = [
    "BodyProximity",
    "ObstaclePoints",
    "PerceptionConfig",
    "ProximityTracker",
    "RobotBody",
    "body_proximity",
    "closest_on_segments",
    "interpolate_joints",
    "points_from_streams",
    "ray_velocity",
    "segment_distance",
    "unit_points",
    "unit_rays",
    "valid_ranges",
]
