"""Obstacle-point covariance: Jacobians against finite differences, the propagated covariance against Monte
Carlo sampling of the pose, range and joint errors, the result's std convention, and the tracker's ``cov``."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from skincal.data.result import CalibrationResult, UnitResult
from skincal.errors import ConfigError
from skincal.kinematics import panda
from skincal.perception import (
    PerceptionConfig,
    ProximityTracker,
    SkinUncertainty,
    assumed_pose_covariance,
    point_covariance,
    points_from_streams,
    pose_jacobian,
    reading_covariance,
    unit_pose_covariance,
    unit_rays,
)
from skincal.skin import SkinUnitPose
from skincal.skin.placement import paper_placement
from skincal.skin.tof import TofModel

Q0 = np.array([0.0, -0.3, 0.0, -2.2, 0.0, 2.0, np.pi / 4])


def exact_point(T_bl, pose: SkinUnitPose, r, dp=0.0, dtheta=None):
    """The base-frame point with the pose errors of the module's convention applied exactly (no
    linearisation): ``p_ls + dp``, ``Exp(dtheta) R_ls``; batched over leading axes of ``T_bl`` (..., 4, 4),
    ``dp``, ``dtheta`` (..., 3)."""
    R_ls = pose.R_link_su
    if dtheta is not None:
        R_ls = (
            Rotation.from_rotvec(np.reshape(dtheta, (-1, 3))).as_matrix().reshape(*np.shape(dtheta)[:-1], 3, 3) @ R_ls
        )
    p_ls = pose.p_link_su + np.asarray(dp)
    p_link = p_ls + np.asarray(r)[..., None] * R_ls[..., :, 2]
    return np.einsum("...ij,...j->...i", T_bl[..., :3, :3], p_link) + T_bl[..., :3, 3]


def random_pose(rng, link=5) -> SkinUnitPose:
    return SkinUnitPose(
        link, Rotation.random(random_state=rng.integers(1 << 31)).as_matrix(), rng.normal(size=3) * 0.05
    )


def test_pose_jacobian_matches_finite_differences(rng):
    chain = panda()
    for _ in range(5):
        pose, r = random_pose(rng), rng.uniform(0.1, 1.2)
        T = chain.link_frames(rng.uniform(-1, 1, 7))[0, pose.link]
        J = pose_jacobian(T[None, :3, :3], pose.R_link_su[None], [r])[0]
        h = 1e-6
        for k in range(7):
            e = np.zeros(7)
            e[k] = h

            def f(s, e=e, T=T, pose=pose, r=r):
                return exact_point(T, pose, r + s * e[6], s * e[:3], s * e[3:6])

            np.testing.assert_allclose((f(1.0) - f(-1.0)) / (2 * h), J[:, k], atol=1e-8)


def test_joint_jacobians_per_configuration_match_finite_differences(rng):
    """Batched form (each point at its own configuration) of the point Jacobian, against the chain moved."""
    chain = panda()
    pose = random_pose(rng, link=6)
    q = rng.uniform(-1, 1, size=(4, 7))
    T = chain.link_frames(q)
    p = exact_point(T[:, pose.link], pose, 0.5)
    J = chain.point_jacobians(T, np.full(4, pose.link), p)
    h = 1e-6
    for j in range(7):
        dq = np.zeros(7)
        dq[j] = h
        fd = (
            exact_point(chain.link_frames(q + dq)[:, pose.link], pose, 0.5)
            - exact_point(chain.link_frames(q - dq)[:, pose.link], pose, 0.5)
        ) / (2 * h)
        np.testing.assert_allclose(fd, J[:, :, j], atol=1e-8)
    assert np.all(J[:, :, pose.link :] == 0)  # joints beyond the unit's link do not move it


def test_covariance_matches_monte_carlo():
    """20000 draws of pose error (correlated, link axes), range noise with rounding, and joint noise."""
    rng = np.random.default_rng(7)
    chain = panda()
    pose = SkinUnitPose(5, Rotation.from_euler("xyz", [20, -30, 60], degrees=True).as_matrix(), [0.03, -0.02, 0.08])
    std = np.array([0.003, 0.004, 0.002, np.radians(1.0), np.radians(2.0), np.radians(0.5)])
    corr = np.eye(6)
    corr[0, 4] = corr[4, 0] = 0.5  # x and ry correlated, as a fit with a short lever gives
    corr[1, 2] = corr[2, 1] = -0.3
    cov6 = corr * np.outer(std, std)
    tof = TofModel(noise_std=0.005, noise_std_per_m=0.005, resolution_m=0.03)  # a coarse rounding: its term shows
    unc = SkinUncertainty({"su": cov6}, tof, joint_std_rad=4e-3)
    r = 0.6
    T = chain.link_frames(Q0)[0]
    p0 = exact_point(T[pose.link], pose, r)
    pred = reading_covariance(chain, T, [pose.link], pose.R_link_su[None], [r], p0[None], cov6[None], unc)[0]

    N = 20000
    d = rng.multivariate_normal(np.zeros(6), cov6, size=N)
    dr = tof.noise_std_at(r) * rng.normal(size=N) + rng.uniform(-0.5, 0.5, N) * tof.resolution_m
    q = Q0 + 4e-3 * rng.normal(size=(N, 7))
    p = exact_point(chain.link_frames(q)[:, pose.link], pose, r + dr, d[:, :3], d[:, 3:])
    sample = np.cov(p.T)
    err = np.linalg.norm(sample - pred) / np.linalg.norm(pred)
    assert err < 0.03
    np.testing.assert_allclose(np.linalg.eigvalsh(sample), np.linalg.eigvalsh(pred), rtol=0.05)
    # each source matters here (else the test would not check its term): drop one, the match breaks
    no_rounding = TofModel(noise_std=0.005, noise_std_per_m=0.005)
    for fewer in (SkinUncertainty({"su": cov6}, tof), SkinUncertainty({"su": cov6}, no_rounding, joint_std_rad=4e-3)):
        c = reading_covariance(chain, T, [pose.link], pose.R_link_su[None], [r], p0[None], cov6[None], fewer)[0]
        assert np.linalg.norm(sample - c) / np.linalg.norm(pred) > 3 * err


def test_point_covariance_without_joint_noise_is_pose_and_range_only(rng):
    pose, r = random_pose(rng), 0.4
    R_bl = Rotation.random(random_state=3).as_matrix()
    cov6 = np.diag([1e-6, 4e-6, 9e-6, 1e-4, 2e-4, 3e-4])
    c = point_covariance(R_bl[None], pose.R_link_su[None], [r], cov6[None], [0.0])[0]
    J = pose_jacobian(R_bl[None], pose.R_link_su[None], [r])[0, :, :6]
    np.testing.assert_allclose(c, J @ cov6 @ J.T, atol=1e-18)
    # the ray direction is unaffected by a rotation about it and by the position error only
    ray = R_bl @ pose.R_link_su[:, 2]
    c_r = point_covariance(R_bl[None], pose.R_link_su[None], [r], np.zeros((1, 6, 6)), [1e-4])[0]
    np.testing.assert_allclose(c_r, 1e-4 * np.outer(ray, ray), atol=1e-18)


def _unit(pos_std, rot_std, pose_covariance=None) -> UnitResult:
    pose = SkinUnitPose(3, np.eye(3), [0.0, 0.0, 0.1])
    return UnitResult(pose, True, pos_std, rot_std, pose_covariance=pose_covariance)


def test_result_std_becomes_the_pose_covariance_and_missing_std_the_assumed_one():
    cfg = PerceptionConfig(assumed_position_std_m=0.01, assumed_rotation_std_deg=3.0)
    cov = unit_pose_covariance(_unit([1e-3, 2e-3, 3e-3], [0.1, 0.2, 0.3]), cfg)
    np.testing.assert_allclose(np.diag(cov), [1e-6, 4e-6, 9e-6, *np.radians([0.1, 0.2, 0.3]) ** 2])
    assumed = np.diag(assumed_pose_covariance(cfg))
    np.testing.assert_allclose(assumed, [1e-4] * 3 + [np.radians(3.0) ** 2] * 3)
    # an axis the data cannot determine (null std) gets the assumed std there, the others keep theirs
    half = unit_pose_covariance(_unit([1e-3, np.nan, 3e-3], [0.1, 0.2, np.nan]), cfg)
    np.testing.assert_allclose(
        np.diag(half), [1e-6, 1e-4, 9e-6, np.radians(0.1) ** 2, np.radians(0.2) ** 2, np.radians(3.0) ** 2]
    )
    # no std at all, or no result: never zero
    np.testing.assert_allclose(unit_pose_covariance(_unit(None, None), cfg), assumed_pose_covariance(cfg))
    np.testing.assert_allclose(unit_pose_covariance(None, cfg), assumed_pose_covariance(cfg))
    # a full covariance wins over the std
    full = np.diag([1.0, 2, 3, 4, 5, 6]) * 1e-6
    np.testing.assert_allclose(unit_pose_covariance(_unit([1e-3] * 3, [0.1] * 3, pose_covariance=full), cfg), full)


def test_from_result_and_a_unit_flagged_as_moved():
    res = CalibrationResult("mle", "panda", "", 0.0, {"a": _unit([1e-4] * 3, [0.01] * 3), "b": _unit(None, None)})
    unc = SkinUncertainty.from_result(res, moved=["a"])
    assumed = assumed_pose_covariance()
    np.testing.assert_allclose(unc.pose_cov["b"], assumed)
    np.testing.assert_allclose(unc.pose_cov["a"], np.diag([1e-8] * 3 + [np.radians(0.01) ** 2] * 3) + assumed)
    np.testing.assert_allclose(unc.unit_covariances(["zz"])[0], assumed)  # a unit without a result


@pytest.mark.adversarial
@pytest.mark.parametrize(
    "bad",
    [np.eye(5), np.full((6, 6), np.nan), -np.eye(6), np.triu(np.ones((6, 6))), "x", [[1, 2]], None],
)
def test_bad_pose_covariance_is_refused_in_one_line(bad):
    with pytest.raises(ConfigError) as err:
        SkinUncertainty({"su\x1b1": bad})
    assert "\n" not in str(err.value) and "\x1b" not in str(err.value) and "su" in str(err.value)


@pytest.mark.adversarial
@pytest.mark.parametrize("bad", [-1.0, np.nan, [[0.1]], "x"])
def test_bad_joint_noise_is_refused(bad):
    with pytest.raises((ConfigError, ValueError)):
        SkinUncertainty(joint_std_rad=bad)


def test_tracker_points_carry_the_newest_readings_covariance():
    chain, poses = panda(), paper_placement(panda())
    cfg = PerceptionConfig(window=3, memory_s=1.0, jump=0.1)
    cov6 = np.diag([1e-6, 1e-6, 4e-6, 1e-5, 1e-5, 1e-6])
    unc = SkinUncertainty({"su4": cov6}, TofModel(noise_std=0.005, noise_std_per_m=0.005))
    tracker = ProximityTracker(chain, {"su4": poses["su4"], "su5": poses["su5"]}, cfg, uncertainty=unc)
    T = chain.link_frames(Q0)[0]

    def expected(name, r, cov):
        o, a = unit_rays(chain, poses[name], Q0[None])
        R = poses[name].R_link_su[None]
        return reading_covariance(chain, T, [poses[name].link], R, [r], o + r * a, cov[None], unc)[0]

    for k, r in enumerate([0.60, 0.58, 0.56]):
        tracker.update(0.02 * k, Q0, {"su4": r, "su5": 0.7})
    pts = tracker.points(0.05)
    i4, i5 = pts.units.index("su4"), pts.units.index("su5")
    np.testing.assert_allclose(pts.cov[i4], expected("su4", 0.56, cov6), rtol=1e-12)
    # su5 has no covariance given: the assumed one, not zero
    np.testing.assert_allclose(pts.cov[i5], expected("su5", 0.7, assumed_pose_covariance(cfg)), rtol=1e-12)
    assert np.linalg.eigvalsh(pts.cov[i5]).min() > 0
    # a jump to another target keeps the old track as a memory point with its covariance
    tracker.update(0.06, Q0, {"su4": 0.3})
    mem = tracker.points(0.07)
    assert mem.units.count("su4") == 2
    np.testing.assert_allclose(mem.cov[len(mem) - 1], expected("su4", 0.56, cov6), rtol=1e-12)
    np.testing.assert_allclose(mem.cov[mem.units.index("su4")], expected("su4", 0.3, cov6), rtol=1e-12)


def test_points_from_streams_carry_covariance():
    chain, poses = panda(), paper_placement(panda())
    t_j = np.arange(0.0, 1.0, 0.001)
    q_j = Q0 + 0.2 * np.sin(t_j)[:, None]
    t = np.array([0.1, 0.5, 0.9])
    r = np.array([0.5, np.nan, 0.7])
    unc = SkinUncertainty(joint_std_rad=1e-3)
    pts = points_from_streams(chain, {"su4": poses["su4"]}, t_j, q_j, {"su4": (t, r)}, uncertainty=unc)
    assert len(pts) == 2 and pts.cov.shape == (2, 3, 3)
    for k, (tk, rk) in enumerate([(0.1, 0.5), (0.9, 0.7)]):
        q = Q0 + 0.2 * np.sin(tk)
        T = chain.link_frames(q)
        exp = reading_covariance(
            chain,
            T,
            [poses["su4"].link],
            poses["su4"].R_link_su[None],
            [rk],
            pts.positions[k][None],
            assumed_pose_covariance()[None],
            unc,
        )[0]
        np.testing.assert_allclose(pts.cov[k], exp, rtol=1e-6)
