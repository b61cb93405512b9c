"""One door to the simulators: a :class:`Session` (what is simulated) and :func:`simulate` (which engine).

Both simulators take the same session: the robot, the true unit poses, the protocol motion, the IMU,
joint-state and clock models and the random generator. The backend registry maps a name to a
function ``(session, options, progress) -> Dataset``; :class:`SimOptions` says how (the ToF scene and
model; for ``mujoco`` also ``mode``, ``position_gain``, ``model_options``).
``progress(done, total)`` is called after each unit.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
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
from skincal.skin.tof import TofModel

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


@dataclass(frozen=True)
class SimOptions:
    """How a simulator runs a :class:`Session` (the session says what is simulated).

    Attributes:
        scene: obstacle primitives in the base frame; when given, every unit also gets a ToF stream.
        tof_model: the time-of-flight model (``None``: :class:`skincal.skin.tof.TofModel` defaults).
        mode: ``mujoco`` only: ``"kinematic"`` (imposed motion) or ``"dynamic"`` (velocity servos
            under gravity).
        position_gain: ``mujoco`` only: ``kp`` of the dynamic mode's velocity command, 1/s (``None``:
            :data:`skincal.sim.mujoco_backend.POSITION_GAIN`).
        model_options: ``mujoco`` only: extra keyword arguments of
            :func:`skincal.sim.mujoco_model.build_model` (e.g. ``link_radius``).
    """

    scene: Sequence[Any] | None = None
    tof_model: TofModel | None = None
    mode: str = "kinematic"
    position_gain: float | None = None
    model_options: Mapping[str, Any] | None = None


Backend = Callable[[Session, SimOptions, "Progress | None"], Dataset]
BACKENDS: dict[str, Backend] = {}
"""Simulator name -> ``fn(session, options, progress) -> Dataset``."""


def register_backend(name: str) -> Callable[[Backend], Backend]:
    """Decorator adding a simulator to :data:`BACKENDS` under ``name``."""

    def add(fn: Backend) -> Backend:
        BACKENDS[name] = fn
        return fn

    return add


@register_backend("analytic")
def _analytic(s: Session, options: SimOptions, progress: Progress | None) -> Dataset:
    from skincal.sim.analytic import simulate

    if options.mode != "kinematic" or options.position_gain is not None or options.model_options is not None:
        raise ConfigError("mode, position_gain and model_options are options of the mujoco backend only")
    return simulate(
        s.chain, s.placements, s.trajectory, s.imu_model, s.rng, tof_model=options.tof_model, scene=options.scene,
        gravity=s.gravity, description=s.description, joint_model=s.joint_model, clock_model=s.clock_model,
        progress=progress,
    )  # fmt: skip


@register_backend("mujoco")
def _mujoco(s: Session, options: SimOptions, progress: Progress | None) -> Dataset:
    from skincal.sim.mujoco_backend import POSITION_GAIN, simulate_mujoco

    gain = POSITION_GAIN if options.position_gain is None else options.position_gain
    return simulate_mujoco(
        s.chain, s.placements, s.trajectory, s.imu_model, s.rng, mode=options.mode, scene=options.scene,
        tof_model=options.tof_model, gravity=s.gravity, description=s.description,
        position_gain=gain, model_options=options.model_options, joint_model=s.joint_model,
        clock_model=s.clock_model, progress=progress,
    )  # fmt: skip


def simulate(
    session: Session, backend: str = "analytic", progress: Progress | None = None, options: SimOptions | None = None
) -> Dataset:
    """Simulate ``session`` with the simulator ``backend`` (a name in :data:`BACKENDS`) and its ``options``
    (default: :class:`SimOptions` defaults)."""
    try:
        run = BACKENDS[backend]
    except KeyError:
        raise ConfigError(f"unknown backend '{backend}' (use {' or '.join(BACKENDS)})") from None
    return run(session, SimOptions() if options is None else options, progress)
