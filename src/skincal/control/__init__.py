"""Obstacle avoidance control: the QP controller and its constraints (kinematics, skin and perception only).

The closed-loop experiment in MuJoCo, the human-approach scenarios, run metrics, plots and playback are
in :mod:`skincal.workflows` (``avoidance``, ``scenarios``, ``avoid_metrics``, ``avoid_plot``, ``playback``).
"""

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

__all__ = [
    "AvoidanceController",
    "ControllerConfig",
    "FrameCache",
    "ObstacleRows",
    "QpProblem",
    "StepResult",
    "approach_speed_bound",
    "cap_candidates",
    "joint_velocity_bounds",
    "obstacle_rows",
    "point_jacobians",
]
