"""``mle``'s link discovery: the gyroscope rules links out, the single-joint segments' activity proposes
one, and candidate links are fitted and compared by the rests' likelihood (:func:`choose_link`)."""

from __future__ import annotations

import numpy as np

from skincal.calib.api import UnitProblem
from skincal.calib.links import GyroLinks, activity_in, discover_link, gyro_rules_out
from skincal.calib.mle.likelihood import rest_nll
from skincal.calib.mle.problem import arrange, fit_problem, use_gyro
from skincal.calib.mle.solver import (
    SCALE_NONE,
    Blocks,
    State,
)
from skincal.calib.model import predict_specific_force
from skincal.calib.signals import SignalTable
from skincal.data.dataset import DYNAMIC, STATIC
from skincal.errors import CalibrationError
from skincal.kinematics.transforms import FloatArray

DECISIVE_ACTIVITY = 0.9
"""Activity confidence above which neighbouring links are not fitted for comparison."""


AMBIGUITY_RATIO = 1.5
"""A second link whose residual level is within this factor of the best makes the link ambiguous."""


AMBIGUITY_NLL = 3.0
"""The rests decide the link when the second candidate's negative log-likelihood over them exceeds the
best's by this much (a likelihood ratio of e^3 = 20; :mod:`skincal.calib.mle.likelihood`)."""


def residual_level(problem: UnitProblem, link: int, state: State) -> float:
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
    if not use_gyro(problem):
        return None
    table: SignalTable = problem.shared.table
    g_t = table.grid_t
    keep = (s.t >= g_t[0]) & (s.t <= g_t[-1]) & np.all(np.isfinite(s.gyro), axis=1)  # NaN: at its rail
    w = np.column_stack([np.interp(s.t[keep], g_t, c) for c in table.angular_speed.T])
    g = s.gyro[keep]
    still = np.max(w, axis=1) < GYRO_STILL_RATE
    bias = np.median(g[still], axis=0) if np.count_nonzero(still) >= 10 else np.zeros(3)
    return np.linalg.norm(g - bias, axis=1), w


def untagged_motion(problem: UnitProblem) -> np.ndarray | None:
    """``(M,)`` the unit's samples while some joint moves outside every single-joint segment, when
    they are more than :data:`GENERAL_MOTION_SHARE` of the samples while some joint moves (general
    motion: the segments cannot judge the link alone); ``None`` otherwise."""
    s = problem.samples
    moving = ~problem.shared.rest.unit_rest(s.t, problem.chain.n_joints)
    untagged = moving & (s.kind != DYNAMIC)
    general = np.any(moving) and np.count_nonzero(untagged) > GENERAL_MOTION_SHARE * np.count_nonzero(moving)
    return untagged if general else None


def choose_link(
    problem: UnitProblem, rates: tuple[FloatArray, FloatArray] | None = None
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
    ``rates``: the unit's :func:`gyro_rates` when the caller has them already.
    """
    n = problem.chain.n_joints
    if rates is None:  # not given by the caller (None from gyro_rates: no gyroscope; computing it again is cheap)
        rates = gyro_rates(problem)
    by_gyro = None if rates is None else gyro_rules_out(*rates)
    allowed = set(range(1, n + 1)) if by_gyro is None else {int(k) + 1 for k in np.flatnonzero(by_gyro.allowed)}
    activity = discover_link(problem.samples, n, use_gyro=True)
    levels: dict[int, float] = {}
    states: dict[int, State] = {}
    warnings = [w for w in activity.warnings if "ambiguous" not in w and "never excited" not in w]
    tagged = bool(np.any(problem.samples.kind == STATIC))  # the activity's noise floor needs static segments
    untagged = untagged_motion(problem)
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
            arranged = arrange(problem, link, decimate=10)
            fit = fit_problem(arranged, Blocks(scale=SCALE_NONE), max_outer=2)
        except CalibrationError:
            continue
        levels[link] = residual_level(problem, link, fit.state)
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
