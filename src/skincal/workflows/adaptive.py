"""The adaptive calibration loop: choose the next best motion, execute it, absorb its data, repeat.

:func:`adaptive_loop` is the loop itself, for any robot that can execute a segment
(:class:`~skincal.protocol.Trajectory`) and feed its data to the streaming calibrator. It asks
:func:`skincal.protocol.design.next_motion` for the segment with the most expected information per
second, hands it to ``execute``, and stops when every unit's std reached the target (or at the
motion budget).

:class:`SimulatedRobot` is such a robot in simulation: a session of :func:`skincal.workflows.session.make_session`
(robot, placement, IMU, joint-state and clock presets) whose robot executes the segments one after
another. The segments so far are one trajectory (:func:`skincal.protocol.concatenate_trajectories`),
simulated from the same random generator state every time, so each unit keeps the IMU errors and
clock it was drawn with (the session's ``truth_sensor``: never redrawn per segment); the samples of
the new segment (stamps in ``[t_start, t_end)`` of the whole) are fed to the calibrator. Noise in the
new window is a fresh draw each time.

:func:`run_simulated` strings them together (``skincal protocol --adaptive --simulate`` and
``benchmarks/bench_adaptive.py``): the total motion time and the TRUE errors of the final estimate
against the session's truth.
"""

from __future__ import annotations

import copy
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from skincal.calib.online import OnlineCalibrator, UnitStatus
from skincal.data.dataset import Dataset
from skincal.errors import ConfigError
from skincal.kinematics.chain import SerialChain
from skincal.protocol import Trajectory, concatenate_trajectories
from skincal.protocol.design import (
    Candidate,
    DesignOptions,
    calibrator_target,
    information_now,
    next_motion,
    realized_gain,
    segment_config,
    unit_weights,
)
from skincal.workflows.live import Target, all_reached, make_calibrator

MAX_MOTION_S = 300.0
"""Default budget of robot motion for the loop, s."""


@dataclass(frozen=True)
class SegmentRecord:
    """One executed segment of the loop.

    Attributes:
        index: 1-based.
        candidate: what was chosen (its trajectory starts at 0).
        t_start, t_end: its place in the whole motion, s.
        statuses: every unit's status once its data was absorbed.
        true_errors: in simulation with ``track_truth``, the estimate's errors against the truth then
            (:func:`skincal.calib.metrics.evaluate`).
    """

    index: int
    candidate: Candidate
    t_start: float
    t_end: float
    statuses: Mapping[str, UnitStatus]
    true_errors: dict[str, Any] | None = None

    def worst(self) -> tuple[float, float]:
        """Largest position std (mm) and rotation std (deg) over the units (inf: not determined)."""
        pos = max((float(np.max(s.position_std_m)) for s in self.statuses.values()), default=np.inf)
        rot = max((float(np.max(s.rotation_std_deg)) for s in self.statuses.values()), default=np.inf)
        return 1e3 * pos, rot


SegmentCallback = Callable[[SegmentRecord], None]
"""``on_segment(record)`` after each executed segment."""


@dataclass
class LoopOutcome:
    """How an adaptive loop ended: the segments, whether every unit reached the target, the motion time."""

    segments: list[SegmentRecord] = field(default_factory=list)
    reached: bool = False
    motion_s: float = 0.0


def probe(calibrator: OnlineCalibrator) -> OnlineCalibrator:
    """A copy of ``calibrator`` with everything fed so far absorbed (``finish``), the original untouched:
    what the data say while the robot rests between segments (the stream's last block waits for later
    samples otherwise)."""
    copy_ = copy.deepcopy(calibrator)
    copy_.finish()
    return copy_


def adaptive_loop(
    calibrator: OnlineCalibrator,
    chain: SerialChain,
    q_start: np.ndarray,
    execute: Callable[[Trajectory], None],
    rng: np.random.Generator,
    *,
    max_motion_s: float = MAX_MOTION_S,
    options: DesignOptions = DesignOptions(),
    on_segment: SegmentCallback | None = None,
    settled: Callable[[OnlineCalibrator], OnlineCalibrator] = probe,
    record_hook: Callable[[SegmentRecord], SegmentRecord] | None = None,
) -> LoopOutcome:
    """Choose, execute and absorb segments until every unit reached its target or ``max_motion_s``.

    ``execute(segment)`` makes the robot run ``segment`` (time from 0, starting at the robot's current
    configuration) and feeds its data to ``calibrator``; ``settled(calibrator)`` gives the calibrator
    to judge and design from once the robot rests (default :func:`probe`); ``record_hook(record)`` may
    complete each segment's record before it is kept and given to ``on_segment``. The robot is assumed
    at ``q_start`` (rest) before the first segment.
    """
    if not (np.isfinite(max_motion_s) and max_motion_s > 0):
        raise ConfigError(f"the motion budget must be a positive number of seconds, got {max_motion_s}")
    config = segment_config(chain, excite_s=options.excite_s)
    q_now = np.asarray(q_start, dtype=float)
    visited = [q_now]
    moved: set[int] = set()
    out = LoopOutcome()
    judge = settled(calibrator)
    discount: dict[int, float] = {}
    while not all_reached(judge.status()) and out.motion_s < max_motion_s:
        cand = next_motion(judge, chain, q_now, rng, config=config, visited=np.array(visited), moved=moved,
                           options=options, discount=discount)  # fmt: skip
        weights = unit_weights(judge.status(), options.reached_weight,
                               calibrator_target(judge) if options.by_distance else None)  # fmt: skip
        before = information_now(judge)
        execute(cand.trajectory)
        t0 = out.motion_s
        out.motion_s += cand.trajectory.duration
        q_end = cand.trajectory.evaluate([cand.trajectory.duration])[0][0]
        moved.add(cand.joint)
        if cand.moves:
            moved.update(int(j) for j in np.flatnonzero(np.abs(q_end - q_now) > 1e-3))
            visited.append(q_end)
            discount = {}
        q_now = q_end
        judge = settled(calibrator)
        if not cand.moves and cand.gain > 0:  # what exciting this joint here again is worth
            ratio = realized_gain(before, information_now(judge), weights, options) / cand.gain
            discount[cand.joint] = float(np.clip(ratio, 0.05, 1.0))
        record = SegmentRecord(len(out.segments) + 1, cand, t0, out.motion_s, judge.status())
        if record_hook is not None:
            record = record_hook(record)
        out.segments.append(record)
        if on_segment is not None:
            on_segment(record)
    out.reached = all_reached(judge.status())
    return out


class SimulatedRobot:
    """A simulated session's robot executing segments (module docstring); feeds ``calibrator``.

    ``session``: a :class:`skincal.sim.Session` (its trajectory is replaced by the executed segments,
    its generator's state is the one every re-simulation starts from); ``q_start``: where the robot rests.
    """

    def __init__(self, session: Any, q_start: np.ndarray, calibrator: OnlineCalibrator | None = None) -> None:
        self.session = session
        self._rng_state = copy.deepcopy(session.rng)
        self.q_start = np.asarray(q_start, dtype=float)
        self.calibrator = calibrator
        self.parts: list[Trajectory] = []
        self.dataset: Dataset | None = None

    @property
    def trajectory(self) -> Trajectory | None:
        """Everything executed so far, as one trajectory (None before the first segment)."""
        return concatenate_trajectories(self.parts) if self.parts else None

    def execute(self, segment: Trajectory) -> None:
        """Run ``segment`` after the previous ones; its samples go to the calibrator."""
        from skincal.sim import simulate

        t_start = sum(p.duration for p in self.parts)
        self.parts.append(segment)
        whole = self.trajectory
        assert whole is not None
        session = replace(self.session, trajectory=whole, rng=copy.deepcopy(self._rng_state))
        self.dataset = simulate(session)
        if self.calibrator is not None:
            feed_window(self.calibrator, self.dataset, t_start, whole.duration)


def feed_window(calibrator: OnlineCalibrator, ds: Dataset, t_from: float, t_to: float) -> None:
    """Give ``calibrator`` the samples of ``ds`` stamped in ``[t_from, t_to)`` (joint states and every
    followed unit's IMU), then ``update()``."""
    j = ds.joints
    if j is not None:
        sel = (j.t >= t_from) & (j.t < t_to)
        if sel.any():
            calibrator.add_joint_states(j.t[sel], j.q[sel], j.qd[sel])
    for unit in calibrator.units:
        s = ds.imu.get(unit)
        if s is None:
            continue
        sel = (s.t >= t_from) & (s.t < t_to)
        if sel.any():
            calibrator.add_imu(unit, s.t[sel], s.accel[sel], None if s.gyro is None else s.gyro[sel])
    calibrator.update()


@dataclass(frozen=True)
class SimulatedRun:
    """The outcome of :func:`run_simulated`.

    Attributes:
        loop: the segments and whether the target was reached.
        motion_s: total robot motion, s.
        result: the calibrator's result (method ``online``) after the last segment.
        errors: :func:`skincal.calib.metrics.evaluate` of the result against the session's truth.
        dataset: the whole simulated session (every segment; truth included).
        trajectory: the executed motion, all segments.
    """

    loop: LoopOutcome
    motion_s: float
    result: Any
    errors: dict[str, Any]
    dataset: Dataset
    trajectory: Trajectory


def start_pose(chain: SerialChain, rng: np.random.Generator) -> np.ndarray:
    """A collision-free rest pose within the limits (one draw of the segment protocol's diverse poses)."""
    from skincal.protocol.limits import sample_static_poses

    config = replace(segment_config(chain), pose_selection="uniform")
    return sample_static_poses(chain, 1, rng, config)[0]


def run_simulated(
    robot: str | SerialChain = "panda",
    placement: str = "paper",
    units: int | None = None,
    noise: str = "realistic",
    seed: int = 0,
    *,
    joints: str = "auto",
    clock: str = "auto",
    target: Target = Target(),
    max_motion_s: float = MAX_MOTION_S,
    options: DesignOptions = DesignOptions(),
    on_segment: SegmentCallback | None = None,
    track_truth: bool = False,
) -> SimulatedRun:
    """The adaptive loop on a simulated session (module docstring); session as
    :func:`skincal.workflows.session.make_session` (its protocol replaced by the loop's segments);
    ``seed`` also seeds the start pose and the candidate draws. ``track_truth``: each segment's record
    (given to ``on_segment`` and kept in the outcome) carries the estimate's true errors then."""
    from skincal.calib.metrics import evaluate
    from skincal.workflows.session import make_session

    session = make_session(robot, placement, units, noise, "fast", seed, joints=joints, clock=clock)
    chain = session.chain
    rng = np.random.default_rng([int(seed), 16])
    q0 = start_pose(chain, rng)
    cal = make_calibrator(chain, list(session.placements), session.gravity, target)
    sim = SimulatedRobot(session, q0, cal)
    settled: dict[str, OnlineCalibrator] = {}

    def settle(c: OnlineCalibrator) -> OnlineCalibrator:
        settled["now"] = probe(c)
        return settled["now"]

    def with_truth(record: SegmentRecord) -> SegmentRecord:
        if not track_truth:
            return record
        done = settled["now"].result()
        assert sim.dataset is not None
        return replace(record, true_errors=evaluate(done, sim.dataset).to_dict() if done.units else {"units": {}})

    loop = adaptive_loop(cal, chain, q0, sim.execute, rng, max_motion_s=max_motion_s, options=options,
                         settled=settle, on_segment=on_segment, record_hook=with_truth)  # fmt: skip
    cal.finish()
    result = cal.result()
    assert sim.dataset is not None and sim.trajectory is not None
    errors = evaluate(result, sim.dataset).to_dict() if result.units else {"units": {}}
    return SimulatedRun(loop, loop.motion_s, result, errors, sim.dataset, sim.trajectory)


class LiveDesigner:
    """The adaptive loop against a live stream (``skincal protocol --adaptive --port``), one :meth:`tick` per
    meter tick of :func:`skincal.workflows.live.record_live`.

    With no segment pending it chooses the next one from the robot's current configuration (the joint
    stream's newest sample; the planned end of the previous segment when the robot is there) and sets
    :attr:`pending` (the caller writes it for the robot; :attr:`index` is its 1-based number). A pending
    segment counts as executed once ``duration`` s of data have arrived since it was chosen and the robot
    rests within ``rest_tol_rad`` of its end pose; :meth:`tick` then returns its :class:`SegmentRecord`.
    :attr:`done` is set when every unit reached the target or the motion budget is spent.
    """

    def __init__(
        self,
        chain: SerialChain,
        rng: np.random.Generator,
        *,
        max_motion_s: float = MAX_MOTION_S,
        options: DesignOptions = DesignOptions(),
        rest_tol_rad: float = 5e-3,
    ) -> None:
        self.chain, self.rng, self.max_motion_s, self.options = chain, rng, float(max_motion_s), options
        self.config = segment_config(chain, excite_s=options.excite_s)
        self.rest_tol_rad = float(rest_tol_rad)
        self.parts: list[Trajectory] = []
        self.pending: Trajectory | None = None
        self.pending_written = False
        self.pending_text = ""
        self.index = 0
        self.motion_s = 0.0
        self.done = False
        self._cand: Candidate | None = None
        self._sent_at = 0.0
        self._visited: list[np.ndarray] = []
        self._moved: set[int] = set()
        self._records: list[SegmentRecord] = []

    def trajectory(self) -> Trajectory | None:
        """The executed segments as one motion (None before the first)."""
        return concatenate_trajectories(self.parts) if self.parts else None

    def _end(self, traj: Trajectory) -> np.ndarray:
        return traj.evaluate([traj.duration])[0][0]

    def tick(self, feed: Any) -> SegmentRecord | None:
        """Advance with the live feed (:class:`skincal.workflows.live.LiveFeed`: its calibrator, statuses and
        data time); the record of a segment just executed, else None."""
        cal = feed.calibrator
        if self.done or cal is None or cal.q_now is None:
            return None
        q_now = np.asarray(cal.q_now, dtype=float)
        if self.pending is not None:
            end = self._end(self.pending)
            late = feed.t_data - self._sent_at < self.pending.duration - 1e-6
            if late or np.max(np.abs(q_now - end)) > self.rest_tol_rad:
                return None
            cand = self._cand
            assert cand is not None
            start = self.pending.evaluate([0.0])[0][0]
            self._moved.add(cand.joint)
            if cand.moves:
                self._moved.update(int(j) for j in np.flatnonzero(np.abs(end - start) > 1e-3))
                self._visited.append(end)
            self.parts.append(self.pending)
            t0 = self.motion_s
            self.motion_s += self.pending.duration
            self.pending, self._cand = None, None
            record = SegmentRecord(self.index, cand, t0, self.motion_s, dict(cal.status()))
            self._records.append(record)
            if all_reached(record.statuses) or self.motion_s >= self.max_motion_s:
                self.done = True
            return record
        if all_reached(cal.status()) or self.motion_s >= self.max_motion_s:
            self.done = True
            return None
        if self.parts and np.max(np.abs(q_now - self._end(self.parts[-1]))) <= self.rest_tol_rad:
            q_now = self._end(self.parts[-1])  # the motion continues exactly from the planned end
        elif self.parts:
            self.parts = []  # the robot was moved elsewhere: the executed motion restarts here
        if not self._visited:
            self._visited.append(q_now)
        cand = next_motion(probe(cal), self.chain, q_now, self.rng, config=self.config,
                           visited=np.array(self._visited), moved=self._moved, options=self.options)  # fmt: skip
        self._cand, self.pending, self.pending_written = cand, cand.trajectory, False
        self.pending_text = cand.describe()
        self.index += 1
        self._sent_at = float(feed.t_data)
        return None
