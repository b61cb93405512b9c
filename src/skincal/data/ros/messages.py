"""A bag's messages read in one pass (``rosbags.highlevel.AnyReader``) into per-source sample lists:
IMU, joint-state, range and scan messages, the robot description, and the units of an IMU stream
(m/s^2 or g, rad/s or deg/s; :mod:`skincal.data.ros.reader`'s docstring)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from skincal.data.ros.topics import IMU, JOINTS, RANGE, ROBOT_DESCRIPTION, SCAN, STRING, TopicMap
from skincal.errors import ConfigError, DatasetError
from skincal.errors import first_line as _first_line
from skincal.skin.imu import STANDARD_GRAVITY

PROGRESS_EVERY = 5000
"""Messages between two calls of :func:`read_bag`'s ``progress`` callback."""


def accel_scale(topic: str, accel: np.ndarray, unit: str, source: str, notes: list[str]) -> float:
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


def gyro_scale(topic: str, gyro: np.ndarray, qd_sum_p99: float, unit: str, notes: list[str]) -> float:
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
class BagPass:
    """What one pass over the bag gave: ROS version, the topics chosen, rows per topic, all topic types."""

    ros: int
    used: TopicMap
    rows: dict[str, list]
    topics: dict[str, str]
    notes: list[str]


def read_messages(
    path: Path,
    source: str,
    tmap: TopicMap,
    description: bool,
    progress: Callable[[int, int], None] | None = None,
    imu_only: bool | None = False,
) -> BagPass:
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
    return BagPass(2 if reader.is2 else 1, used, rows, topics, notes)
