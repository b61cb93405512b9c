"""``skincal ros2``: the streaming calibrator on a live ROS 2 graph.

One participant (:func:`skincal.data.ros2.participant.join`: loopback, multicast off by default)
polls, every :data:`POLL_S`:

* **discovery**: DDS built-in publications; every topic of type ``sensor_msgs/Imu`` whose ROS name
  matches ``imu_topic`` (a glob, default every one) gets a reader (sensor data QoS); other topics are
  ignored (counted);
* **input**: ``/joint_states`` (the robot's joints found by name as ``import`` finds them:
  :func:`skincal.data.ros.reader.match_joints`), the IMU topics, ``/robot_description`` (latched) when
  no robot is given. A unit per topic and ``header.frame_id`` as ``import`` names bag units: the
  frame_id, else the topic (:func:`skincal.data.ros.topics.unit_from_topic`), names checked with
  :func:`skincal.names.name_problem`. Time: ``header.stamp`` less the median stamp of the first
  :data:`ORIGIN_JOINT_STATES` joint states, s; a stamp far ahead of the newest accepted one or far
  behind its topic's newest (:data:`MAX_AHEAD_S`, :data:`MAX_BEHIND_S`) is dropped.
  A malformed or oversized sample is counted and dropped (:mod:`skincal.data.ros2.decode`);
* **calibration**: :class:`skincal.workflows.live.LiveFeed` (the streaming calibrator of ``calibrate
  --follow``, with its moved-unit monitor), fed per poll;
* **output**: ``/tf_static`` (``tf2_msgs/TFMessage``, reliable, transient local, keep last 1: every
  published unit in one message, parent the link's frame, child the unit's name), sent when a unit
  first reaches the target, when a moved unit (the moved-unit monitor's event) has a determined pose
  again and when it reaches the target again, and at the end with the final result;
  ``/diagnostics`` (``diagnostic_msgs/DiagnosticArray``) every :data:`DIAGNOSTICS_EVERY_S`: a status
  per unit (link, std, what is missing, the joint to move, moves) and one for the session (topics,
  drops). ``record``: every accepted message written as received (its CDR bytes) to a ROS 2 bag.

Receiving runs in its own thread (discovery and takes every :data:`POLL_S`), so that a long
calibrator step never lets a reader's queue overflow; calibrating and publishing run in the caller's.
It stops at ``stop`` (Ctrl-C, SIGTERM), when every unit reached the target (``until_decided``),
after ``duration_s`` of wall time or ``idle_s`` without a message.
"""

from __future__ import annotations

import dataclasses
import fnmatch
import math
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from skincal.errors import ConfigError, DatasetError
from skincal.kinematics.chain import SerialChain
from skincal.names import name_problem, printable
from skincal.workflows.live import LiveFeed, LiveOutcome, Target

POLL_S = 0.02
"""Wall time between two takes of the receiving thread, s."""
STEP_S = 0.25
"""Wall time between two calibrator steps (:meth:`Ros2Calibration.poll`), s: a step's cost grows with
the kept history (the calibrator's grid), not with the data since the last step, so steps are spaced."""
DIAGNOSTICS_EVERY_S = 1.0
"""``/diagnostics`` period, s."""
JOINT_TOPIC = "/joint_states"
ROBOT_DESCRIPTION = "/robot_description"
IMU_TYPE = "sensor_msgs::msg::dds_::Imu_"
MAX_SOURCES = 1024
"""IMU sources (topic, frame_id) and joint-name lists remembered at most; beyond, a new one's samples are
dropped and counted (a publisher that changes its frame_id with every message cannot fill memory)."""
MAX_AHEAD_S = 10.0
"""A stamp more than this ahead of the newest accepted stamp (of any stream) is dropped and counted
(``stamp jump``): one far-future stamp would make the calibrator process every block up to it. A robot
clock that really jumps needs a new session."""
MAX_BEHIND_S = 60.0
"""A stamp more than this behind the newest accepted stamp of its own topic is dropped and counted
(``stamp jump``; the calibrator keeps no more history than that). Per topic: under load one topic's
messages may be taken seconds after another's."""
ORIGIN_JOINT_STATES = 5
"""Time 0 is the median stamp of the first this many joint states (one stray stamp cannot set it)."""
MAX_PENDING = 1_000_000
"""Messages kept while waiting for the robot or the first joint states; beyond, the oldest are dropped
(counted ``waiting``)."""
MAX_TOPICS = 1024
"""IMU topics followed at most (more are ignored and counted)."""


@dataclass(frozen=True)
class Ros2Options:
    """``imu_topic``: glob of the ROS IMU topics to follow (None: all); ``until_decided``: stop when every
    unit reached the target; ``duration_s``: stop after this wall time; ``idle_s``: stop this long after
    the last message; ``watch``: the moved-unit monitor; ``warmup_s``: units gathered this long after
    the first joint state before the calibrator starts (wall time, s)."""

    imu_topic: str | None = None
    until_decided: bool = False
    duration_s: float | None = None
    idle_s: float | None = None
    watch: bool = True
    warmup_s: float = 2.0
    poll_s: float = POLL_S
    step_s: float = STEP_S
    diagnostics_every_s: float = DIAGNOSTICS_EVERY_S

    def __post_init__(self) -> None:
        for name in ("duration_s", "idle_s"):
            v = getattr(self, name)
            if v is not None and not (math.isfinite(v) and v > 0):
                raise ConfigError(f"--{name[:-2].replace('_', '-')} {v}: a number of seconds > 0")


@dataclass
class Ros2Stats:
    """Counters of a session: messages accepted per ROS topic, drops (topic -> reason -> count),
    topics ignored, the unit of each ``topic frame_id`` source, TF messages sent, wall times."""

    messages: dict[str, int] = field(default_factory=dict)
    ignored_topics: set[str] = field(default_factory=set)
    units: dict[str, str] = field(default_factory=dict)
    refused: dict[str, str] = field(default_factory=dict)
    tf_messages: int = 0
    tf_delay_max_s: float = 0.0
    """Longest wall time from a calibrator step's statuses to the ``/tf_static`` message they made due, s."""
    last_message_wall: float | None = None
    first_message_wall: float | None = None


class Ros2Calibration:
    """One ``skincal ros2`` session on ``participant`` (module docstring). ``chain``: the robot (None: from
    ``/robot_description``). Call :meth:`poll` repeatedly (or :meth:`run`), then :meth:`finish`."""

    def __init__(
        self,
        participant: Any,
        chain: SerialChain | None,
        target: Target = Target(),
        options: Ros2Options = Ros2Options(),
        record: Path | None = None,
        on_event: Callable[[dict], None] | None = None,
        base_link: str | None = None,
        tip_link: str | None = None,
    ) -> None:
        from cyclonedds.builtin import BuiltinDataReader, BuiltinTopicDcpsPublication
        from cyclonedds.pub import DataWriter
        from cyclonedds.sub import DataReader
        from cyclonedds.topic import Topic

        from skincal.data.ros2 import messages as m
        from skincal.data.ros2 import qos
        from skincal.data.ros2.decode import DropCounts, RawReader

        self.participant, self.chain, self.target, self.options = participant, chain, target, options
        self.base_link, self.tip_link, self.on_event = base_link, tip_link, on_event
        self.drops = DropCounts()
        self.stats = Ros2Stats()
        self._Topic, self._DataReader, self._RawReader = Topic, DataReader, RawReader
        self._discovery = BuiltinDataReader(participant, BuiltinTopicDcpsPublication)

        def reader(topic: str, kind: Any, profile: Any) -> Any:
            dds = DataReader(participant, Topic(participant, m.dds_topic(topic), kind), profile)
            return RawReader(dds, kind, topic, self.drops)

        self._joints = reader(JOINT_TOPIC, m.JointState, qos.sensor_reader())
        self._description = reader(ROBOT_DESCRIPTION, m.String, qos.latched()) if chain is None else None
        self._imu: dict[str, Any] = {}
        self._tf = DataWriter(participant, Topic(participant, m.dds_topic("/tf_static"), m.TFMessage), qos.tf_static())
        self._diag = DataWriter(participant, Topic(participant, m.dds_topic("/diagnostics"), m.DiagnosticArray),
                                qos.default())  # fmt: skip
        self._m = m
        self._pending: list[tuple[str, Any, bytes]] = []  # before the robot and the first joint state are known
        self.origin_ns: int | None = None
        self._t_newest = 0.0  # newest stamp accepted (any stream), s since time 0
        self._t_stream: dict[str, float] = {}  # newest stamp accepted per topic
        self.feed: LiveFeed | None = None
        self._joint_cols: dict[tuple[str, ...], np.ndarray | None] = {}
        self._source_unit: dict[tuple[str, str], str | None] = {}
        self._unit_source: dict[str, tuple[str, str]] = {}
        self._published: dict[str, Any] = {}  # unit -> TransformStamped now on /tf_static
        self._moved: set[str] = set()  # moved, not re-published yet
        self._provisional: set[str] = set()  # re-published after a move, not at the target yet
        self._events = 0
        self._diag_wall = -math.inf
        self._decided_wall = time.monotonic()
        self._t0_wall = time.monotonic()
        self._cpu0 = time.process_time()
        self.robot_source = "given" if chain is not None else ""
        self._bag = None
        self._bag_conns: dict[str, Any] = {}
        self._inbox: list[tuple[str, Any, bytes]] = []
        self._lock = threading.Lock()
        self._closing = threading.Event()
        self._thread: threading.Thread | None = None
        self._receive_error: Exception | None = None
        self._quiet_since: float | None = None
        self._record_path = record

    # ------------------------------------------------------------------ input
    def _open_bag(self, path: Path) -> None:
        from rosbags.rosbag2 import Writer

        bag = Writer(path, version=9)
        bag.open()  # a bag that could not be opened is not kept: closing it would fail too
        self._bag = bag

    def _record(self, topic: str, kind: Any, data: bytes) -> None:
        if self._bag is None:
            return
        conn = self._bag_conns.get(topic)
        if conn is None:
            from rosbags.typesys import Stores, get_typestore

            ros_name = next(n for n, c in self._m.MESSAGE_TYPES.items() if c is kind)
            conn = self._bag.add_connection(topic, ros_name, typestore=get_typestore(Stores.ROS2_HUMBLE))
            self._bag_conns[topic] = conn
        self._bag.write(conn, time.time_ns(), data)

    def _discover(self) -> None:
        for s in self._discovery.take(N=256):
            name, kind = getattr(s, "topic_name", None), getattr(s, "type_name", None)
            if not name:
                continue
            ros = self._m.ros_topic(name)
            if ros is None or ros in (JOINT_TOPIC, ROBOT_DESCRIPTION, "/tf_static", "/diagnostics"):
                continue
            if kind != IMU_TYPE or (self.options.imu_topic is not None
                                    and not fnmatch.fnmatchcase(ros, self.options.imu_topic)) or (
                    ros not in self._imu and len(self._imu) >= MAX_TOPICS):  # fmt: skip
                if len(self.stats.ignored_topics) < MAX_TOPICS:
                    self.stats.ignored_topics.add(ros)
                continue
            if ros not in self._imu:
                from skincal.data.ros2 import qos

                dds = self._DataReader(self.participant, self._Topic(self.participant, name, self._m.Imu),
                                       qos.sensor_reader())  # fmt: skip
                self._imu[ros] = self._RawReader(dds, self._m.Imu, ros, self.drops)

    def _take(self) -> list[tuple[str, Any, bytes]]:
        """Everything received since the last take, ``(topic, message, bytes)`` (recorded)."""
        got: list[tuple[str, Any, bytes]] = []
        readers = [self._joints, *self._imu.values()] + ([self._description] if self._description else [])
        for r in readers:
            while True:
                batch = r.take(4096)
                for msg, data in batch:
                    got.append((r.topic, msg, data))
                    self.stats.messages[r.topic] = self.stats.messages.get(r.topic, 0) + 1
                    self._record(r.topic, r.kind, data)
                if len(batch) < 4096:
                    break
        now = time.monotonic()
        if got:
            self.stats.last_message_wall = now
            self._quiet_since = None
            if self.stats.first_message_wall is None:
                self.stats.first_message_wall = now
        elif self._quiet_since is None and self.stats.last_message_wall is not None:
            self._quiet_since = now
        return got

    def _receive(self) -> None:
        """The receiving thread: discovery and takes every ``poll_s``, handed to :meth:`deliver`, so that a long
        calibrator step never lets a reader's queue overflow."""
        try:
            if self._record_path is not None:  # sqlite: the bag is written and closed by this thread only
                self._open_bag(self._record_path)
            while not self._closing.is_set():
                c0 = time.monotonic()
                self._discover()
                self.deliver(self._take())
                self._closing.wait(max(0.0, self.options.poll_s - (time.monotonic() - c0)))
            self.deliver(self._take())  # the last samples, recorded too
        except Exception as exc:  # noqa: BLE001 - the session must end cleanly, with what it has
            self._receive_error = exc
        finally:
            if self._bag is not None:
                try:
                    self._bag.close()
                finally:
                    self._bag = None

    def start(self) -> None:
        """Start the receiving thread (:meth:`poll` starts it when needed)."""
        if self._thread is None:
            self._thread = threading.Thread(target=self._receive, name="skincal-ros2-receive", daemon=True)
            self._thread.start()

    def deliver(self, messages: list[tuple[str, Any, bytes]]) -> None:
        """Queue received ``(ROS topic, message, bytes)`` for the next :meth:`poll` (thread-safe)."""
        with self._lock:
            self._inbox.extend(messages)

    def _drain(self) -> list[tuple[str, Any, bytes]]:
        with self._lock:
            got, self._inbox = self._inbox, []
        return got

    def _robot_from(self, text: str) -> None:
        from skincal.kinematics.urdf import chain_from_urdf

        try:
            self.chain = chain_from_urdf(text=text, base_link=self.base_link, tip_link=self.tip_link)
        except ConfigError as exc:
            self.drops.add(ROBOT_DESCRIPTION, "not a usable URDF")
            self.stats.refused[ROBOT_DESCRIPTION] = str(exc)
            return
        self.robot_source = ROBOT_DESCRIPTION

    def _unit(self, topic: str, frame: str) -> str | None:
        """The unit of the source ``(topic, frame_id)``: the frame_id, else the topic's name; None when
        neither is a name or the name is another source's (counted)."""
        from skincal.data.ros.topics import unit_from_topic

        key = (topic, frame)
        if key not in self._source_unit:
            if len(self._source_unit) >= MAX_SOURCES:
                return None
            unit = None
            for name in ((frame,) if frame else ()) + (unit_from_topic(topic),):
                if name_problem(name) is None and name not in self._unit_source:
                    unit = name
                    break
            self._source_unit[key] = unit
            label = f"{topic} {frame}".strip()
            if unit is None:
                self.stats.refused[label] = printable(f"no usable unit name (frame_id {frame!r}, topic {topic})")
            else:
                self._unit_source[unit] = key
                self.stats.units[label] = unit
        return self._source_unit[key]

    def _joint_columns(self, names: tuple[str, ...]) -> np.ndarray | None:
        from skincal.data.ros.reader import match_joints

        assert self.chain is not None
        if names not in self._joint_cols:
            if len(self._joint_cols) >= MAX_SOURCES:
                return None
            wanted = self.chain.joint_names
            cols: np.ndarray | None
            if wanted is None:
                cols = np.arange(self.chain.n_joints) if len(names) == self.chain.n_joints else None
            else:
                try:
                    cols, _missing = match_joints(names, tuple(wanted), "ros2", JOINT_TOPIC)
                except DatasetError:  # a joint matches several names: not this robot's message
                    cols = None
            self._joint_cols[names] = cols
        return self._joint_cols[names]

    def _feed(self, got: list[tuple[str, Any, bytes]]) -> None:
        """Batch this poll's joint states and IMU samples per unit into the feed."""
        assert self.feed is not None and self.origin_ns is not None
        rows_t, rows_q, rows_qd = [], [], []
        imu: dict[str, list[tuple[float, tuple[float, ...]]]] = {}
        for topic, msg, _ in got:
            if topic == ROBOT_DESCRIPTION:
                continue
            t = (msg.header.stamp.to_ns() - self.origin_ns) * 1e-9
            own = self._t_stream.get(topic, self._t_newest)  # the newest of this topic's own stream
            if not (own - MAX_BEHIND_S <= t and t <= self._t_newest + MAX_AHEAD_S):
                self.drops.add(topic, "stamp jump")
                continue
            self._t_newest = max(self._t_newest, t)
            self._t_stream[topic] = max(own, t)
            if topic == JOINT_TOPIC:
                cols = self._joint_columns(tuple(msg.name))
                if cols is None:
                    self.drops.add(topic, "not the robot's joints")
                    continue
                pos = np.asarray(msg.position, dtype=float)
                if not np.all(np.isfinite(pos[cols])):
                    self.drops.add(topic, "not finite")
                    continue
                rows_t.append(t)
                rows_q.append(pos[cols])
                rows_qd.append(np.asarray(msg.velocity, dtype=float)[cols] if len(msg.velocity) else np.full(len(cols),
                               np.nan))  # fmt: skip
                continue
            unit = self._unit(topic, msg.header.frame_id)
            if unit is None:
                self.drops.add(topic, "no unit name")
                continue
            a, w = msg.linear_acceleration, msg.angular_velocity
            reading = (a.x, a.y, a.z, w.x, w.y, w.z)
            if not all(math.isfinite(x) for x in reading):
                self.drops.add(topic, "not finite")
                continue
            imu.setdefault(unit, []).append((t, reading))
        if rows_t:
            qd = np.array(rows_qd)
            self.feed.add_joints(np.array(rows_t), np.array(rows_q), None if np.isnan(qd).any() else qd)
        for unit, rows in imu.items():
            t = np.array([r[0] for r in rows])
            v = np.array([r[1] for r in rows], dtype=float)
            self.feed.add_imu(unit, t, v[:, :3], v[:, 3:])

    def poll(self) -> None:
        """One round: what the receiving thread took, fed; calibrate; publish."""
        self.start()
        if self._receive_error is not None:
            from skincal.errors import first_line

            raise ConfigError(f"ROS 2 receiver failed: {first_line(self._receive_error)}")
        got = self._drain()
        if self.chain is None:
            for topic, msg, _ in got:
                if topic == ROBOT_DESCRIPTION and self.chain is None:
                    self._robot_from(msg.data)
        self._pending.extend(g for g in got if g[0] != ROBOT_DESCRIPTION)
        if len(self._pending) > MAX_PENDING:
            for topic, _, _ in self._pending[: len(self._pending) - MAX_PENDING]:
                self.drops.add(topic, "waiting")
            del self._pending[: len(self._pending) - MAX_PENDING]
        if self.feed is None:
            if self.chain is None:
                return
            firsts = [g[1].header.stamp.to_ns() for g in self._pending if g[0] == JOINT_TOPIC][:ORIGIN_JOINT_STATES]
            if len(firsts) < ORIGIN_JOINT_STATES:
                return
            self.origin_ns = int(np.median(firsts))
            self.feed = LiveFeed(self.chain, self.target, warmup_s=self.options.warmup_s, stop_at_target=True,
                                 watch=self.options.watch, on_event=self._moved_event)  # fmt: skip
        if self._pending:
            self._feed(self._pending)
            self._pending = []
        self.feed.tick()
        self._decided_wall = time.monotonic()  # the statuses are the calibrator's decisions of now
        self._publish_decided()
        self._diagnostics()

    # ------------------------------------------------------------------ output
    def _moved_event(self, event: dict) -> None:
        self._events += 1
        self._moved.add(str(event.get("unit")))
        if self.on_event is not None:
            self.on_event(event)

    def _frames(self, result: Any, units: list[str]) -> dict[str, Any]:
        from skincal.workflows.ros2_publish import unit_transforms

        assert self.chain is not None
        return unit_transforms(result, self.chain, units, time.time_ns())

    def _send_tf(self) -> None:
        self._tf.write(self._m.TFMessage(transforms=[self._published[u] for u in sorted(self._published)]))
        self.stats.tf_messages += 1

    def _publish_decided(self) -> None:
        """Publish (all published units in one message) each unit that reached the target for the first
        time; a moved unit as soon as its re-calibration has a determined pose (the pose published
        before is known to be wrong), and again when it reaches the target."""
        assert self.feed is not None
        due = []
        for u, s in self.feed.statuses.items():
            if u in self._moved:
                if s.pose is not None and s.link is not None and not s.missing:
                    due.append(u)
            elif s.reached and (u not in self._published or u in self._provisional):
                due.append(u)
        if not due or self.feed.calibrator is None:
            return
        frames = self._frames(self.feed.calibrator.result(), due)
        if frames:
            self._published.update(frames)
            for u in frames:
                if u in self._moved:
                    self._moved.discard(u)
                    self._provisional.add(u)
                else:
                    self._provisional.discard(u)
            self._send_tf()
            self.stats.tf_delay_max_s = max(self.stats.tf_delay_max_s, time.monotonic() - self._decided_wall)

    def _diagnostics(self, force: bool = False) -> None:
        now = time.monotonic()
        if not force and now - self._diag_wall < self.options.diagnostics_every_s:
            return
        self._diag_wall = now
        self._diag.write(self.diagnostics())

    def diagnostics(self) -> Any:
        """The ``DiagnosticArray`` of now: one status per unit and the session's."""
        from skincal.workflows.ros2_publish import session_status, unit_status

        m = self._m
        statuses = [] if self.feed is None else sorted(self.feed.statuses.items())
        out = []
        for unit, s in statuses:
            state = "moved" if unit in self._moved else "provisional" if unit in self._provisional else ""
            out.append(unit_status(unit, s, self.chain, self.target.text(), state, unit in self._published))
        counts = {
            "imu topics": ", ".join(sorted(self._imu)) or "-",
            "units": str(len(statuses)),
            "messages": str(sum(self.stats.messages.values())),
            "dropped": str(self.drops.total()),
            "ignored topics": str(len(self.stats.ignored_topics)),
            "moves": str(self._events),
            "robot": "-" if self.chain is None else printable(self.chain.name),
        }
        state = "waiting for the robot" if self.chain is None else (
            "waiting for joint states" if self.feed is None else "calibrating")  # fmt: skip
        out.append(session_status(state, self.feed is not None, counts))
        return m.DiagnosticArray(header=m.Header(m.Time.from_ns(time.time_ns()), ""), status=out)

    # ------------------------------------------------------------------ the session
    def done(self, stop: threading.Event | None = None) -> str | None:
        """Why the session ends now (``None``: it goes on)."""
        now = time.monotonic()
        if stop is not None and stop.is_set():
            return "stopped"
        if self.options.until_decided and self.feed is not None and self.feed.reached:
            return "target reached"
        if self.options.duration_s is not None and now - self._t0_wall >= self.options.duration_s:
            return "duration"
        quiet = self._quiet_since
        if self.options.idle_s is not None and quiet is not None and now - quiet >= self.options.idle_s:
            return "idle"
        return None

    def run(
        self,
        stop: threading.Event | None = None,
        on_meter: Callable[[Mapping[str, Any], float, float | None], None] | None = None,
    ) -> str:
        """Poll until :meth:`done`; ``on_meter(statuses, t_data, None)`` after every poll. Returns why it ended."""
        while True:
            c0 = time.monotonic()
            self.poll()
            if on_meter is not None and self.feed is not None:
                on_meter(self.feed.statuses, self.feed.t_data, None)
            why = self.done(stop)
            if why is not None:
                return why
            rest = self.options.step_s - (time.monotonic() - c0)
            if rest > 0:
                if stop is not None:
                    stop.wait(rest)
                else:
                    time.sleep(rest)

    def _count_dds_losses(self) -> None:
        """Samples DDS itself lost (sequence gaps of best-effort traffic) or rejected (a reader's queue
        full), per topic, into the drop counts."""
        for r in [self._joints, *self._imu.values()]:
            for reason, get in (("lost in transport", "get_sample_lost_status"),
                                ("queue full", "get_sample_rejected_status")):  # fmt: skip
                try:
                    n = int(getattr(r.reader, get)().total_count)
                except Exception:  # noqa: BLE001 - a status the binding cannot read is not a loss
                    n = 0
                self.drops.add(r.topic, reason, n)

    def close(self) -> None:
        """Stop the receiving thread (it closes the bag); idempotent."""
        self._closing.set()
        if self._thread is not None:
            self._thread.join()

    def finish(self) -> LiveOutcome | None:
        """Absorb what is left, publish the final poses (every calibrated unit) and diagnostics, close the
        bag; the outcome with the session's counters in ``extras['ros2']`` (None: the calibrator never
        started: no robot, no joint states or no IMU)."""
        c0 = time.monotonic()
        self.close()
        try:
            self._pending.extend(self._drain())
            if self._pending and self.feed is not None:
                self._feed(self._pending)
                self._pending = []
            outcome = None if self.feed is None else self.feed.outcome()
            if outcome is not None:
                result = outcome.result
                self._published = self._frames(result, list(result.units))
                self._moved.clear()
                self._provisional.clear()
                if self._published:
                    self._send_tf()
                self._diagnostics(force=True)
                self._count_dds_losses()
                last = self.stats.last_message_wall
                info = {
                    "domain": None,
                    "imu_topics": sorted(self._imu),
                    "units": dict(self.stats.units),
                    "refused": dict(self.stats.refused),
                    "messages": dict(self.stats.messages),
                    "dropped": self.drops.as_dict(),
                    "ignored_topics": sorted(self.stats.ignored_topics),
                    "robot_source": self.robot_source,
                    "tf_messages": self.stats.tf_messages,
                    "tf_delay_max_s": self.stats.tf_delay_max_s,
                    "finish_s": time.monotonic() - c0,
                    "last_message_to_result_s": None if last is None else time.monotonic() - last,
                    "process_cpu_s": time.process_time() - self._cpu0,
                    "wall_s": time.monotonic() - self._t0_wall,
                }
                result = dataclasses.replace(result, extras={**result.extras, "ros2": info})
                outcome = dataclasses.replace(outcome, result=result)
            return outcome
        finally:
            if self._receive_error is not None:
                from skincal.errors import first_line

                raise ConfigError(f"ROS 2 receiver failed: {first_line(self._receive_error)}")
