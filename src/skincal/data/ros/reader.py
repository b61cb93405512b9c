"""ROS bag import with the ``rosbags`` library: no ROS install.

Reads ROS 1 (``.bag``) and ROS 2 bags (a directory with ``metadata.yaml``, or a bare ``.db3`` /
``.mcap`` file) through ``rosbags.highlevel.AnyReader``:

* The robot: ``--robot`` (a preset, a ``.urdf`` with ``base_link``/``tip_link``, a DH chain file),
  else the URDF on the bag's ``/robot_description`` topic (``std_msgs/String``, latched, as
  ``robot_state_publisher`` publishes it; the last message); a bag with joint states and neither is a
  one-line error asking for ``--robot`` (naming the presets whose joint names it carries).
* ``sensor_msgs/Imu``: ``linear_acceleration`` -> ``/imu/<unit>/accel`` and ``angular_velocity``
  -> ``gyro``. One unit per topic and ``header.frame_id``: a topic whose messages carry several
  frame_ids (IMUs sharing a topic) gives one unit per frame_id, named by it. Unit name: the map,
  else ``header.frame_id``, else the topic; names follow :func:`skincal.names.name_problem`.
  Samples of several sources interleaved under one frame_id are refused, never merged: stamps that
  go back (more than :data:`INTERLEAVED_FRACTION` of the steps in bag order; repeated stamps alone
  are a coarse clock, dropped later with a note), or samples
  that jump away from both neighbours while the neighbours agree (more than
  :data:`INTERLEAVED_FRACTION` of them).
  Units: REP 103 says m/s^2 and rad/s, but some firmware sends g and deg/s (the paper's skin did).
  ``accel_unit="auto"``: the median ``|a|`` of a recording (mostly at rest) is ~1 in g (times
  9.80665) and ~9.81 in m/s^2. ``gyro_unit="auto"``: a link's angular speed never exceeds
  ``sum_j |qd_j|``; a gyro whose 99th percentile speed is several times that of the joints is in deg/s.
* ``sensor_msgs/JointState``: each of the robot's joints is found by name, in any order, among
  extra joints (a gripper's): the topic map's ``joint_names``, else the chain's joint names (the
  URDF's, or a preset's driver names: :mod:`skincal.kinematics.presets`); a message name matches
  exactly or ends with ``_<name>`` / ``/<name>`` (a prefix such as ``lbr_A1``). A joint the messages
  lack is a one-line error naming it. A chain without joint names (a DH chain file) takes the
  message order when a message has exactly ``n`` joints (noted). ``velocity`` missing -> central
  differences of ``position``. Messages without any of the robot's joints (e.g. a gripper's) are
  skipped and counted.
* ``sensor_msgs/Range`` (REP 117: +inf or out of ``[min_range, max_range]`` = no target -> NaN;
  NaN = invalid reading -> dropped) and ``sensor_msgs/LaserScan`` (the minimum valid beam) -> ToF,
  one source per topic and frame_id like the IMUs.

Time: ``header.stamp`` (a topic with zero stamps falls back to the bag's receive time, noted),
shifted so that the first joint state (IMU-only, ``imu_only``: the first IMU or range stamp) is at
0 s (the origin is kept in the description). Samples
are sorted; repeated stamps and NaN samples are dropped with a count in the report.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from skincal.data.dataset import Dataset, ImuStream, JointStates, TofStream
from skincal.data.ros.messages import PROGRESS_EVERY, BagPass, accel_scale, gyro_scale, read_messages
from skincal.data.ros.streams import (
    INTERLEAVED_FRACTION,
    clean_samples,
    first_stamp,
    joint_states_from,
    match_joints,
    refuse_interleaved,
    stamps_ns,
)
from skincal.data.ros.topics import ROBOT_DESCRIPTION, STRING, TopicMap, range_unit, unit_from_topic, unit_name
from skincal.data.validate import validate_dataset
from skincal.errors import ConfigError, DatasetError
from skincal.kinematics.chain import SerialChain
from skincal.names import printable

__all__ = [
    "INTERLEAVED_FRACTION",
    "PROGRESS_EVERY",
    "match_joints",
    "ImportReport",
    "read_bag",
]


@dataclass(frozen=True)
class ImportReport:
    """What :func:`read_bag` read: format, topics and the unit each feeds (``"topic"`` or, for a topic
    carrying several units, ``"topic frame_id"``), the robot and where it came from, and notes (unit
    conversions, fallbacks, dropped samples with counts)."""

    source: str
    ros_version: int
    joint_topic: str
    imu_topics: dict[str, str]
    range_topics: dict[str, str]
    counts: dict[str, int]
    notes: tuple[str, ...]
    time_origin_ns: int
    robot: str = ""
    robot_source: str = ""
    imu_only: bool = False
    """No joint states read (``joint_topic`` is ``""``; ``robot`` ``""`` when the dataset has none)."""


def _robot(robot: SerialChain | str | None, base_link: str | None, tip_link: str | None) -> SerialChain | None:
    """The chain the caller names (None: take it from the bag)."""
    from skincal.kinematics import get_robot

    if isinstance(robot, SerialChain):
        if base_link is not None or tip_link is not None:
            raise ConfigError("--base-link and --tip-link apply to a URDF robot only")
        return robot
    if robot is None:
        return None
    return get_robot(robot, base_link=base_link, tip_link=tip_link)


def _presets_named_by(scan: BagPass) -> list[str]:
    """The presets all of whose joints some JointState message of the bag names: by their exact names,
    else as :func:`match_joints` finds them (a prefix such as ``lbr_A1``)."""
    from skincal.kinematics import PRESETS, get_robot

    topic = scan.used.joints
    seen = {row[2][0] for row in scan.rows.get(topic, [])} if topic is not None else set()
    exact, suffixed = [], []
    for name in PRESETS:
        wanted = get_robot(name).joint_names
        if wanted is None:
            continue
        if any(set(wanted) <= set(names) for names in seen):
            exact.append(name)
            continue
        for names in seen:
            try:
                cols, _ = match_joints(names, wanted, "", topic or "")
            except DatasetError:  # a name matched twice: not this robot's naming
                cols = None
            if cols is not None:
                suffixed.append(name)
                break
    return exact or suffixed


def _robot_from_bag(scan: BagPass, source: str, base_link: str | None, tip_link: str | None) -> tuple[SerialChain, str]:
    """The chain of the bag's ``/robot_description`` (the last message); without one, a one-line error
    asking for ``--robot`` (naming the presets whose joint names the joint states carry): the robot is
    never assumed (it was the Panda, said only in a note)."""
    from skincal.kinematics.urdf import chain_from_urdf

    texts = scan.rows.get(ROBOT_DESCRIPTION) or []
    if not texts:
        if base_link is not None or tip_link is not None:
            raise ConfigError(
                f"--base-link/--tip-link need a URDF: give --robot arm.urdf ({source} has no {ROBOT_DESCRIPTION} topic)"
            )
        fits = _presets_named_by(scan)
        hint = (f"; its joint names are those of {' and '.join(repr(f) for f in fits)}: e.g. --robot {fits[0]}"
                if fits else "")  # fmt: skip
        raise ConfigError(
            printable(
                f"{source} has no {ROBOT_DESCRIPTION}: give the robot with --robot (a preset, arm.urdf or a DH "
                f"chain file){hint}"
            )
        )
    text = texts[-1][2]
    if len({t[2] for t in texts}) > 1:
        scan.notes.append(f"{ROBOT_DESCRIPTION}: {len(texts)} different descriptions; using the last")
    try:
        chain = chain_from_urdf(text=text, base_link=base_link, tip_link=tip_link)
    except ConfigError as exc:
        raise DatasetError(f"{source}: {ROBOT_DESCRIPTION}: {exc}") from None
    scan.notes.append(
        printable(
            f"robot '{chain.name}' from {ROBOT_DESCRIPTION}: {chain.n_joints} joints "
            f"{chain.link_name(0)} -> {chain.link_name(chain.n_joints)}"
        )
    )
    return chain, ROBOT_DESCRIPTION


def _sources(
    topic: str, rows: list, frame_at: int, name: str, source: str, what: str, notes: list[str]
) -> dict[str, list]:
    """The rows of ``topic`` per source: one per ``header.frame_id`` (payload item ``frame_at``). A
    unit name given for a topic that carries several frame_ids is an error."""
    by_frame: dict[str, list] = {}
    for r in rows:
        by_frame.setdefault(r[2][frame_at], []).append(r)
    by_frame = dict(sorted(by_frame.items()))  # units in name order, as with one topic per unit
    if len(by_frame) > 1:
        frames = ", ".join(repr(f) for f in by_frame)
        if name:
            raise DatasetError(
                printable(
                    f"{source}: {what} topic {topic} carries {len(by_frame)} frame_ids "
                    f"({frames}), one unit each; a single unit name '{name}' cannot hold "
                    "them (leave it out to name the units by frame_id)"
                )
            )
        if "" in by_frame:
            raise DatasetError(
                printable(
                    f"{source}: {what} topic {topic} carries frame_ids {frames}, some "
                    "empty: cannot tell which unit those messages come from"
                )
            )
        notes.append(printable(f"{topic}: {len(by_frame)} frame_ids ({frames}): one unit each"))
    return by_frame


def read_bag(
    path: str | Path,
    robot: SerialChain | str | None = None,
    tmap: TopicMap | None = None,
    *,
    base_link: str | None = None,
    tip_link: str | None = None,
    accel_unit: str = "auto",
    gyro_unit: str = "auto",
    progress: Callable[[int, int], None] | None = None,
    imu_only: bool | None = False,
) -> tuple[Dataset, ImportReport]:
    """Read a ROS 1/ROS 2 bag into a :class:`Dataset` without segments (see the module docstring).

    Args:
        path: ``.bag`` file, ROS 2 bag directory, or ``.db3``/``.mcap`` file.
        robot: preset name, ``.urdf`` or DH chain file, or chain; None: the bag's
            ``/robot_description`` (without one, joint states are a :class:`ConfigError` asking for it).
        tmap: topics to read (default: every Imu, JointState, Range and LaserScan topic).
        base_link, tip_link: the serial chain of a URDF (``robot`` a ``.urdf``, or the bag's).
        accel_unit: ``auto``, ``g`` or ``mps2``; gyro_unit: ``auto``, ``rad`` or ``deg`` (per second).
        progress: called as ``progress(read, total)`` with the messages of the selected topics read so
            far and their total (from the bag's index): at the start, every :data:`PROGRESS_EVERY`
            messages and at the end.
        imu_only: True: an IMU-only dataset (no ``/joints``; JointState topics are not read; the
            robot only when ``robot`` is given or the bag has ``/robot_description``, never the
            default); None: IMU-only when the bag has IMU topics and no JointState topic (noted);
            False (default): joint states required. IMU-only time starts at the first IMU or range
            stamp, and ``gyro_unit="auto"`` takes rad/s (noted: no joint speeds to compare with).

    Raises:
        DatasetError: missing, empty, truncated or corrupt bag; no joint states; a joint of the robot
            missing from them; an unknown topic; a topic whose samples are all NaN; interleaved
            sources under one frame_id; one line naming the bag and the topic.
        ConfigError: a bad robot, link or unit option.
    """
    chain = _robot(robot, base_link, tip_link)
    path = Path(path)
    source = str(path)
    tmap = tmap or TopicMap()
    scan = read_messages(path, source, tmap, chain is None, progress, imu_only)
    notes, rows, used = scan.notes, scan.rows, scan.used
    counts = {t: len(r) for t, r in rows.items()}
    with_joints = used.joints is not None
    if chain is None and (with_joints or scan.rows.get(ROBOT_DESCRIPTION)):
        chain, robot_source = _robot_from_bag(scan, source, base_link, tip_link)
    elif chain is None:  # IMU-only, no robot named anywhere: none (not the default panda)
        if base_link is not None or tip_link is not None:
            raise ConfigError(
                f"--base-link/--tip-link need a URDF: give --robot arm.urdf ({source} has no {ROBOT_DESCRIPTION} topic)"
            )
        robot_source = "none"
    else:
        robot_source = str(robot) if isinstance(robot, str) else "chain"
        if scan.topics.get(ROBOT_DESCRIPTION) == STRING:
            notes.append(f"{ROBOT_DESCRIPTION} in the bag not used (robot given: {chain.name})")

    joints: JointStates | None = None
    if with_joints:
        if chain is None:  # pragma: no cover - a robot is always found with joint states
            raise DatasetError(f"{source}: no robot for the joint states")
        t_j, q, qd = joint_states_from(scan, chain, source)
        origin = int(t_j[0])
        qd_sum_p99 = float(np.percentile(np.sum(np.abs(qd), axis=1), 99))
    else:  # IMU-only: time from the first IMU or range stamp
        origin = first_stamp(scan, source)
        qd_sum_p99 = 0.0
        if gyro_unit == "auto":
            notes.append("IMU-only: gyroscopes taken in rad/s (no joint speeds to check; --gyro-unit deg converts)")
    to_s = lambda ns: (ns - origin) * 1e-9  # noqa: E731
    if with_joints:
        joints = JointStates(t=to_s(t_j), q=q, qd=qd)

    # IMUs: one unit per topic and frame_id.
    imu: dict[str, ImuStream] = {}
    imu_units: dict[str, str] = {}
    for topic, name in used.imu.items():
        if not rows[topic]:
            raise DatasetError(f"{source}: IMU topic {topic} has no messages")
        by_frame = _sources(topic, rows[topic], 6, name, source, "IMU", notes)
        split = len(by_frame) > 1
        for frame, frows in by_frame.items():
            if split:
                unit, label = unit_name(frame, source, topic, "frame_id"), f"{topic} {frame}"
            elif name:
                unit, label = name, topic
            elif frame and frame not in imu:
                unit, label = unit_name(frame, source, topic, "frame_id"), topic
            else:
                unit, label = unit_name(unit_from_topic(topic), source, topic, "topic"), topic
            if unit in imu:
                raise DatasetError(
                    printable(
                        f"{source}: {label} and another IMU source both map to unit '{unit}'; "
                        "name them in the topic map"
                    )
                )
            t_ns = stamps_ns([r[:2] for r in frows], label, notes)
            vals = np.array([r[2][:6] for r in frows], dtype=float)
            refuse_interleaved(label, t_ns, vals[np.argsort(t_ns, kind="stable"), :3], source)
            t_ns, vals = clean_samples(label, t_ns, vals, notes, source)
            accel = vals[:, :3] * accel_scale(label, vals[:, :3], accel_unit, source, notes)
            gyro = vals[:, 3:] * gyro_scale(label, vals[:, 3:], qd_sum_p99, gyro_unit, notes)
            imu[unit] = ImuStream(t=to_s(t_ns), accel=accel, gyro=gyro)
            imu_units[label] = unit

    # Time-of-flight: one source per topic and frame_id.
    tof: dict[str, TofStream] = {}
    range_units: dict[str, str] = {}
    one_unit = {t: u for t, u in imu_units.items() if " " not in t}
    for topic, name in used.range.items():
        if not rows[topic]:
            continue
        by_frame = _sources(topic, rows[topic], 3, name, source, "range", notes)
        split = len(by_frame) > 1
        for frame, frows in by_frame.items():
            label = f"{topic} {frame}" if split else topic
            tof_unit = name or range_unit(topic, frame, {} if split else one_unit, set(imu))
            if tof_unit is None:
                if topic in tmap.range:
                    raise DatasetError(
                        printable(f"{source}: range topic {label}: cannot tell its unit; write {topic}=UNIT")
                    )
                notes.append(printable(f"{label}: skipped (cannot tell which unit it belongs to; give {topic}=UNIT)"))
                continue
            if tof_unit not in imu:
                raise DatasetError(
                    printable(f"{source}: range topic {label} maps to unit '{tof_unit}', which has no IMU topic")
                )
            if tof_unit in tof:
                raise DatasetError(printable(f"{source}: range topic {label} and another map to unit '{tof_unit}'"))
            t_ns = stamps_ns([r[:2] for r in frows], label, notes)
            refuse_interleaved(label, t_ns, None, source)
            vals = np.array([r[2][:3] for r in frows], dtype=float)
            t_ns, vals = clean_samples(label, t_ns, vals, notes, source)
            r, lo, hi = vals.T
            no_target = ~((r >= lo) & (r <= hi))
            if np.any(no_target):
                notes.append(f"{label}: {int(np.sum(no_target))} reading(s) out of range (no target) -> NaN")
            tof[tof_unit] = TofStream(t=to_s(t_ns), range=np.where(no_target, np.nan, r))
            range_units[label] = tof_unit

    ds = Dataset(
        robot=chain,
        joints=joints,
        imu=imu,
        tof=tof,
        description=f"imported from {path.name} (ROS {scan.ros}); time origin {origin} ns since the epoch",
    )
    validate_dataset(ds, source)
    report = ImportReport(
        source=source,
        ros_version=scan.ros,
        joint_topic=used.joints or "",
        imu_topics=imu_units,
        range_topics=range_units,
        counts=counts,
        notes=tuple(notes),
        time_origin_ns=origin,
        robot="" if chain is None else chain.name,
        robot_source=robot_source,
        imu_only=not with_joints,
    )
    return ds, report
