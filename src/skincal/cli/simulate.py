"""``skincal simulate``: generate a calibration dataset from the protocol and the sensor models."""

from __future__ import annotations

import time
from pathlib import Path

import typer

from skincal.cli.app import app, console
from skincal.errors import ConfigError

BACKENDS = ("analytic", "mujoco")

IDEAL_NOISE = ("none", "datasheet")
"""IMU presets whose sessions default to ideal joint states (``--joints auto``)."""

DRIVER_CLOCK_NOISE = ("real",)
"""IMU presets whose units default to the measured driver clock (``--clock auto``)."""


def resolve_timing(noise: str, joints: str = "auto", clock: str = "auto") -> tuple[str, str]:
    """The joint-state and clock preset names for ``--joints``/``--clock`` (``auto`` resolved).

    ``auto``: joints ``ideal`` for the IMU presets none/datasheet and ``controller`` otherwise
    (realistic, real); clock ``driver`` for real and ``ideal`` otherwise.
    """
    from skincal.sim.joint_states import get_joint_model
    from skincal.skin.clock import get_clock_model

    if joints == "auto":
        joints = "ideal" if noise in IDEAL_NOISE else "controller"
    if clock == "auto":
        clock = "driver" if noise in DRIVER_CLOCK_NOISE else "ideal"
    get_joint_model(joints)
    get_clock_model(clock)
    return joints, clock


def make_placements(chain, placement: str, units: int | None, rng):
    """Unit poses for ``--placement paper|random|ring`` (``units`` only for random; paper has 6, ring
    is the dense whole-body skin of :func:`skincal.skin.placement.ring_placement`)."""
    from skincal.skin.placement import paper_placement, random_placement, ring_placement

    if placement == "paper":
        if units not in (None, 6):
            raise ConfigError("--placement paper has 6 units; use --placement random for another count")
        return paper_placement(chain)
    if placement == "random":
        return random_placement(chain, 6 if units is None else units, rng)
    if placement == "ring":
        ring = ring_placement(chain)
        if units not in (None, len(ring)):
            raise ConfigError(f"--placement ring has {len(ring)} units on '{chain.name}'; use random for another count")
        return ring
    raise ConfigError(f"unknown placement '{placement}' (use 'paper', 'random' or 'ring')")


def simulate_dataset(
    robot: str = "panda",
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
):
    """Build a simulated :class:`~skincal.data.Dataset` from preset names (used by the CLI and demo).

    ``joints``: joint-state preset (:data:`skincal.sim.joint_states.JOINT_PRESETS`) or ``auto``;
    ``clock``: unit clock preset (:data:`skincal.skin.clock.CLOCK_PRESETS`) or ``auto``; ``auto``
    as :func:`resolve_timing`.
    """
    import numpy as np

    from skincal.kinematics import get_robot
    from skincal.protocol import build_trajectory, get_protocol
    from skincal.sim.joint_states import get_joint_model
    from skincal.skin.clock import get_clock_model
    from skincal.skin.imu import get_imu_model

    if backend not in BACKENDS:
        raise ConfigError(f"unknown backend '{backend}' (use {' or '.join(BACKENDS)})")
    if units is not None and units < 1:
        raise ConfigError(f"--units must be at least 1, got {units}")
    chain = get_robot(robot)
    imu_model = get_imu_model(noise)
    joints, clock = resolve_timing(noise, joints, clock)
    timing = {"joint_model": get_joint_model(joints), "clock_model": get_clock_model(clock)}
    config = get_protocol(protocol)
    rng = np.random.default_rng(seed)
    placements = make_placements(chain, placement, units, rng)
    trajectory = build_trajectory(chain, config, rng)
    text = description or (
        f"simulated: robot={chain.name} placement={placement} noise={noise} protocol={protocol} "
        f"seed={seed} backend={backend}"
        + (f" mode={mujoco_mode}" if backend == "mujoco" else "")
        + (f" joints={joints}" if joints != "ideal" else "")
        + (f" clock={clock}" if clock != "ideal" else "")
    )
    if backend == "mujoco":
        from skincal.sim.mujoco_backend import simulate_mujoco

        if mujoco_mode not in ("kinematic", "dynamic"):
            raise ConfigError(f"unknown MuJoCo mode '{mujoco_mode}' (use kinematic or dynamic)")
        return simulate_mujoco(
            chain, placements, trajectory, imu_model, rng, mode=mujoco_mode, description=text, **timing
        )
    from skincal.sim.analytic import simulate

    return simulate(chain, placements, trajectory, imu_model, rng, description=text, **timing)


@app.command()
def simulate(
    out: Path = typer.Option(..., "--out", "-o", help="dataset file to write (.h5)"),
    robot: str = typer.Option("panda", help="robot preset (panda, sawyer, ur5e) or a chain .yaml/.json"),
    placement: str = typer.Option("paper", help="paper (Table II, 6 units), random or ring (dense skin)"),
    units: int | None = typer.Option(None, help="number of units (random placement; default 6)"),
    noise: str = typer.Option("none", help="IMU preset: none, datasheet, realistic or real (measured IMUs)"),
    protocol: str = typer.Option("paper-sim", help="protocol preset: paper-sim, paper-real, ..."),
    seed: int = typer.Option(0, help="random seed (placements, poses, noise)"),
    backend: str = typer.Option("analytic", help="analytic (exact, fast) or mujoco (independent physics)"),
    mujoco_mode: str = typer.Option(
        "kinematic", help="mujoco backend: kinematic (imposed motion) or dynamic (1 kHz velocity servos)"
    ),
    joints: str = typer.Option(
        "auto", help="joint states: ideal, controller (500 Hz, encoder steps, noisy qd, no qdd) or auto"
    ),
    clock: str = typer.Option(
        "auto", help="unit clocks: ideal, driver, wifi, wifi-resync or auto (driver for --noise real)"
    ),
    force: bool = typer.Option(False, "--force", help="overwrite --out if it exists"),
) -> None:
    """Simulate a calibration session and write it as a dataset file."""
    from skincal.data.atomic import check_output
    from skincal.data.hdf5 import write_dataset

    check_output(out, force=force)
    start = time.perf_counter()
    ds = simulate_dataset(
        robot, placement, units, noise, protocol, seed, backend, mujoco_mode=mujoco_mode, joints=joints, clock=clock
    )
    write_dataset(ds, out)
    n = sum(len(s.t) for s in ds.imu.values())
    console.print(
        f"wrote {out}: {ds.robot.name}, {len(ds.units)} units, {ds.duration:.1f} s of motion, "
        f"{n} IMU samples ({time.perf_counter() - start:.2f} s)"
    )
