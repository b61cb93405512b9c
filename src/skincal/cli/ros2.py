"""``skincal ros2`` (the streaming calibrator on a live ROS 2 graph) and ``skincal ros2-play`` (a
dataset published as a robot and its skin would publish it)."""

from __future__ import annotations

import os
from pathlib import Path

import typer

from skincal.cli.app import LiveMeter, app, console, shown
from skincal.cli.signals import stop_on_signals
from skincal.errors import ConfigError

DOMAIN_HELP = "ROS 2 domain id (default: ROS_DOMAIN_ID, else 0)"
INTERFACE_HELP = "network interface to join (default: loopback only, multicast off)"


@app.command("ros2-play")
def ros2_play(
    dataset: Path = typer.Argument(..., help="dataset file (.h5) with joint states"),
    rate: float = typer.Option(
        1.0, "--rate", help="data seconds per wall second (1: real time; 0: as fast as possible)"
    ),
    domain: int | None = typer.Option(None, "--domain", help=DOMAIN_HELP),
    interface: str | None = typer.Option(None, "--interface", help=INTERFACE_HELP),
    robot_description: Path | None = typer.Option(
        None, "--robot-description", help="a URDF file published latched on /robot_description"
    ),
    wait: float = typer.Option(5.0, "--wait", min=0.0, help="wait up to this long (s) for a subscriber on every topic"),
    origin_ns: int | None = typer.Option(
        None, "--origin-ns", help="stamp of the dataset's time 0, ns since the epoch (default: now)"
    ),
) -> None:
    """Publish a dataset on ROS 2: /joint_states and /skin/<unit>/imu with the dataset's stamps."""
    import math

    from skincal.data.hdf5 import read_dataset
    from skincal.data.ros2.participant import join
    from skincal.workflows.ros2_play import play_dataset

    if not math.isfinite(rate) or rate < 0:
        raise ConfigError(f"--rate {rate}: a finite number >= 0 (0: as fast as possible)")
    if origin_ns is not None and not 0 <= origin_ns < 2**31 * 10**9:  # builtin_interfaces/Time: int32 s
        raise ConfigError(f"--origin-ns {origin_ns}: ns since the epoch, in [0, 2^31 s)")
    ds = read_dataset(dataset)
    ds.require_joints("ros2-play (a robot's joint states)", source=str(dataset))
    urdf = None
    if robot_description is not None:
        urdf = _checked_description(robot_description, ds.robot)
    joined = join(domain, interface)
    console.print(f"joined {joined.joined}", highlight=False)
    with stop_on_signals() as stop:
        report = play_dataset(ds, joined.participant, rate=None if rate == 0 else rate, origin_ns=origin_ns,
                              robot_description=urdf, wait_s=wait, stop=stop)  # fmt: skip
    joined.close()
    total = sum(report.messages.values())
    state = "stopped" if report.stopped else "played"
    console.print(f"{state} {report.t_data_s:.1f} s of data in {report.wall_s:.1f} s: {total} messages on "
                  f"{len(report.messages)} topics", highlight=False)  # fmt: skip


@app.command("ros2")
def ros2(
    result: Path | None = typer.Option(None, "--result", help="write the result (.json) at the end"),
    domain: int | None = typer.Option(None, "--domain", help=DOMAIN_HELP),
    interface: str | None = typer.Option(None, "--interface", help=INTERFACE_HELP),
    robot: str | None = typer.Option(
        None, "--robot", help="robot preset, .urdf or chain file (default: the URDF on /robot_description)"
    ),
    base_link: str | None = typer.Option(None, "--base-link", help="URDF: first link of the serial chain"),
    tip_link: str | None = typer.Option(None, "--tip-link", help="URDF: last link of the serial chain"),
    imu_topic: str | None = typer.Option(
        None, "--imu-topic", help="follow only the sensor_msgs/Imu topics matching this glob (e.g. '/skin/*/imu')"
    ),
    target: str | None = typer.Option(
        None, "--target", help="std to reach on every axis, position and rotation with units (default 0.3mm,0.05deg)"
    ),
    until_decided: bool = typer.Option(False, "--until-decided", help="stop when every unit reached --target"),
    duration: float | None = typer.Option(None, "--duration", help="stop after this many seconds"),
    idle: float | None = typer.Option(None, "--idle", help="stop this many seconds after the last message"),
    record: Path | None = typer.Option(None, "--record", help="write what was received as a ROS 2 bag (a new folder)"),
    watch: bool = typer.Option(True, "--watch/--no-watch", help="watch calibrated units for moves (re-published)"),
    force: bool = typer.Option(False, "--force", help="overwrite --result if it exists"),
) -> None:
    """Calibrate the skin live on a ROS 2 graph: /joint_states and every sensor_msgs/Imu topic in, each
    unit's pose on /tf_static and its status on /diagnostics out, the live meter here."""
    import math

    from skincal.data.result import write_result
    from skincal.data.ros2.participant import join
    from skincal.io.atomic import check_output
    from skincal.workflows.live import Target, parse_target
    from skincal.workflows.ros2_live import Ros2Calibration, Ros2Options

    goal = parse_target(target) if target is not None else Target()
    options = Ros2Options(imu_topic=imu_topic, until_decided=until_decided, duration_s=duration, idle_s=idle,
                          watch=watch)  # fmt: skip
    if result is not None:
        check_output(result, force=force)
    if record is not None:
        if record.exists() or record.is_symlink():
            raise ConfigError(f"--record {shown(str(record))}: exists (a bag is written to a new folder)")
        parent = record.resolve().parent
        if not parent.is_dir() or not _can_make_folder_in(parent):
            raise ConfigError(f"--record {shown(str(record))}: {shown(str(parent))} is not a writable folder")
    chain = None
    if robot is not None:
        from skincal.kinematics import get_robot

        chain = get_robot(robot, base_link=base_link, tip_link=tip_link)
    joined = join(domain, interface)
    console.print(f"joined {joined.joined}", highlight=False)
    meter = LiveMeter(goal, f"ros2 domain {joined.domain_id}")

    def moved(event: dict) -> None:
        console.print(f"[yellow]moved[/]: unit {shown(str(event.get('unit')))} changed at "
                      f"{float(event.get('t_change_s', math.nan)):.1f} s; re-calibrating it, re-published when "
                      "decided", highlight=False)  # fmt: skip

    session = Ros2Calibration(joined.participant, chain, goal, options, record=record, on_event=moved,
                              base_link=base_link, tip_link=tip_link)  # fmt: skip
    try:
        with meter:
            with stop_on_signals() as stop:
                why = session.run(stop, on_meter=meter.show)
                outcome = session.finish()
            if outcome is not None:
                meter.show(outcome.statuses, outcome.t_data, None, force_draw=True)
    finally:
        session.close()  # on an error too: the receiving thread ends and the bag is closed
    joined.close()
    if outcome is None:
        waiting = "robot description on /robot_description (or give --robot)" if session.chain is None else (
            "joint states on /joint_states and sensor_msgs/Imu topics")  # fmt: skip
        raise ConfigError(f"ended ({why}) before the calibrator started: no {waiting}")
    info = outcome.result.extras["ros2"]
    info["domain"] = joined.domain_id
    info["interface"] = interface or "loopback"
    info["ended"] = why
    dropped = sum(sum(r.values()) for r in info["dropped"].values())
    console.print(f"ended ({why}): {len(outcome.result.units)} of {len(outcome.statuses)} units calibrated, "
                  f"{sum(info['messages'].values())} messages, {dropped} dropped, "
                  f"{info['tf_messages']} /tf_static messages", highlight=False)  # fmt: skip
    for note in outcome.notes:
        console.print(f"note: {shown(note)}", highlight=False)
    if result is not None:
        write_result(outcome.result, result)
        console.print(f"wrote {shown(str(result))}", highlight=False)
    if record is not None:
        console.print(f"recorded {shown(str(record))}", highlight=False)


def _can_make_folder_in(parent: Path) -> bool:
    """Whether a folder can be made in ``parent`` (tried and removed, not asked of ``os.access``, which
    answers yes for root on ``/proc``, where the bag's folder then failed in the receiving thread)."""
    import tempfile

    try:
        os.rmdir(tempfile.mkdtemp(prefix=".skincal-", dir=parent))
    except OSError:
        return False
    return True


def _checked_description(path: Path, robot: object) -> str:
    """The URDF text of ``--robot-description`` ``path``, read as the live calibrator will read it
    (:func:`~skincal.kinematics.urdf.chain_from_urdf`), whose chain must hold the joints of the dataset's
    ``robot``: a description that no calibrator could use is refused before anything is published."""
    from skincal.kinematics.urdf import chain_from_urdf, read_urdf_text

    what = f"--robot-description {shown(str(path))}"
    try:
        text = read_urdf_text(path)
        chain = chain_from_urdf(text=text)
    except ConfigError as exc:
        raise ConfigError(f"{what}: {exc}") from None
    wanted = tuple(getattr(robot, "joint_names", None) or ())
    missing = [n for n in wanted if n not in chain.joint_names]
    if missing:
        shown_names = ", ".join(shown(n) for n in missing[:3]) + (", ..." if len(missing) > 3 else "")
        raise ConfigError(
            f"{what}: its chain {shown(chain.link_name(0))} -> {shown(chain.link_name(chain.n_joints))} lacks "
            f"the dataset's joint(s) {shown_names}: the calibrator would find no robot joints"
        )
    return text
