"""The data-collection protocol: static poses, per-joint sinusoidal excitation, rests, limit checks.

``build_trajectory(chain, get_protocol("paper-sim"), rng)`` gives a :class:`Trajectory` sampled at
the robot rate with exact ``evaluate(t)`` at any time; ``export_trajectory`` writes CSV or JSON.
"""

from skincal.protocol.config import ProtocolConfig, with_poses
from skincal.protocol.export import export_trajectory, read_trajectory_csv, read_trajectory_json
from skincal.protocol.limits import check_limits, pose_box, sample_static_poses
from skincal.protocol.presets import PROTOCOLS, get_protocol
from skincal.protocol.trajectory import Trajectory, build_trajectory, concatenate_trajectories, protocol_duration

__all__ = [
    "PROTOCOLS",
    "ProtocolConfig",
    "Trajectory",
    "build_trajectory",
    "check_limits",
    "concatenate_trajectories",
    "export_trajectory",
    "get_protocol",
    "pose_box",
    "protocol_duration",
    "read_trajectory_csv",
    "read_trajectory_json",
    "sample_static_poses",
    "with_poses",
]
