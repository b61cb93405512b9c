"""Named robot points and the avoidance task's start configuration (skincal.kinematics.points)."""

from __future__ import annotations

import numpy as np
import pytest

from skincal.kinematics import get_robot, panda
from skincal.kinematics.points import Q_START, robot_points, start_configuration


@pytest.mark.parametrize("robot", ["panda", "ur5e", "iiwa14", "xarm7"])
def test_start_configuration_is_in_front_within_limits_and_well_conditioned(robot):
    chain = get_robot(robot)
    q0 = start_configuration(chain)
    if chain.joint_lower is not None:
        assert np.all(q0 >= chain.joint_lower + 0.05) and np.all(q0 <= chain.joint_upper - 0.05)
    pts = robot_points(chain, q0)
    x = pts["flange"]
    assert x[0] > 0.3 and abs(x[1]) < 1e-3 and x[2] > pts["shoulder"][2]  # in front, above the shoulder
    J = chain.point_jacobian(q0, chain.n_joints, chain.T_link_flange[:3, 3])[:3]
    assert np.linalg.svd(J, compute_uv=False).min() > 0.1  # the 0.1 m circle is trackable
    np.testing.assert_array_equal(start_configuration(chain), q0)  # deterministic


def test_the_panda_starts_at_q_start_with_its_flange_in_front():
    q0 = start_configuration(panda())
    np.testing.assert_array_equal(q0, Q_START)
    pts = robot_points(panda(), q0)
    np.testing.assert_allclose(pts["flange"], panda().flange_pose(Q_START)[0, :3, 3], atol=1e-12)
    assert pts["flange"][0] == pytest.approx(0.47, abs=0.01) and pts["flange"][2] == pytest.approx(0.52, abs=0.01)
    np.testing.assert_allclose(pts["upper_arm"], 0.5 * (pts["shoulder"] + pts["elbow"]), atol=1e-15)
