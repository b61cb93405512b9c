"""One door to the simulators: a :class:`Session` (what is simulated) and :func:`simulate` (which engine).

Both simulators take the same session: the robot, the true unit poses, the protocol motion, the IMU,
joint-state and clock models and the random generator. The backend registry maps a name to a
function ``(session, progress=None, **options) -> Dataset``; ``options`` are the backend's own
(``mujoco``: ``mode``, ``position_gain``, ``model_options``, ``scene``, ``tof_model``).
``progress(done, total)`` is called after each unit.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from skincal.data.dataset import Dataset
from skincal.errors import ConfigError
from skincal.kinematics.chain import GRAVITY_BASE, SerialChain
from skincal.protocol import Trajectory
from skincal.sim.joint_states import JointStateModel
from skincal.skin.clock import ClockModel
from skincal.skin.imu import ImuModel
from skincal.skin.pose import SkinUnitPose

Progress = Callable[[int, int], None]
"""``progress(done, total)``: units simulated so far out of all."""


@dataclass(frozen=True)
class Session:
    """What a simulator needs; the same for every backend.

    Attributes:
        chain: the robot.
        placements: true unit poses by name.
        trajectory: the protocol motion (:func:`skincal.protocol.build_trajectory`).
        imu_model: the IMU model (:func:`skincal.skin.imu.get_imu_model`).
        rng: the simulation's random generator (each unit draws from its own child).
        joint_model: how the robot reports its joint states (``None``: ideal).
        clock_model: the units' clock type (``None``: ideal).
        gravity: ``(3,)`` base-frame gravity, m/s^2.
        description: stored in the dataset.
    """

    chain: SerialChain
    placements: Mapping[str, SkinUnitPose]
    trajectory: Trajectory
    imu_model: ImuModel
    rng: np.random.Generator
    joint_model: JointStateModel | None = None
    clock_model: ClockModel | None = None
    gravity: np.ndarray = field(default_factory=lambda: np.array(GRAVITY_BASE, dtype=float))
    description: str = ""


Backend = Callable[..., Dataset]
BACKENDS: dict[str, Backend] = {}
"""Simulator name -> ``fn(session, progress=None, **options) -> Dataset``."""


def register_backend(name: str) -> Callable[[Backend], Backend]:
    """Decorator adding a simulator to :data:`BACKENDS` under ``name``."""

    def add(fn: Backend) -> Backend:
        BACKENDS[name] = fn
        return fn

    return add


def _run(run: Callable[..., Dataset], s: Session, progress: Progress | None, options: dict[str, Any]) -> Dataset:
    """Call a simulator function with the session's parts (both share this signature)."""
    return run(
        s.chain, s.placements, s.trajectory, s.imu_model, s.rng, gravity=s.gravity, description=s.description,
        joint_model=s.joint_model, clock_model=s.clock_model, progress=progress, **options,
    )  # fmt: skip


@register_backend("analytic")
def _analytic(session: Session, progress: Progress | None = None, **options: Any) -> Dataset:
    from skincal.sim.analytic import simulate

    return _run(simulate, session, progress, options)


@register_backend("mujoco")
def _mujoco(session: Session, progress: Progress | None = None, **options: Any) -> Dataset:
    from skincal.sim.mujoco_backend import simulate_mujoco

    return _run(simulate_mujoco, session, progress, options)


def simulate(session: Session, backend: str = "analytic", progress: Progress | None = None, **options: Any) -> Dataset:
    """Simulate ``session`` with the simulator ``backend`` (a name in :data:`BACKENDS`)."""
    try:
        run = BACKENDS[backend]
    except KeyError:
        raise ConfigError(f"unknown backend '{backend}' (use {' or '.join(BACKENDS)})") from None
    return run(session, progress=progress, **options)
