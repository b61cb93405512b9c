"""``skincal import`` (ROS bag -> dataset), ``skincal segment`` and ``skincal export``."""

from __future__ import annotations

from pathlib import Path

import typer

from skincal.cli.app import app, console


def segmentation_tables(report, verbose: bool = False) -> list:
    """Rich tables of a :class:`~skincal.data.segment.SegmentationReport`: what was found (per pose:
    static segments, excited joints), what was rejected and why, and (``verbose``) every segment."""
    import numpy as np
    from rich.table import Table

    from skincal.data.dataset import DYNAMIC, STATIC

    seg = report.segments
    kind, pose, joint = (np.asarray(x) for x in (seg.kind, seg.pose, seg.joint))
    dur = np.asarray(seg.t_end) - np.asarray(seg.t_start)
    found = Table(title=f"segments found: {report.n_static} static, {report.n_dynamic} dynamic, "
                        f"{report.n_poses} poses")
    for col in ("pose", "static", "static (s)", "dynamic joints (1-based)", "dynamic (s)"):
        found.add_column(col)
    for p in range(report.n_poses):
        s, d = (pose == p) & (kind == STATIC), (pose == p) & (kind == DYNAMIC)
        found.add_row(str(p), str(int(s.sum())), f"{dur[s].sum():.1f}",
                      " ".join(str(j + 1) for j in joint[d]) or "-", f"{dur[d].sum():.1f}")
    tables = [found]
    if report.rejected:
        rej = Table(title=f"rejected: {len(report.rejected)} interval(s)")
        for col in ("t start (s)", "t end (s)", "reason", "detail"):
            rej.add_column(col)
        for r in report.rejected:
            rej.add_row(f"{r.t_start:.2f}", f"{r.t_end:.2f}", r.reason, r.detail)
        tables.append(rej)
    if verbose:
        every = Table(title="all segments")
        for col in ("#", "kind", "pose", "joint", "t start (s)", "t end (s)"):
            every.add_column(col)
        for i in range(len(seg)):
            every.add_row(str(i), "static" if kind[i] == STATIC else "dynamic", str(pose[i]),
                          "-" if joint[i] < 0 else str(joint[i] + 1), f"{seg.t_start[i]:.3f}", f"{seg.t_end[i]:.3f}")
        tables.append(every)
    return tables


def _segmentation_config(rest_velocity: float | None, min_static: float | None, min_dynamic: float | None):
    from skincal.data.segment import SegmentationConfig

    given = {"rest_velocity": rest_velocity, "min_static_s": min_static, "min_dynamic_s": min_dynamic}
    return SegmentationConfig(**{k: v for k, v in given.items() if v is not None})


# None = the library's default (skincal.data.segment.SegmentationConfig: one set of defaults, which
# accepts every preset protocol)
_REST = typer.Option(None, help="a joint is at rest below this speed, rad/s [default: 0.01]", show_default=False)
_MIN_STATIC = typer.Option(None, help="shortest static segment, s [default: fits every preset protocol]",
                           show_default=False)
_MIN_DYNAMIC = typer.Option(None, help="shortest dynamic segment, s [default: fits every preset protocol]",
                            show_default=False)


_PROTOCOL = typer.Option(None, "--protocol", help="take the segments from this protocol file (.json of `skincal "
                         "protocol`), aligned to the recording's joint positions, instead of finding them")


def _segments_from_protocol(ds, protocol: Path):
    """``ds`` with the segments of the protocol file, aligned by cross-correlation of joint positions."""
    from dataclasses import replace

    from skincal.names import printable
    from skincal.protocol import read_trajectory_json
    from skincal.protocol.align import align_to_protocol

    _, joints = ds.require_joints("--protocol (aligned to the joint positions)")
    al = align_to_protocol(joints.t, joints.q, read_trajectory_json(protocol))
    console.print(printable(f"segments from {protocol}: protocol t=0 at {al.offset_s:.3f} s of the recording, "
                            f"RMS joint difference {al.rms:.2g}, {len(al.segments)} segments" +
                            (f" ({al.dropped} outside the recording dropped)" if al.dropped else "")),
                  highlight=False, markup=False)  # fmt: skip
    return replace(ds, segments=al.segments)


@app.command("import")
def import_bag(
    bag: Path = typer.Argument(..., help="ROS 1 .bag file, ROS 2 bag directory, or .db3/.mcap file"),
    out: Path = typer.Option(..., "--out", "-o", help="dataset file to write (.h5)"),
    robot: str | None = typer.Option(None, help="robot: a preset, the robot's .urdf or a DH chain file (default: "
                                     "the URDF on the bag's /robot_description; without one, required)",
                                     show_default=False),
    base_link: str | None = typer.Option(None, help="URDF link the chain starts from (--robot arm.urdf or the bag's "
                                         "/robot_description)"),
    tip_link: str | None = typer.Option(None, help="URDF link the chain ends at (--robot arm.urdf or the bag's "
                                        "/robot_description)"),
    map_file: Path | None = typer.Option(None, "--map", help="YAML topic map (imu, joints, range, joint_names)"),
    imu_topic: list[str] | None = typer.Option(None, help="sensor_msgs/Imu topic, TOPIC or TOPIC=UNIT (repeatable)"),
    joint_topic: str | None = typer.Option(None, help="sensor_msgs/JointState topic"),
    range_topic: list[str] | None = typer.Option(None, help="Range/LaserScan topic, TOPIC or TOPIC=UNIT (repeatable)"),
    accel_unit: str = typer.Option("auto", help="accelerometer unit: auto, g or mps2"),
    gyro_unit: str = typer.Option("auto", help="gyroscope unit: auto, rad or deg (per second)"),
    segment: bool = typer.Option(True, help="segment the recording automatically"),
    rest_velocity: float | None = _REST,
    min_static: float | None = _MIN_STATIC,
    min_dynamic: float | None = _MIN_DYNAMIC,
    protocol: Path | None = _PROTOCOL,
    imu_only: bool = typer.Option(
        False, "--imu-only", help="no joint states: an IMU-only dataset (automatic, noted, when the bag has no "
        "JointState topic); its robot only from --robot or the bag's /robot_description"
    ),
    force: bool = typer.Option(False, "--force", help="overwrite --out if it exists"),
) -> None:
    """Import a ROS bag (no ROS install needed), segment it and write a dataset."""
    from dataclasses import replace

    from skincal.data.hdf5 import write_dataset
    from skincal.data.ros import topic_map
    from skincal.data.segment import segment_dataset
    from skincal.errors import ConfigError
    from skincal.io.atomic import check_output
    from skincal.io.files import regular_file
    from skincal.kinematics import PRESETS
    from skincal.names import printable

    if not bag.is_dir():  # a ROS 2 bag folder, else a file: a FIFO or a device would block the reader (issue 27)
        regular_file(bag, "ROS bag")
    robot_file = (Path(robot),) if robot is not None and robot not in PRESETS else ()
    check_output(out, force=force, inputs=(bag, *robot_file, *((protocol,) if protocol else ())))
    tmap = topic_map(imu_topic, joint_topic, range_topic, path=map_file)
    if imu_only and protocol is not None:
        raise ConfigError("--protocol aligns the recording's joint positions: an --imu-only import has none")
    ds, report = _read_bag_with_progress(bag, robot, tmap, accel_unit, gyro_unit, base_link, tip_link,
                                         True if imu_only else None)  # fmt: skip
    units = ", ".join(f"{u} <- {t}" for t, u in report.imu_topics.items())
    ranges = ", ".join(f"{u} <- {t}" for t, u in report.range_topics.items())
    if ds.joints is None:
        robot_text = f"robot {report.robot} ({report.robot_source})" if ds.robot is not None else "no robot"
        joints_text = "IMU-only (no joint states)"
    else:
        robot_text = f"robot {report.robot} ({report.robot_source})"
        joints_text = f"joints from {report.joint_topic} ({len(ds.joints.t)} samples)"
    # names come from the bag (topics, frame_ids): no markup, control characters shown escaped
    console.print(printable(f"read {bag} (ROS {report.ros_version}): {robot_text}, {joints_text}, units {units}"
                            + (f"; ranges {ranges}" if ranges else "")), highlight=False, markup=False)  # fmt: skip
    for note in report.notes:
        console.print(printable(f"  note: {note}"), highlight=False, markup=False)
    if ds.joints is None:
        if protocol is not None:
            raise ConfigError(f"{bag}: no joint states in the bag: --protocol cannot be aligned to them")
        ds = replace(ds, segments=None)  # segments come from joint states
    elif segment and protocol is not None:
        ds = _segments_from_protocol(ds, protocol)
    elif segment:
        ds, seg_report = segment_dataset(ds, _segmentation_config(rest_velocity, min_static, min_dynamic))
        for table in segmentation_tables(seg_report):
            console.print(table)
    else:
        ds = replace(ds, segments=None)
    write_dataset(ds, out)
    console.print(f"wrote {out}: {len(ds.units)} units, {ds.duration:.1f} s", highlight=False)


def _read_bag_with_progress(bag: Path, robot: str | None, tmap, accel_unit: str, gyro_unit: str,
                            base_link: str | None = None, tip_link: str | None = None,
                            imu_only: bool | None = False):
    """:func:`~skincal.data.ros.read_bag` with a transient progress bar on stderr (messages read / total)."""
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

    from skincal.cli.app import err_console
    from skincal.data.ros import read_bag

    columns = (TextColumn("reading the bag"), BarColumn(), MofNCompleteColumn(), TextColumn("messages"),
               TimeRemainingColumn())
    with Progress(*columns, console=err_console, transient=True, disable=not err_console.is_terminal) as bar:
        task = bar.add_task("read", total=None)
        return read_bag(bag, robot, tmap, base_link=base_link, tip_link=tip_link, accel_unit=accel_unit,
                        gyro_unit=gyro_unit, progress=lambda done, total: bar.update(task, completed=done, total=total),
                        imu_only=imu_only)


@app.command("segment")
def segment_cmd(
    dataset: Path = typer.Argument(..., help="dataset file (.h5)"),
    out: Path = typer.Option(..., "--out", "-o", help="dataset file to write with /segments (.h5)"),
    rest_velocity: float | None = _REST,
    min_static: float | None = _MIN_STATIC,
    min_dynamic: float | None = _MIN_DYNAMIC,
    protocol: Path | None = _PROTOCOL,
    verbose: bool = typer.Option(False, "--verbose", "-v", help="list every segment"),
    force: bool = typer.Option(False, "--force", help="overwrite --out if it exists"),
) -> None:
    """Find static and single-joint dynamic segments in a recording and write them to /segments."""
    from skincal.data.hdf5 import read_dataset, write_dataset
    from skincal.data.segment import segment_dataset
    from skincal.io.atomic import check_output

    check_output(out, force=force, inputs=(dataset,) + ((protocol,) if protocol else ()))
    ds = read_dataset(dataset)
    ds.require_joints("segment (segments are found in the joint stream)", source=str(dataset))
    had = ds.segments is not None and len(ds.segments) > 0
    if protocol is not None:
        ds = _segments_from_protocol(ds, protocol)
    else:
        ds, report = segment_dataset(ds, _segmentation_config(rest_velocity, min_static, min_dynamic))
        for table in segmentation_tables(report, verbose):
            console.print(table)
    write_dataset(ds, out)
    console.print(f"wrote {out}" + (" (its previous /segments were replaced)" if had else ""), highlight=False)


@app.command("export")
def export_cmd(
    result: Path = typer.Argument(..., help="calibration result (.json)"),
    fmt: str = typer.Option(..., "--format", "-f", help="urdf (complete robot + units), xacro (macro adding the "
                            "units), yaml, json (with 6x6 covariance), tf (ROS 2 node + launch file), tf-ros1 (ROS 1 "
                            "node) or csv"),
    out: Path = typer.Option(..., "--out", "-o", help="file to write"),
    robot: str | None = typer.Option(None, help="robot: a preset, the robot's .urdf or a DH chain file (default: "
                                     "the result's preset)"),
    base_link: str | None = typer.Option(None, help="URDF link the chain starts from (with --robot arm.urdf)"),
    tip_link: str | None = typer.Option(None, help="URDF link the chain ends at (with --robot arm.urdf)"),
    robot_links: Path | None = typer.Option(None, help="YAML map of link number -> frame (+ xyz/rpy offset); "
                                            "overrides the robot's link names"),
    frame: str = typer.Option("unit", help="unit: the unit frames; range: Range frames <unit>_range, +x along the "
                              "ToF beam (sensor_msgs/Range)"),
    prefix: str = typer.Option("", help="prefix of the unit frame names"),
    dataset: Path | None = typer.Option(None, help="the dataset the result was computed from (.h5, checked by its "
                                        "SHA-256): its robot (a URDF robot without --robot), and the frames the "
                                        "poses are moved from onto --robot"),
    force: bool = typer.Option(False, "--force", help="overwrite --out if it exists"),
) -> None:
    """Export calibrated unit poses onto the robot's link frames for ROS (URDF, xacro, YAML/JSON, TF node, CSV).

    Each pose is moved from the link frame of the robot it was computed on into the same link's frame of
    --robot (both chains' forward kinematics; refused when they do not move alike)."""
    from rich.markup import escape

    from skincal.data.export import export_result, without_position
    from skincal.data.result import read_result
    from skincal.io.atomic import check_output
    from skincal.kinematics import PRESETS
    from skincal.names import printable

    robot_file = (Path(robot),) if robot is not None and robot not in PRESETS else ()
    check_output(out, force=force, inputs=(result, *robot_file, *((robot_links,) if robot_links else ()),
                                           *((dataset,) if dataset else ())))
    res = read_result(result)
    source = None
    if dataset is not None:
        from skincal.data.hdf5 import read_dataset
        from skincal.data.provenance import check_result_dataset

        ds = read_dataset(dataset)
        _, provenance_warnings = check_result_dataset(res, result, ds, dataset)
        for text in provenance_warnings:
            console.print("[yellow]warning[/]: " + escape(printable(text)), highlight=False)
        source = ds.chain
    frames = export_result(res, fmt, out, link_map=robot_links, prefix=prefix, robot=robot, base_link=base_link,
                           tip_link=tip_link, frame=frame, source=source)
    # names come from the result and the link map: no markup, control characters shown escaped
    console.print(printable(f"wrote {out}: {len(frames)} unit(s) as {fmt} onto " + ", ".join(
        sorted({f.parent for f in frames}))), highlight=False, markup=False)
    for name in without_position(res):
        console.print("[yellow]warning[/]: " + escape(printable(f"unit {name} not exported (position not determined: "
                                                                 "calibrated from rests only)")), highlight=False)
    for name, reason in res.failed_units.items():
        if name not in res.units:
            console.print("[yellow]warning[/]: " + escape(printable(f"unit {name} not exported (not calibrated: "
                                                                     f"{reason})")), highlight=False)
