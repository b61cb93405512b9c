"""``skincal protocol``: the calibration motion of a robot, written for its controller."""

from __future__ import annotations

from pathlib import Path

import typer

from skincal.cli.app import app, console


@app.command("protocol")
def protocol_cmd(
    robot: str = typer.Option(
        ..., "--robot", help="robot preset, a .urdf file (with --base-link/--tip-link) or a DH chain .yaml/.json"
    ),
    base_link: str | None = typer.Option(None, help="URDF link the chain starts from (with --robot arm.urdf)"),
    tip_link: str | None = typer.Option(None, help="URDF link the chain ends at (with --robot arm.urdf)"),
    protocol: str = typer.Option("fast", "--protocol", help="preset protocol: fast, paper-real or paper-sim"),
    seed: int = typer.Option(0, help="seed of the static-pose draw"),
    rate: float = typer.Option(
        100.0,
        "--rate",
        help="sample rate of the written trajectory, Hz (the limits "
        "are checked at 1 kHz; a real controller interpolates)",
    ),
    out: Path = typer.Option(
        ...,
        "--out",
        "-o",
        help="file to write: .csv (t, q, qd), .json (definition and "
        "segment table, for `skincal segment --protocol`), .yaml (ROS JointTrajectory), .bag (ROS 1 bag) or "
        "a name without suffix (a new ROS 2 bag folder); a bag holds one JointTrajectory on /joint_trajectory",
    ),
    poses: str = typer.Option(
        "diverse",
        "--poses",
        help="static poses: diverse (gravity directions spread in "
        "every link frame) or uniform (the protocol's plain draw)",
    ),
    force: bool = typer.Option(False, "--force", help="overwrite --out if it exists"),
) -> None:
    """Write the calibration motion for a robot: fitted into its position, velocity and acceleration
    limits, static poses collision-free (self and floor z = 0 of the base) along the whole motion."""
    import math
    from dataclasses import replace

    import numpy as np

    from skincal.data.atomic import check_output
    from skincal.errors import ConfigError
    from skincal.kinematics import PRESETS, get_robot
    from skincal.names import printable
    from skincal.protocol import build_trajectory, get_protocol
    from skincal.protocol.config import POSE_SELECTIONS
    from skincal.protocol.export import TRAJECTORY_SUFFIXES, export_trajectory
    from skincal.protocol.limits import fit_to_limits

    if out.suffix.lower() not in TRAJECTORY_SUFFIXES:
        raise ConfigError(
            f"{out}: unknown trajectory format '{out.suffix}' (use .csv, .json, .yaml, .bag or a bag folder name "
            "without suffix)"
        )
    if poses not in POSE_SELECTIONS:
        raise ConfigError(f"--poses must be one of {', '.join(POSE_SELECTIONS)}, got {poses!r}")
    if not (math.isfinite(rate) and 0 < rate <= 10_000):
        raise ConfigError(f"--rate must be a positive sample rate up to 10000 Hz, got {rate}")
    if out.suffix == "" and out.exists():  # (check_output would call it "a folder; give a file name")
        raise ConfigError(f"{out} exists; a ROS 2 bag folder is never overwritten, even with --force (remove it)")
    check_output(out, force=force, inputs=() if robot in PRESETS else (Path(robot),))
    chain = get_robot(robot, base_link=base_link, tip_link=tip_link)
    config = replace(fit_to_limits(chain, get_protocol(protocol)), collision_check=True, pose_selection=poses)
    traj = build_trajectory(chain, config, np.random.default_rng(seed))  # checked at config.rate_hz (1 kHz)
    t = np.arange(int(np.floor(traj.duration * rate + 1e-9)) + 1) / rate
    q, qd, qdd = traj.evaluate(t)
    traj = replace(traj, t=t, q=q, qd=qd, qdd=qdd, config=replace(traj.config, rate_hz=float(rate)))
    names = chain.joint_names or tuple(f"joint{i + 1}" for i in range(chain.n_joints))
    export_trajectory(traj, out, joint_names=names)
    seg = traj.segments
    console.print(printable(
        f"wrote {out}: protocol {config.name} for {chain.name}, {traj.duration:.1f} s, {t.size} points at "
        f"{rate:g} Hz, {traj.poses.shape[0]} poses, {len(seg)} segments"), highlight=False, markup=False)  # fmt: skip
    for note in config.notes:
        console.print(printable(f"  note: {note}"), highlight=False, markup=False)
