"""The one factory of simulated sessions: presets by name -> :class:`skincal.sim.Session` -> dataset.

Used by ``skincal simulate`` and ``skincal demo``, the benchmarks (mle, Table I, core, robustness) and
the avoidance experiment, so that a session of the same names is the same everywhere. The protocol is
always fitted to the robot (:func:`skincal.protocol.limits.fit_to_limits`: robot-relative amplitudes
resolved, amplitudes capped at 95 % of each joint's velocity limit), so every preset runs on every robot;
a protocol ending in ``.json`` is the motion ``skincal protocol`` wrote (:func:`protocol_file`), simulated as
it is: the rehearsal of the session a real robot will record.

Random streams: one generator from ``seed`` draws the placements, then the static poses of the
trajectory, then the simulation (in that order).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace

import numpy as np

from skincal.errors import ConfigError, ProtocolError
from skincal.kinematics.chain import SerialChain
from skincal.protocol import ProtocolConfig, Trajectory
from skincal.sim import BACKENDS, Session
from skincal.sim.session import Progress

IDEAL_NOISE = ("none", "datasheet")
"""IMU presets whose sessions default to ideal joint states (``joints="auto"``)."""

DRIVER_CLOCK_NOISE = ("real",)
"""IMU presets whose units default to the measured driver clock (``clock="auto"``)."""

REAL_RECORDING_NOISE = ("real-consumer",)
"""IMU presets whose sessions default to a real recording's timing (``auto``): the controller's
host-stamped ~14 Hz reports (joints ``report14``) and host-stamped IMU samples with gaps and clock
steps (clock ``host-gaps``)."""

MUJOCO_MODES = ("kinematic", "dynamic")


def resolve_timing(noise: str, joints: str = "auto", clock: str = "auto") -> tuple[str, str]:
    """The joint-state and clock preset names for ``joints``/``clock`` (``auto`` resolved).

    ``auto``: joints ``ideal`` for the IMU presets none/datasheet, ``report14`` for real-consumer
    and ``controller`` otherwise (realistic, real); clock ``driver`` for real, ``host-gaps`` for
    real-consumer and ``ideal`` otherwise.
    """
    from skincal.sim.joint_states import get_joint_model
    from skincal.skin.clock import get_clock_model

    if joints == "auto":
        joints = "ideal" if noise in IDEAL_NOISE else "report14" if noise in REAL_RECORDING_NOISE else "controller"
    if clock == "auto":
        clock = "driver" if noise in DRIVER_CLOCK_NOISE else "host-gaps" if noise in REAL_RECORDING_NOISE else "ideal"
    get_joint_model(joints)
    get_clock_model(clock)
    return joints, clock


def make_placements(chain, placement: str, units: int | None, rng, links: Sequence[int] | None = None):
    """Unit poses for ``placement`` ``paper|random|ring`` (``units`` only for random; paper has 6, ring
    is the dense whole-body skin of :func:`skincal.skin.placement.ring_placement`). ``links``
    (random only): the 1-based link of each unit, one unit per entry."""
    from skincal.skin.placement import paper_placement, random_placement, ring_placement

    if links is not None and placement != "random":
        raise ConfigError(f"unit links can only be chosen for the random placement, not '{placement}'")
    if placement == "paper":
        if units not in (None, 6):
            raise ConfigError("--placement paper has 6 units; use --placement random for another count")
        return paper_placement(chain)
    if placement == "random":
        if links is not None:
            if units not in (None, len(links)):
                raise ConfigError(f"{units} units but {len(links)} links given")
            return random_placement(chain, len(links), rng, links=list(links))
        return random_placement(chain, 6 if units is None else units, rng)
    if placement == "ring":
        ring = ring_placement(chain)
        if units not in (None, len(ring)):
            raise ConfigError(f"--placement ring has {len(ring)} units on '{chain.name}'; use random for another count")
        return ring
    raise ConfigError(f"unknown placement '{placement}' (use 'paper', 'random' or 'ring')")


def fit_protocol(chain, protocol: str | ProtocolConfig) -> ProtocolConfig:
    """The protocol (preset name or config) fitted to ``chain``'s limits (module docstring)."""
    from skincal.protocol import get_protocol
    from skincal.protocol.limits import fit_to_limits

    config = get_protocol(protocol) if isinstance(protocol, str) else protocol
    return fit_to_limits(chain, config)


SIM_RATE_HZ = 1000.0
"""Rate a motion read from a file is sampled at for the simulators, Hz (the protocol's own rate)."""


def protocol_file(chain: SerialChain, path: str) -> Trajectory:
    """The motion of a ``skincal protocol`` JSON file (``.json``: the exact piecewise form) for ``chain``,
    sampled at :data:`SIM_RATE_HZ`, refused (one line) when it was made for another robot or leaves this
    one's position or velocity limits: the simulated rehearsal of a real session."""
    from skincal.protocol import read_trajectory_json
    from skincal.protocol.limits import check_limits
    from skincal.protocol.trajectory import sampled_at

    traj = read_trajectory_json(path)
    if traj.n_joints != chain.n_joints or (traj.robot and traj.robot != chain.name):
        raise ConfigError(
            f"{path}: a motion for robot '{traj.robot}' ({traj.n_joints} joints), not '{chain.name}' "
            f"({chain.n_joints} joints)"
        )
    traj = sampled_at(traj, SIM_RATE_HZ)
    try:
        check_limits(chain, traj.t, traj.q, traj.qd)
    except ProtocolError as exc:
        raise ConfigError(f"{path}: {exc}") from None
    return traj


def make_session(
    robot: str | SerialChain = "panda",
    placement: str = "paper",
    units: int | None = None,
    noise: str = "none",
    protocol: str | ProtocolConfig = "paper-sim",
    seed: int | Sequence[int] = 0,
    *,
    joints: str = "auto",
    clock: str = "auto",
    links: Sequence[int] | None = None,
    description: str = "",
) -> Session:
    """A simulated session from preset names: robot (a chain, or a preset, URDF or chain file), placement, IMU preset
    (``noise``), protocol (fitted to the robot), joint-state and clock presets (``auto`` as
    :func:`resolve_timing`); ``seed`` (an int or a sequence of ints) seeds one generator used in the
    order of the module docstring."""
    from skincal.kinematics import get_robot
    from skincal.protocol import build_trajectory
    from skincal.sim.joint_states import get_joint_model
    from skincal.skin.clock import get_clock_model
    from skincal.skin.imu import get_imu_model

    if units is not None and units < 1:
        raise ConfigError(f"--units must be at least 1, got {units}")
    chain = robot if isinstance(robot, SerialChain) else get_robot(robot)
    imu_model = get_imu_model(noise)
    joints, clock = resolve_timing(noise, joints, clock)
    from_file = isinstance(protocol, str) and protocol.lower().endswith(".json")
    config = None if from_file else fit_protocol(chain, protocol)
    rng = np.random.default_rng(seed)
    placements = make_placements(chain, placement, units, rng, links)
    trajectory = protocol_file(chain, str(protocol)) if config is None else build_trajectory(chain, config, rng)
    return Session(
        chain, placements, trajectory, imu_model, rng, get_joint_model(joints), get_clock_model(clock),
        description=description,
    )  # fmt: skip


def simulate_dataset(
    robot: str | SerialChain = "panda",
    placement: str = "paper",
    units: int | None = None,
    noise: str = "none",
    protocol: str = "paper-sim",
    seed: int = 0,
    backend: str = "analytic",
    description: str | None = None,
    mujoco_mode: str = "kinematic",
    joints: str = "auto",
    clock: str = "auto",
    progress: Progress | None = None,
):
    """A simulated :class:`~skincal.data.Dataset` from preset names (:func:`make_session`, then
    :func:`skincal.sim.simulate` on ``backend``); ``progress(done, total)`` after each unit."""
    from skincal.sim import SimOptions, simulate

    if backend not in BACKENDS:
        raise ConfigError(f"unknown backend '{backend}' (use {' or '.join(BACKENDS)})")
    if backend == "mujoco" and mujoco_mode not in MUJOCO_MODES:
        raise ConfigError(f"unknown MuJoCo mode '{mujoco_mode}' (use kinematic or dynamic)")
    joints, clock = resolve_timing(noise, joints, clock)
    session = make_session(robot, placement, units, noise, protocol, seed, joints=joints, clock=clock)
    text = description or (
        f"simulated: robot={session.chain.name} placement={placement} noise={noise} protocol={protocol} "
        f"seed={seed} backend={backend}"
        + (f" mode={mujoco_mode}" if backend == "mujoco" else "")
        + (f" joints={joints}" if joints != "ideal" else "")
        + (f" clock={clock}" if clock != "ideal" else "")
    )
    options = SimOptions(mode=mujoco_mode) if backend == "mujoco" else SimOptions()
    return simulate(replace(session, description=text), backend, progress=progress, options=options)
