"""A unit that moved is noticed, in simulation: everyday work, a knocked unit, the change detector.

* :func:`work_session`: a simulated session whose motion is an everyday work cycle
  (:mod:`skincal.protocol.workcycle`) instead of a calibration protocol;
* :func:`knocked_dataset`: the same session with one unit knocked (moved by ``translation_m`` and
  turned by ``rotation_deg``) at stamp ``t_knock`` (:func:`skincal.sim.faults.simulate_knock`);
* :func:`monitor_batch`: the monitor on residuals computed with the batch model: the units are
  calibrated with ``mle`` from the first ``initial_s`` s, their residuals over the rest of the session
  (:func:`skincal.calib.residuals.unit_residuals`, divided by the unit's white-noise std) feed
  :class:`~skincal.calib.online.monitor.MovedUnitMonitor`; on an alarm the unit is re-calibrated from
  ``recal_s`` s of data after the estimated change and watched again from there on;
* :func:`monitor_online`: the same with the streaming calibrator
  (:class:`~skincal.calib.online.OnlineCalibrator`, the dataset replayed through it);
* :func:`motion_time`: how long the unit's link moved between two instants (the delay "within 5 s of
  motion" is motion time: a unit knocked while the robot rests cannot show a move of its position).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from skincal.calib.online.monitor import Alarm, MonitorOptions, MovedUnitMonitor
from skincal.data.dataset import Dataset, ImuStream, JointStates, Segments
from skincal.data.result import CalibrationResult, UnitResult, with_events
from skincal.errors import ConfigError
from skincal.kinematics.transforms import FloatArray
from skincal.skin.pose import SkinUnitPose

MOVING_SPEED = 0.05
"""A joint moves when its reported speed exceeds this, rad/s (for :func:`motion_time`)."""


def work_session(
    robot: str = "panda",
    noise: str = "realistic",
    kind: str = "teleop",
    duration_s: float = 120.0,
    seed: int = 0,
    *,
    placement: str = "paper",
    units: int | None = None,
    joints: str = "auto",
    clock: str = "auto",
    rate_hz: float | None = None,
):
    """A :class:`~skincal.sim.Session` of everyday work: the preset session of
    :func:`skincal.workflows.session.make_session` (robot, placement, IMU, joint and clock presets from
    ``seed``) whose motion is the work cycle ``kind`` of ``duration_s`` s (drawn from ``seed + 1``);
    ``rate_hz`` sets the robot stream's sampling (default the work cycle's)."""
    from skincal.protocol.workcycle import WorkCycleConfig, work_cycle
    from skincal.workflows.session import make_session

    session = make_session(robot, placement, units, noise, "fast", seed, joints=joints, clock=clock)
    config = WorkCycleConfig(duration_s=duration_s)
    if rate_hz is not None:
        config = replace(config, rate_hz=rate_hz)
    traj = work_cycle(session.chain, kind, np.random.default_rng(seed + 1), config)
    text = f"simulated work: robot={session.chain.name} {kind} noise={noise} seed={seed}"
    return replace(session, trajectory=traj, description=text)


def simulate_session(session, seed: int) -> Dataset:
    """``session`` simulated (analytic) with a fresh generator from ``seed`` (the same data on every call)."""
    from skincal.sim import simulate

    return simulate(replace(session, rng=np.random.default_rng(seed)))


def knocked_dataset(
    session, unit: str, t_knock: float, translation_m: float, rotation_deg: float, seed: int = 0
) -> Dataset:
    """``session`` simulated with ``unit`` knocked at stamp ``t_knock`` by ``translation_m`` m and
    ``rotation_deg`` deg in random directions (:func:`skincal.sim.faults.knocked_pose` from ``seed``);
    truth as :func:`skincal.sim.faults.splice_knock` records it."""
    from skincal.sim.faults import knocked_pose, simulate_knock

    if unit not in session.placements:
        raise ConfigError(f"unknown unit '{unit}' (session has: {', '.join(session.placements)})")
    moved = knocked_pose(session.placements[unit], translation_m, rotation_deg, np.random.default_rng([seed, 7]))
    return simulate_knock(
        lambda placements: simulate_session(replace(session, placements=placements), seed),
        session.placements, unit, t_knock, moved,
    )  # fmt: skip


def crop(dataset: Dataset, t0: float, t1: float) -> Dataset:
    """The part of ``dataset`` in ``[t0, t1]`` s (joint and IMU streams by their own stamps, segments
    cut to it; ToF streams dropped). The input is not modified."""
    j = dataset.joint_states
    keep = (j.t >= t0) & (j.t <= t1)
    if np.count_nonzero(keep) < 2:
        raise ConfigError(f"crop: fewer than two joint samples in [{t0:g}, {t1:g}] s")
    joints = JointStates(j.t[keep], j.q[keep], j.qd[keep], None if j.qdd is None else j.qdd[keep])
    imu = {}
    for name, s in dataset.imu.items():
        k = (s.t >= t0) & (s.t <= t1)
        imu[name] = ImuStream(s.t[k], s.accel[k], None if s.gyro is None else s.gyro[k])
    segments = dataset.segments
    if segments is not None:
        inside = (segments.t_start >= t0) & (segments.t_end <= t1)
        segments = Segments(*(np.asarray(a)[inside] for a in (segments.t_start, segments.t_end, segments.kind,
                                                                segments.pose, segments.joint)))  # fmt: skip
    return replace(dataset, joints=joints, imu=imu, tof={}, segments=segments)


def noise_std(dataset: Dataset, unit: str) -> FloatArray:
    """``(3,)`` white-noise std of ``unit``'s accelerometer per axis, m/s^2 (second differences, robust:
    :func:`skincal.calib.preprocess.white_noise_std`), floored at 1e-6."""
    from skincal.calib.preprocess import white_noise_std

    return np.maximum(white_noise_std(np.asarray(dataset.imu[unit].accel, dtype=float), 2), 1e-6)


def normalised_residuals(
    dataset: Dataset, unit: str, result: UnitResult, sigma: FloatArray, interpolator=None
) -> tuple[FloatArray, FloatArray]:
    """``t`` ``(M,)`` s and ``r`` ``(M, 3)``: ``unit``'s accelerometer residuals at ``result`` (the model
    of :mod:`skincal.calib.residuals`) divided by ``sigma`` ``(3,)``."""
    from skincal.calib.residuals import unit_residuals

    res = unit_residuals(dataset, unit, result, interpolator)
    return res.t, res.residual / sigma


def motion_time(dataset: Dataset, link: int, t0: float, t1: float) -> float:
    """Time in ``[t0, t1]`` during which one of joints ``1..link`` moved (reported speed above
    :data:`MOVING_SPEED`), s."""
    j = dataset.joint_states
    inside = (j.t >= t0) & (j.t <= t1)
    if np.count_nonzero(inside) < 2:
        return 0.0
    t = j.t[inside]
    moving = np.any(np.abs(j.qd[inside][:, :link]) > MOVING_SPEED, axis=1)
    dt = np.diff(t)
    return float(np.sum(dt[moving[:-1]]))


@dataclass
class MonitorRun:
    """What :func:`monitor_batch` / :func:`monitor_online` saw.

    Attributes:
        initial: the calibration the monitoring started from.
        alarms: every alarm, in the order raised.
        events: moved-unit events (contract fields of ``docs/interfaces.md``, with ``T_link_su_before``
            and ``T_link_su_after`` ``(4, 4)`` lists).
        poses: the final pose of every unit (after re-calibration for a moved one).
        thresholds: per unit, the CUSUM threshold of its last warm-up (None: never left warm-up).
        watched_s: per unit, the time span watched (after the warm-up), s.
        result: the final calibration with the events recorded (:func:`~skincal.data.result.with_events`).
    """

    initial: CalibrationResult | None
    alarms: list[Alarm] = field(default_factory=list)
    events: list[dict[str, Any]] = field(default_factory=list)
    poses: dict[str, SkinUnitPose] = field(default_factory=dict)
    thresholds: dict[str, float | None] = field(default_factory=dict)
    watched_s: dict[str, float] = field(default_factory=dict)
    result: CalibrationResult | None = None


def monitor_batch(
    dataset: Dataset,
    initial_s: float = 60.0,
    *,
    recal_s: float = 60.0,
    options: MonitorOptions = MonitorOptions(),
    units: Sequence[str] | None = None,
    initial: CalibrationResult | None = None,
    chunk_s: float = 1.0,
    on_alarm: Callable[[Alarm], None] | None = None,
) -> MonitorRun:
    """Watch every unit of ``dataset`` with the residuals of the batch model (module docstring).

    ``initial`` (default: ``mle`` on the first ``initial_s`` s) gives each unit's pose; the residuals
    from ``initial_s`` on are fed in chunks of ``chunk_s`` s. On an alarm the unit is re-calibrated
    (``mle``, its link kept) from ``[t_change, t_change + recal_s]`` and watched again from
    ``t_change + recal_s`` on, after a new warm-up.
    """
    from skincal.calib import calibrate
    from skincal.calib.preprocess import JointInterpolator

    t_start = float(dataset.joint_states.t[0])
    t_end = float(dataset.joint_states.t[-1])
    names = list(dataset.units if units is None else units)
    if initial is None:
        initial = calibrate(crop(dataset, t_start, t_start + initial_s), "mle", units=names)
    run = MonitorRun(initial)
    interpolator = JointInterpolator(dataset.joints)
    monitor = MovedUnitMonitor(options, on_alarm=on_alarm)
    final: dict[str, UnitResult] = {}
    for name in names:
        unit = initial.units[name]
        sigma = noise_std(crop(dataset, t_start, t_start + initial_s), name)
        watch_from = t_start + initial_s
        while watch_from < t_end:
            t, r = normalised_residuals(dataset, name, unit, sigma, interpolator)
            keep = t >= watch_from
            t, r = t[keep], r[keep]
            alarm = None
            run.watched_s[name] = run.watched_s.get(name, 0.0) + (float(t[-1] - t[0]) if t.size else 0.0)
            edges = np.searchsorted(t, np.arange(watch_from, t_end + chunk_s, chunk_s))
            for a, b in zip(edges[:-1], edges[1:], strict=True):
                if b > a:
                    before = len(monitor.alarms)
                    monitor.on_residuals(name, t[a:b], r[a:b])
                    if len(monitor.alarms) > before:
                        alarm = monitor.alarms[-1]
                        break
            run.thresholds[name] = monitor.unit(name).threshold or run.thresholds.get(name)
            if alarm is None:
                break
            run.alarms.append(alarm)
            run.watched_s[name] -= float(t[-1] - alarm.t_detected) if t.size else 0.0
            ready = min(alarm.t_change + recal_s, t_end)
            after = calibrate(crop(dataset, alarm.t_change, ready), "mle", units=[name], links={name: unit.pose.link})
            event = alarm.event()
            event.update(link=int(unit.pose.link), t_recalibrated_s=float(ready),
                         T_link_su_before=unit.pose.T_link_su.tolist())  # fmt: skip
            if name in after.units:
                unit = after.units[name]
                event["T_link_su_after"] = unit.pose.T_link_su.tolist()
            run.events.append(event)
            watch_from = ready
        run.poses[name] = unit.pose
        final[name] = unit
    run.result = with_events(replace(initial, units={**initial.units, **final}), run.events)
    return run


def monitor_online(
    dataset: Dataset,
    *,
    options: MonitorOptions = MonitorOptions(),
    online_options: Any = None,
    chunk_s: float = 0.1,
    on_alarm: Callable[[Alarm], None] | None = None,
) -> MonitorRun:
    """The monitor attached to the streaming calibrator, ``dataset`` replayed through it as fast as
    possible (:func:`skincal.calib.online.replay`); the calibrator restarts a moved unit and records the
    event itself (:meth:`~skincal.calib.online.monitor.MovedUnitMonitor.attach`)."""
    from skincal.calib.online import OnlineCalibrator, OnlineOptions, replay

    calibrator = OnlineCalibrator(
        dataset.chain, dataset.units, dataset.gravity, online_options if online_options is not None else OnlineOptions()
    )
    monitor = MovedUnitMonitor(options, on_alarm=on_alarm).attach(calibrator)
    replay(dataset, calibrator, chunk_s=chunk_s)
    result = calibrator.result()
    run = MonitorRun(None, alarms=list(monitor.alarms), events=[dict(e) for e in calibrator.events])
    for name, unit in result.units.items():
        run.poses[name] = unit.pose
        run.thresholds[name] = monitor.unit(name).threshold
    for event in run.events:
        unit = result.units.get(event["unit"])
        if unit is not None and "T_link_su_after" not in event:
            event["T_link_su_after"] = unit.pose.T_link_su.tolist()
    run.result = with_events(result, run.events)
    return run
