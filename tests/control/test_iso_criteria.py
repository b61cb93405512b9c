"""ISO/TS 15066's criteria as metrics (skincal.control.iso_metrics.iso_criteria) and as the QP's rows
(ControllerConfig.pfl): issue 28, item 3. Arrays only, no simulator."""

from __future__ import annotations

import numpy as np
import pytest

from skincal.control import AvoidanceController, ControllerConfig
from skincal.control.body_regions import body_region, pfl_speed_limit
from skincal.control.effective_mass import effective_mass
from skincal.control.iso_metrics import approach_speeds, iso_criteria, nearest_pairs
from skincal.control.separation import SeparationParams, StoppingModel
from skincal.errors import ConfigError
from skincal.kinematics import panda
from skincal.kinematics.points import Q_START
from skincal.perception import RobotBody
from skincal.skin import tof

DT = 1e-3
HAND = body_region("hand")


def flange(chain, q):
    return chain.flange_pose(q)[0, :3, 3]


def spring_mass(q: np.ndarray) -> np.ndarray:
    """A stand-in joint-space inertia (SPD), kg m^2."""
    return np.diag(np.linspace(2.0, 0.5, q.size))


def test_a_person_walking_into_the_stopped_robot_is_person_initiated_and_passes():
    """A hand moving at 1 m/s onto the still robot's flange from 0.3 m: inside S_p the robot never moves,
    the contact is the person's (robot speed 0 at the touch) and within the hand's limits: a pass."""
    chain = panda()
    body = RobotBody.of(chain)
    S = 400
    t = DT * np.arange(S)
    q = np.tile(Q_START, (S, 1))
    start = flange(chain, Q_START) + np.array([0.0, 0.0, -0.35])
    centre = start[None] + np.outer(t, [0.0, 0.0, 1.0])  # up at 1 m/s

    def solids(tt):
        return [tof.Sphere(start[None] + np.outer(tt, [0.0, 0.0, 1.0]), 0.05)]

    res = iso_criteria(t, q, body, solids, np.full(S, 0.3), [HAND], spring_mass, "ssm")
    assert res.violation_steps == 0 and res.inside_sp_s > 0.1
    assert len(res.contacts) == 1
    c = res.contacts[0]
    assert not c.robot_initiated and c.within_limits and c.region == "hand"
    assert c.v_robot == pytest.approx(0.0, abs=1e-9) and c.v_person == pytest.approx(1.0, abs=0.05)
    assert res.passed
    assert centre.shape == (S, 3)


def test_a_robot_moving_into_a_still_hand_is_a_violation_and_robot_initiated():
    """The robot's flange driven at constant joint speed into a still hand: inside S_p it approaches (a
    violation), the contact is robot-initiated; the measured approach speed is the flange's n^T J qd."""
    chain = panda()
    body = RobotBody.of(chain)
    S = 600
    t = DT * np.arange(S)
    qd = np.zeros(7)
    qd[1] = 1.0  # shoulder pitch: the flange moves forward/down
    q = Q_START[None] + np.outer(t, qd)
    x_end = flange(chain, q[-1])
    x0 = flange(chain, q[0])
    centre = x_end + 0.03 * (x_end - x0) / np.linalg.norm(x_end - x0)  # just past where the flange goes

    def solids(tt):
        return [tof.Sphere(np.broadcast_to(centre, (np.size(tt), 3)), 0.05)]

    res = iso_criteria(t, q, body, solids, np.full(S, 0.3), [HAND], spring_mass, "ssm")
    pairs = nearest_pairs(t, q, body, solids)
    v_r, v_h, Jn = approach_speeds(t, q, body, solids, pairs)
    np.testing.assert_allclose(v_h, 0.0, atol=1e-12)
    assert res.violation_steps > 0 and res.max_approach_inside_sp_mps > 0.1
    assert len(res.contacts) == 1  # it touches: robot-initiated, over the hand's limit at 1 rad/s
    c = res.contacts[0]
    assert c.robot_initiated and c.v_robot > 0.3 and c.energy > 0
    assert c.energy == pytest.approx(0.5 * (1 / (1 / 0.6 + 1 / c.m_robot)) * c.v_robot**2, rel=1e-12)
    # the finite-difference speed of the nearest surface point equals n^T J qd (first order in dt)
    k = np.flatnonzero(pairs.clearance < 0.3)[0]
    assert v_r[k] == pytest.approx(Jn[k] @ qd, rel=1e-9)
    assert not res.passed
    # under PFL a slow approach is allowed: the same run at a tenth of the speed
    slow = Q_START[None] + np.outer(t, 0.02 * qd)
    pfl = iso_criteria(t, slow, body, solids, np.full(S, 10.0), [HAND], spring_mass, "pfl")
    ssm = iso_criteria(t, slow, body, solids, np.full(S, 10.0), [HAND], spring_mass, "ssm")
    assert pfl.violation_steps == 0 and ssm.violation_steps > 0


def test_an_unknown_criterion_is_a_config_error():
    chain = panda()
    with pytest.raises(ConfigError, match="unknown ISO criterion"):
        iso_criteria(np.zeros(1), Q_START[None], RobotBody.of(chain), None, np.zeros(1), [], None, "x")


def test_pfl_row_allows_the_annex_a_speed_at_the_effective_mass_and_ssm_a_retreat():
    """A still point 8 cm from the flange capsule, inside S_p: the SSM row's bound is negative (retreat);
    the PFL row's is the share of the hand's speed limit at the row's effective mass, computed apart."""
    chain = panda()
    sep = SeparationParams(stopping=StoppingModel.constant_deceleration(4.0, 0.021))
    x = flange(chain, Q_START)
    point = (x + np.array([0.0, 0.0, -0.15]))[None]
    ssm = AvoidanceController(chain, ControllerConfig(separation=sep))
    cfg = ControllerConfig(separation=sep, pfl=HAND, pfl_share=0.5)
    pfl = AvoidanceController(chain, cfg, mass_matrix=spring_mass)
    a = ssm.problem(Q_START, x, np.zeros(3), point)
    b = pfl.problem(Q_START, x, np.zeros(3), point)
    assert a.distance[0] > 0 and a.h[0] < 0
    np.testing.assert_array_equal(a.G, b.G)
    m = effective_mass(b.G, spring_mass(Q_START))[0]
    assert b.h[0] == pytest.approx(0.5 * float(pfl_speed_limit(HAND, m)), rel=1e-12)
    with pytest.raises(ConfigError, match="mass_matrix"):
        AvoidanceController(chain, cfg)
    with pytest.raises(ConfigError, match="pfl needs"):
        ControllerConfig(pfl=HAND)


def test_pfl_keeps_the_separation_row_for_the_head_and_the_buffer_shifts_the_ramp():
    """No transient contact with the skull: its PFL row is the SSM row. ``sp_buffer`` b: the row at distance d
    is the unbuffered row at d - b (the ramp's zero moved b beyond S_p)."""
    from dataclasses import replace

    chain = panda()
    sep = SeparationParams(stopping=StoppingModel.constant_deceleration(4.0, 0.021))
    x = flange(chain, Q_START)
    point = (x + np.array([0.0, 0.0, -0.15]))[None]
    base = ControllerConfig(separation=sep)
    ssm = AvoidanceController(chain, base).problem(Q_START, x, np.zeros(3), point)
    head = AvoidanceController(chain, replace(base, pfl=body_region("head")), mass_matrix=spring_mass)
    np.testing.assert_array_equal(head.problem(Q_START, x, np.zeros(3), point).h, ssm.h)
    buffered = AvoidanceController(chain, replace(base, sp_buffer=0.03)).problem(Q_START, x, np.zeros(3), point)
    nearer = AvoidanceController(chain, base).problem(Q_START, x, np.zeros(3), point + [0.0, 0.0, 0.03])
    assert buffered.h[0] < ssm.h[0]
    assert buffered.h[0] == pytest.approx(nearer.h[0], abs=0.01)  # the table's 2 mm grid in distance


def test_the_protective_stop_never_approaches_past_a_row():
    """An infeasible QP (row A asks qd0 <= -2 within |qd| <= 1; row B allows -qd0 + 0.1 qd1 <= 0.5). The legacy
    least-violating retreat violates B too (worked by hand: qd = (-1, -1), B's left side 0.9); the protective
    stop keeps B and violates A only down to a stop: qd0 = -0.6, qd1 = -1, B exactly 0.5, A -0.6 <= 0."""
    from skincal.control.qp import QpProblem

    chain = panda()
    prob = QpProblem(
        np.eye(2), np.zeros(2), np.array([[1.0, 0.0], [-1.0, 0.1]]), np.array([-2.0, 0.5]),
        -np.ones(2), np.ones(2), np.zeros(3), np.zeros(2),
    )  # fmt: skip
    legacy, feasible, _, _ = AvoidanceController(chain, ControllerConfig()).solve(prob)
    assert not feasible and prob.G[1] @ legacy > 0.5 + 0.3
    stop, feasible, violation, _ = AvoidanceController(chain, ControllerConfig(stop_never_approaches=True)).solve(prob)
    assert not feasible
    np.testing.assert_allclose(stop, [-0.6, -1.0], atol=1e-4)
    assert np.all(prob.G @ stop <= np.maximum(prob.h, 0.0) + 1e-6)
    assert violation == pytest.approx(1.4, abs=1e-4)
