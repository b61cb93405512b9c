"""``skincal protocol``: the calibration motion of a robot, written for its controller."""

from __future__ import annotations

from pathlib import Path

import typer

from skincal.cli.app import app, at_rate, console, joint_names, seed_option

MIN_RATE_HZ = 10.0
"""The lowest ``--rate``: 5 samples per period of the ``fast`` protocol's 2 Hz excitation (at 1e-9 Hz the file
held one point of an 85 s motion, written as valid)."""


@app.command("protocol")
def protocol_cmd(
    robot: str = typer.Option(
        ..., "--robot", help="robot preset, a .urdf file (with --base-link/--tip-link) or a DH chain .yaml/.json"
    ),
    base_link: str | None = typer.Option(None, help="URDF link the chain starts from (with --robot arm.urdf)"),
    tip_link: str | None = typer.Option(None, help="URDF link the chain ends at (with --robot arm.urdf)"),
    protocol: str = typer.Option("fast", "--protocol", help="preset protocol: fast, paper-real or paper-sim"),
    seed: int = typer.Option(0, callback=seed_option, help="seed of the static-pose draw"),
    rate: float = typer.Option(
        100.0,
        "--rate",
        help="sample rate of the written trajectory, 10-10000 Hz (the limits "
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
    floor: str = typer.Option(
        "0",
        "--floor",
        help="height of the floor the collision check keeps the arm above, m in the base frame, or none (an arm "
        "whose base is not on the floor, e.g. a humanoid's)",
    ),
    imu_range: str | None = typer.Option(
        None,
        "--imu-range",
        help="fit the motion to the IMUs' full scale too: ACCEL,GYRO (2g,245dps or 19.6,4.28 in m/s^2 and "
        "rad/s) or an IMU preset (realistic, ...); every unit anywhere on a link then stays below its rails",
    ),
    adaptive: bool = typer.Option(
        False,
        "--adaptive",
        help="choose the motion segment by segment, each the next best motion for the "
        "calibration so far (D-optimal information per second), until every unit reaches --target; each segment "
        "is written beside --out as NAME_001.EXT, ... when chosen, the whole motion to --out at the end",
    ),
    simulate: bool = typer.Option(
        False,
        "--simulate",
        help="--adaptive: a simulated robot executes the segments (with --noise, --placement, "
        "--units, --joints); prints the true errors at the end",
    ),
    target: str = typer.Option("0.3mm,0.05deg", "--target", help="--adaptive: std to reach on every axis"),
    result: Path | None = typer.Option(
        None, "--result", help="--adaptive: the calibration result (.json; default NAME_result.json beside --out)"
    ),
    max_motion: float = typer.Option(300.0, "--max-motion", help="--adaptive: budget of robot motion, s"),
    noise: str = typer.Option("realistic", "--noise", help="--simulate: IMU preset"),
    placement: str = typer.Option("paper", "--placement", help="--simulate: unit placement (paper, random, ring)"),
    units: int | None = typer.Option(None, "--units", help="--simulate: number of units (random placement)"),
    joints: str = typer.Option("auto", "--joints", help="--simulate: joint-state preset (auto, ideal, controller)"),
    port: int | None = typer.Option(
        None,
        "--port",
        help="--adaptive on a real robot: UDP port of the skin and joint-state stream (0: any free port, printed)",
    ),
    bind: str = typer.Option(
        "127.0.0.1", "--bind", help="--adaptive --port: address to bind (loopback unless --public)"
    ),
    public: bool = typer.Option(False, "--public", help="--adaptive --port: allow a non-loopback --bind"),
    record_out: Path | None = typer.Option(
        None, "--record", help="--adaptive --port: the recording written while the robot executes the segments (.h5)"
    ),
) -> None:
    """Write the calibration motion for a robot: fitted into its position, velocity and acceleration
    limits, static poses collision-free (self and the floor, z = 0 of the base or --floor) along the whole motion.
    With --adaptive, the motion is chosen segment by segment from the data (a live session, or --simulate)."""
    import math
    from dataclasses import replace

    import numpy as np

    from skincal.errors import ConfigError
    from skincal.io.atomic import check_output
    from skincal.kinematics import PRESETS, get_robot
    from skincal.names import printable
    from skincal.protocol import build_trajectory, get_protocol
    from skincal.protocol.config import POSE_SELECTIONS
    from skincal.protocol.export import TRAJECTORY_SUFFIXES, export_trajectory
    from skincal.protocol.imu_range import ImuRange, build_within_imu_range
    from skincal.protocol.limits import fit_to_limits

    if out.suffix.lower() not in TRAJECTORY_SUFFIXES:
        raise ConfigError(
            f"{out}: unknown trajectory format '{out.suffix}' (use .csv, .json, .yaml, .bag or a bag folder name "
            "without suffix)"
        )
    if poses not in POSE_SELECTIONS:
        raise ConfigError(f"--poses must be one of {', '.join(POSE_SELECTIONS)}, got {poses!r}")
    if not (math.isfinite(rate) and MIN_RATE_HZ <= rate <= 10_000):  # (below, the samples no longer show the motion)
        raise ConfigError(f"--rate must be a sample rate of {MIN_RATE_HZ:g} to 10000 Hz, got {rate:g}")
    if out.suffix == "" and out.exists():  # (check_output would call it "a folder; give a file name")
        raise ConfigError(f"{out} exists; a ROS 2 bag folder is never overwritten, even with --force (remove it)")
    check_output(out, force=force, inputs=() if robot in PRESETS else (Path(robot),))
    imu = None if imu_range is None else ImuRange.parse(imu_range)
    try:
        floor_z = None if floor.strip().lower() == "none" else float(floor)
    except ValueError:
        raise ConfigError(f"--floor must be a height in m or none, got {floor!r}") from None
    chain = get_robot(robot, base_link=base_link, tip_link=tip_link)
    if adaptive and imu is not None:
        raise ConfigError("--imu-range does not apply to --adaptive (its segments are not fitted to it yet)")
    if adaptive and floor_z != 0.0:
        raise ConfigError("--floor does not apply to --adaptive (its segments check the floor at z = 0 yet)")
    if adaptive:
        from skincal.cli.protocol_adaptive import run_adaptive  # (it does not import this module)

        run_adaptive(chain, out, rate=rate, seed=seed, force=force, target=target, result=result,
                     max_motion=max_motion, simulate=simulate, noise=noise, placement=placement, units=units,
                     joints=joints, port=port, bind=bind, public=public, record_out=record_out,
                     inputs=() if robot in PRESETS else (Path(robot),))  # fmt: skip
        return
    for given, name in ((simulate or None, "--simulate"), (result, "--result"), (port, "--port"),
                        (record_out, "--record"), (target != "0.3mm,0.05deg" or None, "--target"),
                        (max_motion != 300.0 or None, "--max-motion"), (noise != "realistic" or None, "--noise"),
                        (placement != "paper" or None, "--placement"), (units, "--units"),
                        (joints != "auto" or None, "--joints"), (public or None, "--public"),
                        (bind != "127.0.0.1" or None, "--bind")):  # fmt: skip
        if given is not None:
            raise ConfigError(f"{name} applies to --adaptive only")
    config = replace(
        fit_to_limits(chain, get_protocol(protocol)), collision_check=True, pose_selection=poses, floor_z=floor_z
    )
    if imu is None:
        traj = build_trajectory(chain, config, np.random.default_rng(seed))
    else:
        config, traj = build_within_imu_range(chain, config, imu, np.random.default_rng(seed))
    traj = at_rate(traj, rate)  # checked at 1 kHz
    t = traj.t
    export_trajectory(traj, out, joint_names=joint_names(chain))
    seg = traj.segments
    console.print(printable(
        f"wrote {out}: protocol {config.name} for {chain.name}, {traj.duration:.1f} s, {t.size} points at "
        f"{rate:g} Hz, {traj.poses.shape[0]} poses, {len(seg)} segments"), highlight=False, markup=False)  # fmt: skip
    for note in config.notes:
        console.print(printable(f"  note: {note}"), highlight=False, markup=False)
