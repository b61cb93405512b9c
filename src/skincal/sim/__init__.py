"""skincal.sim: simulated calibration sessions.

:func:`simulate` runs a :class:`Session` on a simulator named in :data:`BACKENDS` (``analytic``:
exact kinematics; ``mujoco``: independent physics, optional dependency), both through ``common``
(the steps every simulator shares); ``joint_states`` is how the robot reports its joints, ``scene``
the obstacles, ``faults`` the faults of real sessions.
"""

from skincal.sim.joint_states import JOINT_PRESETS, JointStateModel, get_joint_model
from skincal.sim.scene import Obstacle, Primitive, Scene, TimeTable
from skincal.sim.session import BACKENDS, Session, SimOptions, register_backend, simulate

__all__ = [
    "BACKENDS",
    "JOINT_PRESETS",
    "JointStateModel",
    "Obstacle",
    "Primitive",
    "Scene",
    "Session",
    "SimOptions",
    "TimeTable",
    "get_joint_model",
    "register_backend",
    "simulate",
]
