"""The live session: a data stream fed to the streaming calibrator until every unit reaches a target.

Two sources, one calibrator (:class:`skincal.calib.online.OnlineCalibrator`):

* :func:`follow_dataset`: a dataset (or a ROS bag, read by :func:`skincal.data.ros.read_bag`, the one
  door for bags) replayed in arrival order at real speed or as fast as possible
  (:func:`skincal.calib.online.replay`); ``skincal calibrate --follow``.
* :func:`record_live`: the UDP receiver while ``skincal record`` writes the recording
  (:func:`skincal.hw.session.record`): each in-order packet is also given to the calibrator, its
  device times mapped to host time by the receiver's clock fit of the stream, exactly as the
  recorder maps them (``t = fit.to_host(device_t) - t_origin``); ``skincal record --live``.

Both stop by themselves when every unit's position and rotation std is within the :class:`Target`
on every axis (or at the end of the data), and give the calibrator's result (method ``online``,
the result JSON contract of every method); the CLI writes it atomically.
"""

from __future__ import annotations

import asyncio
import dataclasses
import math
import re
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from skincal.errors import ConfigError
from skincal.names import name_problem, printable

if TYPE_CHECKING:
    from skincal.calib.online import OnlineCalibrator, UnitStatus
    from skincal.data.dataset import Dataset
    from skincal.data.result import CalibrationResult
    from skincal.hw.receiver import Delivery, SkinReceiver
    from skincal.hw.recorder import Recorder
    from skincal.kinematics.chain import SerialChain

POSITION_UNITS = {"m": 1.0, "cm": 1e-2, "mm": 1e-3, "um": 1e-6, "µm": 1e-6}
"""Length units a ``--target`` position may be given in -> metres."""
ROTATION_UNITS = {"deg": 1.0, "rad": 180.0 / math.pi, "mrad": 0.18 / math.pi, "arcmin": 1.0 / 60.0}
"""Angle units a ``--target`` rotation may be given in -> degrees."""
BAG_SUFFIXES = (".bag", ".db3", ".mcap")
"""A ROS bag (besides a ROS 2 bag directory): followed through :func:`skincal.data.ros.read_bag`."""
CHUNK_S = 0.1
"""Data fed to the calibrator per step of a replay, s."""
STATUS_EVERY_S = 0.5
"""The units' status (the meter, the stop test) is asked for at most this often, s of data (a replay) or
of wall time (live): ``status()`` of 100 units costs ~20 ms of CPU, as much as absorbing 0.5 s of their data."""
LIVE_WARMUP_S = 2.0
"""``record --live``: wall time after the first joint state during which units are gathered before the
calibrator starts (a unit seen first after that is recorded but not followed), s."""

_UNITS_LONGEST_FIRST = sorted([*POSITION_UNITS, *ROTATION_UNITS], key=len, reverse=True)
_NUMBER = re.compile(r"[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?")


@dataclass(frozen=True)
class Target:
    """Std to reach on every axis: position, m; rotation, deg."""

    position_m: float = 3e-4
    rotation_deg: float = 0.05

    def text(self) -> str:
        return f"{self.position_m * 1e3:g}mm,{self.rotation_deg:g}deg"


def parse_target(text: str) -> Target:
    """``--target`` text: a length and an angle with their units, comma-separated, in either order
    (``0.3mm,0.05deg``; lengths :data:`POSITION_UNITS`, angles :data:`ROTATION_UNITS`); each a finite
    number > 0. Anything else is a one-line :class:`ConfigError`."""
    example = "give a position and a rotation std with their units, e.g. --target 0.3mm,0.05deg"
    shown = printable(repr(str(text)))
    parts = str(text).split(",")
    if len(parts) != 2:
        raise ConfigError(f"--target {shown}: {example}")
    position = rotation = None
    for part in parts:
        term = part.strip().lower()
        unit = next((u for u in _UNITS_LONGEST_FIRST if term.endswith(u)), None)
        if unit is None:
            letters = re.search(r"[^\W\d_]+$", term)
            if letters is None:
                raise ConfigError(f"--target {shown}: '{printable(part.strip())}' has no unit; {example}")
            units = ", ".join([*POSITION_UNITS, *ROTATION_UNITS])
            raise ConfigError(f"--target {shown}: unknown unit '{printable(letters.group())}' (use {units})")
        number = term[: -len(unit)].strip()
        if not number:
            raise ConfigError(f"--target {shown}: '{printable(part.strip())}' has no number; {example}")
        if _NUMBER.fullmatch(number) is None:
            raise ConfigError(f"--target {shown}: '{printable(number)}' is not a finite number; {example}")
        value = float(number)
        if not value > 0:
            raise ConfigError(f"--target {shown}: {printable(part.strip())} must be > 0 (a std to reach)")
        if unit in POSITION_UNITS and position is None:
            position = value * POSITION_UNITS[unit]
        elif unit in ROTATION_UNITS and rotation is None:
            rotation = value * ROTATION_UNITS[unit]
        else:
            raise ConfigError(
                f"--target {shown}: two {'positions' if unit in POSITION_UNITS else 'rotations'}; {example}"
            )
    assert position is not None and rotation is not None
    if not (math.isfinite(position) and math.isfinite(rotation)):
        raise ConfigError(f"--target {shown}: not a finite number; {example}")
    return Target(position, rotation)


def all_reached(statuses: Mapping[str, UnitStatus]) -> bool:
    """Every unit within the target (and at least one unit)."""
    return bool(statuses) and all(s.reached for s in statuses.values())


@dataclass(frozen=True)
class LiveOutcome:
    """How a live session ended.

    Attributes:
        result: the calibrator's result (method ``online``).
        statuses: the units' last status.
        reached: every unit reached the target (else the data ended or the session was stopped).
        t_data: data followed, s since the data's start (when it stopped).
        t_end: the data's length, s (a replay; ``None`` live).
        notes: what the user should know (units not followed, ...).
    """

    result: CalibrationResult
    statuses: dict[str, UnitStatus]
    reached: bool
    t_data: float
    t_end: float | None
    notes: tuple[str, ...] = ()
    stopped: bool = False
    """The user stopped the follow (``stop``) before the data's end or the target."""


MeterCallback = Callable[[Mapping[str, "UnitStatus"], float, "float | None"], None]
"""``on_meter(statuses, t_data, t_end)``: the meter's view after a step (times in s since the data's start)."""


def make_calibrator(chain: SerialChain, units: list[str], gravity: Any, target: Target) -> OnlineCalibrator:
    """The streaming calibrator of ``units`` on ``chain`` with ``target`` as its target."""
    from skincal.calib.online import OnlineCalibrator, OnlineOptions

    options = OnlineOptions(target_position_m=target.position_m, target_rotation_deg=target.rotation_deg)
    return OnlineCalibrator(chain, units, gravity=np.asarray(gravity, dtype=float), options=options)


def is_bag(path: str | Path) -> bool:
    """A ROS bag (a directory, or a ``.bag``/``.db3``/``.mcap`` file) rather than an HDF5 dataset."""
    p = Path(path)
    return p.is_dir() or p.suffix.lower() in BAG_SUFFIXES


def load_source(path: str | Path, robot: str | None = None) -> Dataset:
    """The dataset of ``path``: a ROS bag through :func:`skincal.data.ros.read_bag` (``robot``: a preset,
    ``.urdf`` or chain file; default the bag's ``/robot_description``, required without one) or an HDF5 dataset
    (``robot`` must then be ``None``: the dataset has its own). Needs joint states."""
    if is_bag(path):
        from skincal.data.ros import read_bag

        ds, _report = read_bag(path, robot)
    else:
        from skincal.data.hdf5 import read_dataset

        if robot is not None:
            raise ConfigError(f"{printable(str(path))}: --robot is for a bag; a dataset has its own robot")
        ds = read_dataset(path)
    ds.require_joints("calibrate --follow (the stream is absorbed against the joint states)", source=str(path))
    return ds


def data_span(ds: Dataset) -> tuple[float, float]:
    """First and last instant of ``ds``'s joint and IMU streams, s (the meter's data time is from the first)."""
    joints = ds.require_joints("calibrate --follow")[1]
    t0 = min([float(joints.t[0]), *(float(s.t[0]) for s in ds.imu.values() if len(s.t))])
    t1 = max([float(joints.t[-1]), *(float(s.t[-1]) for s in ds.imu.values() if len(s.t))])
    return t0, t1


def follow_dataset(
    ds: Dataset,
    target: Target = Target(),
    *,
    speed: float | None = 1.0,
    units: list[str] | None = None,
    chunk_s: float = CHUNK_S,
    on_meter: MeterCallback | None = None,
    stop_at_target: bool = True,
    dataset_sha256: str = "",
    status_every_s: float = STATUS_EVERY_S,
    watch: bool = False,
    on_event: Callable[[dict], None] | None = None,
    stop: threading.Event | None = None,
    on_progress: Callable[[str], None] | None = None,
) -> LiveOutcome:
    """Replay ``ds`` into a streaming calibrator (at ``speed`` data seconds per wall second, ``None``: as
    fast as possible) until every unit reaches ``target`` (``stop_at_target``) or the data end;
    ``on_meter`` and the stop test every ``status_every_s`` of data. ``watch``: a moved-unit monitor
    (:class:`skincal.calib.online.monitor.MovedUnitMonitor`) watches every settled unit to the data's
    end (no stop at the target); a unit that moved is re-calibrated from the data after the change,
    the event goes to the result's ``events`` and to ``on_event``. ``stop`` set (a user's Ctrl-C, from
    another thread or a signal handler): the replay ends at the next chunk and the outcome is the result of
    the data until then (``stopped``; a result note says so); set during the report-spacing replays, the
    term is left out and a note says so. ``on_progress(line)`` tells of the work after the replay. Nothing is
    written here."""
    from skincal.calib.online import replay

    chain, joints = ds.require_joints("calibrate --follow")
    if speed is not None and not (math.isfinite(speed) and speed > 0):
        raise ConfigError(f"--speed {speed}: a finite number > 0 (0: as fast as possible)")
    names = list(units) if units else ds.units
    unknown = [u for u in names if u not in ds.imu]
    if unknown:
        raise ConfigError(
            f"no unit {printable(unknown[0])!r} in the dataset (it has {', '.join(map(printable, ds.units))})"
        )
    follow = (
        ds
        if names == ds.units
        else dataclasses.replace(
            ds, imu={u: ds.imu[u] for u in names}, tof={u: s for u, s in ds.tof.items() if u in names}
        )
    )
    t0, t1 = data_span(follow)
    cal = make_calibrator(chain, names, ds.gravity, target)
    if watch:
        from skincal.calib.online.monitor import MovedUnitMonitor

        monitor = MovedUnitMonitor().attach(cal)
        if on_event is not None:
            monitor.on_alarm = lambda _alarm: on_event(dict(cal.events[-1])) if cal.events else None
        stop_at_target = False
    state = {"t": t0, "reached": False, "asked": -math.inf, "stopped": False}

    def on_chunk(t: float) -> bool:
        state["t"] = float(t)
        if stop is not None and stop.is_set() and t < t1 - 1e-9:  # on the last chunk: the data's end
            state["stopped"] = True
            return True
        if t - state["asked"] < status_every_s - 1e-9:
            return False
        state["asked"] = float(t)
        statuses = cal.status()
        if stop_at_target and all_reached(statuses):  # the stop judged on a fresh split check, not a cached one
            statuses = cal.status(fresh=True)
        if on_meter is not None:
            on_meter(statuses, float(t) - t0, t1 - t0)
        state["reached"] = all_reached(statuses)
        return stop_at_target and state["reached"]

    replay(follow, cal, chunk_s=chunk_s, speed=speed, on_chunk=on_chunk)  # finish() at the data's end
    stopped = bool(state["stopped"])
    # at the data's end after finish() (what was left absorbed), or where the user stopped: not a cached split check
    statuses = cal.status(fresh=stopped)
    reached = bool(state["reached"]) or all_reached(statuses)
    if on_progress is not None:
        on_progress(f"computing the result of {len(names)} unit(s) from {state['t'] - t0:.1f} s of data")
    result = cal.result()
    if stopped:
        result = dataclasses.replace(result, notes=(*result.notes, f"stopped by the user after {state['t'] - t0:.1f}"
                                                    f" s of {t1 - t0:.1f} s of data"))  # fmt: skip
    if not cal.events:  # a unit that moved is re-calibrated from the data after its move: no whole-stream replay
        result = report_spacing_checked(follow, result, state["t"], stop=stop, on_progress=on_progress)
        reached = reached and within_target(result, target)  # the std written, report-spacing term included
    result = dataclasses.replace(result, dataset_sha256=dataset_sha256)
    if on_meter is not None:
        on_meter(statuses, state["t"] - t0, t1 - t0)
    return LiveOutcome(result, dict(statuses), reached, state["t"] - t0, t1 - t0, stopped=stopped)


def outside_target(result: CalibrationResult, target: Target) -> list[str]:
    """The units of ``result`` whose written position or rotation std exceeds ``target``, and those it could not
    calibrate (a unit without a position counts by its rotation, as the status does)."""
    def ok(u: Any) -> bool:
        p = np.zeros(3) if u.position_std_m is None else np.nan_to_num(np.asarray(u.position_std_m, float), nan=0.0)
        r = np.asarray(u.rotation_std_deg if u.rotation_std_deg is not None else np.full(3, np.inf), dtype=float)
        return bool(np.all(p <= target.position_m) and np.all(r <= target.rotation_deg))

    return [*result.failed_units, *(name for name, u in result.units.items() if not ok(u))]


def within_target(result: CalibrationResult, target: Target) -> bool:
    """Every unit of ``result`` is calibrated within ``target`` by its written std (:func:`outside_target`)."""
    return bool(result.units) and not outside_target(result, target)


def report_spacing_checked(
    ds: Dataset, result: CalibrationResult, t_end: float, *, stop: threading.Event | None = None,
    on_progress: Callable[[str], None] | None = None,
) -> CalibrationResult:  # fmt: skip
    """``result`` of the streaming calibrator on ``ds`` up to ``t_end`` (joint clock, s) with the report-spacing
    term of a low-rate joint stream (:func:`skincal.calib.joint_rate.check`, as ``mle`` has it): the recording's
    part up to ``t_end`` replayed again with every second and every third joint report. A stream at a
    controller's rate is left alone (no replay). ``on_progress(line)`` before each replay; ``stop`` set before
    or during them: ``result`` as given, with a note that the term was not computed (before) or left out
    (during: no term is made of a replay cut short)."""
    from skincal.calib import joint_rate
    from skincal.calib.online import OnlineCalibrator, OnlineOptions, replay
    from skincal.calib.preprocess import is_low_rate
    from skincal.workflows.monitoring import crop

    if ds.joints is None or not result.units or not is_low_rate(ds.joints.t):
        return result

    def noted(why: str) -> CalibrationResult:
        note = f"report-spacing term of the low-rate joint stream {why}"
        return dataclasses.replace(result, notes=(*result.notes, note))

    if stop is not None and stop.is_set():
        return noted("not computed: stopped by the user before its replays")
    part = crop(ds, -math.inf, t_end) if t_end < data_span(ds)[1] else ds
    assert part.joints is not None
    rate_hz = 1.0 / float(np.median(np.diff(part.joints.t)))
    used = joint_rate.thinnings(part.joints.t)
    which = " and ".join({2: "every second", 3: "every third"}.get(k, f"every {k}th") for k in used) + " report"
    done = [0]

    def refit(thinned: Dataset, links: dict[str, int]) -> CalibrationResult:
        """The streaming calibrator on a thinned stream as on the full one (its candidates all links: one
        candidate never makes a unit decided, which weighs its data otherwise), without the split check."""
        done[0] += 1
        if on_progress is not None:
            on_progress(f"report spacing of the {rate_hz:.0f} Hz joint stream: replay {done[0]} of {sum(used)} "
                        f"({which})")  # fmt: skip
        options = OnlineOptions(consistency=False)
        cal = OnlineCalibrator(thinned.chain, list(links), np.asarray(thinned.gravity, dtype=float), options)
        replay(thinned, cal, on_chunk=None if stop is None else lambda _t: stop.is_set())
        if stop is not None and stop.is_set():
            raise _Stopped
        return cal.result()

    try:
        return joint_rate.check(part, result, refit)
    except _Stopped:
        return noted("not applied: stopped by the user during its replays")


class _Stopped(BaseException):
    """Raised out of a report-spacing replay when the user stopped: past ``joint_rate.check``'s handling of a
    failed thinned fit (an ``Exception``), so no term is made of a replay cut short."""


# -- live from the UDP receiver --------------------------------------------------------------------


@dataclass
class LiveFeed:
    """Samples of a live source turned into calibrator input: the deliveries of a recording session
    (``record --live``, :meth:`on_delivery`) or any other stream (:meth:`add_joints`, :meth:`add_imu`;
    ``skincal ros2``).

    Packets are buffered until :meth:`tick` starts the calibrator (the first tick at least
    :data:`LIVE_WARMUP_S` after the first joint state, with the units seen by then), then fed as they
    arrive; :meth:`tick` absorbs what is complete and sets ``stop`` when every unit reached the target.
    """

    chain: SerialChain
    target: Target
    gravity: Any = None
    warmup_s: float = LIVE_WARMUP_S
    stop_at_target: bool = True
    status_every_s: float = STATUS_EVERY_S
    clock: Callable[[], float] = time.monotonic
    watch: bool = False
    """A moved-unit monitor watches every settled unit (as ``calibrate --follow --watch``); a unit that
    moved is re-calibrated from the data after the change and ``on_event(event)`` is called."""
    on_event: Callable[[dict], None] | None = None
    calibrator: OnlineCalibrator | None = None
    statuses: dict[str, UnitStatus] = field(default_factory=dict)
    t_data: float = 0.0
    reached: bool = False
    late_units: set[str] = field(default_factory=set)
    _joints: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = field(default_factory=list)
    _imu: dict[str, list[tuple[np.ndarray, np.ndarray, np.ndarray | None]]] = field(default_factory=dict)
    _first_joint_s: float | None = None
    _names: dict[int, str | None] = field(default_factory=dict)
    _units: list[str] = field(default_factory=list)
    _asked_s: float = -math.inf

    def _unit_name(self, recorder: Recorder, unit_id: int) -> str | None:
        from skincal.hw.recorder import default_unit_name

        if unit_id not in self._names:
            name = recorder.unit_names.get(unit_id, default_unit_name(unit_id))
            self._names[unit_id] = name if name_problem(name) is None else None
        return self._names[unit_id]

    def on_delivery(self, delivery: Delivery, recorder: Recorder, receiver: SkinReceiver) -> None:
        """One in-order packet: its samples on the recording's host time axis, to the calibrator (or the
        buffer before it starts)."""
        from skincal.hw.packet import JointPacket

        p = delivery.packet
        fit = receiver.clock_fit(delivery.key)
        device_s = np.asarray(p.t_us, dtype=np.int64) * 1e-6
        t = fit.to_host(device_s) if fit is not None else np.full(device_s.shape, delivery.host_receive_s)
        t = np.asarray(t, dtype=float) - recorder.t_origin_s
        if isinstance(p, JointPacket):
            if p.q.shape[1] != self.chain.n_joints:
                return  # another robot: the recorder ignores it too
            self.add_joints(t, np.asarray(p.q, dtype=float), np.asarray(p.qd, dtype=float))
            return
        if p.accel is None:
            return
        name = self._unit_name(recorder, p.unit_id)
        if name is None:
            return
        gyro = None if p.gyro is None else np.asarray(p.gyro, dtype=float)
        self.add_imu(name, t, np.asarray(p.accel, dtype=float), gyro)

    def add_joints(self, t: np.ndarray, q: np.ndarray, qd: np.ndarray | None) -> None:
        """Joint states on the feed's time axis: ``t`` ``(N,)`` s, ``q``/``qd`` ``(N, n)`` rad, rad/s (any
        source: the UDP receiver, a ROS 2 topic)."""
        if self._first_joint_s is None:
            self._first_joint_s = self.clock()
        if self.calibrator is None:
            self._joints.append((t, q, qd))
        else:
            self.calibrator.add_joint_states(t, q, qd)
        if len(t):
            self.t_data = max(self.t_data, float(np.max(t)))

    def add_imu(self, name: str, t: np.ndarray, accel: np.ndarray, gyro: np.ndarray | None) -> None:
        """IMU samples of unit ``name`` (a checked name) on the feed's time axis: ``t`` ``(M,)`` s, ``accel``
        ``(M, 3)`` m/s^2, ``gyro`` ``(M, 3)`` rad/s or None. A unit first seen after the calibrator started
        is counted in :attr:`late_units`, not followed."""
        if self.calibrator is None:
            self._imu.setdefault(name, []).append((t, accel, gyro))
        elif name in self._units:
            self.calibrator.add_imu(name, t, accel, gyro)
        else:
            self.late_units.add(name)

    def _start(self) -> None:
        self._units = sorted(self._imu)
        from skincal.kinematics.chain import GRAVITY_BASE

        gravity = self.gravity if self.gravity is not None else GRAVITY_BASE
        self.calibrator = make_calibrator(self.chain, self._units, gravity, self.target)
        if self.watch:
            from skincal.calib.online.monitor import MovedUnitMonitor

            cal = self.calibrator
            monitor = MovedUnitMonitor().attach(cal)
            if self.on_event is not None:
                on_event = self.on_event
                monitor.on_alarm = lambda _alarm: on_event(dict(cal.events[-1])) if cal.events else None
        for t, q, qd in self._joints:
            self.calibrator.add_joint_states(t, q, qd)
        for name, parts in self._imu.items():
            for t, accel, gyro in parts:
                self.calibrator.add_imu(name, t, accel, gyro)
        self._joints.clear()
        self._imu.clear()

    def tick(self) -> bool:
        """Start the calibrator when due, absorb what is complete, refresh :attr:`statuses` (at most every
        ``status_every_s`` of wall time); returns whether every unit is at the target."""
        if self.calibrator is None:
            if self._first_joint_s is None or not self._imu or self.clock() - self._first_joint_s < self.warmup_s:
                return False
            self._start()
        assert self.calibrator is not None
        self.calibrator.update()
        now = self.clock()
        if now - self._asked_s >= self.status_every_s:
            self._asked_s = now
            self.statuses = dict(self.calibrator.status())
            self.reached = all_reached(self.statuses)
        return self.reached

    def notes(self) -> tuple[str, ...]:
        out = []
        if self.calibrator is None:
            out.append("waiting for joint states and skin units" if self._first_joint_s is None or not self._imu
                       else "gathering units")  # fmt: skip
        if self.late_units:
            late = ", ".join(printable(n) for n in sorted(self.late_units))
            out.append(f"recorded but not followed (first seen after the meter started): {late}")
        return tuple(out)

    def outcome(self) -> LiveOutcome | None:
        """At the end of the session: absorb what is left and give the result (``None`` when the
        calibrator never started: no joint states or no skin unit)."""
        if self.calibrator is None:
            if self._first_joint_s is None or not self._imu:
                return None
            self._start()
        assert self.calibrator is not None
        self.calibrator.finish()
        self.statuses = dict(self.calibrator.status())
        self.reached = all_reached(self.statuses)
        return LiveOutcome(self.calibrator.result(), dict(self.statuses), self.reached, self.t_data, None,
                           self.notes())  # fmt: skip


async def record_live(
    path: str | Path,
    chain: SerialChain,
    target: Target = Target(),
    *,
    stop: asyncio.Event | None = None,
    on_meter: Callable[[LiveFeed, Any, Recorder, SkinReceiver], None] | None = None,
    stop_at_target: bool = True,
    warmup_s: float = LIVE_WARMUP_S,
    **record_options: Any,
) -> tuple[Any, Any, LiveFeed]:
    """:func:`skincal.hw.session.record` with the live calibrator fed from the same packets (``robot`` is
    ``chain``); ``on_meter(feed, stats, recorder, receiver)`` every tick; the session stops when every
    unit reached ``target`` (``stop_at_target``), at ``duration_s`` or when ``stop`` is set. Returns the
    recording summary, the receiver's counters and the :class:`LiveFeed` (its :meth:`LiveFeed.outcome`
    gives the result)."""
    from skincal.hw.session import record

    stop = stop or asyncio.Event()
    feed = LiveFeed(chain, target, warmup_s=warmup_s, stop_at_target=stop_at_target)

    def on_tick(stats: Any, recorder: Recorder, receiver: SkinReceiver) -> None:
        if feed.tick() and stop_at_target:
            stop.set()
        if on_meter is not None:
            on_meter(feed, stats, recorder, receiver)

    summary, stats = await record(path, stop=stop, robot=chain, on_tick=on_tick, on_delivery=feed.on_delivery,
                                  **record_options)  # fmt: skip
    return summary, stats, feed
