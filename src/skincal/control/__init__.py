"""Obstacle avoidance control: the QP controller and its constraints (kinematics, skin and perception only).

The closed-loop experiment in MuJoCo, the human-approach scenarios, run metrics, plots and playback are
in :mod:`skincal.workflows` (``experiment``, ``avoidance``, ``avoid_plot``, ``playback``), the scenarios in
:mod:`skincal.sim.scenarios`; the metrics of a run as functions of arrays are :mod:`skincal.control.iso_metrics`.
"""

from skincal.control.constraints import (
    FrameCache,
    ObstacleRows,
    approach_speed_bound,
    approach_speed_slope,
    cap_candidates,
    joint_velocity_bounds,
    obstacle_bounds,
    obstacle_geometry,
    obstacle_rows,
    point_jacobians,
    ramp_width,
)
from skincal.control.qp import AvoidanceController, ControllerConfig, QpProblem, StepResult
from skincal.control.separation import (
    HAND_SPEED_MPS,
    WALKING_SPEED_MPS,
    ApproachSpeedTable,
    SeparationParams,
    SeparationTerms,
    StoppingModel,
    allowed_approach_speed,
    protective_separation,
)

__all__ = [
    "HAND_SPEED_MPS",
    "WALKING_SPEED_MPS",
    "ApproachSpeedTable",
    "AvoidanceController",
    "ControllerConfig",
    "FrameCache",
    "ObstacleRows",
    "QpProblem",
    "SeparationParams",
    "SeparationTerms",
    "StepResult",
    "StoppingModel",
    "allowed_approach_speed",
    "approach_speed_bound",
    "approach_speed_slope",
    "cap_candidates",
    "joint_velocity_bounds",
    "obstacle_bounds",
    "obstacle_geometry",
    "obstacle_rows",
    "point_jacobians",
    "protective_separation",
    "ramp_width",
]
