"""Robots for tests: real robot descriptions shipped by a registry package (``example-robot-data``, a
test dependency), and random general chains."""

from __future__ import annotations

import importlib.metadata
from pathlib import Path

import numpy as np

from skincal.kinematics.chain import SerialChain
from skincal.kinematics.transforms import homogeneous, matrix_from_quat_wxyz


def robots_dir() -> Path:
    """The folder of ``example-robot-data``'s robot descriptions."""
    dist = importlib.metadata.distribution("example-robot-data")
    return Path(str(dist.locate_file("cmeel.prefix/share/example-robot-data/robots")))


REGISTRY_URDFS = {
    "panda": "panda_description/urdf/panda.urdf",
    "ur5": "ur_description/urdf/ur5_robot.urdf",
    "ur10": "ur_description/urdf/ur10_robot.urdf",
    "xarm7": "xarm_description/urdf/xarm7.urdf",
    "kinova": "kinova_description/robots/kinova.urdf",
}
"""Serial arms among them, by short name: relative paths under :func:`robots_dir`."""

OTHER_URDFS = {
    "so101": "so_arm_description/urdf/so101.urdf",
    "z1": "z1_description/urdf/z1.urdf",
}
"""Arms that are not presets and whose tree needs care (issue 27): SO-101 (joints to 10 rad/s, the gripper
jaw a revolute joint at the tip), Unitree Z1 (a gripper joint on the tip link)."""


def registry_urdf(name: str) -> Path:
    """Path of the registry URDF ``name`` (a key of :data:`REGISTRY_URDFS` or :data:`OTHER_URDFS`)."""
    return robots_dir() / {**REGISTRY_URDFS, **OTHER_URDFS}[name]


def random_chain(rng: np.random.Generator, n: int) -> SerialChain:
    """A chain with random joint origins, random axes, and prismatic joints among revolute ones."""
    T = []
    for _ in range(n):
        q = rng.normal(size=4)
        T.append(homogeneous(matrix_from_quat_wxyz(q / np.linalg.norm(q)), rng.uniform(-0.3, 0.3, 3)))
    after = [homogeneous(np.eye(3), rng.uniform(-0.1, 0.1, 3)) for _ in range(n)]
    types = tuple("prismatic" if k % 3 == 1 else "revolute" for k in range(n))
    return SerialChain(
        name="random",
        T_parent_joint=np.array(T),
        axis=rng.normal(size=(n, 3)),
        T_joint_link=np.array(after),
        joint_type=types,
    )
