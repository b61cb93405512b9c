"""The next best motion (skincal.protocol.design) and the segment pieces it builds on (protocol)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from skincal.errors import ConfigError
from skincal.kinematics import get_robot
from skincal.protocol import build_trajectory, concatenate_trajectories
from skincal.protocol.design import (
    DesignOptions,
    build_segment,
    candidate_poses,
    d_optimal_gain,
    excitable,
    segment_config,
)
from skincal.protocol.limits import check_limits, position_bounds


@pytest.fixture(scope="module")
def panda():
    return get_robot("panda")


@pytest.fixture(scope="module")
def config(panda):
    return segment_config(panda)


# ------------------------------------------------------------------ protocol pieces


def test_start_adds_the_move_and_equal_start_adds_none(panda, config):
    q0 = np.array([0.0, -0.3, 0.0, -2.0, 0.0, 1.8, 0.7])
    q1 = q0 + np.array([0.3, 0.2, -0.2, 0.3, 0.1, -0.2, 0.4])
    plain = build_trajectory(panda, replace(config, excited_joints=(3,)), poses=q1[None])
    moved = build_trajectory(panda, replace(config, excited_joints=(3,)), poses=q1[None], start=q0)
    still = build_trajectory(panda, replace(config, excited_joints=(3,)), poses=q1[None], start=q1)
    assert still.duration == pytest.approx(plain.duration)
    assert moved.duration > plain.duration + 0.5
    q, qd, _ = moved.evaluate([0.0, moved.duration])
    np.testing.assert_allclose(q[0], q0, atol=1e-12)
    np.testing.assert_allclose(q[1], q1, atol=1e-12)
    np.testing.assert_allclose(qd, 0.0, atol=1e-12)
    # the segments of the moved one are the plain one's, shifted by the move
    shift = moved.duration - plain.duration
    np.testing.assert_allclose(moved.segments.t_start, plain.segments.t_start + shift)


def test_concatenation_is_continuous_and_shifts_segments(panda, config):
    q0 = np.array([0.0, -0.3, 0.0, -2.0, 0.0, 1.8, 0.7])
    q1 = q0 + np.array([0.3, 0.2, -0.2, 0.3, 0.1, -0.2, 0.4])
    a = build_segment(panda, config, q0, q0, 5, check=False)
    b = build_segment(panda, config, q0, q1, 1, check=False)
    c = build_segment(panda, config, q1, q1, 6, check=False)
    whole = concatenate_trajectories([a, b, c])
    assert whole.duration == pytest.approx(a.duration + b.duration + c.duration)
    assert list(whole.segments.joint) == [-1, 5, -1, 1, -1, 6]
    assert list(whole.segments.pose) == [0, 0, 1, 1, 2, 2]
    np.testing.assert_allclose(whole.segments.t_start[2:4], b.segments.t_start + a.duration)
    # each part evaluates the same in the whole, shifted
    tau = np.linspace(0.0, b.duration, 77)
    for x, y in zip(whole.evaluate(tau + a.duration), b.evaluate(tau), strict=True):
        np.testing.assert_allclose(x, y, atol=1e-9)
    t = np.linspace(0.0, whole.duration, 200001)
    q, qd, _ = whole.evaluate(t)
    assert np.abs(np.diff(q, axis=0)).max() < 1e-3  # continuous positions (no jump at the joins)
    assert np.abs(np.diff(qd, axis=0)).max() < 1e-2
    assert whole.t[-1] == pytest.approx(whole.duration, abs=1.0 / config.rate_hz)


def test_concatenation_refuses_a_gap(panda, config):
    q0 = np.array([0.0, -0.3, 0.0, -2.0, 0.0, 1.8, 0.7])
    a = build_segment(panda, config, q0, q0, 5, check=False)
    b = build_segment(panda, config, q0 + 0.1, q0 + 0.1, 1, check=False)
    with pytest.raises(ConfigError, match="does not start where"):
        concatenate_trajectories([a, b])
    with pytest.raises(ConfigError):
        concatenate_trajectories([])


# ------------------------------------------------------------------ limits


def test_excitable_matches_the_limit_check(panda, config):
    """A joint is offered for excitation exactly where its segment stays within the limits."""
    lower, upper = position_bounds(panda)
    rng = np.random.default_rng(3)
    q = rng.uniform(lower, upper, size=(40, panda.n_joints))
    ok = excitable(panda, config, q)
    assert ok.any() and not ok.all()
    for k in range(q.shape[0]):
        for j in (1, 3, 6):
            try:
                traj = build_segment(panda, config, q[k], q[k], j, check=False)
                check_limits(panda, traj.t, traj.q, traj.qd, margin=config.limit_margin)
                inside = True
            except Exception:  # ProtocolError: leaves the limits
                inside = False
            assert ok[k, j] == inside, (k, j)


def test_candidate_poses_are_collision_free_and_within_limits(panda, config):
    from skincal.protocol.collision import CollisionModel

    rng = np.random.default_rng(0)
    visited = np.array([[0.0, -0.3, 0.0, -2.0, 0.0, 1.8, 0.7]])
    poses = candidate_poses(panda, config, visited, rng, DesignOptions(pose_candidates=5, pose_pool=40))
    assert poses.shape == (5, panda.n_joints)
    lower, upper = position_bounds(panda)
    assert np.all(poses >= lower + config.limit_margin) and np.all(poses <= upper - config.limit_margin)
    assert CollisionModel(panda).free(poses).all()


# ------------------------------------------------------------------ D-optimal gain


def test_d_optimal_gain_matches_brute_force_log_det():
    rng = np.random.default_rng(7)
    A = rng.normal(size=(6, 9))
    info = A @ A.T
    B = rng.normal(size=(6, 2))
    added = B @ B.T  # rank 2: only two directions gain
    prior = DesignOptions().prior
    brute = np.log(np.linalg.det(info + prior + added)) - np.log(np.linalg.det(info + prior))
    assert d_optimal_gain(info, added, prior) == pytest.approx(brute, rel=1e-10)
    # and through the eigenvalues of the whitened update: sum log(1 + lambda)
    L = np.linalg.cholesky(info + prior)
    W = np.linalg.solve(L, np.linalg.solve(L, added).T)
    assert d_optimal_gain(info, added, prior) == pytest.approx(np.sum(np.log1p(np.linalg.eigvalsh(W))), rel=1e-9)
    assert d_optimal_gain(info, np.zeros((6, 6)), prior) == 0.0
    # invariant to the units of the parameters (rad vs mrad, m vs mm)
    S = np.diag([1e3, 1e3, 1e3, 1e3, 1e3, 1e3 * 1e3])
    assert d_optimal_gain(S @ info @ S, S @ added @ S) == pytest.approx(d_optimal_gain(info, added), rel=1e-8)


def test_d_optimal_gain_refuses_a_singular_information():
    with pytest.raises(ConfigError, match="positive definite"):
        d_optimal_gain(np.zeros((6, 6)), np.eye(6))


def test_realized_gain_is_the_log_det_change_of_units_on_the_same_link():
    from skincal.protocol.design import realized_gain

    rng = np.random.default_rng(11)
    A, B = rng.normal(size=(6, 8)), rng.normal(size=(6, 3))
    before = {"a": (3, A @ A.T), "b": (2, np.eye(6)), "c": (4, np.eye(6))}
    after = {"a": (3, A @ A.T + B @ B.T), "b": (5, 4 * np.eye(6))}  # b changed its link, c is gone
    prior = DesignOptions().prior
    brute = np.log(np.linalg.det(A @ A.T + B @ B.T + prior)) - np.log(np.linalg.det(A @ A.T + prior))
    weights = {"a": 0.5, "b": 1.0, "c": 1.0}
    assert realized_gain(before, after, weights) == pytest.approx(0.5 * brute, rel=1e-9)
