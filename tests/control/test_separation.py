"""ISO/TS 15066 protective separation: the terms against a hand-worked example, the stopping table, and the
controller with ``separation`` set (per-point S_p from the covariance, retreat inside S_p, a poorly
calibrated unit keeps the robot farther away)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from skincal.control import (
    ApproachSpeedTable,
    AvoidanceController,
    ControllerConfig,
    SeparationParams,
    StoppingModel,
    allowed_approach_speed,
    approach_speed_bound,
    approach_speed_slope,
    protective_separation,
    ramp_width,
)
from skincal.errors import ConfigError
from skincal.kinematics import panda
from skincal.perception import (
    ObstaclePoints,
    PerceptionConfig,
    ProximityTracker,
    RobotBody,
    SkinUncertainty,
    body_proximity,
    unit_rays,
)
from skincal.skin import SkinUnitPose
from skincal.skin.placement import frame_from_normal
from skincal.skin.tof import TofModel

Q0 = np.array([0.0, -0.3, 0.0, -2.2, 0.0, 2.0, np.pi / 4])
TABLE = StoppingModel([0.0, 0.5, 1.0], [0.0, 0.2, 0.3], [0.0, 0.05, 0.15], reaction_time_s=0.1)
PARAMS = SeparationParams(
    human_speed_mps=1.6, intrusion_m=0.05, robot_position_uncertainty_m=0.01, sigma_level=3.0, stopping=TABLE
)


def test_terms_against_a_hand_worked_example():
    # Point 0: robot toward it at v_r = 0.5 m/s (a table entry: T_s = 0.2 s, S_s = 0.05 m), person at the
    #   design speed v_h = 1.6 m/s, std 0.02 m along the normal (Z_d = 3 * 0.02 = 0.06 m):
    #   S_h = 1.6 (0.1 + 0.2) = 0.48, S_r = 0.5 * 0.1 = 0.05, S_s = 0.05, C = 0.05, Z_d = 0.06, Z_r = 0.01
    #   S_p = 0.48 + 0.05 + 0.05 + 0.05 + 0.06 + 0.01 = 0.70 m
    # Point 1: v_r = 0.75 (half-way 0.5..1.0: T_s = 0.25 s, S_s = 0.10 m), measured approach 2.0 m/s > 1.6:
    #   S_h = 2.0 (0.1 + 0.25) = 0.70, S_r = 0.075, S_s = 0.10, C = 0.05, Z_d = 0, Z_r = 0.01 -> S_p = 0.935 m
    # Point 2: robot moving away (v_r = -0.3 counts as 0), a slower measured approach (1.0 < 1.6):
    #   S_h = 1.6 * 0.1 = 0.16, S_r = S_s = 0 -> S_p = 0.16 + 0.05 + 0.01 = 0.22 m
    t = protective_separation(PARAMS, [0.5, 0.75, -0.3], [0.0, 2.0, 1.0], [0.06, 0.0, 0.0])
    np.testing.assert_allclose(t.S_h, [0.48, 0.70, 0.16], atol=1e-12)
    np.testing.assert_allclose(t.S_r, [0.05, 0.075, 0.0], atol=1e-12)
    np.testing.assert_allclose(t.S_s, [0.05, 0.10, 0.0], atol=1e-12)
    np.testing.assert_allclose(t.C, 0.05)
    np.testing.assert_allclose(t.Z_d, [0.06, 0.0, 0.0])
    np.testing.assert_allclose(t.Z_r, 0.01)
    np.testing.assert_allclose(t.total, [0.70, 0.935, 0.22], atol=1e-12)
    assert t.at(1)["S_p"] == pytest.approx(0.935)
    # without measured speeds the design speed is used for every point
    np.testing.assert_allclose(protective_separation(PARAMS, [0.75], None, [0.0]).S_h, [1.6 * 0.35])


def test_stopping_table_interpolates_and_extrapolates():
    np.testing.assert_allclose(TABLE.stopping_time([0.0, 0.25, 0.5, 0.75, 1.0]), [0, 0.1, 0.2, 0.25, 0.3])
    # beyond the table: the last slope (0.2 s and 0.2 m per m/s)
    assert TABLE.stopping_time(1.5) == pytest.approx(0.4)
    assert TABLE.stopping_distance(1.5) == pytest.approx(0.25)
    assert TABLE.stopping_distance(-1.0) == 0.0
    cd = StoppingModel.constant_deceleration(2.0, 0.05, v_max=2.0, n=41)
    assert cd.stopping_time(1.0) == pytest.approx(0.5)
    assert cd.stopping_distance(1.0) == pytest.approx(0.25)  # v^2 / 2a on a table entry
    again = StoppingModel.from_dict(cd.to_dict())
    np.testing.assert_array_equal(again.distances, cd.distances)
    assert again.reaction_time_s == 0.05
    p = SeparationParams.from_dict(PARAMS.to_dict())
    assert p.to_dict() == PARAMS.to_dict()
    # configs with a table compare and hash by value (arrays inside)
    assert again == cd and hash(again) == hash(cd) and again != TABLE
    assert ControllerConfig(separation=p) == ControllerConfig(separation=PARAMS) != ControllerConfig()
    assert hash(ControllerConfig(separation=p)) == hash(ControllerConfig(separation=PARAMS))
    assert SeparationParams.from_dict({"human_speed_mps": 2.0}).human_speed_mps == 2.0


@pytest.mark.adversarial
@pytest.mark.parametrize(
    "bad",
    [
        {"speeds_mps": [0.1, 1.0], "times_s": [0, 1], "distances_m": [0, 1], "reaction_time_s": 0.1},
        {"speeds_mps": [0, 1.0], "times_s": [0, 1], "distances_m": [0, 1, 2], "reaction_time_s": 0.1},
        {"speeds_mps": [0, 1.0], "times_s": [0, 1], "distances_m": [1, 0], "reaction_time_s": 0.1},
        {"speeds_mps": [0, 1.0], "times_s": [0, "x"], "distances_m": [0, 1], "reaction_time_s": 0.1},
        {"speeds_mps": [0, 1.0], "times_s": [0, 1], "distances_m": [0, float("nan")], "reaction_time_s": 0.1},
        {"speeds_mps": [0, 1.0], "times_s": [0, 1], "distances_m": [0, 1], "reaction_time_s": -1},
        {"speeds_mps": [0, 1.0], "times_s": [0, 1], "distances_m": [0, 1], "reaction_time_s": True},
        {"speeds_mps": [0, 1.0], "times_s": [0, 1], "distances_m": [0, 1]},
        {"speeds_mps": [0, 1.0], "times_s": [0, 1], "distances_m": [0, 1], "reaction_time_s": 0, "x\n": 1},
        [1, 2],
    ],
)
def test_bad_stopping_model_is_one_line_config_error(bad):
    with pytest.raises(ConfigError) as err:
        StoppingModel.from_dict(bad)
    assert "\n" not in str(err.value)


@pytest.mark.adversarial
@pytest.mark.parametrize("bad", [{"sigma_level": -1}, {"human_speed_mps": float("inf")}, {"stopping": 3}, 5])
def test_bad_separation_params_are_refused(bad):
    with pytest.raises(ConfigError):
        SeparationParams.from_dict(bad)
    with pytest.raises(ConfigError):
        ControllerConfig(separation="fast")  # type: ignore[arg-type]


def forearm_point(ctl: AvoidanceController, gap: float) -> np.ndarray:
    """A point ``gap`` m from the padded forearm (the long capsule of link 4), straight out along +y at Q0."""
    a, b = ctl.body.segments(ctl.chain.link_frames(Q0))
    k = int(np.argmax(np.where(ctl.body.link == 4, np.linalg.norm(b[0] - a[0], axis=1), 0.0)))
    return 0.5 * (a[0, k] + b[0, k]) + np.array([0.0, 1.0, 0.0]) * (ctl.body.radius[k] + gap)


def padded_distance(chain, q, p) -> float:
    return float(
        body_proximity(RobotBody.of(chain).inflated(ControllerConfig().padding), chain.link_frames(q), p).distance[0]
    )


def test_per_point_margin_from_covariance_and_robot_speed():
    chain = panda()
    cfg = ControllerConfig(separation=PARAMS)
    ctl = AvoidanceController(chain, cfg)
    p = forearm_point(ctl, 0.6)
    cov = np.diag([1e-4, 4e-4, 9e-4])  # std 2 cm along the normal (+y)
    pts = ObstaclePoints(
        p[None], ("su",), np.zeros(1), np.zeros(1), np.zeros((1, 3)), np.zeros((1, 3)), np.zeros(1), cov[None]
    )
    x = chain.flange_pose(Q0)[0, :3, 3]
    prob = ctl.problem(Q0, x, np.zeros(3), pts, qd_now=np.zeros(7))
    # robot still: S_p = 1.6 * 0.1 + 0 + 0 + 0.05 + 3 * 0.02 + 0.01 = 0.28 m
    assert prob.critical[0] == pytest.approx(0.28, abs=1e-9)
    w = ramp_width(cfg.critical, cfg.notice)

    def b(gap):
        return float(approach_speed_bound(gap, 0.0, cfg.notice, cfg.v_max, w))

    def s_p(v):
        return float(protective_separation(PARAMS, [v], [0.0], [0.06]).total[0])

    # the row allows the speed that keeps its own S_p: v* = b(d - S_p(v*)) (a fixed point), below the
    # bound at rest b(d - 0.28), since approaching faster needs a larger margin
    d = float(prob.distance[0])
    v_star = float(prob.h[0])
    assert 0 < v_star < b(d - 0.28) - 0.05
    assert v_star == pytest.approx(b(d - s_p(v_star)), abs=0.007) and v_star <= b(d - s_p(v_star)) + 1e-12
    # the robot moving toward the point at v_r = 0.5 m/s (S_h = 0.48, S_r = 0.05, S_s = 0.05): 0.70 m
    qd = np.linalg.lstsq(prob.G, [0.5], rcond=None)[0]
    moving = ctl.problem(Q0, x, np.zeros(3), pts, qd_now=qd)
    assert moving.critical[0] == pytest.approx(0.70, abs=1e-9)
    assert moving.terms.at(0)["S_r"] == pytest.approx(0.05)
    assert moving.h[0] == pytest.approx(b(d - 0.70))  # from 0.5 m/s the robot must first slow down
    # the step reports S_p at the command's speed toward the point, or the present speed when larger
    res = ctl.step(Q0, x, np.zeros(3), pts, qd_now=qd)
    assert res.margin == pytest.approx(0.70) and res.terms is not None
    assert res.clearance == pytest.approx(res.min_distance - 0.70)
    fast = ctl.step(Q0, x, np.array([0.0, 3.0, 0.0]), pts)  # the task drives the arm at the point
    v_cmd = float(prob.G[0] @ fast.qd)
    assert v_cmd == pytest.approx(v_star, abs=1e-6)  # the row is active
    assert fast.margin == pytest.approx(s_p(v_cmd))


def test_still_point_inside_the_separation_makes_the_robot_retreat():
    chain = panda()
    ctl = AvoidanceController(chain, ControllerConfig(separation=PARAMS))
    p = forearm_point(ctl, 0.12)  # S_p of a still robot here is 0.22 m (no covariance)
    x = chain.flange_pose(Q0)[0, :3, 3]
    xd_des = np.array([0.0, 0.3, 0.0])  # the task pulls the arm toward the point
    res = ctl.step(Q0, x, xd_des, p[None], qd_now=np.zeros(7))
    assert res.feasible and res.margin == pytest.approx(0.22)
    b = float(approach_speed_bound(0.12, 0.22, ctl.config.notice, ctl.config.v_max, ramp_width(0.25, 1.0)))
    assert b < 0
    h = 1e-6
    rate = (padded_distance(chain, Q0 + h * res.qd, p) - padded_distance(chain, Q0, p)) / h
    assert rate >= -b - 1e-3 and rate > 0.05  # it moves away, at least as fast as the bound asks
    # the same point with the fixed critical distance of 0.1 m: no retreat (only approach limited)
    fixed = AvoidanceController(chain, ControllerConfig(critical=0.1)).step(Q0, x, xd_des, p[None])
    assert (padded_distance(chain, Q0 + h * fixed.qd, p) - padded_distance(chain, Q0, p)) / h < 0
    # in closed loop it backs off to S_p and holds there
    q, d = Q0.copy(), []
    for _ in range(1500):
        r = ctl.step(q, x, np.zeros(3), p[None])
        assert r.feasible
        q = q + r.qd * ctl.config.dt
        d.append(padded_distance(chain, q, p))
    assert d[-1] == pytest.approx(0.22, abs=0.01) and min(d) > 0.12 - 1e-6


def _unit_facing(chain, q, target) -> SkinUnitPose:
    """A unit on link 4 whose +z axis points at ``target`` (base frame) at ``q``."""
    T = chain.link_frames(q)[0, 4]
    origin_link = np.array([0.0, 0.0, 0.0])
    o = T[:3, :3] @ origin_link + T[:3, 3]
    axis_link = T[:3, :3].T @ (target - o)
    return SkinUnitPose(
        4, frame_from_normal((axis_link / np.linalg.norm(axis_link))[None], np.zeros(1))[0], origin_link
    )


def test_poorly_calibrated_unit_widens_the_margin_and_keeps_the_robot_away():
    chain = panda()
    ctl0 = AvoidanceController(chain, ControllerConfig(separation=PARAMS))
    target = forearm_point(ctl0, 0.3)
    pose = _unit_facing(chain, Q0, target)
    o, a = unit_rays(chain, pose, Q0[None])
    r = float(np.linalg.norm(target - o[0]))
    final, z_d, s_p = [], [], []
    for pos_std, rot_deg in [(0.001, 0.1), (0.02, 3.0)]:
        cov6 = np.diag([pos_std**2] * 3 + [np.radians(rot_deg) ** 2] * 3)
        unc = SkinUncertainty({"su": cov6}, TofModel(noise_std=0.005, noise_std_per_m=0.005))
        tracker = ProximityTracker(chain, {"su": pose}, PerceptionConfig(), uncertainty=unc)
        tracker.update(0.0, Q0, {"su": r})
        pts = replace(tracker.points(0.0), spread=np.zeros(1))  # on the axis: the covariance alone differs
        np.testing.assert_allclose(pts.positions[0], target, atol=1e-9)
        ctl = AvoidanceController(chain, ControllerConfig(separation=PARAMS))
        res = ctl.step(Q0, chain.flange_pose(Q0)[0, :3, 3], np.zeros(3), pts, qd_now=np.zeros(7))
        z_d.append(res.terms.Z_d[0])
        s_p.append(res.margin)
        # the task drives the forearm at the (still) point; it stops at its S_p
        q = Q0.copy()
        x = chain.flange_pose(Q0)[0, :3, 3]
        for _ in range(2000):
            q = q + ctl.step(q, x + np.array([0.0, 0.3, 0.0]), np.zeros(3), pts).qd * ctl.config.dt
        final.append(padded_distance(chain, q, target))
    assert z_d[1] > 3 * z_d[0] and s_p[1] - s_p[0] == pytest.approx(z_d[1] - z_d[0])
    assert final[1] > final[0] + 0.5 * (z_d[1] - z_d[0])
    assert final[0] >= s_p[0] - 0.01 and final[1] >= s_p[1] - 0.01


def test_separation_none_ignores_covariance_and_reports_the_fixed_margin():
    chain = panda()
    ctl = AvoidanceController(chain, ControllerConfig())
    p = np.array([forearm_point(ctl, 0.3), forearm_point(ctl, 0.5)])
    x = chain.flange_pose(Q0)[0, :3, 3]
    zero = ctl.step(Q0, x, np.array([0.0, 0.3, 0.0]), ObstaclePoints.still(p))
    k = len(p)
    wide = ObstaclePoints(
        p,
        ("a", "b"),
        np.zeros(k),
        np.zeros(k),
        np.zeros((k, 3)),
        np.zeros((k, 3)),
        np.zeros(k),
        np.repeat(np.eye(3)[None], k, axis=0),
    )
    res = ctl.step(Q0, x, np.array([0.0, 0.3, 0.0]), wide, qd_now=np.ones(7))
    np.testing.assert_array_equal(res.qd, zero.qd)
    assert res.terms is None and res.margin == ctl.config.critical
    assert res.clearance == pytest.approx(0.3 - ctl.config.critical)
    assert np.isnan(ctl.step(Q0, x, np.zeros(3), np.zeros((0, 3))).margin)


def _bisection_fixed_point(params, d, v_now, v_h, z_d, bound):
    """Reference ``u*``: 60 halvings of ``u + a <= b(d - S_p(max(u, v_now)))`` (slow and sure), ``a = max(v_h, 0)``
    the point's approach speed."""

    def g(v):
        return bound(d - protective_separation(params, np.maximum(v, v_now), v_h, z_d).total)[0] - np.maximum(v_h, 0)

    v0 = np.maximum(v_now, 0.0)
    b0 = g(v0)
    lo, hi = v0.copy(), np.maximum(b0, v0)
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        ok = mid <= g(mid)
        lo, hi = np.where(ok, mid, lo), np.where(ok, hi, mid)
    return np.where(b0 <= v0, b0, lo)


@pytest.mark.parametrize(
    "stopping",
    [TABLE, StoppingModel.constant_deceleration(4.0, 0.05), StoppingModel.constant_deceleration(1.0, 0.2)],
)
def test_allowed_speed_is_never_above_the_fixed_point_and_close_to_it(stopping):
    params = SeparationParams(stopping=stopping)
    w = ramp_width(0.25, 1.0)

    def bound(gap):
        return approach_speed_bound(gap, 0.0, 1.0, 1.0, w), approach_speed_slope(gap, 1.0, w)

    rng = np.random.default_rng(3)
    K = 3000
    d = rng.uniform(-0.1, 2.5, K)
    v_now = rng.uniform(-0.5, 1.5, K) * (rng.uniform(size=K) < 0.3)
    v_h = np.where(rng.uniform(size=K) < 0.5, 0.0, rng.uniform(0.0, 5.0, K))  # half at the design speed
    z_d = rng.uniform(0.0, 0.1, K)
    ref = _bisection_fixed_point(params, d, v_now, v_h, z_d, bound)
    exact = allowed_approach_speed(params, d, v_now, v_h, z_d, bound, 16)
    assert np.all(exact <= ref + 1e-9) and np.max(ref - exact) < 1e-3
    table = ApproachSpeedTable(params, bound)(d, v_now, v_h, z_d)
    assert np.all(table <= ref + 1e-9)
    still = (v_h <= 0) & (v_now <= 0)  # a still point at the design speed and a still robot: the table's grid
    assert np.max((ref - table)[still]) < 0.01  # the table's e step (2 mm) times the ramp's slope, at most
    receding = (v_h <= params.human_speed_mps) & (v_h <= 0)
    assert np.max((ref - table)[receding]) < 0.01  # a receding point or a moving robot when c0 <= v0 is exact
    # a person coming, or faster than the design speed: max(V - a, v0) or the v_h step, cautious but close
    assert np.median(ref - table) < 1e-3 and np.max(ref - table) < 0.5
    # inside S_p at rest the answer is the (negative) bound itself: retreat
    inside = ref < 0
    assert inside.any()
    np.testing.assert_allclose(table[inside], ref[inside], atol=0.01)


def test_step_benchmark_runs_feasible_problems_with_covariances():
    """The benchmark's problem is the one it claims (no timing asserted here: benchmarks/bench_qp.py)."""
    from skincal.bench.qp import benchmark_points, format_qp_benchmark, qp_step_benchmark

    pts = benchmark_points(panda(), 30)
    assert len(pts) == 30 and np.all(pts.spread > 0) and np.all(np.linalg.norm(pts.velocities, axis=1) > 0)
    assert np.all(np.linalg.eigvalsh(pts.cov)[:, 0] > 0)  # every point with a proper covariance
    res = qp_step_benchmark(n_points=30, repeats=3)
    for mode in ("fixed", "separation"):
        assert res[mode]["rows"] > 20 and res[mode]["feasible_fraction"] == 1.0
    assert "separation / fixed" in format_qp_benchmark(res)


def test_separation_speed_keeps_a_tracking_transient_out_of_the_margin():
    """Torque mode: S_p takes the command the robot tracks, the measured speed counted up to the tracking
    tolerance from it. Tracking (within tolerance): the measured speed itself. A 1.2 m/s transient toward the
    point while the arm is commanded away: the margin stays that of the command plus the tolerance (the raw
    measured speed, as the loop passed it before, makes it jump by about half a metre)."""
    from skincal.control.separation import TRACKING_TOLERANCE_RADPS, separation_speed

    cmd = np.array([0.5, -0.2, 0.0, 1.0, 0.0, 0.0, -0.3])
    near = cmd + np.array([0.05, -0.08, 0.0, 0.02, -0.1, 0.0, 0.09])
    np.testing.assert_array_equal(separation_speed(near, cmd), near)
    far = cmd + np.array([2.0, -3.0, 0.0, 0.0, 0.0, 0.5, 0.0])
    tol = TRACKING_TOLERANCE_RADPS
    np.testing.assert_allclose(separation_speed(far, cmd), cmd + [tol, -tol, 0, 0, 0, tol, 0], atol=1e-15)
    np.testing.assert_array_equal(far, cmd + np.array([2.0, -3.0, 0.0, 0.0, 0.0, 0.5, 0.0]))  # inputs untouched
    # a command the arm has not followed yet is not its speed: never above the measured one
    lagging = 0.3 * cmd
    np.testing.assert_array_equal(separation_speed(lagging, cmd), lagging)
    # measured one way, commanded the other: up to the tolerance
    np.testing.assert_allclose(separation_speed(-cmd, cmd), np.clip(-cmd, -tol, tol), atol=1e-15)

    chain = panda()
    ctl = AvoidanceController(chain, ControllerConfig(separation=PARAMS))
    p = forearm_point(ctl, 0.6)
    x = chain.flange_pose(Q0)[0, :3, 3]
    g = ctl.problem(Q0, x, np.zeros(3), p[None], qd_now=np.zeros(7)).G[0]
    u = g / np.dot(g, g)
    away = -0.2 * u  # commanded: away from the point at 0.2 m/s
    measured = 1.2 * u  # the arm still moving toward it at 1.2 m/s (a transient)
    raw = ctl.step(Q0, x, np.zeros(3), p[None], qd_now=measured)
    cut = ctl.step(Q0, x, np.zeros(3), p[None], qd_now=separation_speed(measured, away))
    v_cut = float(g @ separation_speed(measured, away))
    assert v_cut <= np.abs(g).sum() * tol + 1e-12  # commanded away: toward it at most the tolerance
    assert cut.margin == pytest.approx(float(protective_separation(PARAMS, [v_cut], [0.0], [0.0]).total[0]))
    assert raw.margin > cut.margin + 0.4
