"""Real robot descriptions shipped by a registry package (``example-robot-data``, a test dependency)."""

from __future__ import annotations

import importlib.metadata
from pathlib import Path


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


def registry_urdf(name: str) -> Path:
    """Path of the registry URDF ``name`` (a key of :data:`REGISTRY_URDFS`)."""
    return robots_dir() / REGISTRY_URDFS[name]
