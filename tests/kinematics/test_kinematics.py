"""Forward and point kinematics against independent computations.

Independent references: finite differences of FK, a product-of-exponentials formulation built in
this file from the chain's home-configuration screw axes, and Franka's published flange poses.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.linalg import expm

from skincal.errors import ConfigError
from skincal.kinematics import SerialChain, get_robot, load_chain, panda, skew, transform_points


def random_state(chain, rng, N=6):
    lo = chain.joint_lower if chain.joint_lower is not None else -np.pi
    hi = chain.joint_upper if chain.joint_upper is not None else np.pi
    q = rng.uniform(lo, hi, size=(N, chain.n_joints))
    return q, rng.normal(size=q.shape), rng.normal(size=q.shape)


def test_panda_published_flange_poses():
    chain = panda()
    T0 = chain.flange_pose(np.zeros(7))[0]
    np.testing.assert_allclose(T0[:3, 3], [0.088, 0.0, 0.926], atol=1e-12)
    np.testing.assert_allclose(T0[:3, :3], np.diag([1.0, -1.0, -1.0]), atol=1e-12)
    ready = np.array([0, -np.pi / 4, 0, -3 * np.pi / 4, 0, np.pi / 2, np.pi / 4])
    T = chain.flange_pose(ready)[0]
    np.testing.assert_allclose(T[:3, 3], [0.30689, 0.0, 0.59028], atol=2e-5)
    np.testing.assert_allclose(T[:3, 2], [0.0, 0.0, -1.0], atol=1e-12)


def test_product_of_exponentials_matches_dh(chain, rng):
    """FK from screw axes at q = 0 (an independent formulation) equals the DH product."""
    T_home = chain.link_frames(np.zeros(chain.n_joints))[0]
    c, z = chain.joint_axes(T_home[None])
    twists = []
    for i in range(chain.n_joints):
        w, p = z[0, i], c[0, i]
        xi = np.zeros((4, 4))
        xi[:3, :3] = skew(w)
        xi[:3, 3] = -np.cross(w, p)
        twists.append(xi)
    q, _, _ = random_state(chain, rng, N=5)
    frames = chain.link_frames(q)
    for s in range(q.shape[0]):
        prod = np.eye(4)
        for i in range(chain.n_joints):
            prod = prod @ expm(twists[i] * q[s, i])
            np.testing.assert_allclose(frames[s, i + 1], prod @ T_home[i + 1], atol=1e-12)


def test_point_velocity_and_jacobian_vs_finite_differences(chain, rng):
    q, qd, qdd = random_state(chain, rng)
    h = 1e-6
    for link in range(1, chain.n_joints + 1):
        p = rng.normal(scale=0.1, size=3)
        _, v, _ = chain.link_motion(q, qd, qdd).point(link, p)
        x = lambda dq, link=link, p=p: transform_points(chain.link_frames(q + dq)[:, link], p)  # noqa: E731
        v_fd = (x(h * qd) - x(-h * qd)) / (2 * h)
        np.testing.assert_allclose(v, v_fd, atol=1e-8)
        J = chain.point_jacobian(q, link, p)
        np.testing.assert_allclose(np.einsum("nij,nj->ni", J[:, :3], qd), v, atol=1e-12)
        assert np.all(J[:, :, link:] == 0.0)


def test_point_acceleration_vs_second_differences(chain, rng):
    q, qd, qdd = random_state(chain, rng)
    h = 1e-4
    for link in range(1, chain.n_joints + 1):
        p = rng.normal(scale=0.1, size=3)
        _, _, a = chain.link_motion(q, qd, qdd).point(link, p)
        x = lambda t, link=link, p=p: transform_points(  # noqa: E731
            chain.link_frames(q + qd * t + 0.5 * qdd * t * t)[:, link], p
        )
        a_fd = (x(h) - 2 * x(0.0) + x(-h)) / h**2
        np.testing.assert_allclose(a, a_fd, atol=2e-6)


def test_angular_velocity_and_acceleration_vs_finite_differences(chain, rng):
    q, qd, qdd = random_state(chain, rng)
    motion = chain.link_motion(q, qd, qdd)
    h = 1e-5

    def R(t):
        return chain.link_frames(q + qd * t + 0.5 * qdd * t * t)[:, :, :3, :3]

    Rdot = (R(h) - R(-h)) / (2 * h)
    W = np.einsum("nkij,nkmj->nkim", Rdot, R(0.0))  # [w]_x = Rdot R^T
    w_fd = np.stack([W[..., 2, 1], W[..., 0, 2], W[..., 1, 0]], axis=-1)
    np.testing.assert_allclose(motion.omega, w_fd, atol=1e-8)
    w = lambda t: chain.link_motion(q + qd * t + 0.5 * qdd * t * t, qd + qdd * t, qdd).omega  # noqa: E731
    np.testing.assert_allclose(motion.omega_dot, (w(h) - w(-h)) / (2 * h), atol=1e-7)


def test_batched_equals_single_sample(rng):
    chain = panda()
    q, qd, qdd = random_state(chain, rng, N=4)
    full = chain.link_motion(q, qd, qdd).point(4, [0.05, 0.0, 0.1])
    for s in range(4):
        one = chain.link_motion(q[s], qd[s], qdd[s]).point(4, [0.05, 0.0, 0.1])
        for a, b in zip(full, one, strict=True):
            np.testing.assert_allclose(a[s], b[0], atol=1e-15)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"dh": np.zeros((0, 4))}, "empty"),
        ({"dh": np.full((3, 4), np.nan)}, "NaN"),
        ({"dh": np.zeros((3, 3))}, "shape"),
        ({"dh": np.zeros((2, 4)), "convention": "craig"}, "convention"),
        ({"dh": np.zeros((2, 4)), "joint_lower": [1.0, 0.0], "joint_upper": [0.0, 1.0]}, "lower limit"),
    ],
)
def test_bad_chains_are_rejected(kwargs, message):
    kwargs = {"name": "bad", "convention": "modified", **kwargs}
    with pytest.raises(ConfigError, match=message):
        SerialChain.from_dh(**kwargs)


def test_bad_joint_arrays_are_rejected():
    chain = panda()
    with pytest.raises(ConfigError, match="shape"):
        chain.link_frames(np.zeros((3, 6)))
    q = np.zeros((2, 7))
    q[1, 3] = np.nan
    with pytest.raises(ConfigError, match="NaN"):
        chain.link_frames(q)
    with pytest.raises(ConfigError, match="link"):
        chain.point_jacobian(np.zeros(7), 8, np.zeros(3))


def test_unknown_robot_and_chain_files(tmp_path):
    with pytest.raises(ConfigError, match="unknown robot 'kuka'"):
        get_robot("kuka")
    good = tmp_path / "arm.yaml"
    good.write_text("name: arm\nconvention: standard\ndh:\n  - [0, 0.3, 0, 1.5707963]\n  - [0, 0, 0.4, 0]\n")
    chain = get_robot(str(good))
    assert chain.n_joints == 2 and chain.convention == "standard"
    np.testing.assert_allclose(chain.flange_pose(np.zeros(2))[0, :3, 3], [0.4, 0.0, 0.3], atol=1e-9)
    js = tmp_path / "arm.json"
    js.write_text('{"convention": "modified", "dh": [[0, 0.1, 0, 0]], "joint_lower": [-1], "joint_upper": [1]}')
    assert load_chain(js).name == "arm"
    bad = tmp_path / "bad.yaml"
    bad.write_text("convention: modified\ndh: [[0, 0.1, 0]]\n")
    with pytest.raises(ConfigError, match=r"bad.yaml: .*shape"):
        load_chain(bad)
    with pytest.raises(ConfigError, match="missing field 'dh'"):
        bad.write_text("convention: modified\n")
        load_chain(bad)
    with pytest.raises(ConfigError, match="cannot read"):
        load_chain(tmp_path / "nope.yaml")


def test_nearest_rotation_is_the_polar_factor_and_never_a_reflection(rng):
    """``nearest_rotation`` (the one SVD projection): for ``det M > 0`` the orthogonal polar factor of ``M``;
    for a reflected ``M`` still a rotation (det +1); a rotation maps to itself."""
    from scipy.linalg import polar
    from scipy.spatial.transform import Rotation

    from skincal.kinematics import nearest_rotation

    R = Rotation.random(random_state=1).as_matrix()
    M = R + 0.05 * rng.normal(size=(3, 3))
    np.testing.assert_allclose(nearest_rotation(M), polar(M)[0], atol=1e-12)
    np.testing.assert_allclose(nearest_rotation(R), R, atol=1e-14)
    flipped = nearest_rotation(M @ np.diag([1.0, 1.0, -1.0]))
    np.testing.assert_allclose(flipped @ flipped.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(flipped) == pytest.approx(1.0, abs=1e-12)


def test_rotation_angle_is_accurate_for_tiny_and_large_angles():
    """The one rotation error (atan2 form): exact to rounding near 0, where ``arccos((tr - 1) / 2)`` loses
    half the digits, and near pi."""
    from scipy.spatial.transform import Rotation

    from skincal.kinematics import rotation_angle

    axis = np.array([1.0, 2.0, -2.0]) / 3.0
    for angle in (1e-9, 1e-6, 0.3, np.pi - 1e-6):
        R = Rotation.from_rotvec(angle * axis).as_matrix()
        assert rotation_angle(np.eye(3), R) == pytest.approx(angle, rel=1e-6)


def test_exp_rotation_is_rodrigues_and_scipys_rotation_vector():
    """``exp_rotation`` against Rodrigues' formula ``I + sin(a) [k]x + (1 - cos(a)) [k]x^2`` and against
    ``scipy``'s ``Rotation.from_rotvec`` over angles from 1e-12 rad to 3 rad (the Taylor branch below 1e-3)."""
    from scipy.spatial.transform import Rotation

    from skincal.kinematics.transforms import exp_rotation, skew

    rng = np.random.default_rng(7)
    for scale in 10.0 ** np.linspace(-12, 0.45, 40):
        v = rng.normal(size=3)
        v *= scale / np.linalg.norm(v)
        a, K = scale, skew(v / scale)
        rodrigues = np.eye(3) + np.sin(a) * K + (1 - np.cos(a)) * K @ K
        R = exp_rotation(v)
        np.testing.assert_allclose(R, rodrigues, rtol=0, atol=4e-16)
        np.testing.assert_allclose(R, Rotation.from_rotvec(v).as_matrix(), rtol=0, atol=4e-16)
        np.testing.assert_allclose(R @ R.T, np.eye(3), rtol=0, atol=1e-15)
