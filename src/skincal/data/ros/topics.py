"""Which topics of a bag feed what: the topic map (file and options), message types, and the rules
that name a unit from a topic, a ``header.frame_id`` or a range topic's namespace."""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from skincal.errors import ConfigError, DatasetError
from skincal.io.jsonio import load_yaml
from skincal.names import name_problem, printable

IMU, JOINTS, RANGE, SCAN = (f"sensor_msgs/msg/{x}" for x in ("Imu", "JointState", "Range", "LaserScan"))
STRING = "std_msgs/msg/String"
ROBOT_DESCRIPTION = "/robot_description"
"""The topic ``robot_state_publisher`` publishes the URDF on (``std_msgs/String``, latched)."""


@dataclass(frozen=True)
class TopicMap:
    """Which topics to read. ``imu`` / ``range``: topic -> unit name (``""``: from frame_id or topic);
    ``joints``: the JointState topic; ``joint_names``: the robot's joints in kinematic order (default:
    the chain's joint names). Empty fields are filled automatically from the bag's message types."""

    imu: dict[str, str] = field(default_factory=dict)
    joints: str | None = None
    range: dict[str, str] = field(default_factory=dict)
    joint_names: tuple[str, ...] | None = None


def _parse_topic_spec(specs: list[str] | tuple[str, ...] | None) -> dict[str, str]:
    out = {}
    for spec in specs or ():
        topic, _, name = spec.partition("=")
        out[topic.strip()] = name.strip()
    return out


def topic_map(
    imu: list[str] | None = None,
    joints: str | None = None,
    range_: list[str] | None = None,
    joint_names: list[str] | None = None,
    path: str | Path | None = None,
) -> TopicMap:
    """A :class:`TopicMap` from a YAML file (``imu``, ``joints``, ``range``, ``joint_names`` keys;
    ``imu``/``range`` a topic -> unit mapping or a list of topics) overridden by options
    (``TOPIC`` or ``TOPIC=UNIT`` strings). Unit names given here follow
    :func:`skincal.names.name_problem`."""
    doc: dict[str, Any] = {}
    if path is not None:
        doc = load_yaml(path, "topic map", ConfigError) or {}
        if not isinstance(doc, dict) or set(doc) - {"imu", "joints", "range", "joint_names"}:
            raise ConfigError(f"{path}: a topic map has keys imu, joints, range, joint_names; got {doc!r:.80}")
    where = f"{path}: " if path is not None else ""
    maps = {}
    for key in ("imu", "range"):
        value = doc.get(key) or {}
        if isinstance(value, list):
            value = {t: None for t in value}
        if not isinstance(value, dict):
            raise ConfigError(f"{where}'{key}' must map topics to unit names or list topics")
        for k, v in value.items():  # YAML reads `3` or `yes` as a number or a bool: never a name by accident
            if not isinstance(k, str) or not (v is None or isinstance(v, str)):
                bad = k if not isinstance(k, str) else v
                raise ConfigError(printable(
                    f"{where}'{key}' entry {bad!r} is a {type(bad).__name__}, not a "
                    f"{'topic' if bad is k else 'unit name'}; quote it in the YAML ('{bad}')"
                ))
        maps[key] = {k: "" if v is None else v for k, v in value.items()}
    maps["imu"].update(_parse_topic_spec(imu))
    maps["range"].update(_parse_topic_spec(range_))
    for key, mapping in maps.items():
        for topic, unit in mapping.items():
            problem = name_problem(unit) if unit else None
            if problem is not None:
                raise ConfigError(printable(f"{where}{key} topic {topic}: unit name {unit!r} {problem}"))
    names = joint_names or doc.get("joint_names")
    if names is not None and not (isinstance(names, list | tuple) and all(isinstance(n, str) for n in names)):
        raise ConfigError(f"{where}'joint_names' must be a list of the robot's joint names in kinematic order")
    if "joints" in doc and doc["joints"] is not None and not isinstance(doc["joints"], str):
        raise ConfigError(printable(f"{where}'joints' must be the joint-state topic, got {doc['joints']!r:.80}"))
    return TopicMap(
        imu=maps["imu"],
        joints=joints or doc.get("joints"),
        range=maps["range"],
        joint_names=None if not names else tuple(str(n) for n in names),
    )


def unit_from_topic(topic: str) -> str:
    """A unit name from a topic: its parts without the usual ``imu``/``data``/``range`` words."""
    parts = [p for p in topic.split("/") if p and p not in ("imu", "data", "data_raw", "range", "tof", "scan")]
    return "_".join(parts) or topic.strip("/").replace("/", "_")


def unit_name(name: str, source: str, topic: str, what: str) -> str:
    """``name`` if :func:`skincal.names.name_problem` accepts it, else a one-line
    :class:`DatasetError` naming the bag, the topic and where the name came from."""
    problem = name_problem(name)
    if problem is not None:
        raise DatasetError(
            printable(
                f"{source}: topic {topic}: unit name {name!r} (from the {what}) {problem}; "
                f"name the unit with {topic}=UNIT"
            )
        )
    return name


def range_unit(topic: str, frame: str, imu_topics: dict[str, str], imu_units: set[str]) -> str | None:
    """The unit of a range source: its frame_id if that is a unit, else the unit of the one IMU topic in
    the same namespace (``imu_topics``: IMU topic -> its unit when it carries one unit), else the
    frame_id without a ``_tof``/``_range`` suffix."""
    if frame in imu_units:
        return frame
    ns = topic.rsplit("/", 1)[0]
    hits = [u for t, u in imu_topics.items() if t.rsplit("/", 1)[0] == ns and ns]
    if len(hits) == 1:
        return hits[0]
    m = re.sub(r"_(tof|range)$", "", frame)
    return m if m in imu_units else None
