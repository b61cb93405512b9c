"""Proximity perception: time-of-flight readings + calibrated unit poses -> obstacle points in the base frame."""

from skincal.perception.body import BodyProximity, RobotBody, body_proximity, closest_on_segments, segment_distance
from skincal.perception.points import (
    ObstaclePoints,
    PerceptionConfig,
    ProximityTracker,
    interpolate_joints,
    points_from_streams,
    unit_points,
    unit_rays,
    valid_ranges,
)

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
    "segment_distance",
    "unit_points",
    "unit_rays",
    "valid_ranges",
]
