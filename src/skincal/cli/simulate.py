"""``skincal simulate``: generate a calibration dataset from the protocol and the sensor models."""

from __future__ import annotations

import time
from pathlib import Path

import typer

from skincal.cli.app import app, console, err_console, seed_option

ROBOT_HELP = "robot preset (panda, iiwa14, gen3, sawyer, ur5, ur5e, ur10e, xarm7), a .urdf file, or a DH chain file"


DATASET_SUFFIXES = (".h5", ".hdf5")
"""Names ``simulate --out`` takes: the dataset is HDF5 whatever its name (a ``.json`` would be misleading)."""


@app.command()
def simulate(
    out: Path = typer.Option(..., "--out", "-o", help="dataset file to write (.h5)"),
    robot: str = typer.Option("panda", help=ROBOT_HELP),
    base_link: str | None = typer.Option(None, help="URDF link the chain starts from (default: the root)"),
    tip_link: str | None = typer.Option(None, help="URDF link the chain ends at (default: where the tree branches)"),
    placement: str = typer.Option("paper", help="paper (Table II, 6 units), random or ring (dense skin)"),
    units: int | None = typer.Option(None, help="number of units (random placement; default 6)"),
    noise: str = typer.Option(
        "none",
        help="IMU preset: none, datasheet, realistic, real (measured IMUs) or real-consumer (a real recording "
        "like the ABB tool-IMU ones: consumer IMU with gyroscope scale/misalignment; auto joints report14, "
        "auto clock host-gaps)",
    ),
    protocol: str = typer.Option(
        "paper-sim",
        help="protocol preset: paper-sim, paper-real, fast (fitted to the robot), or a motion .json written by "
        "skincal protocol (simulated as it is: the rehearsal of a real session)",
    ),
    seed: int = typer.Option(
        0,
        callback=seed_option,
        help="random seed (one stream: placements first, then poses, then noise; so a preset's poses differ from "
        "skincal protocol's of the same seed: to simulate a planned motion give its .json as --protocol)",
    ),
    backend: str = typer.Option("analytic", help="analytic (exact, fast) or mujoco (independent physics)"),
    mujoco_mode: str = typer.Option(
        "kinematic", help="mujoco backend: kinematic (imposed motion) or dynamic (1 kHz velocity servos)"
    ),
    joints: str = typer.Option(
        "auto",
        help="joint states: ideal, controller (500 Hz, encoder steps, noisy qd, no qdd), report14 (13.6 Hz "
        "host-stamped reports, jitter, 8 % lost, qd by central differences, no qdd) or auto",
    ),
    clock: str = typer.Option(
        "auto",
        help="unit clocks: ideal, driver, wifi, wifi-resync, host (host-stamped: 80-100 ms lag, spacing "
        "2.5-17.5 ms), host-gaps (host with 0.3-0.7 s gaps and a clock step after each) or auto (driver "
        "for --noise real, host-gaps for real-consumer)",
    ),
    force: bool = typer.Option(False, "--force", help="overwrite --out if it exists"),
    handheld: bool = typer.Option(
        False, "--handheld", help="no robot: --units units (default 2) on one body moved by hand, --spacing apart"
    ),
    spacing: float = typer.Option(0.2, help="--handheld: distance between neighbouring units, m"),
    duration: float = typer.Option(60.0, help="--handheld: length of the session, s"),
    other_body: int = typer.Option(0, min=0, help="--handheld: units on a second, independently moved body"),
) -> None:
    """Simulate a calibration session and write it as a dataset file."""
    if Path(out).suffix.lower() not in DATASET_SUFFIXES:
        from skincal.errors import ConfigError

        raise ConfigError(f"{out}: a dataset is an HDF5 file; name it .h5 (or .hdf5)")
    _check_unit_counts(units, other_body)
    if handheld:
        _simulate_handheld(out, 2 if units is None else units, spacing, duration, noise, clock, seed, other_body,
                           force)  # fmt: skip
        return
    from rich.progress import Progress

    from skincal.data.hdf5 import write_dataset
    from skincal.io.atomic import check_output
    from skincal.kinematics import get_robot
    from skincal.workflows.session import simulate_dataset

    check_output(out, force=force, inputs=tuple(Path(p) for p in (robot, protocol) if Path(p).is_file()))
    chain = get_robot(robot, base_link=base_link, tip_link=tip_link)
    start = time.perf_counter()
    with Progress(console=err_console, transient=True, disable=not err_console.is_terminal) as bar:
        task = bar.add_task(f"simulating ({backend})", total=None)
        ds = simulate_dataset(
            chain, placement, units, noise, protocol, seed, backend, mujoco_mode=mujoco_mode, joints=joints,
            clock=clock, progress=lambda done, total: bar.update(task, completed=done, total=total),
        )  # fmt: skip
    write_dataset(ds, out)
    n = sum(len(s.t) for s in ds.imu.values())
    console.print(
        f"wrote {out}: {ds.robot.name}, {len(ds.units)} units, {ds.duration:.1f} s of motion, "
        f"{n} IMU samples ({time.perf_counter() - start:.2f} s)"
    )
    if placement == "paper" and robot != "panda":
        from skincal.names import printable

        console.print(printable(
            f"  note: --placement paper is the paper's Table II on the Panda; on {chain.name} its unit poses are "
            f"reused in the frames of links 2..{len(ds.units) + 1} as they are (--placement random fits any robot)"
        ), highlight=False, markup=False)  # fmt: skip


MAX_SIMULATED_UNITS = 256
"""Most units ``simulate`` places on a robot or a hand-held body (256: a dense skin; 100,000 ran for minutes,
1,000 takes a minute)."""


def _check_unit_counts(units: int | None, other_body: int) -> None:
    """``--units`` in 1..:data:`MAX_SIMULATED_UNITS` and ``--other-body`` in 0.. of it, refused with one line
    before any work (``--handheld --units 0`` wrote 2 units; 100,000 still ran at 60 s) (issue 27)."""
    from skincal.errors import ConfigError

    if units is not None and not 1 <= units <= MAX_SIMULATED_UNITS:
        raise ConfigError(f"--units {units} must be in 1..{MAX_SIMULATED_UNITS}")
    if not 0 <= other_body <= MAX_SIMULATED_UNITS:
        raise ConfigError(f"--other-body {other_body} must be in 0..{MAX_SIMULATED_UNITS}")


def _simulate_handheld(
    out: Path, units: int, spacing: float, duration: float, noise: str, clock: str, seed: int, other_body: int,
    force: bool,
) -> None:  # fmt: skip
    """``--handheld``: an IMU-only session (:func:`skincal.workflows.handheld.handheld_dataset`)."""
    from skincal.data.hdf5 import write_dataset
    from skincal.errors import ConfigError
    from skincal.io.atomic import check_output
    from skincal.workflows.handheld import handheld_dataset
    from skincal.workflows.session import resolve_timing

    check_output(out, force=force)
    if not (0.0 < duration <= 3600.0):
        raise ConfigError(f"--duration must be in (0, 3600] s, got {duration}")
    clock_name = resolve_timing(noise, clock=clock)[1]
    ds = handheld_dataset(units, spacing, duration, noise, clock_name, seed, other_body)
    write_dataset(ds, out)
    n = sum(len(s.t) for s in ds.imu.values())
    console.print(f"wrote {out}: hand-held, {len(ds.units)} units, {duration:.1f} s, {n} IMU samples, no joints")
