"""The analytic simulator against independent computations of the same physics."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from skincal.data.dataset import DYNAMIC, STATIC
from skincal.data.hdf5 import read_dataset, write_dataset
from skincal.kinematics import GRAVITY_BASE, panda, sawyer, transform_points
from skincal.protocol import ProtocolConfig, build_trajectory
from skincal.sim.analytic import simulate
from skincal.skin.imu import ImuModel, get_imu_model
from skincal.skin.pose import SkinUnitPose

SHORT = ProtocolConfig(
    n_poses=2, amplitude=1.2, excite_duration=1.0, rest_duration=1.0, static_duration=0.5, name="short"
)


def placements(chain):
    return {
        "a": SkinUnitPose.from_dh6(2, [0.3, 0.05, -0.4, 0.06, 0.02, 1.3]),
        "b": SkinUnitPose.from_dh6(chain.n_joints - 1, [-1.2, -0.03, 0.8, 0.05, 0.01, 1.7]),
        "c": SkinUnitPose.from_dh6(chain.n_joints, [2.0, 0.02, 0.1, 0.04, 0.0, 1.57]),
    }


@pytest.fixture(scope="module", params=["panda", "sawyer"])
def session(request):
    chain = {"panda": panda, "sawyer": sawyer}[request.param]()
    rng = np.random.default_rng(3)
    traj = build_trajectory(chain, SHORT, rng)
    ds = simulate(chain, placements(chain), traj, get_imu_model("none"), rng)
    return chain, traj, ds


def fd_specific_force(chain, traj, pose, t, h=1e-4):
    """Specific force from second differences of the unit's FK position (no link_motion)."""

    def x(tt):
        q, _, _ = traj.evaluate(tt)
        return transform_points(chain.link_frames(q)[:, pose.link], pose.p_link_su)

    a = (x(t + h) - 2 * x(t) + x(t - h)) / h**2
    q, _, _ = traj.evaluate(t)
    R_base_su = chain.link_frames(q)[:, pose.link, :3, :3] @ pose.R_link_su
    return np.einsum("nji,nj->ni", R_base_su, a - GRAVITY_BASE)


def test_static_reading_is_gravity_in_unit_frame(session):
    chain, traj, ds = session
    for name, pose in ds.truth.items():
        stream = ds.imu[name]
        idx = np.searchsorted(ds.segments.t_start, stream.t, side="right") - 1
        ok = idx >= 0
        static = ok & (ds.segments.kind[np.clip(idx, 0, None)] == STATIC) & (stream.t <= ds.segments.t_end[idx])
        assert static.sum() > 20
        q, qd, _ = traj.evaluate(stream.t[static])
        assert np.abs(qd).max() == 0.0
        R_base_su = chain.link_frames(q)[:, pose.link, :3, :3] @ pose.R_link_su
        expected = np.einsum("nji,j->ni", R_base_su, [0.0, 0.0, 9.81])
        np.testing.assert_allclose(stream.accel[static], expected, atol=1e-12)


def test_dynamic_reading_matches_second_differences(session):
    chain, traj, ds = session
    for name, pose in ds.truth.items():
        stream = ds.imu[name]
        t = stream.t[(stream.t > traj.t[0] + 0.01) & (stream.t < traj.t[-1] - 0.01)]
        t = t[:: max(1, t.size // 400)]
        # The sine excitations start with a jump in qdd; second differences across it are invalid.
        smooth = np.abs(traj.evaluate(t + 2e-4)[2] - traj.evaluate(t - 2e-4)[2]).max(axis=1) < 1e-2
        t = t[smooth]
        sel = np.isin(stream.t, t)
        np.testing.assert_allclose(stream.accel[sel], fd_specific_force(chain, traj, pose, t), atol=2e-5)
    assert np.any(ds.segments.kind == DYNAMIC)


def test_gyro_is_link_rate_in_unit_frame(session):
    chain, traj, ds = session
    pose = ds.truth["b"]
    t = ds.imu["b"].t[::50]
    h = 1e-6
    q_p, _, _ = traj.evaluate(t + h)
    q_m, _, _ = traj.evaluate(t - h)
    R_p = chain.link_frames(q_p)[:, pose.link, :3, :3] @ pose.R_link_su
    R_m = chain.link_frames(q_m)[:, pose.link, :3, :3] @ pose.R_link_su
    W = np.einsum("nji,njk->nik", R_m, R_p)  # R(t-h)^T R(t+h) ~ I + [w]_x 2h in the unit frame
    w_fd = np.stack([W[:, 2, 1] - W[:, 1, 2], W[:, 0, 2] - W[:, 2, 0], W[:, 1, 0] - W[:, 0, 1]], axis=1) / (4 * h)
    np.testing.assert_allclose(ds.imu["b"].gyro[np.isin(ds.imu["b"].t, t)], w_fd, atol=1e-6)


def test_latency_shifts_the_measured_motion():
    chain = panda()
    rng = np.random.default_rng(5)
    traj = build_trajectory(chain, SHORT, rng)
    pl = {"a": placements(chain)["b"]}
    late = simulate(chain, pl, traj, ImuModel(rate_hz=100.0, latency_s=0.015), np.random.default_rng(1))
    stream = late.imu["a"]
    assert late.truth_sensor["a"]["time_offset_s"] == pytest.approx(0.015)
    ideal_at_true = fd_specific_force(chain, traj, pl["a"], stream.t[50:300] - 0.015)
    np.testing.assert_allclose(stream.accel[50:300], ideal_at_true, atol=2e-5)
    ideal_at_stamp = fd_specific_force(chain, traj, pl["a"], stream.t[50:300])
    assert np.abs(stream.accel[50:300] - ideal_at_stamp).max() > 1e-2  # the offset is visible


def test_seeded_and_round_trips_through_hdf5(tmp_path):
    chain = panda()
    traj = build_trajectory(chain, SHORT, np.random.default_rng(0))
    model = replace(get_imu_model("realistic"))
    a = simulate(chain, placements(chain), traj, model, np.random.default_rng(9))
    b = simulate(chain, placements(chain), traj, model, np.random.default_rng(9))
    c = simulate(chain, placements(chain), traj, model, np.random.default_rng(10))
    np.testing.assert_array_equal(a.imu["a"].accel, b.imu["a"].accel)
    assert a.imu["a"].accel.shape != c.imu["a"].accel.shape or np.any(a.imu["a"].accel != c.imu["a"].accel)
    path = tmp_path / "sim.h5"
    write_dataset(a, path)
    back = read_dataset(path)
    np.testing.assert_array_equal(back.imu["c"].accel, a.imu["c"].accel)
    np.testing.assert_allclose(back.truth["c"].T_link_su, a.truth["c"].T_link_su, atol=1e-15)
    np.testing.assert_allclose(back.truth_sensor["a"]["accel_bias"], a.truth_sensor["a"]["accel_bias"])
