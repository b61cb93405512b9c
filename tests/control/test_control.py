"""Controller: barrier shape, Jacobians, the approach-velocity bound checked by finite differences of the
resulting motion, safe stop on infeasible problems, joint limits, metrics helpers."""

from __future__ import annotations

import numpy as np
import pytest

from skincal.control import (
    AvoidanceController,
    ControllerConfig,
    FrameCache,
    approach_speed_bound,
    cap_candidates,
    joint_velocity_bounds,
    point_jacobians,
)
from skincal.control.iso_metrics import count_contacts, recovery_time
from skincal.kinematics import panda, sawyer
from skincal.perception import RobotBody

Q0 = np.array([0.0, -0.3, 0.0, -2.2, 0.0, 2.0, np.pi / 4])
CFG = ControllerConfig()


def sampled_distance(body: RobotBody, q: np.ndarray, p: np.ndarray) -> float:
    """Independent distance from ``p`` to the robot surface: dense samples of every capsule core."""
    a, b = body.segments(body.chain.link_frames(q))
    s = np.linspace(0.0, 1.0, 20001)
    best = np.inf
    for ai, bi, r in zip(a[0], b[0], body.radius, strict=True):
        best = min(best, np.min(np.linalg.norm(ai + s[:, None] * (bi - ai) - p, axis=1)) - r)
    return float(best)


def test_barrier_shape():
    d = np.linspace(0.0, 1.0, 1001)
    b = approach_speed_bound(d, 0.12, 0.3, 0.3)
    assert approach_speed_bound(0.12, 0.12, 0.3, 0.3) == pytest.approx(0.0, abs=1e-15)
    assert approach_speed_bound(0.3, 0.12, 0.3, 0.3) == pytest.approx(0.99 * 0.3)
    assert np.all(np.diff(b) > 0) and np.all(b[d < 0.12] < 0) and np.all(b <= 0.3)
    assert b[-1] == pytest.approx(0.3, rel=1e-6)


@pytest.mark.parametrize("make", [panda, sawyer])
def test_frames_and_jacobians_match_the_chain(make, rng):
    chain = make()
    q = rng.uniform(-1, 1, chain.n_joints)
    T = FrameCache(chain).frames(q)
    np.testing.assert_allclose(T, chain.link_frames(q)[0], atol=1e-12)
    for link in (2, 5, chain.n_joints):
        p_link = rng.normal(size=3) * 0.1
        p_base = T[link, :3, :3] @ p_link + T[link, :3, 3]
        J = point_jacobians(chain, T, [link], p_base)[0]
        np.testing.assert_allclose(J, chain.point_jacobian(q, link, p_link)[0, :3], atol=1e-12)


def _toward_obstacle_problem(distance_to_padded: float):
    """An obstacle point straight out (+y) from the forearm and a reference pushing the flange toward it."""
    chain = panda()
    ctl = AvoidanceController(chain, CFG)
    # the middle of the forearm (the long capsule of link 4, in the x-z plane at Q0) and the obstacle beside it
    a, b = ctl.body.segments(chain.link_frames(Q0))
    k = int(np.argmax(np.where(ctl.body.link == 4, np.linalg.norm(b[0] - a[0], axis=1), 0.0)))
    mid = 0.5 * (a[0, k] + b[0, k])
    radius = ctl.body.radius[0]
    p_obs = mid + np.array([0.0, 1.0, 0.0]) * (radius + distance_to_padded)
    x = chain.flange_pose(Q0)[0, :3, 3]
    return chain, ctl, p_obs, x


@pytest.mark.parametrize("d_padded", [0.3, 0.05])  # between critical and notice; below critical
def test_constraint_bounds_the_approach_velocity_finite_differences(d_padded):
    chain, ctl, p_obs, x = _toward_obstacle_problem(d_padded)
    xd_des = np.array([0.0, 1.0, 0.0])  # drive the flange (and forearm) toward +y fast
    free = AvoidanceController(chain, CFG).step(Q0, x, xd_des, np.zeros((0, 3)))
    res = ctl.step(Q0, x, xd_des, p_obs[None])
    assert res.feasible and res.n_obstacles == 1
    true_body = RobotBody.of(chain).inflated(CFG.padding)
    h = 1e-5
    d0 = sampled_distance(true_body, Q0, p_obs)
    assert d0 == pytest.approx(d_padded, abs=1e-6)
    rate = (sampled_distance(true_body, Q0 + h * res.qd, p_obs) - d0) / h
    rate_free = (sampled_distance(true_body, Q0 + h * free.qd, p_obs) - d0) / h
    b = float(approach_speed_bound(d_padded, CFG.critical, CFG.notice, CFG.v_max))
    assert rate_free < -b - 0.01  # without the row the robot would approach faster than allowed
    assert rate >= -b - 1e-3  # with it, d(distance)/dt >= -b
    assert rate == pytest.approx(-b, abs=1e-3)  # and the row is active
    if d_padded < CFG.critical:
        assert rate > 0  # below the critical distance the robot retreats


def test_infeasible_pinch_stops_and_says_so():
    chain, ctl, p_obs, x = _toward_obstacle_problem(0.03)
    mirror = p_obs - 2 * np.array([0.0, 1.0, 0.0]) * (ctl.body.radius[0] + 0.03)
    res = ctl.step(Q0, x, np.array([0.0, 0.2, 0.0]), np.array([p_obs, mirror]))
    assert not res.feasible and res.violation > 0
    assert np.max(np.abs(res.qd)) < 0.05  # (nearly) still: no task motion while pinched
    # the least-violating stop violates no more than standing still does
    prob = ctl.problem(Q0, x, np.array([0.0, 0.2, 0.0]), np.array([p_obs, mirror]))
    assert res.violation <= np.max(-prob.h) + 1e-9


def test_unreachable_point_at_the_base_stops():
    chain = panda()
    ctl = AvoidanceController(chain, CFG)
    x = chain.flange_pose(Q0)[0, :3, 3]
    res = ctl.step(Q0, x, np.array([0.0, 0.2, 0.0]), np.array([[0.0, 0.1 + CFG.padding + 0.06, 0.1]]))
    assert not res.feasible
    np.testing.assert_allclose(res.qd, 0.0, atol=1e-6)
    ok = ctl.step(Q0, x, np.array([0.0, 0.2, 0.0]), np.array([[0.0, 0.9, 0.1]]))
    assert ok.feasible and np.linalg.norm(ok.qd) > 0.1


def test_joint_position_limits_over_one_step():
    chain = panda()
    q = Q0.copy()
    q[3] = chain.joint_upper[3] - 0.05  # at the margin
    lb, ub = joint_velocity_bounds(chain, q, 0.001, margin=0.05)
    assert ub[3] == pytest.approx(0.0, abs=1e-9) and lb[3] == -chain.velocity_limit[3]
    q[3] = chain.joint_upper[3] + 0.01  # beyond: may only come back
    lb, ub = joint_velocity_bounds(chain, q, 0.001, margin=0.05)
    assert ub[3] == 0.0 and lb[3] < 0
    ctl = AvoidanceController(chain, CFG)
    x = chain.flange_pose(q)[0, :3, 3]
    res = ctl.step(q, x + [0.0, 0.0, 0.05], np.zeros(3), np.zeros((0, 3)))
    assert res.qd[3] <= 1e-9 and np.all(np.abs(res.qd) <= chain.velocity_limit + 1e-9)


def test_contacts_and_recovery_helpers():
    assert count_contacts(np.array([0.1, -0.01, -0.02, 0.1, -0.1, 0.2])) == 2
    t = np.arange(10.0)
    err = np.array([0, 0, 0.1, 0.1, 0.01, 0.004, 0.003, 0.002, 0.001, 0.0])
    assert recovery_time(t, err, 3.0) == pytest.approx(2.0)
    assert recovery_time(t, np.zeros(10), 3.0) == 0.0
    assert np.isnan(recovery_time(t, np.full(10, 1.0), 3.0))


def test_cap_candidates_lie_on_the_cone_edge_at_the_range(rng):
    origin = rng.normal(size=(4, 3))
    axis = rng.normal(size=(4, 3))
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    r = rng.uniform(0.2, 1.0, 4)
    half = np.deg2rad(13.5)
    cand = cap_candidates(origin + r[:, None] * axis, axis, r, r * np.sin(half), n_rim=6)
    d = cand - origin[:, None]
    np.testing.assert_allclose(np.linalg.norm(d, axis=-1), r[:, None] * np.ones(7), atol=1e-12)
    cos = np.einsum("kci,ki->kc", d, axis) / r[:, None]
    np.testing.assert_allclose(cos[:, 0], 1.0)
    np.testing.assert_allclose(cos[:, 1:], np.cos(half), atol=1e-12)


def test_velocity_aware_row_bounds_the_closing_speed_finite_differences():
    """A point approaching the forearm at 0.5 m/s: the commanded motion keeps d(distance)/dt >= -b(d)
    including the point's own motion, so the robot backs away even though the task pulls it closer."""
    from skincal.perception import ObstaclePoints

    chain, ctl, p_obs, x = _toward_obstacle_problem(0.4)
    v_obs = np.array([0.0, -0.5, 0.0])  # toward the robot
    pts = ObstaclePoints(p_obs[None], ("su4",), np.zeros(1), np.zeros(1), v_obs[None], np.zeros((1, 3)), np.zeros(1))
    res = ctl.step(Q0, x, np.array([0.0, 0.2, 0.0]), pts)
    still = ctl.step(Q0, x, np.array([0.0, 0.2, 0.0]), p_obs[None])
    assert res.feasible
    body = RobotBody.of(chain).inflated(CFG.padding)
    h = 1e-5
    d0 = sampled_distance(body, Q0, p_obs)
    rate = (sampled_distance(body, Q0 + h * res.qd, p_obs + h * v_obs) - d0) / h
    b = float(approach_speed_bound(d0, CFG.critical, CFG.notice, CFG.v_max))
    assert rate == pytest.approx(-b, abs=2e-3)  # active: closes exactly at the allowed speed
    robot_rate = (sampled_distance(body, Q0 + h * res.qd, p_obs) - d0) / h
    assert robot_rate > 0.5 - b - 2e-3  # the robot itself retreats
    assert (sampled_distance(body, Q0 + h * still.qd, p_obs) - d0) / h < 0  # a still point lets it approach


def _max_retreat_rate(g: np.ndarray, lb: np.ndarray, ub: np.ndarray) -> float:
    """The fastest a row ``g qd`` can go negative inside the box ``lb <= qd <= ub``: ``-min g qd``, m/s."""
    return float(-np.sum(np.minimum(g * lb, g * ub)))


def test_still_point_inside_the_margin_the_arm_retreats_at_the_limits_pace():
    """Issue 17: a point inside the critical distance that the arm cannot leave as fast as the ramp asks
    (joint speeds scaled to 30 %): the command backs away at the joint limits' pace (0.31 m/s), not as little
    as it can (the former stop: 0.065 m/s)."""
    chain = panda()
    cfg = ControllerConfig(velocity_scale=0.3)
    ctl = AvoidanceController(chain, cfg)
    _, _, p_obs, x = _toward_obstacle_problem(0.05)
    prob = ctl.problem(Q0, x, np.zeros(3), p_obs[None])
    res = ctl.step(Q0, x, np.zeros(3), p_obs[None])
    assert not res.feasible and res.violation > 0
    fastest = _max_retreat_rate(prob.G[0], prob.lb, prob.ub)
    assert -prob.h[0] > fastest  # (infeasible: the ramp asks for more than the limits give)
    body = RobotBody.of(chain).inflated(cfg.padding)
    h = 1e-5
    rate = (sampled_distance(body, Q0 + h * res.qd, p_obs) - sampled_distance(body, Q0, p_obs)) / h
    assert rate == pytest.approx(fastest, rel=1e-3)  # the gap opens as fast as the limits allow
    assert res.violation == pytest.approx(-prob.h[0] - fastest, rel=1e-4)
    assert np.all(res.qd >= prob.lb - 1e-9) and np.all(res.qd <= prob.ub + 1e-9)


def test_pinch_escapes_along_the_free_direction():
    """Two points either side of the forearm (+-y), both a little above it: no command keeps both rows, and
    the arm moves down, out from between them: both gaps open (the former stop stood almost still)."""
    chain, ctl, p_obs, x = _toward_obstacle_problem(0.03)
    a, b = ctl.body.segments(chain.link_frames(Q0))
    k = int(np.argmax(np.where(ctl.body.link == 4, np.linalg.norm(b[0] - a[0], axis=1), 0.0)))
    mid = 0.5 * (a[0, k] + b[0, k])
    r = ctl.body.radius[0] + 0.03
    tilt = np.radians(15.0)
    pts = np.array([mid + r * np.array([0.0, s * np.cos(tilt), np.sin(tilt)]) for s in (1.0, -1.0)])
    res = ctl.step(Q0, x, np.zeros(3), pts)
    assert not res.feasible
    prob = ctl.problem(Q0, x, np.zeros(3), pts)
    assert res.violation < np.max(-prob.h) - 0.05  # clearly less than standing still
    body = RobotBody.of(chain).inflated(CFG.padding)
    h = 1e-5
    for p in pts:
        rate = (sampled_distance(body, Q0 + h * res.qd, p) - sampled_distance(body, Q0, p)) / h
        assert rate > 0.05  # both gaps open
    assert np.linalg.norm(res.qd) > 0.5


def test_exact_pinch_stands_still_because_every_motion_violates_more(rng):
    """Exactly opposite points: any motion along the normal opens one gap and closes the other; the least
    squared violation is to stand still in that direction (and nowhere else to go: the stillest command),
    and no command in the box does better (random samples)."""
    chain, ctl, p_obs, x = _toward_obstacle_problem(0.03)
    mirror = p_obs - 2 * np.array([0.0, 1.0, 0.0]) * (ctl.body.radius[0] + 0.03)
    pts = np.array([p_obs, mirror])
    prob = ctl.problem(Q0, x, np.zeros(3), pts)
    res = ctl.step(Q0, x, np.zeros(3), pts)
    assert not res.feasible
    np.testing.assert_allclose(prob.G @ res.qd, 0.0, atol=1e-6)
    np.testing.assert_allclose(res.qd, 0.0, atol=1e-5)

    def cost(qd):
        return float(np.sum(np.maximum(prob.G @ qd - prob.h, 0.0) ** 2))

    samples = rng.uniform(prob.lb, prob.ub, size=(2000, prob.lb.size))
    assert cost(res.qd) <= min(cost(s) for s in samples) + 1e-9


def test_least_violation_beats_every_sampled_command(rng):
    """Random infeasible problems (1-6 still points inside the margin around the arm): the retreat's squared
    violation is at most that of standing still and of any of 500 random commands within the limits."""
    chain = panda()
    ctl = AvoidanceController(chain, CFG)
    x = chain.flange_pose(Q0)[0, :3, 3]
    a, b = ctl.body.segments(chain.link_frames(Q0))
    checked = 0
    for _ in range(40):
        k = rng.integers(2, a.shape[1])
        c = a[0, k] + rng.uniform() * (b[0, k] - a[0, k])
        pts = c + rng.normal(size=(rng.integers(1, 7), 3)) * 0.12
        prob = ctl.problem(Q0, x, np.zeros(3), pts)
        res = ctl.step(Q0, x, np.zeros(3), pts)
        if res.feasible:
            continue
        checked += 1

        def cost(qd, prob=prob):
            return float(np.sum(np.maximum(prob.G @ qd - prob.h, 0.0) ** 2))

        samples = rng.uniform(prob.lb, prob.ub, size=(500, prob.lb.size))
        best = min(cost(np.zeros_like(res.qd)), min(cost(s) for s in samples))
        assert cost(res.qd) <= best * (1 + 1e-6) + 1e-9
        assert np.all(res.qd >= prob.lb - 1e-9) and np.all(res.qd <= prob.ub + 1e-9)
    assert checked >= 10
