"""The default calibrator ``mle``: global time alignment, closed-form start, robust joint maximum
likelihood, and residual tests that keep the reported uncertainty honest.

Per unit:

0. **Time** (before anything else, in :func:`align`): the IMU stream's offset to the joint stream
   is found globally by cross-correlation (:mod:`skincal.calib.timing`), up to +-0.5 s.
1. **Rest** (:mod:`skincal.calib.rest`): from ``/segments`` when the dataset has them, else from
   the joint positions over windows with noise-derived thresholds; every rest run cross-checked
   against the unit's own IMU (runs in which it moved are dropped and named).
2. **Link** (unless given): the activity matrix (accelerometer and gyroscope) proposes link
   ``n*``; unless that is decisive, the links ``1 .. n* + 1`` are each fitted quickly and the one
   whose model explains every sample best wins. Two links that explain the data about equally
   are reported as ambiguous, never silently chosen.
3. **Start** (no bounds, no seed): rotation and bias from the rest runs (Wahba's problem) or, with
   fewer than two, from the angular velocities; position and bias by linear least squares.
4. **Refinement** (:mod:`skincal.calib.mle.solver`): pose, accelerometer bias, scale/misalignment,
   gyroscope bias, time offset and clock drift, and a bias drift when the rest runs span the
   session, by robust Gauss-Newton over every sample of both sensors.
5. **Uncertainty**: covariance from the normal matrix with each sensor's robust residual variance
   and autocorrelation, inflated by the rest runs' disagreement with the model; directions the
   data cannot determine are reported (``observable: false``, ``null`` std) and left at the start.
   Warnings name what the model had to absorb ("bias drifts", "clock drifts", "time offset
   uncertain", "static segment moved", "rest poses disagree").
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from skincal.calib.api import MethodSpec, UnitProblem, register
from skincal.calib.closed_form import position_and_bias, static_rotation_and_bias, wahba
from skincal.calib.gyro import GyroScale, gyro_scale
from skincal.calib.links import GyroLinks, activity_in, discover_link, gyro_rules_out
from skincal.calib.mle.arrange import UnitData, arrange_unit_data
from skincal.calib.mle.likelihood import rest_nll
from skincal.calib.mle.solver import (
    SCALE_FULL,
    SCALE_NONE,
    SCALE_SYM,
    Blocks,
    Fit,
    Linearisation,
    Rows,
    State,
    solve,
    sym_from_e,
)
from skincal.calib.model import predict_specific_force
from skincal.calib.preprocess import JointInterpolator, check_gyro_units
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
)
from skincal.data.dataset import DYNAMIC, STATIC, Dataset, ImuStream
from skincal.data.imu_calibration import ImuCalibration
from skincal.data.result import UnitResult
from skincal.errors import CalibrationError
from skincal.kinematics.chain import SerialChain
from skincal.kinematics.transforms import FloatArray, skew
from skincal.skin.pose import SkinUnitPose

MAX_RESIDUAL_OFFSET_S = 0.1
"""Largest time offset left after the coarse alignment that the data are trimmed for, s."""
SCALE_STD_LIMIT = 0.01
"""Scale/misalignment is kept only when each of its components is determined to this std."""
DECISIVE_ACTIVITY = 0.9
"""Activity confidence above which neighbouring links are not fitted for comparison."""
AMBIGUITY_RATIO = 1.5
"""A second link whose residual level is within this factor of the best makes the link ambiguous."""
AMBIGUITY_NLL = 3.0
"""The rests decide the link when the second candidate's negative log-likelihood over them exceeds the
best's by this much (a likelihood ratio of e^3 = 20; :mod:`skincal.calib.mle.likelihood`)."""
CLOCK_DRIFT_MIN_SPAN_S = 60.0
"""The clock drift is estimated when the unit's moving samples span at least this long, s."""
BIAS_DRIFT_MIN_RUNS = 6
"""The accelerometer bias drift is estimated with at least this many rest runs..."""
BIAS_DRIFT_MIN_SPAN_S = 60.0
"""...spanning at least this long, s."""
DRIFT_WARN_SIGMAS = 4.0
"""A drift (clock or bias) is reported when it exceeds this many of its standard deviations..."""
CLOCK_DRIFT_WARN_PPM = 20.0
"""...and this many ppm (clock)..."""
BIAS_DRIFT_WARN_MPS2 = 0.01
"""...or this change over the session, m/s^2 (bias)."""
STATIC_CHI2_WARN = 4.0
"""Rest runs whose residuals exceed the rest noise by this factor in variance are flagged."""
REST_NOISE_FLOOR = 1e-4
"""Smallest rest noise the rest-pose test assumes, m/s^2 (10 µg, below any real IMU's: noise-free
simulated data must not count as inconsistent)."""
OFFSET_SHARPNESS_MIN = 0.02
"""Coarse-alignment peaks less distinct than this (correlation units) leave the offset uncertain."""
OFFSET_JUMP_WARN_S = 0.05
"""A refined offset further than this from the coarse one is flagged as uncertain, s."""
MOVE_MIN_RUNS = 4
"""A move is looked for only with this many rest runs on each side of it."""
MOVE_IMPROVEMENT = 10.0
"""A before/after split must explain the rest runs this many times better than one pose..."""
MOVE_MIN_ANGLE_DEG = 1.0
"""...and the two poses' rotations differ by this much, deg."""
SANDWICH_WARN = 2.0
"""A block-sandwich factor on the position std above this is reported (``solver.sandwich_inflation``)."""
CORRELATION_WARN = 4.0
"""Residual autocorrelation factors above this are reported (model error, covariance inflated)."""


@dataclass(frozen=True)
class MleOptions:
    """Options of ``mle`` (``calibrate(ds, "mle", scale=False)``, ``skincal calibrate --option
    scale=false``); each turns one block of the model off (all on by default).

    Attributes:
        scale: estimate the accelerometer's scale/misalignment matrix (symmetric without a
            gyroscope, full with one).
        time_offset: estimate the IMU's time offset to the joint stream (and, with ``clock_drift``,
            its drift); off: the stamps are taken as they are.
        clock_drift: estimate a clock drift when the moving data span long enough.
        bias_drift: estimate a linear accelerometer bias drift when rest runs span the session.
        gravity: estimate the gravity scale (needs ``scale``).
        gyro: use the gyroscope when the unit has one.
        detect_move: look for a unit that moved on its link during the session.
        consistency: calibrate independent parts of the recording too and inflate the std where they
            disagree beyond it (:mod:`skincal.calib.consistency`).
    """

    scale: bool = True
    time_offset: bool = True
    clock_drift: bool = True
    bias_drift: bool = True
    gravity: bool = True
    gyro: bool = True
    detect_move: bool = True
    consistency: bool = True


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
    return Shared(table, rest, motion_profile(table.grid_t, table.angular_speed, table.joint_speed), interpolator)


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
class _Problem:
    table: SignalTable
    data: UnitData
    sandwich: bool = False
    """Raise the covariance to the block sandwich's (:func:`~skincal.calib.mle.solver.sandwich_inflation`):
    for a low-rate joint stream, whose interpolated accelerations carry an error that follows the motion
    and that the noise model does not name."""

    def linearise(self, tau: float, d: float) -> Linearisation:
        rows = self.data.rows
        s = self.data.moving_t - tau - d * rows.moving_t
        u, K, du, dK, w, dw, ug = self.table.at(self.data.link, s)
        return Linearisation(tau_k=tau, d_k=d, u=u, K=K, du=du, dK=dK, w=w, dw=dw, ug=ug)


def _decimated(p: _Problem, step: int) -> _Problem:
    """The same problem keeping every ``step``-th moving sample (rest rows all kept)."""
    r = p.data.rows
    sub = lambda x: None if x is None else x[::step]  # noqa: E731
    rows = replace(r, moving_t=r.moving_t[::step], moving_f=r.moving_f[::step], moving_g=sub(r.moving_g))
    return _Problem(p.table, replace(p.data, rows=rows), p.sandwich)


def _use_gyro(problem: UnitProblem) -> bool:
    return problem.samples.gyro is not None and problem.options.gyro


def _arrange(
    problem: UnitProblem, link: int, decimate: int = 1, window: tuple[float, float] | None = None
) -> _Problem:
    s = problem.samples
    shared: Shared = problem.shared
    # Keep samples whose instants stay inside the joint stream for any residual offset tried.
    margin = MAX_RESIDUAL_OFFSET_S + 0.01
    keep = (s.t >= shared.interpolator.t_start + margin) & (s.t <= shared.interpolator.t_end - margin)
    if window is not None:
        keep &= (s.t >= window[0]) & (s.t <= window[1])
    gyro = s.gyro[keep] if _use_gyro(problem) else None
    data = arrange_unit_data(
        problem.chain, link, s.t[keep], s.accel[keep], gyro, shared.rest, shared.interpolator, problem.gravity
    )
    p = _Problem(shared.table, data, sandwich=shared.interpolator.conditioning.qdd_variance is not None)
    return _decimated(p, decimate) if decimate > 1 else p


@dataclass(frozen=True)
class Move:
    """A unit that moved on its link during the session (knocked, peeled and re-stuck): the rest
    runs before ``t_before`` and after ``t_after`` (s) each fit one pose but not together."""

    t_before: float
    t_after: float
    angle_deg: float
    improvement: float


def _turn_fit(f: FloatArray, r: FloatArray, w: FloatArray) -> tuple[float, FloatArray]:
    """Weighted least squares of rest-row residuals ``r`` by a small turn ``phi`` and bias change
    ``c`` of the unit, ``r ~ [f]x phi + c`` (``f`` the readings, unit frame): the residual sum of
    squares left and ``phi`` (rad)."""
    X = np.zeros((len(f), 3, 6))
    X[:, :, :3] = skew(f)
    X[:, :, 3:] = np.eye(3)
    sw = np.sqrt(w)[:, None, None]
    A = (X * sw).reshape(-1, 6)
    y = (r[:, :, None] * sw).reshape(-1)
    coef, *_ = np.linalg.lstsq(A, y, rcond=None)
    left = A @ coef - y
    return float(left @ left), np.asarray(coef[:3], dtype=np.float64)


def find_move(rows: Rows, residuals: FloatArray, t_c: float) -> Move | None:
    """A change of the unit's pose during the session, from the fitted model's rest-row residuals.

    A unit that moved on its link leaves rest residuals that a small turn and bias change explain,
    differently before and after the move. Each split of the time-ordered rest runs (at least
    ``MOVE_MIN_RUNS`` each side) gets its own ``phi, c`` per side (:func:`_turn_fit`); the best
    split is a move when it lowers the weighted residual sum by more than ``MOVE_IMPROVEMENT``
    times and the two turns differ by more than ``MOVE_MIN_ANGLE_DEG`` (a drifting bias improves a
    split too, but turns nothing).
    """
    S = len(rows.static_u)
    if S < 2 * MOVE_MIN_RUNS or residuals is None:
        return None
    order = np.argsort(rows.static_t)
    f, w, t, r = rows.static_f[order], rows.static_weight[order], rows.static_t[order], residuals[:S][order]
    total = float(np.sum(w * np.sum(r * r, axis=1)))
    best = (np.inf, 0, np.zeros(3), np.zeros(3))
    for k in range(MOVE_MIN_RUNS, S - MOVE_MIN_RUNS + 1):
        (c1, phi1), (c2, phi2) = _turn_fit(f[:k], r[:k], w[:k]), _turn_fit(f[k:], r[k:], w[k:])
        if c1 + c2 < best[0]:
            best = (c1 + c2, k, phi1, phi2)
    cost, k, phi1, phi2 = best
    angle = float(np.degrees(np.linalg.norm(phi2 - phi1)))
    improvement = total / max(cost, 1e-300)
    if improvement < MOVE_IMPROVEMENT or angle < MOVE_MIN_ANGLE_DEG:
        return None
    return Move(float(t[k - 1] + t_c), float(t[k] + t_c), angle, improvement)


def _gyro_bias_start(rows: Rows) -> FloatArray:
    """The gyroscope's reading at rest: the median of its rest runs' means, rad/s (0 without any)."""
    return np.median(rows.static_g, axis=0) if rows.static_g is not None and len(rows.static_g) else np.zeros(3)


GYRO_MOVING_RPS = 0.1
"""Samples whose link turns faster than this (rad/s) check the gyroscope's scale."""


def _gyro_scale(problem: UnitProblem, link: int) -> GyroScale | None:
    """:func:`~skincal.calib.gyro.gyro_scale` of the unit's moving samples on ``link`` (the link's rate from
    the signal table at the samples' aligned instants); None without enough motion about three axes."""
    s = problem.samples
    shared: Shared = problem.shared
    table = shared.table
    assert s.gyro is not None
    inside = (s.t >= table.t[0]) & (s.t <= table.t[-1]) & shared.interpolator.reliable(s.t)
    if inside.sum() < 12:
        return None
    w = table.at(link, s.t[inside])[4]
    moving = np.linalg.norm(w, axis=1) > GYRO_MOVING_RPS
    if moving.sum() < 12:
        return None
    return gyro_scale(w[moving], s.gyro[inside][moving])


def _start(p: _Problem) -> State:
    """Closed-form start: rotation from the rest runs (or the angular velocities), then position."""
    rows = p.data.rows
    S, M = len(rows.static_u), len(rows.moving_t)
    bg = _gyro_bias_start(rows)
    lin = p.linearise(0.0, 0.0) if M >= 10 else None
    if S >= 2:
        R, b = static_rotation_and_bias(rows.static_u, rows.static_f, rows.static_weight)
    elif rows.moving_g is not None and lin is not None:
        R, b = wahba(lin.w, rows.moving_g - bg), np.zeros(3)
    else:
        raise CalibrationError(
            f"only {S} rest period(s) for link {p.data.link} and no gyroscope; at least 2 distinct static "
            "poses are needed"
        )
    if lin is not None:
        pos, b_dyn = position_and_bias(R, lin.u, lin.K, rows.moving_f)
        return State(R=R, p=pos, b=b_dyn if np.linalg.norm(b) == 0 else b, bg=bg)
    return State(R=R, p=np.zeros(3), b=b, bg=bg)


def _fit(p: _Problem, blocks: Blocks, state: State | None = None, **kw) -> Fit:
    state = _start(p) if state is None else state
    rows = p.data.rows
    if len(rows.moving_t) < 10:
        rows = replace(rows, moving_t=rows.moving_t[:0], moving_f=rows.moving_f[:0],
                       moving_g=None if rows.moving_g is None else rows.moving_g[:0])
        return solve(state, blocks, rows, None, **kw)
    return solve(state, blocks, rows, p.linearise, sandwich=p.sandwich, **kw)


def _residual_level(problem: UnitProblem, link: int, state: State) -> float:
    """Median residual norm of the fitted model over every sample of the unit (m/s^2)."""
    s = problem.samples.select(slice(None, None, 4))
    table: SignalTable = problem.shared.table
    t = s.t - state.tau
    keep = (t >= table.t[0]) & (t <= table.t[-1])
    u, K, *_, ug = table.at(link, t[keep])
    pred = predict_specific_force(state.R, state.p, state.A, state.b, u, K, ug=ug, gravity_scale=state.k)
    return float(np.median(np.linalg.norm(pred - s.accel[keep], axis=1)))


GYRO_STILL_RATE = 0.01
"""Instants at which every link turns slower than this (rad/s) give the gyroscope's bias for the
rate comparisons of link discovery and the unit check."""
GENERAL_MOTION_SHARE = 0.25
"""When more than this share of a unit's moving samples lies outside the single-joint (dynamic)
segments, the motion is general: the segments' activity matrix cannot judge the link alone."""


def gyro_rates(problem: UnitProblem) -> tuple[FloatArray, FloatArray] | None:
    """The unit's gyroscope rate ``|w_meas - b|`` ``(M,)`` and every link's rotation rate from the
    chain ``(M, n)`` at the unit's (coarsely aligned) instants inside the joint stream, rad/s; ``b``
    the median reading where no link turns (0 when the robot never rests). ``None`` without a
    gyroscope (or with ``gyro=false``)."""
    s = problem.samples
    if not _use_gyro(problem):
        return None
    table: SignalTable = problem.shared.table
    g_t = table.grid_t
    keep = (s.t >= g_t[0]) & (s.t <= g_t[-1])
    w = np.column_stack([np.interp(s.t[keep], g_t, c) for c in table.angular_speed.T])
    g = s.gyro[keep]
    still = np.max(w, axis=1) < GYRO_STILL_RATE
    bias = np.median(g[still], axis=0) if np.count_nonzero(still) >= 10 else np.zeros(3)
    return np.linalg.norm(g - bias, axis=1), w


def _untagged_motion(problem: UnitProblem) -> np.ndarray | None:
    """``(M,)`` the unit's samples while some joint moves outside every single-joint segment, when
    they are more than :data:`GENERAL_MOTION_SHARE` of the samples while some joint moves (general
    motion: the segments cannot judge the link alone); ``None`` otherwise."""
    s = problem.samples
    moving = ~problem.shared.rest.unit_rest(s.t, problem.chain.n_joints)
    untagged = moving & (s.kind != DYNAMIC)
    general = np.any(moving) and np.count_nonzero(untagged) > GENERAL_MOTION_SHARE * np.count_nonzero(moving)
    return untagged if general else None


def choose_link(
    problem: UnitProblem,
) -> tuple[int, float, list[str], dict[int, float], State | None, GyroLinks | None]:
    """Link discovery by activity and the gyroscope, then model comparison among candidate links.

    A turning gyroscope first rules out the links whose chain cannot turn it so
    (:func:`~skincal.calib.links.gyro_rules_out`). A decisive activity (single-joint segments) on a
    link the gyroscope allows is taken; otherwise, with single-joint segments covering the motion,
    neighbouring links of the activity's proposal compete, and with general (multi-joint) motion
    (:data:`GENERAL_MOTION_SHARE`) every link not ruled out does (the segments' verdict that no
    excited joint moves the unit is then no verdict: the motion they did not tag may).

    Returns the link, its confidence, warnings, the residual level of each candidate fitted, the
    winner's quick-fit state (a start for the full fit; ``None`` when the activity alone was
    decisive and no candidate had to be fitted) and the gyroscope's verdict (``None`` without one).
    """
    n = problem.chain.n_joints
    rates = gyro_rates(problem)
    by_gyro = None if rates is None else gyro_rules_out(*rates)
    allowed = set(range(1, n + 1)) if by_gyro is None else {int(k) + 1 for k in np.flatnonzero(by_gyro.allowed)}
    activity = discover_link(problem.samples, n, use_gyro=True)
    levels: dict[int, float] = {}
    states: dict[int, State] = {}
    warnings = [w for w in activity.warnings if "ambiguous" not in w and "never excited" not in w]
    tagged = bool(np.any(problem.samples.kind == STATIC))  # the activity's noise floor needs static segments
    untagged = _untagged_motion(problem)
    general = untagged is not None
    if general and np.nan_to_num(activity_in(problem.samples, untagged, use_gyro=True)) < 1.0:
        general = False  # the unit did not move in the motion the segments do not tag either
    if not tagged or general:
        warnings = []  # the segments do not tell which joint moved the unit
    segmented = tagged and not general
    if tagged and activity.link in allowed and activity.confidence >= DECISIVE_ACTIVITY:
        return activity.link, activity.confidence, warnings, levels, None, by_gyro  # no doubt: nothing to compare
    if segmented and activity.link == 0 and np.any(np.isfinite(activity.activity)):  # joints excited, none moved it
        raise CalibrationError("; ".join(activity.warnings) or "no joint motion excites this unit")
    # Not decisive: a joint's motion can shake earlier links through the servos' finite stiffness
    # (the activity then points too far out), so every link up to one past the suggestion competes;
    # without any activity (no segments to tell the excited joint, or general motion), every link does.
    hint = problem.alignment.search.link if problem.alignment is not None else n
    top = n if activity.link == 0 or not segmented else min(n, max(activity.link, hint) + 1)
    common = None  # the rests of the furthest candidate: every candidate's joints rest in them
    for link in range(1, top + 1):
        if link not in allowed:
            continue
        try:
            arranged = _arrange(problem, link, decimate=10)
            fit = _fit(arranged, Blocks(scale=SCALE_NONE), max_outer=2)
        except CalibrationError:
            continue
        levels[link] = _residual_level(problem, link, fit.state)
        states[link] = fit.state
        common = arranged.data
    if not levels:
        raise CalibrationError("; ".join(activity.warnings) or "no candidate link could be fitted")
    nll = {} if common is None or len(common.rows.static_f) < 2 else rest_nll(
        problem.chain, problem.gravity, common.static_q, common.rows.static_f, common.rows.static_weight,
        common.rest.accel_noise, states,
    )  # fmt: skip
    by_rests = sorted(nll, key=nll.get)
    if len(by_rests) > 1 and nll[by_rests[1]] - nll[by_rests[0]] >= AMBIGUITY_NLL:
        # the rests decide (a sum over every rest: one decisive pose counts); else the median below
        gap = np.array([nll[k] - nll[by_rests[0]] for k in by_rests])
        confidence = float(1.0 / np.sum(np.exp(-np.minimum(gap, 700.0))))
        return by_rests[0], confidence, warnings, levels, states[by_rests[0]], by_gyro
    ranked = sorted(levels, key=levels.get)
    best = ranked[0]
    confidence = 1.0
    if len(ranked) > 1:
        ratio = levels[ranked[1]] / max(levels[best], 1e-12)
        confidence = float(np.clip(1.0 - 1.0 / ratio, 0.0, 1.0))
        if ratio < AMBIGUITY_RATIO:
            warnings.append(
                f"link is ambiguous: links {best} and {ranked[1]} explain the data almost equally "
                f"(residual {levels[best]:.3g} vs {levels[ranked[1]]:.3g} m/s^2); chose {best}"
            )
    return best, confidence, warnings, levels, states[best], by_gyro


def sample_account(problem: UnitProblem, p: _Problem) -> dict:
    """Where the unit's motion went: IMU samples at instants when some joint up to its link moves
    (the *motion*), those the fit kept as moving samples, and those dropped, by reason: at the joint
    stream's kinks (:meth:`JointInterpolator.reliable`), saturated (:class:`SampleAccount`, the
    moving ones), stuck, at the joint stream's ends (the residual clock margin) and otherwise (a
    rest run the IMU contradicted, the part before or after a move). Counts and shares of the motion."""
    s = problem.samples
    shared: Shared = problem.shared
    link = p.data.link
    ip = shared.interpolator
    moving = ~shared.rest.unit_rest(s.t, link)
    margin = MAX_RESIDUAL_OFFSET_S + 0.01
    inside = (s.t >= ip.t_start + margin) & (s.t <= ip.t_end - margin)
    kinks = int(np.count_nonzero(moving & inside & ~ip.reliable(s.t)))
    ends = int(np.count_nonzero(moving & ~inside))
    acc = s.account
    saturated = 0
    stuck = 0
    if acc is not None:
        sat_t = np.asarray(acc.saturated_t if acc.saturated_t is not None else np.zeros(0))
        sat_t = sat_t[(sat_t >= ip.t_start) & (sat_t <= ip.t_end)]
        saturated = int(np.count_nonzero(~shared.rest.unit_rest(sat_t, link))) if sat_t.size else 0
        stuck = int(acc.n_stuck)
    kept = int(len(p.data.rows.moving_t))
    motion = int(np.count_nonzero(moving)) + saturated + stuck
    other = max(motion - kept - kinks - ends - saturated - stuck, 0)
    counts = {"motion": motion, "kept": kept, "kinks": kinks, "saturated": saturated, "stuck": stuck,
              "ends": ends, "other": other}
    return {**counts, "shares": {k: (v / motion if motion else 0.0) for k, v in counts.items() if k != "motion"}}


_ACCOUNT_WORDS = {
    "kinks": "at the joint stream's kinks",
    "saturated": "saturated",
    "stuck": "a stuck axis",
    "ends": "at the joint stream's ends",
    "other": "in rest runs the IMU contradicted or beyond a move",
}


def describe_account(account: dict) -> str:
    """One line for :func:`sample_account`: "kept 52 % of the motion (1065 samples): 31 % at the
    joint stream's kinks, 17 % saturated"."""
    sh = account["shares"]
    dropped = [f"{100 * sh[k]:.0f} % {w}" for k, w in _ACCOUNT_WORDS.items() if account[k] > 0]
    head = f"kept {100 * sh['kept']:.0f} % of the motion ({account['kept']} of {account['motion']} samples)"
    return head + (": " + ", ".join(dropped) if dropped else "")


NULL_POSITION_SCALE_M = 0.1
"""Positions are compared with rotations in null-space directions in units of this length (a unit
turned by one radian about an axis 0.1 m away moves by 0.1 m)."""


NULL_SHARE = 0.05
"""A pose component whose share in the null space (row norm of its orthonormal basis) exceeds this
is undetermined: its std is reported as null."""


def _pose_null_basis(null: FloatArray) -> FloatArray:
    """Orthonormal basis ``(6, k)`` of the pose part of the null space (rows: rotation in the unit
    frame, rad; position in units of :data:`NULL_POSITION_SCALE_M`), whatever basis the solver
    returned: the row norms of it (the share of each parameter in the null space) do not depend on
    that basis. Directions of the sensor parameters alone are dropped."""
    pose = null[0:6].copy()
    pose[3:6] /= NULL_POSITION_SCALE_M
    if pose.size == 0 or not np.any(pose):
        return np.zeros((6, 0))
    U, s, _ = np.linalg.svd(pose, full_matrices=False)
    return U[:, s > 1e-12 * s.max()]


def _describe_null(basis: FloatArray, R: FloatArray, axis_link: FloatArray, joint: int) -> str:
    """Words for a pose null space ``basis`` (:func:`_pose_null_basis`): the rotation axes it turns
    about (link frame) and the directions it shifts along without turning."""
    parts = []
    rot = R @ basis[0:3]  # rotation part in link frame
    U, s, Vt = np.linalg.svd(rot, full_matrices=True)
    for k in range(min(3, s.size)):
        if s[k] > 0.3:
            a = U[:, k]
            what = f"joint-{joint} axis" if abs(a @ axis_link) > 0.99 else f"axis {np.round(a, 3).tolist()}"
            parts.append(f"rotation (yaw) about the {what}")
    # combinations of the basis that do not turn: the right singular vectors of the rotation part
    # with (near) zero singular value
    n_turn = int(np.sum(s > 1e-6))
    for v in Vt[n_turn:]:
        pos = basis[3:6] @ v
        if np.linalg.norm(pos) > 0.1:
            a = pos / np.linalg.norm(pos)
            what = f"joint-{joint} axis" if abs(a @ axis_link) > 0.99 else f"direction {np.round(a, 3).tolist()}"
            parts.append(f"offset along the {what}")
    if not parts:
        parts.append("a combination of sensor parameters")
    return "unobservable: " + " and ".join(dict.fromkeys(parts)) + " (left at the closed-form start)"


def _joint_axis_in_link(chain: SerialChain, link: int) -> FloatArray:
    """Unit direction of joint ``link``'s axis in link frame ``link`` (constant): the joint axis
    ``T_joint_link^-1`` maps into the link frame (it is fixed on both sides of the joint)."""
    return chain.T_joint_link[link - 1, :3, :3].T @ chain.axis[link - 1]


def _distinct_orientations(u_link: FloatArray, min_angle_deg: float = 5.0) -> int:
    """Number of static gravity directions (link frame) at least ``min_angle_deg`` apart."""
    if len(u_link) == 0:
        return 0
    dirs = u_link / np.linalg.norm(u_link, axis=1, keepdims=True)
    chosen: list[FloatArray] = []
    for d in dirs:
        if all(np.degrees(np.arccos(np.clip(d @ c, -1, 1))) >= min_angle_deg for c in chosen):
            chosen.append(d)
    return len(chosen)


def _blocks(problem: UnitProblem, p: _Problem) -> Blocks:
    opts: MleOptions = problem.options
    rows = p.data.rows
    gyro = rows.static_g is not None
    scale = (SCALE_FULL if gyro else SCALE_SYM) if opts.scale else SCALE_NONE
    time_offset = opts.time_offset
    span = float(np.ptp(rows.moving_t)) if len(rows.moving_t) else 0.0
    static_span = float(np.ptp(rows.static_t)) if len(rows.static_t) else 0.0
    return Blocks(
        scale=scale,
        gravity=scale != SCALE_NONE and opts.gravity and len(rows.moving_t) >= 10,
        time_offset=time_offset,
        clock_drift=time_offset and opts.clock_drift and span >= CLOCK_DRIFT_MIN_SPAN_S,
        gyro=gyro,
        bias_drift=opts.bias_drift
        and len(rows.static_t) >= BIAS_DRIFT_MIN_RUNS
        and static_span >= BIAS_DRIFT_MIN_SPAN_S,
    )


def _static_chi2(fit: Fit, rows: Rows, rest_noise: float, angle_noise: float = 0.0) -> float:
    """Variance ratio of the rest rows' residuals to what the noise explains (1 when consistent).

    A rest run of ``n`` samples with white noise ``sigma_r`` has a mean residual of variance ``sigma_r^2
    / n`` per axis (``rest_noise`` carries the noise's autocorrelation factor when it is not white), plus
    ``(|u| sigma_q)^2`` from the joint angles' own error ``sigma_q`` (rad; an encoder's rounding tilts
    the predicted gravity); the ratio over all runs, ``sum |r|^2 / (3 var (S - k))``, exceeds 1 when the
    runs disagree with the model (bias drift, a moved unit, wrong gravity).
    """
    S = len(rows.static_u)
    if fit.residuals is None or S < 4:
        return 1.0
    rest_noise = max(rest_noise, REST_NOISE_FLOOR)
    r = fit.residuals[:S]
    var = rest_noise**2 / rows.static_weight + (np.linalg.norm(rows.static_u, axis=1) * angle_noise) ** 2
    dof = max(3 * S - 9, 1)
    return float(np.sum(np.sum(r * r, axis=1) / var) / dof)


def _honesty(
    fit: Fit, p: _Problem, alignment: OffsetSearch | None, total_offset: float, angle_noise: float = 0.0
) -> tuple[FloatArray, list[str], list[str]]:
    """Residual tests: the covariance inflated where the model leaves something out, warnings (the
    estimate may be off: the reported std accounts for it) and notes (found and corrected, e.g. a
    drifting clock) (``angle_noise``: error of the rest poses' joint angles along the chain, rad)."""
    rows = p.data.rows
    sl = fit.blocks.slices()
    cov = fit.covariance
    std = np.sqrt(np.maximum(np.diag(cov), 0.0))
    st = fit.state
    warnings: list[str] = []
    notes: list[str] = []
    # The rest means vary as the IMU's noise at rest is correlated (measured inside the rest runs: the
    # moving residuals' correlation also carries model error, which the robot at rest does not have).
    chi2 = _static_chi2(fit, rows, p.data.rest.accel_noise * np.sqrt(p.data.rest.accel_correlation), angle_noise)
    if chi2 > STATIC_CHI2_WARN:
        cov = cov * chi2
        warnings.append(
            f"rest poses disagree with the model ({np.sqrt(chi2):.1f}x the rest noise; bias drift, gravity or "
            "a moved unit?): uncertainty inflated accordingly"
        )
    if "d" in sl:
        d, sd = st.d, std[sl["d"].start]
        if abs(d) > DRIFT_WARN_SIGMAS * sd and abs(d) * 1e6 > CLOCK_DRIFT_WARN_PPM:
            notes.append(f"clock drifts: {d * 1e6:+.0f} ppm relative to the robot's clock (estimated and corrected)")
    if "c" in sl:
        T = float(np.ptp(rows.static_t))
        change = np.linalg.norm(st.c) * T
        sc = np.linalg.norm(std[sl["c"]]) * T
        if change > DRIFT_WARN_SIGMAS * sc and change > BIAS_DRIFT_WARN_MPS2:
            warnings.append(
                f"bias drifts: the accelerometer bias changed by {change:.3g} m/s^2 over {T:.0f} s "
                "(estimated as a linear drift)"
            )
    if alignment is not None and (
        alignment.sharpness < OFFSET_SHARPNESS_MIN or abs(total_offset - alignment.offset_s) > OFFSET_JUMP_WARN_S
    ):
        warnings.append(
            f"time offset uncertain: coarse alignment {alignment.offset_s * 1e3:.0f} ms (peak sharpness "
            f"{alignment.sharpness:.2f}), refined {total_offset * 1e3:.0f} ms"
        )
    if fit.sandwich is not None and float(fit.sandwich[3:6].max()) > SANDWICH_WARN:
        warnings.append(
            f"residual errors follow the motion beyond the noise model (a low-rate joint stream's interpolation, "
            f"an unmodelled effect): position std raised up to x{float(fit.sandwich[3:6].max()):.1f} to what the "
            "residuals show"
        )
    if fit.residual_correlation > CORRELATION_WARN:
        warnings.append(
            f"residuals strongly correlated in time (factor {fit.residual_correlation:.1f}: unmodelled dynamics "
            "or joint-state errors); uncertainty inflated by it"
        )
    return cov, warnings, notes


def run_unit(problem: UnitProblem) -> UnitResult:
    """Calibrate one unit with the default method (module docstring)."""
    warnings: list[str] = []
    extras: dict = {}
    start, confidence = None, None
    early_notes: list[str] = []
    account = problem.samples.account
    if account is not None:  # the gyroscope's screening (the accelerometer's reaches the result elsewhere)
        warnings += [w for w in account.warnings if not w.startswith("accelerometer ")]
    if problem.link == 0:
        link, confidence, link_warnings, levels, start, by_gyro = choose_link(problem)
        warnings += link_warnings
        extras["link_residual_mps2"] = {str(k): v for k, v in levels.items()}
        ruled_out = None if by_gyro is None else by_gyro.note()
        if ruled_out:
            early_notes.append(ruled_out)
    else:
        link = problem.link
    rates = gyro_rates(problem)
    if rates is not None:
        warnings += check_gyro_units(problem.samples.unit, rates[0], rates[1][:, link - 1])
    if _use_gyro(problem):  # the gyroscope's scale checked against the robot's rotation rate (calib.gyro)
        # Checked, not corrected: a gyroscope's misalignment to the accelerometer has an antisymmetric part
        # that only a rotation of its own could absorb; correcting the scale alone made the gyroscope's
        # (misaligned) axes decide the rotation more firmly (simulated: 4.5 % scale, 1 % misalignment).
        scale = _gyro_scale(problem, link)
        if scale is not None and scale.off:
            warnings.append(scale.describe())
            extras["gyro_scale_misalignment"] = scale.A
    p = _arrange(problem, link)
    warnings += list(p.data.rest.warnings)
    n_orient = _distinct_orientations(p.data.rows.static_u)
    if n_orient < 3:
        warnings.append(
            f"only {n_orient} distinct static orientation(s) (3 or more recommended): rotation, bias and scale "
            "rest on the moving data"
        )
    blocks = _blocks(problem, p)
    if start is not None:
        start = replace(start, E=np.zeros((3, 3)), bg=_gyro_bias_start(p.data.rows))
    # Converge on every 8th moving sample, then one Gauss-Newton step on all of them, whose
    # normal matrix also gives the covariance.
    coarse = _fit(_decimated(p, 8), blocks, state=start)
    move = None
    if problem.options.detect_move and coarse.residuals is not None:
        # a fitted bias drift can soak up part of a move: look with and without it
        S = len(p.data.rows.static_u)
        undrifted = coarse.residuals.copy()
        undrifted[:S] -= np.outer(p.data.rows.static_t, coarse.state.c)
        move = find_move(p.data.rows, coarse.residuals, p.data.t_c) or find_move(p.data.rows, undrifted, p.data.t_c)
    if move is not None:  # keep the longer part and fit again
        s = problem.samples
        before = np.count_nonzero(s.t <= move.t_before) >= np.count_nonzero(s.t >= move.t_after)
        p = _arrange(problem, link, window=(-np.inf, move.t_before) if before else (move.t_after, np.inf))
        blocks = _blocks(problem, p)
        coarse = _fit(_decimated(p, 8), blocks, state=coarse.state)
        extras["moved_between_s"] = [move.t_before, move.t_after]
        warnings.append(
            f"unit moved on its link between {move.t_before:.1f} s and {move.t_after:.1f} s (its rest poses before "
            f"and after differ by about {move.angle_deg:.1f} deg): calibrated from the part "
            f"{'before' if before else 'after'} it only"
        )
    fit = _fit(p, blocks, state=coarse.state, max_outer=1, max_inner=1)
    e = fit.blocks.slices().get("e")
    if e is not None:
        std_e = np.sqrt(np.maximum(np.diag(fit.covariance)[e], 0.0))
        if np.any(std_e > SCALE_STD_LIMIT):
            warnings.append(
                f"scale/misalignment weakly determined by the data (std up to {100 * std_e.max():.1f} %, "
                "held near zero by a 5 % prior; its uncertainty is in the reported std)"
            )
    st = fit.state
    sl = fit.blocks.slices()
    total_offset = problem.time_offset_s + st.tau
    steps = None if problem.alignment is None else problem.alignment.steps
    alignment: Alignment | None = problem.alignment
    sigma_q = problem.shared.interpolator.conditioning.position_noise
    angle_noise = 0.0 if sigma_q is None else float(np.sqrt(np.sum(np.square(sigma_q[:link]))))
    cov, honesty, notes = _honesty(fit, p, None if alignment is None else alignment.search, total_offset, angle_noise)

    warnings += honesty
    notes = early_notes + notes
    kept = sample_account(problem, p)
    extras["samples"] = kept
    notes.append(describe_account(kept))
    observable = fit.null_space.shape[1] == 0
    std = np.sqrt(np.maximum(np.diag(cov), 0.0))
    pos_std = std[3:6].copy()
    rot_cov = st.R @ cov[0:3, 0:3] @ st.R.T
    rot_std = np.degrees(np.sqrt(np.maximum(np.diag(rot_cov), 0.0)))
    if not observable:
        basis = _pose_null_basis(fit.null_space)
        warnings.append(_describe_null(basis, st.R, _joint_axis_in_link(problem.chain, link), link))
        affected_p = np.linalg.norm(basis[3:6], axis=1) > NULL_SHARE
        affected_r = np.linalg.norm(st.R @ basis[0:3], axis=1) > NULL_SHARE
        pos_std = np.where(affected_p, np.nan, pos_std)
        rot_std = np.where(affected_r, np.nan, rot_std)

    def get_std(name: str) -> FloatArray:
        """The std of a fitted block (callers check ``name in sl``)."""
        return std[sl[name]]

    # The offset at the start of the joint stream (where a simulation's truth and a user's sync
    # refer to), carried from the fit's reference t_c along the drift: tau + d (t_ref - t_c).
    t_ref = problem.shared.interpolator.t_start
    lever = t_ref - p.data.t_c
    offset_ref = total_offset + (st.d * lever if "d" in sl else 0.0)
    offset_ref_std = None
    if "tau" in sl:
        j = np.zeros(len(std))
        j[sl["tau"].start] = 1.0
        if "d" in sl:
            j[sl["d"].start] = lever
        offset_ref_std = float(np.sqrt(max(j @ cov @ j, 0.0)))
    imu: dict = {
        "accel_bias_mps2": st.b,
        "accel_scale_misalignment": st.A,
        "accel_bias_std_mps2": std[6:9],
        "time_offset_s": offset_ref,
        "time_offset_std_s": offset_ref_std,
        "time_reference_s": t_ref,
        "clock_drift_ppm": (st.d * 1e6 if "d" in sl else 0.0) + (steps.drift_ppm if steps is not None else 0.0)
        if "d" in sl or steps is not None
        else None,
        "clock_drift_std_ppm": float(get_std("d")[0]) * 1e6 if "d" in sl else None,
    }
    extras.update(
        {
            "time_offset_coarse_s": None if alignment is None else alignment.offset_s,
            "residual_std_mps2": fit.sigma,
            "residual_correlation": fit.residual_correlation,
            "covariance_sandwich": None if fit.sandwich is None else fit.sandwich[:6].copy(),
            "n_static_runs": int(p.data.n_static),
            "n_static_dropped": int(len(p.data.rest.dropped)),
            "n_moving_samples": int(len(p.data.rows.moving_t)),
            "iterations": fit.iterations,
            "scale_estimated": fit.blocks.scale != SCALE_NONE,
            "rest_source": problem.shared.rest.source,
        }
    )
    if steps is not None:
        imu["clock_resync_steps"] = steps.n_steps
        imu["clock_resync_period_s"] = steps.period_s
        imu["clock_resync_step_s"] = steps.mean_step_s
        notes.append(
            f"clock re-synced {steps.n_steps} times (every {steps.period_s:.2f} s, steps of "
            f"{steps.mean_step_s * 1e3:.2f} ms: the sensor clock drifts {steps.drift_ppm:+.0f} ppm between "
            "re-syncs); stamps corrected"
        )
    gaps = None if alignment is None else alignment.gaps
    if gaps is not None:  # a step found is named; one not corrected is a warning (the estimate had to cope)
        (notes if gaps.corrected.all() else warnings).append(gaps.describe())
        extras["clock_gap_steps"] = np.c_[gaps.gap_start_s, gaps.gap_end_s, gaps.step_s].tolist()
    if "bg" in sl:
        imu["gyro_bias_rps"] = st.bg
        imu["gyro_bias_std_rps"] = get_std("bg")
        extras["gyro_residual_std_rps"] = fit.sigma_gyro
    if "k" in sl:
        g0 = float(np.linalg.norm(problem.gravity))
        imu["gravity_mps2"] = g0 * (1.0 + st.k)
        imu["gravity_std_mps2"] = g0 * float(get_std("k")[0])
    if "c" in sl:
        imu["accel_bias_drift_mps3"] = st.c
        imu["accel_bias_drift_std_mps3"] = get_std("c")
        imu["accel_bias_reference_s"] = p.data.t_c
    if "e" in sl:
        std_e = get_std("e")
        imu["accel_scale_misalignment_std"] = (
            std_e.reshape(3, 3) if fit.blocks.scale == SCALE_FULL else sym_from_e(std_e)
        )
        extras["accel_scale"] = np.diag(st.A).copy()
        sym = 0.5 * (st.E + st.E.T)
        extras["accel_misalignment_sym"] = sym - np.diag(np.diag(sym))
    return UnitResult(
        pose=SkinUnitPose(link, st.R, st.p),
        observable=observable,
        position_std_m=pos_std,
        rotation_std_deg=rot_std,
        warnings=tuple(warnings),
        extras=extras,
        imu=ImuCalibration(**imu),
        link_confidence=confidence,
        notes=tuple(notes),
    )


register(
    "mle",
    MethodSpec(
        run_unit=run_unit,
        description="global time alignment + closed-form start + robust joint maximum likelihood "
        "(pose, IMU errors, clock) with residual tests",
        discovers_links=True,
        use_gyro_for_links=True,
        prepare=prepare,
        exact_joint_states=False,
        align=align,
        needs_segments=False,
        options=MleOptions,
    ),
)
