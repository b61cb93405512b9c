"""ROS 2's QoS profiles, as Cyclone DDS ``Qos`` objects (the values of ``rmw/qos_profiles.h`` and
``tf2_ros``), and the keep-last depths skincal uses on each topic.

=====================  ===========  ===============  ==========  =====================================
profile                reliability  durability       keep last   used for
=====================  ===========  ===============  ==========  =====================================
sensor data            best effort  volatile         5           writers of ``/joint_states`` and IMUs
sensor reader          best effort  volatile         keep all    readers of them: a queue of at most
                                                                  200000 samples (400 s of 500 Hz joint
                                                                  states), never overwritten; beyond, new
                                                                  samples are rejected (counted)
default                reliable     volatile         10          ``/diagnostics``
tf_static (writer)     reliable     transient local  1           ``/tf_static`` (``StaticBroadcasterQoS``;
                                                                  one message holds every unit)
tf_static (listener)   reliable     transient local  100         ``StaticListenerQoS``
latched                reliable     transient local  1           ``/robot_description``
=====================  ===========  ===============  ==========  =====================================

A best-effort reader matches a reliable or best-effort writer, so the sensor readers hear a
``joint_state_broadcaster`` (system default QoS: reliable) as well as a sensor driver.
"""

from __future__ import annotations

from cyclonedds.qos import Policy, Qos
from cyclonedds.util import duration

SENSOR_DEPTH = 5
"""``rmw_qos_profile_sensor_data``: keep last 5."""
SENSOR_READER_MAX_SAMPLES = 200_000
"""Samples a sensor reader queues at most between two takes (keep all: a slow take loses nothing until
this many are waiting; then new ones are rejected, and counted by DDS)."""
DEFAULT_DEPTH = 10
"""``rmw_qos_profile_default``: keep last 10."""
TF_STATIC_DEPTH = 1
"""``tf2_ros::StaticBroadcasterQoS``: keep last 1 (the broadcaster sends every transform in one message)."""
TF_STATIC_LISTENER_DEPTH = 100
"""``tf2_ros::StaticListenerQoS``: keep last 100."""
LATCHED_DEPTH = 1
"""``robot_state_publisher``'s ``/robot_description``: keep last 1, transient local."""


def sensor_data(depth: int = SENSOR_DEPTH) -> Qos:
    """Best effort, volatile, keep last ``depth``."""
    return Qos(Policy.Reliability.BestEffort, Policy.Durability.Volatile, Policy.History.KeepLast(depth))


def sensor_reader(max_samples: int = SENSOR_READER_MAX_SAMPLES) -> Qos:
    """Best effort, volatile, keep all, at most ``max_samples`` queued (:data:`SENSOR_READER_MAX_SAMPLES`)."""
    return Qos(
        Policy.Reliability.BestEffort,
        Policy.Durability.Volatile,
        Policy.History.KeepAll,
        Policy.ResourceLimits(max_samples=max_samples, max_samples_per_instance=max_samples),
    )


def default(depth: int = DEFAULT_DEPTH) -> Qos:
    """Reliable, volatile, keep last ``depth``."""
    return Qos(
        Policy.Reliability.Reliable(max_blocking_time=duration(milliseconds=100)),
        Policy.Durability.Volatile,
        Policy.History.KeepLast(depth),
    )


def latched(depth: int = LATCHED_DEPTH) -> Qos:
    """Reliable, transient local (a late joiner gets the last ``depth`` messages), keep last ``depth``."""
    return Qos(
        Policy.Reliability.Reliable(max_blocking_time=duration(milliseconds=100)),
        Policy.Durability.TransientLocal,
        Policy.History.KeepLast(depth),
    )


def tf_static() -> Qos:
    """``/tf_static`` writer: reliable, transient local, keep last 1."""
    return latched(TF_STATIC_DEPTH)


def tf_static_listener() -> Qos:
    """``/tf_static`` reader: reliable, transient local, keep last 100."""
    return latched(TF_STATIC_LISTENER_DEPTH)
