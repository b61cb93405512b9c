"""Obstacle avoidance: the QP controller, its constraints, human-approach scenarios, metrics and plots."""

from skincal.control.constraints import (
    FrameCache,
    ObstacleRows,
    approach_speed_bound,
    cap_candidates,
    joint_velocity_bounds,
    obstacle_rows,
    point_jacobians,
)
from skincal.control.qp import AvoidanceController, ControllerConfig, QpProblem, StepResult
from skincal.control.scenarios import Q_START, SCENARIOS, Circle, Scenario, get_scenario

__all__ = [
    "Q_START",
    "SCENARIOS",
    "AvoidanceController",
    "Circle",
    "ControllerConfig",
    "FrameCache",
    "ObstacleRows",
    "QpProblem",
    "Scenario",
    "StepResult",
    "approach_speed_bound",
    "cap_candidates",
    "get_scenario",
    "joint_velocity_bounds",
    "obstacle_rows",
    "point_jacobians",
]
