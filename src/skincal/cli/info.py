"""``skincal info``: summary of a dataset file, or of the serial chain a URDF gives; ``skincal version``."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import typer

from skincal.cli.app import app, console, require_file, shown

if TYPE_CHECKING:
    import numpy as np


@app.command()
def version() -> None:
    """Print the skincal version."""
    import skincal

    console.print(skincal.__version__)


def _print_version(value: bool) -> None:
    if value:
        version()
        raise typer.Exit(0)


@app.callback()
def _root(
    show_version: bool = typer.Option(
        False, "--version", help="print the skincal version and exit", callback=_print_version, is_eager=True
    ),
) -> None:
    """Self-contained kinematic calibration of robot skin units from accelerometers."""


def _rate_hz(t: np.ndarray) -> float | None:
    """Nominal sample rate, Hz: the inverse of the median sample interval (None below 2 samples)."""
    import numpy as np

    return float(1.0 / np.median(np.diff(t))) if len(t) >= 2 else None


def _fmt_rate(rate: float | None) -> str:
    return "-" if rate is None else f"{rate:.4g}"


def _urdf_info(path: Path, base_link: str | None, tip_link: str | None) -> None:
    """The chain every command takes from the URDF ``path``: links, joints and limits, what was left out."""
    import numpy as np
    from rich.table import Table

    from skincal.kinematics.urdf import urdf_chain

    picked = urdf_chain(path, base_link=base_link, tip_link=tip_link)
    chain = picked.chain
    head = Table.grid(padding=(0, 2))
    head.add_column(style="bold")
    head.add_column()
    head.add_row("file", shown(path))
    head.add_row("robot", f"{shown(chain.name)} (URDF, {chain.n_joints} joints)")
    head.add_row("chain", f"{shown(picked.base_link)} -> {shown(picked.tip_link)} (the flange's link)")
    if picked.excluded:
        head.add_row(
            "left out",
            f"{', '.join(shown(j) for j in picked.excluded)}: the gripper's joint(s) at the tip, not the arm's "
            "(--tip-link takes them in)",
        )
    console.print(head)
    table = Table(title="joints of the chain", title_justify="left")
    for column, justify in (("#", "right"), ("joint", "left"), ("type", "left"), ("link (frame)", "left"),
                            ("lower", "right"), ("upper", "right"), ("velocity", "right")):  # fmt: skip
        table.add_column(column, justify=justify)  # type: ignore[arg-type]
    names = chain.joint_names or tuple(f"joint{k + 1}" for k in range(chain.n_joints))
    links = chain.link_names or tuple(str(k) for k in range(chain.n_joints + 1))
    for k in range(chain.n_joints):
        unit = "m" if chain.joint_type[k] == "prismatic" else "rad"
        lo, hi = chain.joint_lower[k], chain.joint_upper[k]
        v = "-" if chain.velocity_limit is None else f"{chain.velocity_limit[k]:.4g} {unit}/s"
        table.add_row(str(k + 1), shown(names[k]), chain.joint_type[k], shown(links[k + 1]),
                      f"{lo:.4g}" if np.isfinite(lo) else "-", f"{hi:.4g}" if np.isfinite(hi) else "-", v)  # fmt: skip
    console.print(table)


@app.command()
def info(
    path: Path = typer.Argument(..., help="dataset file (.h5), or a robot's .urdf (the chain it gives)"),
    base_link: str | None = typer.Option(None, "--base-link", help="with a .urdf: the link the chain starts from"),
    tip_link: str | None = typer.Option(None, "--tip-link", help="with a .urdf: the link the chain ends at"),
) -> None:
    """Summarise a dataset: robot, units, duration, segments, sample rates; or the serial chain of a URDF."""
    if path.suffix.lower() != ".urdf":
        from skincal.io.files import DATASET_FILE

        require_file(path, DATASET_FILE)  # before NumPy and h5py are loaded

    import numpy as np
    from rich.table import Table

    from skincal.data.dataset import DYNAMIC, STATIC
    from skincal.data.hdf5 import read_dataset
    from skincal.errors import ConfigError

    if path.suffix.lower() == ".urdf":
        _urdf_info(path, base_link, tip_link)
        return
    if base_link is not None or tip_link is not None:
        raise ConfigError("--base-link and --tip-link apply to a .urdf only")
    ds = read_dataset(path)
    robot = ds.robot
    js = ds.joints

    head = Table.grid(padding=(0, 2))
    head.add_column(style="bold")
    head.add_column()
    head.add_row("file", shown(path))  # names and free text as stored, escaped (shown)
    if ds.description:
        head.add_row("description", shown(ds.description))
    if robot is not None:
        head.add_row("robot", f"{shown(robot.name)} ({robot.described_by}, {robot.n_joints} joints)")
    else:
        head.add_row("robot", "none")
    if js is not None:
        head.add_row("duration", f"{ds.duration:.3f} s (t = {js.t[0]:.3f} .. {js.t[-1]:.3f} s)")
        qdd = "with qdd" if js.qdd is not None else "no qdd"
        head.add_row("joint stream", f"{len(js.t)} samples, {_fmt_rate(_rate_hz(js.t))} Hz, {qdd}")
    else:
        spans = [(float(s.t[0]), float(s.t[-1])) for s in ds.imu.values() if len(s.t)]
        span = f" (IMU t = {min(a for a, _ in spans):.3f} .. {max(b for _, b in spans):.3f} s)" if spans else ""
        head.add_row("duration", f"{ds.duration:.3f} s{span}")
        head.add_row("joint stream", "none: IMU-only (calibrate with --reference UNIT)")
        head.add_row("gravity", f"{np.linalg.norm(ds.gravity):.4g} m/s^2")
    if ds.segments is None and js is None:
        head.add_row("segments", "none")
    elif ds.segments is None:
        head.add_row("segments", "none (segmented automatically)")
    else:
        kind = np.asarray(ds.segments.kind)
        poses = len(np.unique(ds.segments.pose))
        head.add_row(
            "segments",
            f"{len(ds.segments)} ({int(np.sum(kind == STATIC))} static, {int(np.sum(kind == DYNAMIC))} dynamic), "
            f"{poses} poses",
        )
    console.print(head)

    units = Table(title=f"skin units ({len(ds.imu)})", title_justify="left")
    for column, justify in (
        ("unit", "left"),
        ("IMU samples", "right"),
        ("rate Hz", "right"),
        ("gyro", "center"),
        ("ToF", "center"),
        ("truth link", "right"),
        *((("truth body", "left"),) if ds.truth_body else ()),
    ):
        units.add_column(column, justify=justify)  # type: ignore[arg-type]
    for name, imu in ds.imu.items():
        truth = ds.truth.get(name)
        units.add_row(
            shown(name),
            str(len(imu.t)),
            _fmt_rate(_rate_hz(imu.t)),
            "yes" if imu.gyro is not None else "no",
            "yes" if name in ds.tof else "no",
            str(truth.link) if truth is not None else "-",
            *((shown(ds.truth_body[name].body) if name in ds.truth_body else "-",) if ds.truth_body else ()),
        )
    console.print(units)
