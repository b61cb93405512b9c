"""A dataset as a ROS 1 or ROS 2 bag (``sensor_msgs`` Imu, JointState, Range; optionally the URDF on
``/robot_description``), written with the ``rosbags`` library: no ROS install."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from skincal.data.dataset import Dataset
from skincal.data.ros.topics import IMU, JOINTS, RANGE, ROBOT_DESCRIPTION, STRING
from skincal.errors import ConfigError
from skincal.skin.imu import STANDARD_GRAVITY


def _latched_qos() -> Any:
    """The QoS ``robot_state_publisher`` offers on ``/robot_description``: reliable, transient local
    (ROS 2's latching), keep last 1."""
    from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime

    forever = QosTime(sec=0, nsec=0)
    return Qos(
        history=QosHistory.KEEP_LAST,
        depth=1,
        reliability=QosReliability.RELIABLE,
        durability=QosDurability.TRANSIENT_LOCAL,
        deadline=forever,
        lifespan=forever,
        liveliness=QosLiveliness.AUTOMATIC,
        liveliness_lease_duration=forever,
        avoid_ros_namespace_conventions=False,
    )


def write_bag(
    ds: Dataset,
    path: str | Path,
    *,
    ros_version: int = 2,
    storage: str = "sqlite3",
    accel_unit: str = "mps2",
    gyro_unit: str = "rad",
    joint_names: tuple[str, ...] | None = None,
    joint_velocity: bool = True,
    origin_ns: int = 1_700_000_000_000_000_000,
    robot_description: str | None = None,
    imu_topic: str | None = None,
) -> None:
    """Write ``ds`` as a ROS bag (``sensor_msgs`` Imu per unit on ``/skin/<unit>/imu``, JointState on
    ``/joint_states``, Range on ``/skin/<unit>/range``), messages in time order, header stamps
    ``origin_ns + t``; the bag time is the stamp. ``ros_version`` 1 writes a ``.bag`` file
    (noetic types), 2 a bag directory (humble types) with ``storage`` ``sqlite3`` or ``mcap``.
    ``accel_unit`` ``g`` and ``gyro_unit`` ``deg`` write what some firmware sends; NaN ranges
    (no target) become +inf (REP 117). JointState names: ``joint_names``, else the chain's
    (:meth:`~skincal.kinematics.chain.SerialChain.joint_name`). ``robot_description``: URDF text
    published once, latched, on ``/robot_description`` (``std_msgs/String``) before the first sample.
    ``imu_topic``: every unit's Imu on this one topic, told apart by ``header.frame_id`` (the unit
    name). The target must not exist."""
    from rosbags.rosbag1 import Writer as Writer1
    from rosbags.rosbag2 import StoragePlugin
    from rosbags.rosbag2 import Writer as Writer2
    from rosbags.typesys import Stores, get_typestore

    if ros_version not in (1, 2) or storage not in ("sqlite3", "mcap"):
        raise ConfigError(
            f"write_bag: ros_version must be 1 or 2 and storage sqlite3 or mcap, got {ros_version}, {storage}"
        )
    ts = get_typestore(Stores.ROS1_NOETIC if ros_version == 1 else Stores.ROS2_HUMBLE)
    T = ts.types
    chain = ds.robot
    n = 0 if chain is None else chain.n_joints
    names = list(joint_names or (() if chain is None else (chain.joint_name(i) for i in range(1, n + 1))))
    a_scale = 1.0 / STANDARD_GRAVITY if accel_unit == "g" else 1.0
    w_scale = 180.0 / np.pi if gyro_unit == "deg" else 1.0
    zeros9 = np.zeros(9)

    def header(ns: int, frame: str) -> Any:
        stamp = T["builtin_interfaces/msg/Time"](sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)
        extra = {"seq": 0} if ros_version == 1 else {}
        return T["std_msgs/msg/Header"](stamp=stamp, frame_id=frame, **extra)

    def vec(v: np.ndarray) -> Any:
        return T["geometry_msgs/msg/Vector3"](x=float(v[0]), y=float(v[1]), z=float(v[2]))

    streams: list[tuple[str, str, np.ndarray, Any]] = []  # an IMU-only dataset: no joint stream
    if ds.joints is not None:
        streams.append(("/joint_states", JOINTS, ds.joints.t, ds.joints))
    streams += [(imu_topic or f"/skin/{u}/imu", IMU, s.t, (u, s)) for u, s in ds.imu.items()]
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
        by_topic: dict[str, Any] = {}
        for topic, kind, _, _ in streams:  # one connection per topic (units may share one IMU topic)
            if topic not in by_topic:
                by_topic[topic] = writer.add_connection(topic, kind, typestore=ts)
        conns = [by_topic[topic] for topic, _, _, _ in streams]
        if robot_description is not None:
            latched = {"latching": 1} if ros_version == 1 else {"offered_qos_profiles": [_latched_qos()]}
            desc = writer.add_connection(ROBOT_DESCRIPTION, STRING, typestore=ts, **latched)
            first = int(ns_all.min()) if len(ns_all) else origin_ns
            writer.write(desc, first, serialize(T[STRING](data=robot_description), STRING))
        for k in order:  # one message per sample: serialisation is per message
            s, i, ns = int(which[k]), int(index[k]), int(ns_all[k])
            topic, kind, _, data = streams[s]
            if kind == JOINTS:
                js = data
                msg = T[JOINTS](
                    header=header(ns, ""),
                    name=names,
                    position=np.array(js.q[i], float),
                    velocity=np.array(js.qd[i], float) if joint_velocity else np.zeros(0),
                    effort=np.zeros(0),
                )
            elif kind == IMU:
                unit, st = data
                gyro = st.gyro[i] if st.gyro is not None else np.zeros(3)
                msg = T[IMU](
                    header=header(ns, unit),
                    orientation=identity,
                    orientation_covariance=zeros9,
                    angular_velocity=vec(gyro * w_scale),
                    angular_velocity_covariance=zeros9,
                    linear_acceleration=vec(st.accel[i] * a_scale),
                    linear_acceleration_covariance=zeros9,
                )
            else:
                unit, st = data
                r = float(st.range[i])
                msg = T[RANGE](
                    header=header(ns, unit),
                    radiation_type=1,
                    field_of_view=float(np.radians(27.0)),
                    min_range=0.01,
                    max_range=4.0,
                    range=np.inf if np.isnan(r) else r,
                )
            writer.write(conns[s], ns, serialize(msg, kind))
