"""ROS bag import with the ``rosbags`` library: no ROS install.

Reads ROS 1 (``.bag``) and ROS 2 bags (a directory with ``metadata.yaml``, or a bare ``.db3`` /
``.mcap`` file) through ``rosbags.highlevel.AnyReader``:

* The robot: ``--robot`` (a preset, a ``.urdf`` with ``base_link``/``tip_link``, a DH chain file),
  else the URDF on the bag's ``/robot_description`` topic (``std_msgs/String``, latched, as
  ``robot_state_publisher`` publishes it; the last message), else the ``panda`` preset (noted).
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
from typing import Any

import numpy as np

from skincal.data.dataset import Dataset, ImuStream, JointStates, TofStream
from skincal.data.ros.topics import (
    IMU,
    JOINTS,
    RANGE,
    ROBOT_DESCRIPTION,
    SCAN,
    STRING,
    TopicMap,
    range_unit,
    unit_from_topic,
    unit_name,
)
from skincal.data.validate import validate_dataset
from skincal.errors import ConfigError, DatasetError
from skincal.errors import first_line as _first_line
from skincal.kinematics.chain import SerialChain
from skincal.names import printable
from skincal.skin.imu import STANDARD_GRAVITY

PROGRESS_EVERY = 5000
"""Messages between two calls of :func:`read_bag`'s ``progress`` callback."""
INTERLEAVED_FRACTION = 0.01
"""Above this fraction of stamps going back or repeating (in bag order), or of samples jumping away
from both neighbours, one frame_id's samples come from several sources: refused."""
JUMP_RELATIVE = 0.05
"""A sample "jumps" when it is farther than this times the median ``|a|`` (and 3 times the gap
between its neighbours) from both neighbours."""


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


def _stamps(rows: list[tuple[int, int]], topic: str, notes: list[str]) -> np.ndarray:
    """``(M,)`` int64 ns from (header stamp ns, bag time ns) rows; bag time if a stamp is zero."""
    arr = np.array(rows, dtype=np.int64).reshape(-1, 2)
    if np.any(arr[:, 0] == 0):
        notes.append(f"{topic}: header.stamp is zero in {int(np.sum(arr[:, 0] == 0))} message(s); using bag time")
        return arr[:, 1]
    return arr[:, 0]


def _clean(
    topic: str, t_ns: np.ndarray, values: np.ndarray, notes: list[str], source: str, nan_ok: bool = False
) -> tuple[np.ndarray, np.ndarray]:
    """Sort by time, drop repeated stamps and (unless ``nan_ok``) samples with NaN; error if none left."""
    order = np.argsort(t_ns, kind="stable")
    t_ns, values = t_ns[order], values[order]
    keep = np.concatenate([[True], np.diff(t_ns) > 0])
    if not np.all(keep):
        notes.append(f"{topic}: dropped {int(np.sum(~keep))} message(s) with a repeated time stamp")
    flat = values.reshape(len(values), -1)
    bad = np.zeros(len(values), dtype=bool) if nan_ok else np.any(np.isnan(flat), axis=1)
    if np.all(bad):
        raise DatasetError(f"{source}: topic {topic}: all {len(values)} samples contain NaN")
    if np.any(bad & keep):
        notes.append(f"{topic}: dropped {int(np.sum(bad & keep))} sample(s) containing NaN")
    keep &= ~bad
    return t_ns[keep], values[keep]


def _refuse_interleaved(label: str, t_ns: np.ndarray, accel: np.ndarray | None, source: str) -> None:
    """One-line :class:`DatasetError` when one source's samples (``t_ns`` in bag order; ``accel`` in
    time order, raw units) look like several sources interleaved (module docstring)."""
    hint = "give each sensor its own frame_id or topic"
    steps = np.diff(t_ns)
    back = int(np.sum(steps < 0))  # repeated stamps alone are coarse clocks (dropped later, with a note)
    if back > max(1, INTERLEAVED_FRACTION * len(steps)):
        raise DatasetError(
            printable(
                f"{source}: {label}: {back} of {len(steps)} time stamps go back: "
                f"samples of several sources interleaved (not merged); {hint}"
            )
        )
    if accel is None or len(accel) < 3:
        return
    a = accel[np.all(np.isfinite(accel), axis=1)]
    if len(a) < 3:
        return
    d_prev = np.linalg.norm(a[1:-1] - a[:-2], axis=1)
    d_next = np.linalg.norm(a[1:-1] - a[2:], axis=1)
    d_skip = np.linalg.norm(a[2:] - a[:-2], axis=1)
    eps = JUMP_RELATIVE * float(np.median(np.linalg.norm(a, axis=1)))
    jumps = int(np.sum(np.minimum(d_prev, d_next) > 3.0 * d_skip + eps))
    if jumps > max(1, INTERLEAVED_FRACTION * len(d_skip)):
        raise DatasetError(
            printable(
                f"{source}: {label}: {jumps} of {len(d_skip)} samples jump away from both "
                f"neighbours: samples of several sources interleaved (not merged); {hint}"
            )
        )


def match_joints(
    names: tuple[str, ...], wanted: tuple[str, ...], source: str, topic: str
) -> tuple[np.ndarray | None, list[str]]:
    """Index into the message's arrays of each wanted joint (None if some are missing) and the
    missing ones. A name matches exactly, else as a ``_``/``/`` suffix; two matches are an error."""
    cols, missing = [], []
    for w in wanted:
        hits = [i for i, name in enumerate(names) if name == w]
        if not hits:
            hits = [i for i, name in enumerate(names) if name.endswith("_" + w) or name.endswith("/" + w)]
        if len(hits) > 1:
            raise DatasetError(
                printable(
                    f"{source}: topic {topic}: joint '{w}' matches several names of a message "
                    f"({', '.join(names[i] for i in hits)}); give joint_names in the topic map"
                )
            )
        if hits:
            cols.append(hits[0])
        else:
            missing.append(w)
    return (None if missing else np.array(cols, dtype=int)), missing


def _accel_scale(topic: str, accel: np.ndarray, unit: str, source: str, notes: list[str]) -> float:
    if unit in ("g", "mps2"):
        return STANDARD_GRAVITY if unit == "g" else 1.0
    if unit != "auto":
        raise ConfigError(f"accel unit must be auto, g or mps2, got '{unit}'")
    med = float(np.median(np.linalg.norm(accel, axis=1)))
    if 0.5 < med < 2.0:
        notes.append(f"{topic}: accelerometer in g (median |a| = {med:.3f}); converted to m/s^2 (x {STANDARD_GRAVITY})")
        return STANDARD_GRAVITY
    if 5.0 < med < 20.0:
        return 1.0
    raise DatasetError(
        f"{source}: topic {topic}: median |linear_acceleration| is {med:.3g}, neither ~1 (g) nor "
        "~9.81 (m/s^2); give the unit (--accel-unit)"
    )


def _gyro_scale(topic: str, gyro: np.ndarray, qd_sum_p99: float, unit: str, notes: list[str]) -> float:
    if unit in ("rad", "deg"):
        return np.pi / 180.0 if unit == "deg" else 1.0
    if unit != "auto":
        raise ConfigError(f"gyro unit must be auto, rad or deg, got '{unit}'")
    w99 = float(np.percentile(np.linalg.norm(gyro, axis=1), 99))
    if qd_sum_p99 > 0.1 and w99 > 5.0 * qd_sum_p99 + 0.5:
        notes.append(f"{topic}: gyroscope in deg/s (99th pct {w99:.3g} vs joints {qd_sum_p99:.3g} rad/s); converted")
        return np.pi / 180.0
    return 1.0


def _open_reader(path: Path):
    from rosbags.highlevel import AnyReader

    if not path.exists():
        raise DatasetError(f"{path}: no such bag file or directory")
    reader = AnyReader([path])
    reader.open()
    return reader


@dataclass
class _Pass:
    """What one pass over the bag gave: ROS version, the topics chosen, rows per topic, all topic types."""

    ros: int
    used: TopicMap
    rows: dict[str, list]
    topics: dict[str, str]
    notes: list[str]


def _read_messages(
    path: Path,
    source: str,
    tmap: TopicMap,
    description: bool,
    progress: Callable[[int, int], None] | None = None,
    imu_only: bool | None = False,
) -> _Pass:
    """One pass over the bag: per selected topic, a list of (stamp ns, bag ns, payload) rows (and the
    ``/robot_description`` text when ``description``); ``progress(read, total)`` every
    :data:`PROGRESS_EVERY` messages of the selected topics and at the end. ``imu_only``: True reads
    no joint states; None reads none when the bag has no JointState topic (noted); False needs them.
    ``used.joints`` is None when no joint states are read."""
    notes: list[str] = []
    try:
        reader = _open_reader(path)
    except DatasetError:
        raise
    except Exception as exc:  # rosbags/sqlite/mcap raise many types; the user gets one line
        raise DatasetError(f"{source}: cannot open the bag ({_first_line(exc)}; truncated or not a bag?)") from None
    try:
        topics = {name: info.msgtype for name, info in reader.topics.items()}
        if reader.message_count == 0:
            raise DatasetError(f"{source}: the bag is empty (no messages)")
        listing = ", ".join(f"{k} ({v})" for k, v in sorted(topics.items()))

        def pick(kind: tuple[str, ...], given: dict[str, str], what: str) -> dict[str, str]:
            for topic in given:
                if topic not in topics:
                    raise DatasetError(f"{source}: {what} topic '{topic}' is not in the bag (topics: {listing})")
                if topics[topic] not in kind:
                    raise DatasetError(f"{source}: topic '{topic}' is {topics[topic]}, expected {' or '.join(kind)}")
            return dict(given) if given else {t: "" for t, ty in sorted(topics.items()) if ty in kind}

        imu = pick((IMU,), tmap.imu, "IMU")
        ranges = pick((RANGE, SCAN), tmap.range, "range")
        joint_topic: str | None = None
        found = [t for t, ty in topics.items() if ty == JOINTS]
        if imu_only:
            if tmap.joints:
                raise ConfigError("an IMU-only import reads no joint states: give no joint topic with it")
            if found:
                notes.append(f"IMU-only: joint states on {', '.join(sorted(found))} not read")
        elif tmap.joints:
            pick((JOINTS,), {tmap.joints: ""}, "joint state")
            joint_topic = tmap.joints
        elif not found and imu_only is None and imu:
            notes.append("no sensor_msgs/JointState topic: an IMU-only dataset (calibrate it with --reference UNIT)")
        else:
            if not found:
                raise DatasetError(
                    f"{source}: no sensor_msgs/JointState topic; calibration needs the robot's joint "
                    f"states, or import it IMU-only (--imu-only) (topics: {listing})"
                )
            if len(found) > 1:
                raise DatasetError(
                    f"{source}: several JointState topics ({', '.join(sorted(found))}); choose one with --joint-topic"
                )
            joint_topic = found[0]
        if not imu:
            raise DatasetError(f"{source}: no sensor_msgs/Imu topic (topics: {listing})")
        selected = {*((joint_topic,) if joint_topic else ()), *imu, *ranges}
        if description and topics.get(ROBOT_DESCRIPTION) == STRING:
            selected.add(ROBOT_DESCRIPTION)
        rows: dict[str, list] = {t: [] for t in selected}
        conns = [c for c in reader.connections if c.topic in selected]
        total, done = sum(int(c.msgcount) for c in conns), 0
        if progress is not None:
            progress(0, total)
        for conn, bag_ns, raw in reader.messages(connections=conns):  # deserialisation is per message
            done += 1
            if progress is not None and done % PROGRESS_EVERY == 0:
                progress(done, total)
            msg = reader.deserialize(raw, conn.msgtype)
            if conn.msgtype == STRING:
                rows[conn.topic].append((0, bag_ns, str(msg.data)))
                continue
            stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
            if conn.msgtype == IMU:
                a, w = msg.linear_acceleration, msg.angular_velocity
                payload: Any = (a.x, a.y, a.z, w.x, w.y, w.z, msg.header.frame_id)
            elif conn.msgtype == JOINTS:
                payload = (tuple(msg.name), np.asarray(msg.position, float), np.asarray(msg.velocity, float))
            elif conn.msgtype == RANGE:
                payload = (msg.range, msg.min_range, msg.max_range, msg.header.frame_id)
            else:
                r = np.asarray(msg.ranges, dtype=float)
                r = r[(r >= msg.range_min) & (r <= msg.range_max)]
                payload = (float(r.min()) if r.size else np.inf, msg.range_min, msg.range_max, msg.header.frame_id)
            rows[conn.topic].append((stamp, bag_ns, payload))
        if progress is not None and done % PROGRESS_EVERY:
            progress(done, total)
    except DatasetError:
        raise
    except Exception as exc:
        raise DatasetError(f"{source}: cannot read the bag ({_first_line(exc)}; truncated or corrupt?)") from None
    finally:
        try:
            reader.close()
        except Exception:  # noqa: BLE001 - closing a broken bag must not hide the first error
            pass
    used = TopicMap(imu=imu, joints=joint_topic, range=ranges, joint_names=tmap.joint_names)
    return _Pass(2 if reader.is2 else 1, used, rows, topics, notes)


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


def _robot_from_bag(scan: _Pass, source: str, base_link: str | None, tip_link: str | None) -> tuple[SerialChain, str]:
    """The chain of the bag's ``/robot_description`` (the last message), else the panda preset."""
    from skincal.kinematics import get_robot
    from skincal.kinematics.urdf import chain_from_urdf

    texts = scan.rows.get(ROBOT_DESCRIPTION) or []
    if not texts:
        if base_link is not None or tip_link is not None:
            raise ConfigError(
                f"--base-link/--tip-link need a URDF: give --robot arm.urdf ({source} has no {ROBOT_DESCRIPTION} topic)"
            )
        scan.notes.append(f"no --robot given and no {ROBOT_DESCRIPTION} in the bag: robot 'panda' (the default)")
        return get_robot("panda"), "default"
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


def _joint_states(scan: _Pass, chain: SerialChain, source: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(t_ns, q, qd)`` of the robot's joints, found by name (module docstring)."""
    topic, notes = scan.used.joints, scan.notes
    jrows = scan.rows[topic]
    if not jrows:
        raise DatasetError(f"{source}: joint state topic {topic} has no messages")
    n = chain.n_joints
    wanted = scan.used.joint_names or chain.joint_names
    if wanted is not None and len(wanted) != n:
        raise ConfigError(f"joint_names has {len(wanted)} names but robot '{chain.name}' has {n} joints")
    matched: dict[tuple[str, ...], tuple[np.ndarray | None, list[str]]] = {}
    keep, q_rows, qd_rows = [], [], []
    for i, (_, _, (names, pos, vel)) in enumerate(jrows):  # per message: name order may differ between messages
        if names not in matched:
            if wanted is not None:
                matched[names] = match_joints(names, wanted, source, topic)
            elif len(names) == n:
                matched[names] = (np.arange(n), [])
                notes.append(
                    printable(
                        f"{topic}: robot '{chain.name}' has no joint names; taking the message's "
                        f"order {', '.join(names)} as joints 1..{n}"
                    )
                )
            else:
                matched[names] = (None, [f"joint{j}" for j in range(1, n + 1)])
        cols = matched[names][0]
        if cols is None or pos.shape[0] != len(names):
            continue
        keep.append(i)
        q_rows.append(pos[cols])
        qd_rows.append(vel[cols] if vel.shape[0] == len(names) else np.full(len(cols), np.nan))
    if not keep:
        seen = "; ".join(", ".join(k) for k in list(matched)[:2])
        if wanted is None:
            raise DatasetError(
                printable(
                    f"{source}: topic {topic}: robot '{chain.name}' has no joint names and no "
                    f"message has exactly its {n} joints (names seen: {seen}); give "
                    "joint_names in the topic map"
                )
            )
        missing = min((m for _, m in matched.values()), key=len)
        raise DatasetError(
            printable(
                f"{source}: topic {topic}: joint{'s' if len(missing) > 1 else ''} {', '.join(missing)} of robot "
                f"'{chain.name}' missing from the messages (names seen: {seen}); give joint_names in the topic map"
            )
        )
    if len(keep) < len(jrows):
        partial = sorted({m for c, ms in matched.values() if c is None and len(ms) < n for m in ms})
        notes.append(
            f"{topic}: skipped {len(jrows) - len(keep)} message(s) without the robot's joints"
            + (f" (some lack {', '.join(partial)})" if partial else "")
        )
    t_j = _stamps([jrows[i][:2] for i in keep], topic, notes)
    q, qd = np.array(q_rows), np.array(qd_rows)
    no_velocity = np.all(np.isnan(qd), axis=1)
    t_j, qq = _clean(topic, t_j, np.stack([q, np.where(no_velocity[:, None], 0.0, qd)], axis=1), notes, source)
    q, qd = qq[:, 0], qq[:, 1]
    if np.any(no_velocity):
        if len(t_j) < 3:
            raise DatasetError(f"{source}: topic {topic}: {len(t_j)} samples, too few to differentiate")
        qd = np.gradient(q, (t_j - t_j[0]) * 1e-9, axis=0)  # relative: epoch seconds lose precision
        notes.append(
            f"{topic}: no velocities in {int(np.sum(no_velocity))} message(s); joint velocities "
            "from central differences of the positions"
        )
    return t_j, q, qd


def _first_stamp(scan: _Pass, source: str) -> int:
    """The earliest header stamp (the bag time where a topic's stamps are zero) of the IMU and range
    topics read: time 0 of an IMU-only dataset."""
    firsts = []
    for topic in (*scan.used.imu, *scan.used.range):
        rows = scan.rows.get(topic) or []
        if rows:
            firsts.append(int(_stamps([r[:2] for r in rows], topic, []).min()))
    if not firsts:
        raise DatasetError(f"{source}: the IMU topics have no messages")
    return min(firsts)


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
            ``/robot_description``, else the ``panda`` preset (noted).
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
    scan = _read_messages(path, source, tmap, chain is None, progress, imu_only)
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
        t_j, q, qd = _joint_states(scan, chain, source)
        origin = int(t_j[0])
        qd_sum_p99 = float(np.percentile(np.sum(np.abs(qd), axis=1), 99))
    else:  # IMU-only: time from the first IMU or range stamp
        origin = _first_stamp(scan, source)
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
            t_ns = _stamps([r[:2] for r in frows], label, notes)
            vals = np.array([r[2][:6] for r in frows], dtype=float)
            _refuse_interleaved(label, t_ns, vals[np.argsort(t_ns, kind="stable"), :3], source)
            t_ns, vals = _clean(label, t_ns, vals, notes, source)
            accel = vals[:, :3] * _accel_scale(label, vals[:, :3], accel_unit, source, notes)
            gyro = vals[:, 3:] * _gyro_scale(label, vals[:, 3:], qd_sum_p99, gyro_unit, notes)
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
            t_ns = _stamps([r[:2] for r in frows], label, notes)
            _refuse_interleaved(label, t_ns, None, source)
            vals = np.array([r[2][:3] for r in frows], dtype=float)
            t_ns, vals = _clean(label, t_ns, vals, notes, source)
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
