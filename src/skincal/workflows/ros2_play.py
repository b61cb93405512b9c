"""A dataset played on a live ROS 2 graph (``skincal ros2-play DATA.h5``): what a robot and its skin
would publish, for ``skincal ros2`` and any other ROS 2 tool.

Topics (QoS: :mod:`skincal.data.ros2.qos`):

* ``/joint_states`` (``sensor_msgs/JointState``, sensor data): the chain's joint names, ``position``
  rad and ``velocity`` rad/s of each joint sample;
* ``/skin/<unit>/imu`` (``sensor_msgs/Imu``, sensor data), one per unit, ``header.frame_id`` the
  unit's name: ``linear_acceleration`` m/s^2, ``angular_velocity`` rad/s (zeros without a
  gyroscope; orientation not given: ``orientation_covariance[0] = -1``, REP 145);
* ``/robot_description`` (``std_msgs/String``, latched) when a URDF text is given.

Stamps: ``header.stamp = origin_ns + round(t * 1e9)`` (``t`` the dataset's time, s; ``origin_ns``
default: the wall clock when playing starts, so that ROS tools see current stamps). Messages go out in
stamp order, paced so that ``t`` advances ``rate`` times faster than the wall clock (``rate=None``: as
fast as they can be written).
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from skincal.data.dataset import Dataset
from skincal.errors import ConfigError

JOINT_TOPIC = "/joint_states"
IMU_TOPIC = "/skin/{unit}/imu"
"""The topic of a unit's IMU (as :func:`skincal.data.ros.write_bag` writes bags)."""
PACE_S = 0.002
"""The player sleeps when it is this far ahead of the wall clock, s."""


@dataclass(frozen=True)
class PlayReport:
    """What was played: messages per topic, the data span played (s), the wall time it took (s), the
    stamp origin (ns since the epoch) and whether it was stopped before the end."""

    messages: dict[str, int]
    t_data_s: float
    wall_s: float
    origin_ns: int
    stopped: bool


def wait_for_subscribers(writers: dict[str, object], timeout_s: float, stop: threading.Event | None = None) -> bool:
    """Wait until every writer has a matched reader (at most ``timeout_s``); whether they all have."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline and not (stop is not None and stop.is_set()):
        if all(w.get_publication_matched_status().current_count > 0 for w in writers.values()):  # type: ignore[attr-defined]
            return True
        time.sleep(0.02)
    return all(w.get_publication_matched_status().current_count > 0 for w in writers.values())  # type: ignore[attr-defined]


def play_dataset(
    ds: Dataset,
    participant: object,
    *,
    rate: float | None = 1.0,
    origin_ns: int | None = None,
    robot_description: str | None = None,
    wait_s: float = 0.0,
    stop: threading.Event | None = None,
    on_progress: Callable[[float, float], None] | None = None,
    linger_s: float = 0.5,
) -> PlayReport:
    """Publish ``ds`` on ``participant`` (a ``cyclonedds`` ``DomainParticipant``; module docstring).

    ``wait_s``: first wait up to this long for a subscriber on every topic (discovery takes a
    moment; a best-effort sample sent before it is lost). ``stop`` ends the play early;
    ``on_progress(t_data, t_end)`` about every 0.5 s of wall time; ``linger_s``: wall time the writers
    stay after the last message (for a latched description and the last samples in flight).
    """
    from cyclonedds.pub import DataWriter
    from cyclonedds.topic import Topic

    from skincal.data.ros2 import messages as m
    from skincal.data.ros2 import qos

    chain, joints = ds.require_joints("ros2-play (a robot's joint states)")
    if rate is not None and not (math.isfinite(rate) and rate > 0):
        raise ConfigError(f"--rate {rate}: a finite number > 0 (data seconds per wall second)")
    names = [chain.joint_name(i) for i in range(1, chain.n_joints + 1)]
    topics = {JOINT_TOPIC: m.JointState, **{IMU_TOPIC.format(unit=u): m.Imu for u in ds.units}}
    writers = {
        t: DataWriter(participant, Topic(participant, m.dds_topic(t), kind), qos.sensor_data())
        for t, kind in topics.items()
    }  # type: ignore[arg-type]
    latched = None
    if robot_description is not None:
        latched = DataWriter(participant, Topic(participant, m.dds_topic("/robot_description"), m.String),
                             qos.latched())  # type: ignore[arg-type]  # fmt: skip
        latched.write(m.String(data=robot_description))
    if wait_s > 0:
        wait_for_subscribers(writers, wait_s, stop)

    # every sample in time order: (t, stream k, row i), stream 0 the joints
    streams = [joints.t, *(ds.imu[u].t for u in ds.units)]
    t_all = np.concatenate(streams)
    which = np.concatenate([np.full(len(s), k) for k, s in enumerate(streams)])
    index = np.concatenate([np.arange(len(s)) for s in streams])
    order = np.argsort(t_all, kind="stable")
    origin = time.time_ns() if origin_ns is None else int(origin_ns)
    ns_all = origin + np.round(t_all * 1e9).astype(np.int64)
    t0, t_end = float(t_all.min()), float(t_all.max())
    imu_writers = [writers[IMU_TOPIC.format(unit=u)] for u in ds.units]
    cov_unknown = [-1.0] + [0.0] * 8
    zero3 = np.zeros(3)
    counts = dict.fromkeys(topics, 0)
    unit_topics = [IMU_TOPIC.format(unit=u) for u in ds.units]
    wall0 = time.monotonic()
    shown = wall0
    stopped = False
    t_now = t0
    for k in order:
        s, i = int(which[k]), int(index[k])
        t_now = float(t_all[k])
        if rate is not None:
            ahead = (t_now - t0) / rate - (time.monotonic() - wall0)
            if ahead > PACE_S:
                time.sleep(ahead)
        if stop is not None and stop.is_set():
            stopped = True
            break
        header = m.Header(m.Time.from_ns(int(ns_all[k])), "")
        if s == 0:
            writers[JOINT_TOPIC].write(m.JointState(header=header, name=names, position=joints.q[i].tolist(),
                                                    velocity=joints.qd[i].tolist(), effort=[]))  # fmt: skip
            counts[JOINT_TOPIC] += 1
        else:
            unit = ds.units[s - 1]
            st = ds.imu[unit]
            header.frame_id = unit
            a = st.accel[i]
            w = st.gyro[i] if st.gyro is not None else zero3
            imu_writers[s - 1].write(m.Imu(
                header=header, orientation_covariance=cov_unknown,
                angular_velocity=m.Vector3(float(w[0]), float(w[1]), float(w[2])),
                linear_acceleration=m.Vector3(float(a[0]), float(a[1]), float(a[2])),
            ))  # fmt: skip
            counts[unit_topics[s - 1]] += 1
        if on_progress is not None and time.monotonic() - shown >= 0.5:
            shown = time.monotonic()
            on_progress(t_now - t0, t_end - t0)
    wall = time.monotonic() - wall0
    if on_progress is not None:
        on_progress(t_now - t0, t_end - t0)
    if linger_s > 0:
        time.sleep(linger_s)
    return PlayReport(counts, t_now - t0, wall, origin, stopped)
