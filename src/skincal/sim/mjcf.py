"""MJCF text helpers shared by the robot model (:mod:`skincal.sim.mujoco_model`) and the scene
(:mod:`skincal.sim.scene`)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from skincal.kinematics.transforms import FloatArray


def mjcf_floats(values: FloatArray | Sequence[float] | float) -> str:
    """Floats as MJCF attribute text at full precision (repr round-trips), so frames survive the XML
    text exactly: the one float formatting of every MJCF skincal writes (robot and scene)."""
    arr = np.atleast_1d(np.asarray(values, dtype=float))
    return " ".join(repr(float(x)) for x in arr)
