"""ROS bag import (and export of a dataset as a bag) with the ``rosbags`` library: no ROS install.

Reads ROS 1 (``.bag``) and ROS 2 bags (a directory with ``metadata.yaml``, or a bare ``.db3`` /
``.mcap`` file) through ``rosbags.highlevel.AnyReader``:

* ``sensor_msgs/Imu``, one topic per unit: ``linear_acceleration`` -> ``/imu/<unit>/accel`` and
  ``angular_velocity`` -> ``gyro``. Units: REP 103 says m/s^2 and rad/s, but some firmware sends
  g and deg/s (the paper's skin did). ``accel_unit="auto"``: the median ``|a|`` of a recording
  (mostly at rest) is ~1 in g (times 9.80665) and ~9.81 in m/s^2. ``gyro_unit="auto"``: a link's
  angular speed never exceeds ``sum_j |qd_j|``; a gyro whose 99th percentile speed is several times
  that of the joints is in deg/s. Unit name: the map, else ``header.frame_id``, else the topic.
* ``sensor_msgs/JointState``: ``name`` order mapped to the robot's joints (explicit names, the
  preset's known names, or the message order when it has exactly ``n`` joints); ``velocity``
  missing -> central differences of ``position``. Messages without the robot's joints (e.g. a
  gripper's) are skipped and counted.
* ``sensor_msgs/Range`` (REP 117: +inf or out of ``[min_range, max_range]`` = no target -> NaN;
  NaN = invalid reading -> dropped) and ``sensor_msgs/LaserScan`` (the minimum valid beam) -> ToF.

Time: ``header.stamp`` (a topic with zero stamps falls back to the bag's receive time, noted),
shifted so that the first joint state is at 0 s (the origin is kept in the description). Samples
are sorted; repeated stamps and NaN samples are dropped with a count in the report.
"""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from skincal.data.dataset import Dataset, ImuStream, JointStates, TofStream
from skincal.data.jsonio import load_yaml
from skincal.data.validate import validate_dataset
from skincal.errors import ConfigError, DatasetError
from skincal.errors import first_line as _first_line
from skincal.kinematics.chain import SerialChain
from skincal.skin.imu import STANDARD_GRAVITY

PROGRESS_EVERY = 5000
"""Messages between two calls of :func:`read_bag`'s ``progress`` callback."""
IMU, JOINTS, RANGE, SCAN = (f"sensor_msgs/msg/{x}" for x in ("Imu", "JointState", "Range", "LaserScan"))
KNOWN_JOINT_NAMES: dict[str, tuple[str, ...]] = {
    "panda": tuple(f"panda_joint{i}" for i in range(1, 8)),
    "sawyer": tuple(f"right_j{i}" for i in range(7)),
    "ur5e": ("shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint", "wrist_1_joint", "wrist_2_joint",
             "wrist_3_joint"),
}
"""Joint names robots publish, in kinematic order (matched as suffixes, so ``ur_elbow_joint`` works)."""


@dataclass(frozen=True)
class TopicMap:
    """Which topics to read. ``imu`` / ``range``: topic -> unit name (``""``: from frame_id or topic);
    ``joints``: the JointState topic; ``joint_names``: the robot's joints in kinematic order. Empty
    fields are filled automatically from the bag's message types."""

    imu: dict[str, str] = field(default_factory=dict)
    joints: str | None = None
    range: dict[str, str] = field(default_factory=dict)
    joint_names: tuple[str, ...] | None = None


@dataclass(frozen=True)
class ImportReport:
    """What :func:`read_bag` read: format, topics and the unit each feeds, and notes (unit
    conversions, fallbacks, dropped samples with counts)."""

    source: str
    ros_version: int
    joint_topic: str
    imu_topics: dict[str, str]
    range_topics: dict[str, str]
    counts: dict[str, int]
    notes: tuple[str, ...]
    time_origin_ns: int


def _parse_topic_spec(specs: list[str] | tuple[str, ...] | None) -> dict[str, str]:
    out = {}
    for spec in specs or ():
        topic, _, name = spec.partition("=")
        out[topic.strip()] = name.strip()
    return out


def topic_map(imu: list[str] | None = None, joints: str | None = None, range_: list[str] | None = None,
              joint_names: list[str] | None = None, path: str | Path | None = None) -> TopicMap:
    """A :class:`TopicMap` from a YAML file (``imu``, ``joints``, ``range``, ``joint_names`` keys;
    ``imu``/``range`` a topic -> unit mapping or a list of topics) overridden by options
    (``TOPIC`` or ``TOPIC=UNIT`` strings)."""
    doc: dict[str, Any] = {}
    if path is not None:
        doc = load_yaml(path, "topic map", ConfigError) or {}
        if not isinstance(doc, dict) or set(doc) - {"imu", "joints", "range", "joint_names"}:
            raise ConfigError(f"{path}: a topic map has keys imu, joints, range, joint_names; got {doc!r:.80}")
    maps = {}
    for key in ("imu", "range"):
        value = doc.get(key) or {}
        if isinstance(value, list):
            value = {str(t): "" for t in value}
        if not isinstance(value, dict):
            raise ConfigError(f"{path}: '{key}' must map topics to unit names or list topics")
        maps[key] = {str(k): "" if v is None else str(v) for k, v in value.items()}
    maps["imu"].update(_parse_topic_spec(imu))
    maps["range"].update(_parse_topic_spec(range_))
    names = joint_names or doc.get("joint_names")
    return TopicMap(imu=maps["imu"], joints=joints or doc.get("joints"), range=maps["range"],
                    joint_names=None if not names else tuple(str(n) for n in names))


def _unit_from_topic(topic: str) -> str:
    parts = [p for p in topic.split("/") if p and p not in ("imu", "data", "data_raw", "range", "tof", "scan")]
    return "_".join(parts) or topic.strip("/").replace("/", "_")


def _stamps(rows: list[tuple[int, int]], topic: str, notes: list[str]) -> np.ndarray:
    """``(M,)`` int64 ns from (header stamp ns, bag time ns) rows; bag time if a stamp is zero."""
    arr = np.array(rows, dtype=np.int64).reshape(-1, 2)
    if np.any(arr[:, 0] == 0):
        notes.append(f"{topic}: header.stamp is zero in {int(np.sum(arr[:, 0] == 0))} message(s); using bag time")
        return arr[:, 1]
    return arr[:, 0]


def _clean(topic: str, t_ns: np.ndarray, values: np.ndarray, notes: list[str], source: str,
           nan_ok: bool = False) -> tuple[np.ndarray, np.ndarray]:
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


def _joint_columns(names: tuple[str, ...], chain: SerialChain, tmap: TopicMap) -> np.ndarray | None:
    """Index into the message's arrays of each robot joint, or None if the message lacks them."""
    n = chain.n_joints
    wanted = tmap.joint_names or KNOWN_JOINT_NAMES.get(chain.name)
    if wanted is not None:
        if len(wanted) != n:
            raise ConfigError(f"joint_names has {len(wanted)} names but robot '{chain.name}' has {n} joints")
        cols = []
        for w in wanted:
            hits = [i for i, name in enumerate(names) if name == w or name.endswith("_" + w) or name.endswith("/" + w)]
            if len(hits) != 1:
                return None
            cols.append(hits[0])
        return np.array(cols)
    return np.arange(n) if len(names) == n else None


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
    raise DatasetError(f"{source}: topic {topic}: median |linear_acceleration| is {med:.3g}, neither ~1 (g) nor "
                       "~9.81 (m/s^2); give the unit (--accel-unit)")


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


def _read_messages(
    path: Path, source: str, tmap: TopicMap, progress: Callable[[int, int], None] | None = None
) -> tuple[int, TopicMap, dict[str, list], list[str]]:
    """One pass over the bag: per selected topic, a list of (stamp ns, bag ns, payload) rows;
    ``progress(read, total)`` every :data:`PROGRESS_EVERY` messages of the selected topics and at the end."""
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
        if tmap.joints:
            pick((JOINTS,), {tmap.joints: ""}, "joint state")
            joint_topic = tmap.joints
        else:
            found = [t for t, ty in topics.items() if ty == JOINTS]
            if not found:
                raise DatasetError(f"{source}: no sensor_msgs/JointState topic; calibration needs the robot's joint "
                                   f"states (topics: {listing})")
            if len(found) > 1:
                raise DatasetError(f"{source}: several JointState topics ({', '.join(sorted(found))}); choose one "
                                   "with --joint-topic")
            joint_topic = found[0]
        if not imu:
            raise DatasetError(f"{source}: no sensor_msgs/Imu topic (topics: {listing})")
        selected = {joint_topic, *imu, *ranges}
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
    return (2 if reader.is2 else 1), used, rows, notes


def read_bag(path: str | Path, robot: SerialChain | str = "panda", tmap: TopicMap | None = None, *,
             accel_unit: str = "auto", gyro_unit: str = "auto",
             progress: Callable[[int, int], None] | None = None) -> tuple[Dataset, ImportReport]:
    """Read a ROS 1/ROS 2 bag into a :class:`Dataset` without segments (see the module docstring).

    Args:
        path: ``.bag`` file, ROS 2 bag directory, or ``.db3``/``.mcap`` file.
        robot: preset name, chain file, or chain.
        tmap: topics to read (default: every Imu, JointState, Range and LaserScan topic).
        accel_unit: ``auto``, ``g`` or ``mps2``; gyro_unit: ``auto``, ``rad`` or ``deg`` (per second).
        progress: called as ``progress(read, total)`` with the messages of the selected topics read so
            far and their total (from the bag's index): at the start, every :data:`PROGRESS_EVERY`
            messages and at the end.

    Raises:
        DatasetError: missing, empty, truncated or corrupt bag; no joint states; an unknown topic;
            a topic whose samples are all NaN; one line naming the bag and the topic.
    """
    from skincal.kinematics import get_robot

    chain = get_robot(robot) if isinstance(robot, str) else robot
    path = Path(path)
    source = str(path)
    ros, used, rows, notes = _read_messages(path, source, tmap or TopicMap(), progress)
    counts = {t: len(r) for t, r in rows.items()}

    # Joint states.
    jrows = rows[used.joints]
    if not jrows:
        raise DatasetError(f"{source}: joint state topic {used.joints} has no messages")
    cols_by_names: dict[tuple[str, ...], np.ndarray | None] = {}
    keep, q_rows, qd_rows = [], [], []
    for i, (_, _, (names, pos, vel)) in enumerate(jrows):  # per message: name order may differ between messages
        if names not in cols_by_names:
            cols_by_names[names] = _joint_columns(names, chain, used)
        cols = cols_by_names[names]
        if cols is None or pos.shape[0] != len(names):
            continue
        keep.append(i)
        q_rows.append(pos[cols])
        qd_rows.append(vel[cols] if vel.shape[0] == len(names) else np.full(len(cols), np.nan))
    if not keep:
        seen = "; ".join(", ".join(n) for n in list(cols_by_names)[:2])
        raise DatasetError(f"{source}: topic {used.joints}: no message names the {chain.n_joints} joints of "
                           f"'{chain.name}' (names seen: {seen}); give joint_names in the topic map")
    if len(keep) < len(jrows):
        notes.append(f"{used.joints}: skipped {len(jrows) - len(keep)} message(s) without the robot's joints")
    t_j = _stamps([jrows[i][:2] for i in keep], used.joints, notes)
    q, qd = np.array(q_rows), np.array(qd_rows)
    no_velocity = np.all(np.isnan(qd), axis=1)
    t_j, qq = _clean(used.joints, t_j, np.stack([q, np.where(no_velocity[:, None], 0.0, qd)], axis=1), notes, source)
    q, qd = qq[:, 0], qq[:, 1]
    if np.any(no_velocity):
        if len(t_j) < 3:
            raise DatasetError(f"{source}: topic {used.joints}: {len(t_j)} samples, too few to differentiate")
        qd = np.gradient(q, (t_j - t_j[0]) * 1e-9, axis=0)  # relative: epoch seconds lose precision
        notes.append(f"{used.joints}: no velocities in {int(np.sum(no_velocity))} message(s); joint velocities "
                     "from central differences of the positions")
    origin = int(t_j[0])
    to_s = lambda ns: (ns - origin) * 1e-9  # noqa: E731
    qd_sum_p99 = float(np.percentile(np.sum(np.abs(qd), axis=1), 99))

    # IMUs.
    imu: dict[str, ImuStream] = {}
    imu_units: dict[str, str] = {}
    for topic, name in used.imu.items():
        if not rows[topic]:
            raise DatasetError(f"{source}: IMU topic {topic} has no messages")
        frame = rows[topic][0][2][6]
        unit = name or (frame if frame and frame not in imu_units.values() else _unit_from_topic(topic))
        if unit in imu:
            raise DatasetError(f"{source}: topics {topic} and another both map to unit '{unit}'; name them in the map")
        t_ns = _stamps([r[:2] for r in rows[topic]], topic, notes)
        vals = np.array([r[2][:6] for r in rows[topic]], dtype=float)
        t_ns, vals = _clean(topic, t_ns, vals, notes, source)
        accel = vals[:, :3] * _accel_scale(topic, vals[:, :3], accel_unit, source, notes)
        gyro = vals[:, 3:] * _gyro_scale(topic, vals[:, 3:], qd_sum_p99, gyro_unit, notes)
        imu[unit] = ImuStream(t=to_s(t_ns), accel=accel, gyro=gyro)
        imu_units[topic] = unit

    # Time-of-flight.
    tof: dict[str, TofStream] = {}
    range_units: dict[str, str] = {}
    for topic, name in used.range.items():
        unit = name or _range_unit(topic, rows[topic], imu_units)
        if unit is None:
            if topic in (tmap.range if tmap else {}):
                raise DatasetError(f"{source}: range topic {topic}: cannot tell its unit; write {topic}=UNIT")
            notes.append(f"{topic}: skipped (cannot tell which unit it belongs to; give {topic}=UNIT)")
            continue
        if unit not in imu:
            raise DatasetError(f"{source}: range topic {topic} maps to unit '{unit}', which has no IMU topic")
        if not rows[topic]:
            continue
        t_ns = _stamps([r[:2] for r in rows[topic]], topic, notes)
        vals = np.array([r[2][:3] for r in rows[topic]], dtype=float)
        t_ns, vals = _clean(topic, t_ns, vals, notes, source)
        r, lo, hi = vals.T
        no_target = ~((r >= lo) & (r <= hi))
        if np.any(no_target):
            notes.append(f"{topic}: {int(np.sum(no_target))} reading(s) out of range (no target) -> NaN")
        tof[unit] = TofStream(t=to_s(t_ns), range=np.where(no_target, np.nan, r))
        range_units[topic] = unit

    ds = Dataset(robot=chain, joints=JointStates(t=to_s(t_j), q=q, qd=qd), imu=imu, tof=tof,
                 description=f"imported from {path.name} (ROS {ros}); time origin {origin} ns since the epoch")
    validate_dataset(ds, source)
    report = ImportReport(source=source, ros_version=ros, joint_topic=used.joints, imu_topics=imu_units,
                          range_topics=range_units, counts=counts, notes=tuple(notes), time_origin_ns=origin)
    return ds, report


def _range_unit(topic: str, rows: list, imu_units: dict[str, str]) -> str | None:
    """The unit of a range topic: its frame_id if that is a unit, else the IMU topic in the same namespace."""
    frame = rows[0][2][3] if rows else ""
    if frame in imu_units.values():
        return frame
    ns = topic.rsplit("/", 1)[0]
    hits = [u for t, u in imu_units.items() if t.rsplit("/", 1)[0] == ns and ns]
    if len(hits) == 1:
        return hits[0]
    m = re.sub(r"_(tof|range)$", "", frame)
    return m if m in imu_units.values() else None


def write_bag(ds: Dataset, path: str | Path, *, ros_version: int = 2, storage: str = "sqlite3",
              accel_unit: str = "mps2", gyro_unit: str = "rad", joint_names: tuple[str, ...] | None = None,
              joint_velocity: bool = True, origin_ns: int = 1_700_000_000_000_000_000) -> None:
    """Write ``ds`` as a ROS bag (``sensor_msgs`` Imu per unit on ``/skin/<unit>/imu``, JointState on
    ``/joint_states``, Range on ``/skin/<unit>/range``), messages in time order, header stamps
    ``origin_ns + t``; the bag time is the stamp. ``ros_version`` 1 writes a ``.bag`` file
    (noetic types), 2 a bag directory (humble types) with ``storage`` ``sqlite3`` or ``mcap``.
    ``accel_unit`` ``g`` and ``gyro_unit`` ``deg`` write what some firmware sends; NaN ranges
    (no target) become +inf (REP 117). The target must not exist."""
    from rosbags.rosbag1 import Writer as Writer1
    from rosbags.rosbag2 import StoragePlugin
    from rosbags.rosbag2 import Writer as Writer2
    from rosbags.typesys import Stores, get_typestore

    if ros_version not in (1, 2) or storage not in ("sqlite3", "mcap"):
        raise ConfigError(f"write_bag: ros_version must be 1 or 2 and storage sqlite3 or mcap, got {ros_version}, "
                          f"{storage}")
    ts = get_typestore(Stores.ROS1_NOETIC if ros_version == 1 else Stores.ROS2_HUMBLE)
    T = ts.types
    n = ds.robot.n_joints
    names = list(joint_names or KNOWN_JOINT_NAMES.get(ds.robot.name) or [f"joint{i + 1}" for i in range(n)])
    a_scale = 1.0 / STANDARD_GRAVITY if accel_unit == "g" else 1.0
    w_scale = 180.0 / np.pi if gyro_unit == "deg" else 1.0
    zeros9 = np.zeros(9)

    def header(ns: int, frame: str) -> Any:
        stamp = T["builtin_interfaces/msg/Time"](sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)
        extra = {"seq": 0} if ros_version == 1 else {}
        return T["std_msgs/msg/Header"](stamp=stamp, frame_id=frame, **extra)

    def vec(v: np.ndarray) -> Any:
        return T["geometry_msgs/msg/Vector3"](x=float(v[0]), y=float(v[1]), z=float(v[2]))

    streams: list[tuple[str, str, np.ndarray, Any]] = [("/joint_states", JOINTS, ds.joints.t, None)]
    streams += [(f"/skin/{u}/imu", IMU, s.t, (u, s)) for u, s in ds.imu.items()]
    streams += [(f"/skin/{u}/range", RANGE, s.t, (u, s)) for u, s in ds.tof.items()]
    t_all = np.concatenate([s[2] for s in streams])
    which = np.concatenate([np.full(len(s[2]), k) for k, s in enumerate(streams)])
    index = np.concatenate([np.arange(len(s[2])) for s in streams])
    order = np.argsort(t_all, kind="stable")
    ns_all = origin_ns + np.round(t_all * 1e9).astype(np.int64)
    identity = T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0)
    path = Path(path)
    if ros_version == 1:
        writer: Any = Writer1(path)
        serialize = ts.serialize_ros1
    else:
        plugin = StoragePlugin.SQLITE3 if storage == "sqlite3" else StoragePlugin.MCAP
        writer = Writer2(path, version=9, storage_plugin=plugin)
        serialize = ts.serialize_cdr
    with writer:
        conns = [writer.add_connection(topic, kind, typestore=ts) for topic, kind, _, _ in streams]
        for k in order:  # one message per sample: serialisation is per message
            s, i, ns = int(which[k]), int(index[k]), int(ns_all[k])
            topic, kind, _, data = streams[s]
            if kind == JOINTS:
                js = ds.joints
                msg = T[JOINTS](header=header(ns, ""), name=names, position=np.array(js.q[i], float),
                                velocity=np.array(js.qd[i], float) if joint_velocity else np.zeros(0),
                                effort=np.zeros(0))
            elif kind == IMU:
                unit, st = data
                gyro = st.gyro[i] if st.gyro is not None else np.zeros(3)
                msg = T[IMU](header=header(ns, unit), orientation=identity, orientation_covariance=zeros9,
                             angular_velocity=vec(gyro * w_scale), angular_velocity_covariance=zeros9,
                             linear_acceleration=vec(st.accel[i] * a_scale), linear_acceleration_covariance=zeros9)
            else:
                unit, st = data
                r = float(st.range[i])
                msg = T[RANGE](header=header(ns, unit), radiation_type=1, field_of_view=float(np.radians(27.0)),
                               min_range=0.01, max_range=4.0, range=np.inf if np.isnan(r) else r)
            writer.write(conns[s], ns, serialize(msg, kind))
