"""The ROS 2 messages skincal speaks on a live graph, written once as Cyclone DDS IDL structs.

ROS 2 (``rmw_cyclonedds_cpp``, the default in Jazzy's binaries and common in Humble) maps a message
``pkg/msg/Name`` to the DDS type ``pkg::msg::dds_::Name_`` and a topic ``/name`` to the DDS topic
``rt/name``; the payload is plain CDR (XCDR1, little endian, 4-byte encapsulation header). Each
class below is the ROS 2 definition field for field (ROS ``byte`` is an IDL ``octet``, ``uint8`` an
``uint8``, ``float64[9]`` an ``double[9]``, ``T[]`` a ``sequence<T>``), so that
``Imu(...).serialize()`` is byte for byte what ``rosbags``' ROS 2 CDR serialiser writes
(``tests/data/test_ros2_messages.py``). The frames follow REP 103 (m/s^2, rad/s) and the quaternions
ROS order ``(x, y, z, w)``.

:data:`MESSAGE_TYPES` maps ROS 2 type names (``sensor_msgs/msg/Imu``, as rosbags writes them) to the
struct; :func:`dds_topic` turns a ROS 2 topic name into its DDS topic name.
"""

# No ``from __future__ import annotations``: cyclonedds reads the field types at run time.
from dataclasses import dataclass, field

from cyclonedds.idl import IdlStruct
from cyclonedds.idl.types import array, byte, float64, int32, sequence, uint32

ROS_TOPIC_PREFIX = "rt"
"""``rmw_cyclonedds``: a ROS 2 topic ``/a/b`` is the DDS topic ``rt/a/b``."""


def dds_topic(ros_topic: str) -> str:
    """The DDS topic name of a ROS 2 topic: ``/joint_states`` -> ``rt/joint_states``."""
    return f"{ROS_TOPIC_PREFIX}/{ros_topic.lstrip('/')}"


def ros_topic(dds_name: str) -> str | None:
    """The ROS 2 topic of a DDS topic name (``rt/skin/su1/imu`` -> ``/skin/su1/imu``), else ``None``
    (a service, action or non-ROS topic)."""
    prefix = ROS_TOPIC_PREFIX + "/"
    return "/" + dds_name[len(prefix) :] if dds_name.startswith(prefix) else None


def ros_type(dds_type: str) -> str | None:
    """The ROS 2 type name of a DDS type name (``sensor_msgs::msg::dds_::Imu_`` ->
    ``sensor_msgs/msg/Imu``), else ``None``."""
    parts = dds_type.split("::")
    if len(parts) != 4 or parts[1] != "msg" or parts[2] != "dds_" or not parts[3].endswith("_"):
        return None
    return f"{parts[0]}/msg/{parts[3][:-1]}"


# -- builtin_interfaces, std_msgs ------------------------------------------------------------------


@dataclass
class Time(IdlStruct, typename="builtin_interfaces::msg::dds_::Time_"):
    """``builtin_interfaces/msg/Time``: ``sec`` (int32) and ``nanosec`` (uint32, < 1e9) since the epoch."""

    sec: int32 = 0
    nanosec: uint32 = 0

    @classmethod
    def from_ns(cls, ns: int) -> "Time":
        """From integer nanoseconds since the epoch (>= 0)."""
        return cls(sec=int(ns) // 1_000_000_000, nanosec=int(ns) % 1_000_000_000)

    def to_ns(self) -> int:
        return int(self.sec) * 1_000_000_000 + int(self.nanosec)


@dataclass
class Header(IdlStruct, typename="std_msgs::msg::dds_::Header_"):
    """``std_msgs/msg/Header`` (ROS 2: no ``seq``)."""

    stamp: Time = field(default_factory=Time)
    frame_id: str = ""


@dataclass
class String(IdlStruct, typename="std_msgs::msg::dds_::String_"):
    """``std_msgs/msg/String`` (``/robot_description`` carries the URDF in one)."""

    data: str = ""


# -- geometry_msgs ----------------------------------------------------------------------------------


@dataclass
class Vector3(IdlStruct, typename="geometry_msgs::msg::dds_::Vector3_"):
    x: float64 = 0.0
    y: float64 = 0.0
    z: float64 = 0.0


@dataclass
class Quaternion(IdlStruct, typename="geometry_msgs::msg::dds_::Quaternion_"):
    """ROS order ``(x, y, z, w)``; the ROS 2 default is the identity (``w = 1``)."""

    x: float64 = 0.0
    y: float64 = 0.0
    z: float64 = 0.0
    w: float64 = 1.0


@dataclass
class Transform(IdlStruct, typename="geometry_msgs::msg::dds_::Transform_"):
    """``T_parent_child``: ``translation`` m and ``rotation`` of the child frame in the parent's."""

    translation: Vector3 = field(default_factory=Vector3)
    rotation: Quaternion = field(default_factory=Quaternion)


@dataclass
class TransformStamped(IdlStruct, typename="geometry_msgs::msg::dds_::TransformStamped_"):
    """``header.frame_id`` is the parent frame, ``child_frame_id`` the child."""

    header: Header = field(default_factory=Header)
    child_frame_id: str = ""
    transform: Transform = field(default_factory=Transform)


# -- sensor_msgs ------------------------------------------------------------------------------------


def _zeros9() -> list[float]:
    return [0.0] * 9


@dataclass
class JointState(IdlStruct, typename="sensor_msgs::msg::dds_::JointState_"):
    """``sensor_msgs/msg/JointState``: names, positions rad (m), velocities rad/s (m/s), efforts;
    ``velocity``/``effort`` may be empty."""

    header: Header = field(default_factory=Header)
    name: sequence[str] = field(default_factory=list)
    position: sequence[float64] = field(default_factory=list)
    velocity: sequence[float64] = field(default_factory=list)
    effort: sequence[float64] = field(default_factory=list)


@dataclass
class Imu(IdlStruct, typename="sensor_msgs::msg::dds_::Imu_"):
    """``sensor_msgs/msg/Imu`` in the sensor frame ``header.frame_id``: ``linear_acceleration`` m/s^2
    (the specific force), ``angular_velocity`` rad/s; covariances row-major 3x3 (``-1`` in element 0:
    not given)."""

    header: Header = field(default_factory=Header)
    orientation: Quaternion = field(default_factory=Quaternion)
    orientation_covariance: array[float64, 9] = field(default_factory=_zeros9)
    angular_velocity: Vector3 = field(default_factory=Vector3)
    angular_velocity_covariance: array[float64, 9] = field(default_factory=_zeros9)
    linear_acceleration: Vector3 = field(default_factory=Vector3)
    linear_acceleration_covariance: array[float64, 9] = field(default_factory=_zeros9)


# -- tf2_msgs, diagnostic_msgs ----------------------------------------------------------------------


@dataclass
class TFMessage(IdlStruct, typename="tf2_msgs::msg::dds_::TFMessage_"):
    """``tf2_msgs/msg/TFMessage`` (``/tf`` and ``/tf_static``)."""

    transforms: sequence[TransformStamped] = field(default_factory=list)


@dataclass
class KeyValue(IdlStruct, typename="diagnostic_msgs::msg::dds_::KeyValue_"):
    key: str = ""
    value: str = ""


@dataclass
class DiagnosticStatus(IdlStruct, typename="diagnostic_msgs::msg::dds_::DiagnosticStatus_"):
    """``diagnostic_msgs/msg/DiagnosticStatus``; ``level`` a ROS ``byte``: :data:`OK`, :data:`WARN`,
    :data:`ERROR`, :data:`STALE`."""

    level: byte = 0
    name: str = ""
    message: str = ""
    hardware_id: str = ""
    values: sequence[KeyValue] = field(default_factory=list)


OK, WARN, ERROR, STALE = 0, 1, 2, 3
"""``DiagnosticStatus`` levels (the message's constants)."""


@dataclass
class DiagnosticArray(IdlStruct, typename="diagnostic_msgs::msg::dds_::DiagnosticArray_"):
    header: Header = field(default_factory=Header)
    status: sequence[DiagnosticStatus] = field(default_factory=list)


MESSAGE_TYPES: dict[str, type[IdlStruct]] = {
    "builtin_interfaces/msg/Time": Time,
    "std_msgs/msg/Header": Header,
    "std_msgs/msg/String": String,
    "geometry_msgs/msg/Vector3": Vector3,
    "geometry_msgs/msg/Quaternion": Quaternion,
    "geometry_msgs/msg/Transform": Transform,
    "geometry_msgs/msg/TransformStamped": TransformStamped,
    "sensor_msgs/msg/JointState": JointState,
    "sensor_msgs/msg/Imu": Imu,
    "tf2_msgs/msg/TFMessage": TFMessage,
    "diagnostic_msgs/msg/KeyValue": KeyValue,
    "diagnostic_msgs/msg/DiagnosticStatus": DiagnosticStatus,
    "diagnostic_msgs/msg/DiagnosticArray": DiagnosticArray,
}
"""ROS 2 type name -> its IDL struct."""
