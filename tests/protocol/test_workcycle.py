"""Everyday motion (issue 16, item 4): pick-and-place and teleoperation on any robot, within its limits,
collision-free, with rests at pick and place, accepted by the simulators."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from skincal.data import STATIC
from skincal.errors import ConfigError
from skincal.kinematics import PRESETS, get_robot
from skincal.protocol.collision import CollisionModel
from skincal.protocol.limits import acceleration_bounds, position_bounds
from skincal.protocol.workcycle import (
    WORK_CYCLES,
    WorkCycleConfig,
    pick_and_place,
    via_quintic_coef,
    work_cycle,
)

SHORT = WorkCycleConfig(duration_s=20.0, rate_hz=200.0)


def test_via_quintic_meets_its_boundary_states():
    x0, v0, x1, v1, T = np.array([0.1, -0.3]), np.array([0.5, 0.0]), np.array([0.7, 0.2]), np.array([-0.2, 0.4]), 1.3
    c = via_quintic_coef(x0, v0, x1, v1, T)
    P = np.polynomial.polynomial
    for j in range(2):
        d1, d2 = P.polyder(c[j]), P.polyder(c[j], 2)
        np.testing.assert_allclose(
            [P.polyval(0, c[j]), P.polyval(0, d1), P.polyval(0, d2)], [x0[j], v0[j], 0], atol=1e-12
        )
        np.testing.assert_allclose(
            [P.polyval(T, c[j]), P.polyval(T, d1), P.polyval(T, d2)], [x1[j], v1[j], 0], atol=1e-12
        )


@pytest.mark.parametrize("robot", sorted(PRESETS))
@pytest.mark.parametrize("kind", WORK_CYCLES)
def test_any_robot_within_limits_and_collision_free(robot, kind):
    chain = get_robot(robot)
    traj = work_cycle(chain, kind, np.random.default_rng(5), SHORT)
    assert traj.duration >= SHORT.duration_s
    lo, hi = position_bounds(chain)
    assert np.all(traj.q >= lo + SHORT.limit_margin - 1e-9) and np.all(traj.q <= hi - SHORT.limit_margin + 1e-9)
    if chain.velocity_limit is not None:
        assert np.all(np.abs(traj.qd) <= chain.velocity_limit * (1 + 1e-9))
    assert np.all(np.abs(traj.qdd) <= acceleration_bounds(chain, traj.config) * (1 + 1e-9) + 1e-9)
    t = np.arange(0.0, traj.duration, 0.02)
    assert CollisionModel(chain).free(traj.evaluate(t)[0]).all()
    # several joints move at once somewhere (not a one-joint-at-a-time protocol)
    assert np.max(np.sum(np.abs(traj.qd) > 0.05, axis=1)) >= 3


@pytest.mark.parametrize("kind", WORK_CYCLES)
def test_smooth_position_velocity_acceleration(kind):
    traj = work_cycle(get_robot("panda"), kind, np.random.default_rng(2), SHORT)
    inner = traj.knots[1:-1]
    eps = 1e-7
    before, after = traj.evaluate(inner - eps), traj.evaluate(inner + eps)
    for a, b, tol in zip(before, after, (1e-5, 1e-4, 1e-3), strict=True):
        np.testing.assert_allclose(a, b, atol=tol)


def test_pick_and_place_rests_at_pick_and_place_and_repeats():
    cfg = replace(SHORT, duration_s=40.0)
    traj = pick_and_place(get_robot("panda"), np.random.default_rng(9), cfg)
    seg = traj.segments
    assert np.all(seg.kind == STATIC) and np.all(seg.joint == -1)
    # the robot is at rest over every STATIC segment, at the pose it lists
    for k in range(len(seg)):
        t = np.linspace(seg.t_start[k], seg.t_end[k], 7)
        q, qd, qdd = traj.evaluate(t)
        assert np.abs(qd).max() == 0 and np.abs(qdd).max() == 0
        np.testing.assert_allclose(q, np.broadcast_to(traj.poses[seg.pose[k]], q.shape), atol=1e-12)
    # pick, place and home rests per cycle: pick/place rests last pick_rest_s/place_rest_s
    lengths = (seg.t_end - seg.t_start) + 2 * min(cfg.settle_s, cfg.pick_rest_s / 4)
    assert np.sum(np.isclose(lengths, cfg.pick_rest_s)) >= 4  # at least two cycles' pick and place
    # pick poses vary from cycle to cycle, by about jitter_rad
    picks = traj.poses[np.isclose(lengths, cfg.pick_rest_s)][0::2]
    spread = np.std(picks, axis=0).mean()
    assert 0 < spread < 5 * cfg.jitter_rad


def test_deterministic_for_a_seed():
    chain = get_robot("ur5e")
    a = work_cycle(chain, "teleop", np.random.default_rng(4), SHORT)
    b = work_cycle(chain, "teleop", np.random.default_rng(4), SHORT)
    c = work_cycle(chain, "teleop", np.random.default_rng(5), SHORT)
    np.testing.assert_array_equal(a.q, b.q)
    assert a.q.shape != c.q.shape or not np.array_equal(a.q, c.q)


def test_simulators_accept_it_and_the_dataset_calibrates():
    from skincal.calib import calibrate
    from skincal.sim import simulate
    from skincal.workflows.session import make_session

    session = make_session("panda", "paper", noise="none", protocol="fast", seed=1)
    traj = work_cycle(session.chain, "teleop", np.random.default_rng(1), WorkCycleConfig(duration_s=25.0))
    ds = simulate(replace(session, trajectory=traj))
    np.testing.assert_array_equal(ds.joints.t, traj.t)
    res = calibrate(ds, "mle", units=["su3", "su6"])
    for u in ("su3", "su6"):
        assert res.units[u].pose.link == ds.truth[u].link
        assert np.linalg.norm(res.units[u].pose.p_link_su - ds.truth[u].p_link_su) < 1e-4


@pytest.mark.adversarial
@pytest.mark.parametrize(
    "bad",
    [
        dict(duration_s=0.0),
        dict(rate_hz=float("nan")),
        dict(pause_probability=1.5),
        dict(speed_range=(1.0, 0.5)),
        dict(tangent_range=(0.0, 2.0)),
        dict(limit_margin=-0.1),
        dict(pause_range_s=(0.0, 1.0)),
    ],
)
def test_bad_config_is_a_config_error(bad):
    with pytest.raises(ConfigError):
        WorkCycleConfig(**bad)


def test_unknown_kind_is_named():
    with pytest.raises(ConfigError, match="unknown work cycle 'dance'"):
        work_cycle(get_robot("panda"), "dance", np.random.default_rng(0))
