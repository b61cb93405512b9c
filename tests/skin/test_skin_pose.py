"""The paper's 6-parameter SU form: exact round trips, singular cases, quaternion conventions."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from skincal.errors import ConfigError
from skincal.kinematics import homogeneous, modified_dh, rot_x, rot_z
from skincal.skin import SkinUnitPose, dh6_from_transform, dh6_to_transform


def test_dh6_matches_explicit_product():
    x = np.array([0.3, -0.08, 1.1, 0.05, 0.02, 1.2])
    Tz = np.eye(4)
    Tz[2, 3] = x[1]
    expected = homogeneous(rot_z(x[0]), np.zeros(3)) @ Tz
    # modDH(theta, d, a, alpha) = Rx(alpha) Tx(a) Rz(theta) Tz(d), built from elementary transforms
    Tx = np.eye(4)
    Tx[0, 3] = x[4]
    Tzd = np.eye(4)
    Tzd[2, 3] = x[3]
    expected = expected @ homogeneous(rot_x(x[5]), np.zeros(3)) @ Tx @ homogeneous(rot_z(x[2]), np.zeros(3)) @ Tzd
    np.testing.assert_allclose(dh6_to_transform(x), expected, atol=1e-15)
    T_v = homogeneous(rot_z(x[0]), [0.0, 0.0, x[1]])
    np.testing.assert_allclose(modified_dh(x[2], x[3], x[4], x[5]), np.linalg.inv(T_v) @ expected, atol=1e-14)


def test_round_trip_on_thousands_of_random_poses():
    R = Rotation.random(5000, random_state=7).as_matrix()
    p = np.random.default_rng(7).uniform(-0.4, 0.4, size=(5000, 3))
    T = homogeneous(R, p)
    params = dh6_from_transform(T)
    np.testing.assert_allclose(dh6_to_transform(params), T, atol=1e-12)
    assert np.all(params[:, 4] >= 0.0), "the paper bounds a_su to [0, 1]"
    assert np.all(np.abs(params[:, [0, 2, 5]]) <= np.pi + 1e-12)


@pytest.mark.parametrize(
    "R",
    [
        np.eye(3),
        np.diag([1.0, -1.0, -1.0]),
        Rotation.from_euler("z", 0.7).as_matrix(),
        Rotation.from_euler("zx", [0.4, np.pi]).as_matrix(),
        Rotation.from_euler("zx", [0.4, 1e-9]).as_matrix(),
        Rotation.from_euler("zx", [-2.0, np.pi - 1e-10]).as_matrix(),
    ],
)
@pytest.mark.parametrize("p", [[0.1, -0.2, 0.3], [0.0, 0.0, 0.2], [0.0, 0.0, 0.0]])
def test_round_trip_singular_cases(R, p):
    """SU z axis (anti)parallel to the joint axis: the DH form is singular but the pose is kept."""
    T = homogeneous(R, p)
    np.testing.assert_allclose(dh6_to_transform(dh6_from_transform(T)), T, atol=1e-8)


def test_paper_table2_parameters_give_outward_units():
    """Table II SU2: theta_v=0, d_v=-0.08, theta_su=0, d_su=0.05, a_su=0, alpha=pi/2."""
    pose = SkinUnitPose.from_dh6(3, [0.0, -0.08, 0.0, 0.05, 0.0, np.pi / 2])
    # p = Rz(0) [0, 0, -0.08] + 0.05 * z_su, z_su = Rx(pi/2) e_z = [0, -1, 0]
    np.testing.assert_allclose(pose.p_link_su, [0.0, -0.05, -0.08], atol=1e-15)
    np.testing.assert_allclose(pose.R_link_su[:, 2], [0.0, -1.0, 0.0], atol=1e-15)
    np.testing.assert_allclose(SkinUnitPose.from_dh6(3, pose.dh6()).T_link_su, pose.T_link_su, atol=1e-14)


def test_quaternion_order_is_wxyz():
    pose = SkinUnitPose.from_quaternion(2, [0.1, 0.2, 0.3], [np.cos(0.25), 0.0, 0.0, np.sin(0.25)])
    np.testing.assert_allclose(pose.R_link_su, rot_z(0.5), atol=1e-15)
    np.testing.assert_allclose(pose.quaternion_wxyz, [np.cos(0.25), 0.0, 0.0, np.sin(0.25)], atol=1e-15)


def test_bad_poses_are_rejected():
    with pytest.raises(ConfigError, match="link"):
        SkinUnitPose(-1, np.eye(3), np.zeros(3))
    with pytest.raises(ConfigError, match="rotation"):
        SkinUnitPose(1, np.diag([1.0, 1.0, -1.0]), np.zeros(3))
    with pytest.raises(ConfigError, match="NaN"):
        SkinUnitPose(1, np.eye(3), [np.nan, 0, 0])
    with pytest.raises(ConfigError, match="quaternion"):
        SkinUnitPose.from_quaternion(1, np.zeros(3), [0, 0, 0, 0])
