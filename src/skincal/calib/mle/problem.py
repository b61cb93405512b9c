"""One unit's ``mle`` problem on one candidate link: what is computed once per dataset (:class:`Shared`),
the unit's clock alignment (:func:`align`), its samples arranged for the fit (:func:`arrange`), the
closed-form start (:func:`start_state`) and the robust fit (:func:`fit_problem`)."""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from skincal.calib.api import UnitProblem
from skincal.calib.closed_form import position_and_bias, static_rotation_and_bias, wahba
from skincal.calib.mle.arrange import UnitData, arrange_unit_data
from skincal.calib.mle.solver import (
    Blocks,
    Fit,
    Linearisation,
    Rows,
    State,
    solve,
)
from skincal.calib.preprocess import JointInterpolator
from skincal.calib.rest import JointRest, joint_rest
from skincal.calib.signals import SignalTable
from skincal.calib.timing import (
    ClockSteps,
    GapSteps,
    MotionProfile,
    OffsetSearch,
    coarse_time_offset,
    find_clock_steps,
    find_gap_steps,
    motion_profile,
    resolved_speed,
)
from skincal.data.dataset import Dataset, ImuStream
from skincal.errors import CalibrationError
from skincal.kinematics.transforms import FloatArray

MAX_RESIDUAL_OFFSET_S = 0.1
"""Largest time offset left after the coarse alignment that the data are trimmed for, s."""


@dataclass(frozen=True)
class Shared:
    """What ``mle`` computes once per dataset: the link-signal table, when each joint rests and the
    motion profile of the coarse time alignment."""

    table: SignalTable
    rest: JointRest
    profile: MotionProfile
    interpolator: JointInterpolator

    def warm(self) -> None:
        """Fill the lazily built tables now (before forking workers that then share them)."""
        self.table.warm()


def prepare(dataset: Dataset, interpolator: JointInterpolator) -> Shared:
    """Once per dataset: the link signals of every link on a uniform grid and the joint rests."""
    c = interpolator.conditioning
    noise = None if c.velocity_noise is None else (c.position_noise, c.velocity_noise)
    rest = joint_rest(dataset.joints, dataset.segments, noise=noise)
    table = SignalTable(dataset.robot, interpolator, np.asarray(dataset.gravity, dtype=float))
    resolved = resolved_speed(dataset.joint_states.t)
    profile = motion_profile(table.grid_t, table.angular_speed, table.joint_speed, resolved)
    return Shared(table, rest, profile, interpolator)


@dataclass(frozen=True)
class Alignment:
    """A unit's stream put on the joint clock before calibration: periodic re-sync steps removed
    from its stamps (when its stamps show them) and the coarse time offset.

    Attributes:
        offset_s: coarse offset (the sample stamped ``t`` measured the motion at ``t - offset_s``).
        search: the cross-correlation's outcome.
        steps: the re-sync steps found, or ``None``.
        stamps: ``(M,)`` the corrected stamps, or ``None`` when unchanged.
        gaps: one-off clock steps found at stamp gaps (:func:`~skincal.calib.timing.find_gap_steps`), or ``None``.
    """

    offset_s: float
    search: OffsetSearch
    steps: ClockSteps | None = None
    stamps: FloatArray | None = None
    gaps: GapSteps | None = None

    def for_stream(self, imu: ImuStream) -> Alignment:
        """This alignment (found on a unit's whole stream) applied to ``imu``, a part of that stream:
        the same steps removed from its stamps and the same coarse offset, without searching again (a
        part with holes in it, such as alternate windows, would show the holes as stamp gaps)."""
        t = np.asarray(imu.t, dtype=float)
        stamps = None
        if self.steps is not None:
            t = stamps = self.steps.correct(t)
        if self.gaps is not None and self.gaps.corrected.any():
            t = stamps = self.gaps.correct(t)
        return replace(self, stamps=stamps)


def align(shared: Shared, imu: ImuStream) -> Alignment:
    """Re-sync steps (:func:`~skincal.calib.timing.find_clock_steps`) and coarse time offset
    (:func:`~skincal.calib.timing.coarse_time_offset`) of one unit's stream."""
    t = np.asarray(imu.t, dtype=float)
    steps = find_clock_steps(t)
    stamps = steps.correct(t) if steps is not None else None
    if stamps is not None:
        t = stamps
    accel = np.asarray(imu.accel, dtype=float)
    finite = np.all(np.isfinite(accel), axis=1)
    gyro = None if imu.gyro is None else np.asarray(imu.gyro, dtype=float)[finite]
    gaps = find_gap_steps(shared.profile, t[finite], accel[finite], gyro)
    if gaps is not None and gaps.corrected.any():  # large one-off clock steps at stamp gaps: stamps put back
        t = stamps = gaps.correct(t)
    search = coarse_time_offset(shared.profile, t[finite], accel[finite], gyro)
    return Alignment(search.offset_s, search, steps, stamps, gaps)


@dataclass(frozen=True)
class Problem:
    table: SignalTable
    data: UnitData
    sandwich: bool = False
    """Raise the covariance to the block sandwich's (:func:`~skincal.calib.mle.solver.sandwich_inflation`):
    for a low-rate joint stream, whose interpolated accelerations carry an error that follows the motion
    and that the noise model does not name."""
    _last: dict = field(default_factory=dict, init=False, compare=False, repr=False)
    """The last linearisation, by ``(tau, d)`` (the start and the solver's first step ask for the same one)."""

    def linearise(self, tau: float, d: float) -> Linearisation:
        """The signals of the moving samples at their physical instants under ``(tau, d)``
        (:class:`~skincal.calib.mle.solver.Linearisation`; read only)."""
        key = (float(tau), float(d))
        if key not in self._last:
            rows = self.data.rows
            s = self.data.moving_t - tau - d * rows.moving_t
            u, K, du, dK, w, dw, ug = self.table.at(self.data.link, s)
            self._last.clear()
            self._last[key] = Linearisation(tau_k=tau, d_k=d, u=u, K=K, du=du, dK=dK, w=w, dw=dw, ug=ug)
        return self._last[key]


def decimated(p: Problem, step: int) -> Problem:
    """The same problem keeping every ``step``-th moving sample (rest rows all kept)."""
    r = p.data.rows
    sub = lambda x: None if x is None else x[::step]  # noqa: E731
    rows = replace(r, moving_t=r.moving_t[::step], moving_f=r.moving_f[::step], moving_g=sub(r.moving_g))
    return Problem(p.table, replace(p.data, rows=rows), p.sandwich)


def use_gyro(problem: UnitProblem) -> bool:
    return problem.samples.gyro is not None and problem.options.gyro


def arrange(
    problem: UnitProblem, link: int, decimate: int = 1, window: tuple[float, float] | None = None
) -> Problem:
    s = problem.samples
    shared: Shared = problem.shared
    # Keep samples whose instants stay inside the joint stream for any residual offset tried.
    margin = MAX_RESIDUAL_OFFSET_S + 0.01
    keep = (s.t >= shared.interpolator.t_start + margin) & (s.t <= shared.interpolator.t_end - margin)
    if window is not None:
        keep &= (s.t >= window[0]) & (s.t <= window[1])
    gyro = s.gyro[keep] if use_gyro(problem) else None
    data = arrange_unit_data(
        problem.chain, link, s.t[keep], s.accel[keep], gyro, shared.rest, shared.interpolator, problem.gravity
    )
    p = Problem(shared.table, data, sandwich=shared.interpolator.conditioning.source == "spline")
    return decimated(p, decimate) if decimate > 1 else p


def gyro_bias_start(rows: Rows) -> FloatArray:
    """The gyroscope's reading at rest: the median of its rest runs' means, rad/s (0 without any)."""
    if rows.static_g is None:
        return np.zeros(3)
    g = rows.static_g[np.all(np.isfinite(rows.static_g), axis=1)]  # a run all at the rail: NaN
    return np.median(g, axis=0) if len(g) else np.zeros(3)


def start_state(p: Problem) -> State:
    """Closed-form start: rotation from the rest runs (or the angular velocities), then position."""
    rows = p.data.rows
    S, M = len(rows.static_u), len(rows.moving_t)
    bg = gyro_bias_start(rows)
    lin = p.linearise(0.0, 0.0) if M >= 10 else None
    if S >= 2:
        R, b = static_rotation_and_bias(rows.static_u, rows.static_f, rows.static_weight)
    elif rows.moving_g is not None and lin is not None:
        ok = np.all(np.isfinite(rows.moving_g), axis=1)  # NaN: a reading at the gyroscope's rail
        R, b = wahba(lin.w[ok], rows.moving_g[ok] - bg), np.zeros(3)
    else:
        raise CalibrationError(
            f"only {S} rest period(s) for link {p.data.link} and no gyroscope; at least 2 distinct static "
            "poses are needed"
        )
    if lin is not None:
        pos, b_dyn = position_and_bias(R, lin.u, lin.K, rows.moving_f)
        return State(R=R, p=pos, b=b_dyn if np.linalg.norm(b) == 0 else b, bg=bg)
    return State(R=R, p=np.zeros(3), b=b, bg=bg)


def fit_problem(p: Problem, blocks: Blocks, state: State | None = None, **kw) -> Fit:
    state = start_state(p) if state is None else state
    rows = p.data.rows
    if len(rows.moving_t) < 10:
        rows = replace(rows, moving_t=rows.moving_t[:0], moving_f=rows.moving_f[:0],
                       moving_g=None if rows.moving_g is None else rows.moving_g[:0])
        return solve(state, blocks, rows, None, **kw)
    return solve(state, blocks, rows, p.linearise, sandwich=p.sandwich, **kw)
