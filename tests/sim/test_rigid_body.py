"""The hand-moved rigid-body simulator: exact signals against finite differences of the motion."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from skincal.errors import ConfigError
from skincal.kinematics.chain import GRAVITY_BASE
from skincal.sim.rigid_body import HandMotion, rigid_body_matrix, simulate_rigid_bodies, unit_truth
from skincal.skin.imu import get_imu_model


def _pose(rotvec, p) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec(rotvec).as_matrix()
    T[:3, 3] = p
    return T


def test_unit_signals_match_finite_differences_of_the_motion():
    motion = HandMotion.random(np.random.default_rng(4))
    T = _pose([0.4, -1.0, 0.7], [0.12, -0.05, 0.2])
    t = np.linspace(1.0, 9.0, 41)
    f, w = unit_truth(motion, T, t)
    h = 1e-3

    def unit_position(tt):
        return motion.position(tt) + motion.rotation(tt) @ T[:3, 3]

    a_fd = (unit_position(t + h) - 2 * unit_position(t) + unit_position(t - h)) / h**2
    R_su = motion.rotation(t) @ T[:3, :3]
    f_fd = np.einsum("mji,mj->mi", R_su, a_fd - GRAVITY_BASE)
    np.testing.assert_allclose(f, f_fd, atol=2e-4)
    hr = 1e-5
    dR = (motion.rotation(t + hr) @ T[:3, :3] - motion.rotation(t - hr) @ T[:3, :3]) / (2 * hr)
    W = np.einsum("mji,mjk->mik", R_su, dR)
    np.testing.assert_allclose(w, np.stack([W[:, 2, 1], W[:, 0, 2], W[:, 1, 0]], axis=1), atol=1e-5)


def test_position_equation_holds_for_two_units_of_one_body():
    """``R f_j - f_ref = ([dw]x + [w]x^2) r`` in the reference unit's frame (the method's equation)."""
    motion = HandMotion.random(np.random.default_rng(5))
    T_ref, T_j = _pose([0.1, 0.2, 0.3], [0.0, 0.05, 0.0]), _pose([1.0, 0.0, -0.5], [0.2, 0.0, 0.03])
    t = np.linspace(0.5, 19.5, 200)
    f_ref, w_ref = unit_truth(motion, T_ref, t)
    f_j, _ = unit_truth(motion, T_j, t)
    T_rel = np.linalg.inv(T_ref) @ T_j
    R, r = T_rel[:3, :3], T_rel[:3, 3]
    h = 1e-4
    dw = (unit_truth(motion, T_ref, t + h)[1] - unit_truth(motion, T_ref, t - h)[1]) / (2 * h)
    lhs = f_j @ R.T - f_ref
    np.testing.assert_allclose(lhs, rigid_body_matrix(w_ref, dw) @ r, atol=1e-5)
    assert np.sqrt(np.mean(lhs**2)) > 0.5  # the rigid-body terms are there to be measured


def test_hand_motion_has_hand_amplitudes():
    motion = HandMotion.random(np.random.default_rng(0), rate_rms=1.5, accel_rms=5.0)
    t = np.linspace(0, 60, 6000)
    _, w, _, a = motion.state(t)
    assert 1.0 < np.sqrt(np.mean(np.sum(w**2, axis=1))) < 2.2
    assert 3.0 < np.sqrt(np.mean(np.sum(a**2, axis=1))) < 7.5
    singular = np.linalg.svd(w - w.mean(axis=0), compute_uv=False)
    assert singular[2] > 0.2 * singular[0]  # about every axis


def test_rotation_about_one_axis_stays_on_it():
    axis = np.array([0.0, 0.6, 0.8])
    motion = HandMotion.random(np.random.default_rng(1), rotation_axes=axis)
    w = motion.angular_velocity(np.linspace(0, 10, 500))
    R0_axis = axis  # rotation vector along axis: body-frame rate along R0-independent axis
    assert np.max(np.linalg.norm(np.cross(w, R0_axis), axis=1)) < 1e-6


def test_dataset_has_no_joints_and_body_truth():
    rng = np.random.default_rng(2)
    motions = {"hand": HandMotion.random(rng), "other": HandMotion.random(rng)}
    T = _pose([0, 0, 1.0], [0.2, 0, 0])
    ds = simulate_rigid_bodies(
        {"su1": ("hand", np.eye(4)), "su2": ("hand", T), "su3": ("other", np.eye(4))}, motions, 5.0,
        get_imu_model("real"), rng,
    )  # fmt: skip
    assert ds.joints is None and ds.robot is None and not ds.has_joints
    assert ds.truth_body["su2"].body == "hand" and ds.truth_body["su3"].body == "other"
    np.testing.assert_array_equal(ds.truth_body["su2"].T_body_su, T)
    for stream in ds.imu.values():
        assert np.all(np.diff(stream.t) > 0) and stream.gyro is not None and 250 < len(stream.t) <= 313
    assert set(ds.truth_sensor["su1"]) >= {"accel_bias", "gyro_bias", "time_offset_s"}


def test_unknown_body_is_refused():
    with pytest.raises(ConfigError, match="body 'arm'"):
        simulate_rigid_bodies({"su1": ("arm", np.eye(4))}, {}, 1.0, get_imu_model("none"), np.random.default_rng(0))


def test_turn_over_motion_holds_still_in_orientations_spread_over_the_sphere():
    """The "turn it over" motion: exactly still inside each hold (|f| = g), the holds' gravity directions
    spread over the sphere, a hand's rates between them, and exact signals (finite differences of the
    motion, away from the ends of the ramps, where the envelope's third derivative jumps)."""
    motion = HandMotion.turn_over(np.random.default_rng(6), 30.0, holds=10, hold_s=1.2)
    assert motion.hold_times.shape == (10, 2)
    np.testing.assert_allclose(np.diff(motion.hold_times, axis=1), 1.2)
    T = _pose([0.3, 0.2, -0.4], [0.1, -0.05, 0.02])
    t = np.linspace(0.05, 29.95, 2000)
    f, w = unit_truth(motion, T, t)
    still = motion.still(t)
    assert still.sum() > 700 and np.all(w[still] == 0.0)
    np.testing.assert_allclose(np.linalg.norm(f[still], axis=1), 9.81, atol=1e-9)
    assert 1.0 < np.sqrt(np.mean(np.sum(w[~still] ** 2, axis=1))) < 3.0
    ups, _ = unit_truth(motion, np.eye(4), motion.hold_times.mean(axis=1))
    ups /= np.linalg.norm(ups, axis=1, keepdims=True)
    assert np.linalg.svd(ups, compute_uv=False).min() > 0.5 * np.sqrt(10 / 3)  # no plane, no cone
    assert np.min(np.arccos(np.clip(ups @ ups.T - 2 * np.eye(10), -1, 1))) > np.radians(30)  # all distinct
    edges = np.concatenate([motion.hold_times.ravel() + d for d in (-motion.ramp_s, 0.0, motion.ramp_s)])
    away = np.min(np.abs(t[:, None] - edges[None]), axis=1) > 0.01
    h = 1e-3

    def unit_position(tt):
        return motion.position(tt) + motion.rotation(tt) @ T[:3, 3]

    a_fd = (unit_position(t + h) - 2 * unit_position(t) + unit_position(t - h)) / h**2
    f_fd = np.einsum("mji,mj->mi", motion.rotation(t) @ T[:3, :3], a_fd - GRAVITY_BASE)
    np.testing.assert_allclose(f[away], f_fd[away], atol=1e-3)


def test_turn_over_refuses_holds_that_do_not_fit():
    with pytest.raises(ConfigError, match="do not fit in 10 s"):
        HandMotion.turn_over(np.random.default_rng(0), 10.0, holds=8, hold_s=1.5)
    with pytest.raises(ConfigError, match="holds >= 1"):
        HandMotion.turn_over(np.random.default_rng(0), 10.0, holds=0)
