"""Data-collection protocol: timeline, exact evaluation, limits, presets and export."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from skincal.data import DYNAMIC, STATIC
from skincal.errors import ConfigError, DatasetError, ProtocolError
from skincal.kinematics import panda, sawyer, ur5e
from skincal.protocol import (
    PROTOCOLS,
    ProtocolConfig,
    build_trajectory,
    export_trajectory,
    get_protocol,
    pose_box,
    protocol_duration,
    read_trajectory_csv,
    read_trajectory_json,
    sample_static_poses,
)
from skincal.protocol.motion import hermite_quintic_coef, stop_duration

REAL_F = (0.75, 0.25, 0.35, 0.55, 0.75, 0.9, 0.9)


@pytest.fixture(scope="module")
def chain():
    return panda()


@pytest.fixture(scope="module")
def real_like(chain):
    """paper-real frequencies (no whole periods in 3 s: every joint needs a stop), short rests."""
    cfg = replace(get_protocol("paper-real"), n_poses=2, rest_duration=0.6, static_duration=0.4, rate_hz=500.0)
    return build_trajectory(chain, cfg, np.random.default_rng(11))


@pytest.fixture(scope="module")
def sim_like(chain):
    """paper-sim motion (3 whole periods per joint: no stop) on two poses."""
    cfg = replace(get_protocol("paper-sim"), n_poses=2, rate_hz=400.0)
    return build_trajectory(chain, cfg, np.random.default_rng(5))


def _away_from_knots(traj, t, gap):
    d = np.min(np.abs(t[:, None] - traj.knots[None, :]), axis=1)
    return t[d > gap]


@pytest.mark.parametrize("name", ["real_like", "sim_like"])
def test_sampled_derivatives_match_central_differences(name, request):
    traj = request.getfixturevalue(name)
    dt = 1.0 / traj.config.rate_hz
    i = np.arange(1, traj.t.size - 1)
    # central differences are valid where no knot lies within one sample
    d = np.min(np.abs(traj.t[i, None] - traj.knots[None, :]), axis=1)
    i = i[d > 1.5 * dt]
    qd_fd = (traj.q[i + 1] - traj.q[i - 1]) / (2 * dt)
    qdd_fd = (traj.qd[i + 1] - traj.qd[i - 1]) / (2 * dt)
    # truncation error h^2/6 |q'''| with |q'''| <= A w^2 ~ 80 rad/s^3 (and |q''''| ~ 500) at these rates
    np.testing.assert_allclose(traj.qd[i], qd_fd, atol=2e-4 * (500 / traj.config.rate_hz) ** 2)
    np.testing.assert_allclose(traj.qdd[i], qdd_fd, atol=2e-3 * (500 / traj.config.rate_hz) ** 2)
    assert np.abs(traj.qdd).max() > 1.0  # the check is not vacuous


def test_evaluate_exact_derivatives_at_random_times(real_like):
    traj = real_like
    t = np.random.default_rng(0).uniform(0, traj.duration, 3000)
    t = _away_from_knots(traj, t, 1e-4)
    h = 1e-5
    q_p, qd_p, _ = traj.evaluate(t + h)
    q_m, qd_m, _ = traj.evaluate(t - h)
    _, qd, qdd = traj.evaluate(t)
    np.testing.assert_allclose((q_p - q_m) / (2 * h), qd, atol=1e-7)
    np.testing.assert_allclose((qd_p - qd_m) / (2 * h), qdd, atol=1e-6)


def test_evaluate_equals_samples_and_is_continuous(real_like):
    traj = real_like
    q, qd, qdd = traj.evaluate(traj.t[::-1])  # any order
    np.testing.assert_allclose(q[::-1], traj.q, atol=1e-13)
    np.testing.assert_allclose(qd[::-1], traj.qd, atol=1e-12)
    np.testing.assert_allclose(qdd[::-1], traj.qdd, atol=1e-12)
    eps = 1e-9
    inner = traj.knots[1:-1]
    qa, qda, qdda = traj.evaluate(inner - eps)
    qb, qdb, qddb = traj.evaluate(inner + eps)
    np.testing.assert_allclose(qa, qb, atol=1e-7)
    np.testing.assert_allclose(qda, qdb, atol=1e-6)
    # acceleration jumps only where a sine starts (by 2 pi f A on the excited joint)
    sine_start = np.isin(inner, traj.segments.t_start[traj.segments.kind == DYNAMIC])
    np.testing.assert_allclose(qdda[~sine_start], qddb[~sine_start], atol=1e-5)
    jump = np.abs(qddb - qdda)[sine_start].max(axis=1)
    A, f = 2.0, np.array(REAL_F)
    np.testing.assert_allclose(np.sort(jump), np.sort(np.tile(2 * np.pi * f * A, 2)), rtol=1e-6)
    # outside [0, T] the robot rests at the first/last pose
    q0, qd0, _ = traj.evaluate(np.array([-1.0, traj.duration + 5.0]))
    np.testing.assert_allclose(q0, traj.poses[[0, -1]], atol=1e-12)
    assert np.all(qd0 == 0)


def test_dynamic_segments_follow_the_paper_formula(real_like):
    traj, seg = real_like, real_like.segments
    A, f = 2.0, np.array(REAL_F)
    for s in np.flatnonzero(seg.kind == DYNAMIC):
        j, p = seg.joint[s], seg.pose[s]
        tau = np.linspace(0, traj.config.excite_duration, 301)
        q, qd, qdd = traj.evaluate(seg.t_start[s] + tau)
        w = 2 * np.pi * f[j]
        q0 = traj.poses[p]
        np.testing.assert_allclose(qd[:, j], A * np.sin(w * tau), atol=1e-9)
        np.testing.assert_allclose(q[:, j], q0[j] + A / w * (1 - np.cos(w * tau)), atol=1e-9)
        np.testing.assert_allclose(qdd[:, j], A * w * np.cos(w * tau), atol=1e-8)
        others = np.arange(7) != j
        np.testing.assert_allclose(q[:, others], np.broadcast_to(q0[others], (tau.size, 6)), atol=1e-12)
        assert np.all(qd[:, others] == 0)
        # after the stop the joint is back on its pose, at rest, before the next segment
        t_back = seg.t_end[s] + stop_duration(A, f[j], traj.config.excite_duration) + traj.config.rest_duration
        assert t_back <= (seg.t_start[s + 1] if s + 1 < len(seg) else traj.duration) + 1e-9
        q1, qd1, qdd1 = traj.evaluate(np.array([t_back - 1e-6]))
        np.testing.assert_allclose(q1[0], q0, atol=1e-9)
        assert np.abs(qd1).max() < 1e-9 and np.abs(qdd1).max() < 1e-9


def test_segment_timing_matches_config(real_like, sim_like):
    for traj in (real_like, sim_like):
        cfg, seg = traj.config, traj.segments
        P, n = cfg.n_poses, 7
        assert len(seg) == P * (1 + n)
        kinds = np.tile([STATIC] + [DYNAMIC] * n, P)
        np.testing.assert_array_equal(seg.kind, kinds)
        np.testing.assert_array_equal(seg.pose, np.repeat(np.arange(P), 1 + n))
        np.testing.assert_array_equal(seg.joint, np.tile([-1] + list(range(n)), P))
        dur = seg.t_end - seg.t_start
        np.testing.assert_allclose(dur[seg.kind == STATIC], cfg.static_duration, atol=1e-9)
        np.testing.assert_allclose(dur[seg.kind == DYNAMIC], cfg.excite_duration, atol=1e-9)
        gap = seg.t_start[1:] - seg.t_end[:-1]
        assert np.all(gap >= -1e-9)
        assert np.all(gap[seg.kind[:-1] == DYNAMIC] >= cfg.rest_duration - 1e-9)  # a rest after every excitation
        # the static window is centred in the first rest at a pose: (rest - static) / 2 before the first sine
        np.testing.assert_allclose(gap[seg.kind[:-1] == STATIC], (cfg.rest_duration - cfg.static_duration) / 2)
        # the static window: robot at rest exactly on its pose
        for s in np.flatnonzero(seg.kind == STATIC):
            inside = (traj.t >= seg.t_start[s]) & (traj.t <= seg.t_end[s])
            np.testing.assert_allclose(traj.q[inside], np.broadcast_to(traj.poses[seg.pose[s]], (inside.sum(), n)))
            assert np.all(traj.qd[inside] == 0) and np.all(traj.qdd[inside] == 0)
        # sampling grid at the configured rate
        np.testing.assert_allclose(np.diff(traj.t), 1 / cfg.rate_hz, rtol=1e-9)


def test_whole_periods_need_no_stop_and_duration_formula(chain):
    assert stop_duration(2.0, 1.0, 3.0) == 0.0
    assert stop_duration(2.0, 0.25, 3.0) > 0.0
    cfg = replace(get_protocol("paper-sim"), n_poses=3, move_duration=4.0, rate_hz=100.0)
    traj = build_trajectory(chain, cfg, np.random.default_rng(2))
    # P (rest + n (excite + rest)) + (P - 1) move, exactly
    assert traj.duration == pytest.approx(3 * (2 + 7 * 5) + 2 * 4.0, abs=1e-9)
    assert protocol_duration(cfg, 7) == pytest.approx(traj.duration, abs=1e-9)
    real = replace(get_protocol("paper-real"), n_poses=2, move_duration=5.0, rate_hz=100.0)
    assert protocol_duration(real, 7) == pytest.approx(build_trajectory(chain, real, np.random.default_rng(1)).duration)


def test_stop_is_a_smooth_hermite():
    # independent check of the Hermite coefficients: end conditions by polynomial derivatives
    c = hermite_quintic_coef(0.7, -1.3, 2.1, 0.2, 1.7)
    P = np.polynomial.Polynomial(c)
    assert P(0) == pytest.approx(0.7) and P.deriv()(0) == pytest.approx(-1.3) and P.deriv(2)(0) == pytest.approx(2.1)
    assert P(1.7) == pytest.approx(0.2) and abs(P.deriv()(1.7)) < 1e-12 and abs(P.deriv(2)(1.7)) < 1e-12


@pytest.mark.parametrize("traj_name", ["real_like", "sim_like"])
def test_samples_within_limits(traj_name, request, chain):
    traj = request.getfixturevalue(traj_name)
    m = traj.config.limit_margin
    assert np.all(traj.q >= chain.joint_lower + m - 1e-12) and np.all(traj.q <= chain.joint_upper - m + 1e-12)
    assert np.all(np.abs(traj.qd) <= chain.velocity_limit + 1e-12)


def test_sample_static_poses_seeded_and_leave_room(chain):
    cfg = get_protocol("paper-real")
    a = sample_static_poses(chain, 50, np.random.default_rng(4), cfg)
    b = sample_static_poses(chain, 50, np.random.default_rng(4), cfg)
    np.testing.assert_array_equal(a, b)
    assert a.shape == (50, 7)
    # the sine's full sweep 2 A / w (f * 3 s >= 1/2 here) fits above every pose
    A, f = 2.0, np.array(REAL_F)
    top = a + 2 * A / (2 * np.pi * f)
    assert np.all(top <= chain.joint_upper - cfg.limit_margin + 1e-9)
    assert np.all(a >= chain.joint_lower + cfg.limit_margin)
    lo, hi = pose_box(chain, cfg)
    assert np.all(a >= lo) and np.all(a <= hi)
    # the full paper-real protocol builds on the Panda and stays under the paper's 30 minutes
    assert protocol_duration(cfg, 7) < 30 * 60


def test_user_poses_in_config(chain):
    poses = np.array([[0.0, 0.0, 0.0, -1.8, 0.0, 1.2, 0.0], [0.3, -0.4, 0.2, -2.0, 0.1, 1.5, -0.2]])
    cfg = ProtocolConfig(poses=poses, excited_joints=(1, 3), rest_duration=0.5, static_duration=0.5, rate_hz=200.0)
    assert cfg.n_poses == 2
    traj = build_trajectory(chain, cfg)
    np.testing.assert_array_equal(traj.poses, poses)
    np.testing.assert_array_equal(traj.segments.joint, [-1, 1, 3, -1, 1, 3])
    np.testing.assert_allclose(traj.q[0], poses[0])
    np.testing.assert_allclose(traj.q[-1], poses[1])


def test_impossible_protocols_raise_protocol_error_naming_the_joint(chain):
    too_fast = ProtocolConfig(amplitude=(2.0, 2.0, 2.0, 2.5, 2.0, 2.0, 2.0), n_poses=1)
    with pytest.raises(ProtocolError, match="joint 4: excitation amplitude 2.500 rad/s exceeds"):
        build_trajectory(chain, too_fast, np.random.default_rng(0))
    too_wide = ProtocolConfig(frequency=(1.0, 0.1, 1.0, 1.0, 1.0, 1.0, 1.0), n_poses=1)
    with pytest.raises(ProtocolError, match="joint 2: its excitation sweeps"):
        build_trajectory(chain, too_wide, np.random.default_rng(0))
    # a user pose near joint 4's upper limit: the sine (which moves up by up to 2A/w) leaves the limits
    pose = np.array([[0.0, 0.0, 0.0, -0.3, 0.0, 1.2, 0.0]])
    cfg = ProtocolConfig(poses=pose, excited_joints=(3,), rest_duration=0.5, static_duration=0.5, rate_hz=200.0)
    with pytest.raises(ProtocolError, match=r"joint 4 would reach -0\.\d+ rad at t=\d+\.\d+ s \(limit -0\.0698"):
        build_trajectory(chain, cfg)
    # Sawyer's joint 1 (1.74 rad/s) cannot do 2 rad/s
    with pytest.raises(
        ProtocolError, match="joint 1: excitation amplitude 2.000 rad/s exceeds the velocity limit 1.740"
    ):
        build_trajectory(sawyer(), get_protocol("paper-sim"), np.random.default_rng(0))


def test_config_validation_and_presets():
    assert set(PROTOCOLS) == {"paper-sim", "paper-real", "fast"}
    real = get_protocol("paper-real")
    assert real.frequency == REAL_F and real.rest_duration == 10.0 and real.n_poses == 12
    sim = get_protocol("paper-sim")
    assert (sim.amplitude, sim.frequency, sim.excite_duration, sim.rest_duration, sim.n_poses) == (
        2.0,
        1.0,
        3.0,
        2.0,
        16,
    )
    with pytest.raises(ConfigError, match="paper-sim, paper-real"):
        get_protocol("paper")
    with pytest.raises(ConfigError, match="static_duration"):
        ProtocolConfig(static_duration=3.0, rest_duration=2.0)
    with pytest.raises(ConfigError, match="frequency"):
        ProtocolConfig(frequency=-1.0)
    with pytest.raises(ConfigError, match="6 joints"):
        build_trajectory(ur5e(), real, np.random.default_rng(0))
    with pytest.raises(ConfigError, match="rng"):
        build_trajectory(panda(), sim)
    again = ProtocolConfig.from_dict(json.loads(json.dumps(real.to_dict())))
    assert again.to_dict() == real.to_dict()
    with pytest.raises(ConfigError, match="unknown protocol field"):
        ProtocolConfig.from_dict({"amplitudes": 1.0})


def test_export_round_trips(real_like, tmp_path):
    traj = real_like
    csv = export_trajectory(traj, tmp_path / "traj.csv")
    header = csv.read_text().splitlines()[0]
    assert header == "t," + ",".join(f"q{i}" for i in range(1, 8)) + "," + ",".join(f"qd{i}" for i in range(1, 8))
    t, q, qd = read_trajectory_csv(csv)
    np.testing.assert_array_equal(t, traj.t)
    np.testing.assert_array_equal(q, traj.q)
    np.testing.assert_array_equal(qd, traj.qd)
    js = export_trajectory(traj, tmp_path / "traj.json")
    doc = json.loads(js.read_text())
    assert doc["format"] == "skincal-protocol" and doc["config"]["name"] == "paper-real"
    back = read_trajectory_json(js)
    np.testing.assert_array_equal(back.segments.t_start, traj.segments.t_start)
    np.testing.assert_array_equal(back.segments.kind, traj.segments.kind)
    np.testing.assert_allclose(back.q, traj.q, atol=1e-12)
    np.testing.assert_allclose(back.qdd, traj.qdd, atol=1e-12)
    tt = np.linspace(-1, traj.duration + 1, 777)
    np.testing.assert_allclose(back.evaluate(tt)[1], traj.evaluate(tt)[1], atol=1e-12)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["traj.csv", "traj.json"]  # no temporaries left
    with pytest.raises(ConfigError, match=r"use \.csv, \.json, \.yaml, \.bag"):
        export_trajectory(traj, tmp_path / "traj.txt")
    (tmp_path / "bad.json").write_text('{"format": "other"}')
    with pytest.raises(DatasetError, match="bad.json: field 'format'"):
        read_trajectory_json(tmp_path / "bad.json")


def test_failed_export_keeps_old_file(real_like, tmp_path, monkeypatch):
    target = tmp_path / "traj.csv"
    target.write_text("old")

    def boom(*args, **kwargs):
        raise OSError("disk full")

    monkeypatch.setattr(np, "savetxt", boom)
    with pytest.raises(OSError, match="disk full"):
        export_trajectory(real_like, target)
    assert target.read_text() == "old"
    assert [p.name for p in tmp_path.iterdir()] == ["traj.csv"]


def test_fast_protocol_fits_every_preset_robot_under_two_minutes():
    """The fast preset scales its amplitudes to each robot's velocity limits."""
    from skincal.kinematics import panda, sawyer, ur5e

    config = get_protocol("fast")
    for chain in (panda(), sawyer(), ur5e()):
        traj = build_trajectory(chain, config, np.random.default_rng(0))
        assert traj.duration < 120.0
        assert np.all(np.abs(traj.qd).max(axis=0) <= chain.velocity_limit + 1e-9)
        assert np.abs(traj.qd).max() > 0.85 * chain.velocity_limit.min()


@pytest.mark.parametrize("seed", [101, 115])
def test_a_pose_no_collision_free_move_leaves_is_drawn_again(seed):
    """Issue 27: the Sawyer's `fast` sessions of seeds 101 and 115 (``benchmark mle``'s placements 2 and 16)
    failed with 'no collision-free static pose found in 200 draws': the pose before was a dead end that no
    collision-free move leaves. The uniform draw now draws that pose again; the motion is collision-free."""
    from skincal.protocol.collision import CollisionModel
    from skincal.workflows.session import make_session

    session = make_session("sawyer", "random", 6, "realistic", "fast", seed, joints="controller")
    traj = session.trajectory
    assert traj.poses.shape[0] == 6
    model = CollisionModel(session.chain)
    assert model.free(traj.q[::10]).all()


def test_a_velocity_fraction_protocol_on_a_chain_without_velocity_limits_names_the_way_out():
    """A URDF with one joint's ``<limit velocity="0">`` has no velocity limits as a chain: ``fast`` cannot scale
    its amplitudes and says why, and which presets need none."""
    from skincal.kinematics.urdf import chain_from_urdf

    limit = '<limit lower="-1" upper="1" velocity="{}" effort="1"/>'
    joint = '<joint name="j{0}" type="revolute"><parent link="l{1}"/><child link="l{0}"/><axis xyz="0 0 1"/>{2}</joint>'
    text = ('<robot name="r"><link name="l0"/><link name="l1"/><link name="l2"/>'
            + joint.format(1, 0, limit.format(2)) + joint.format(2, 1, limit.format(0)) + "</robot>")  # fmt: skip
    chain = chain_from_urdf(text=text)
    assert chain.velocity_limit is None
    with pytest.raises(ConfigError, match=r"every joint's <limit velocity> is above 0.*\(paper-sim, paper-real\)"):
        get_protocol("fast").for_chain(chain)
    get_protocol("paper-sim").for_chain(chain)  # fixed amplitudes: no velocity limits needed
