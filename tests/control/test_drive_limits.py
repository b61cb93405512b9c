"""The controller and an acceleration-limited drive (issue 28, torque mode): commands within a_j dt of the previous
one, the protective stop braking a row at the drive's limit, and the share of a violation that is a stop in
progress (iso_metrics.braking_steps). Arrays only, no simulator."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from skincal.control import AvoidanceController, ControllerConfig
from skincal.control.constraints import joint_velocity_bounds
from skincal.control.iso_metrics import braking_steps
from skincal.control.qp import drive_bounds
from skincal.control.separation import SeparationParams, StoppingModel
from skincal.errors import ConfigError
from skincal.kinematics import panda
from skincal.kinematics.points import Q_START

SEP = SeparationParams(human_speed_mps=1.6, stopping=StoppingModel.constant_deceleration(4.0, 0.021))
ACC = (15.0, 7.5, 10.0, 12.5, 15.0, 20.0, 20.0)


def test_drive_bounds_clip_the_box_into_one_step_of_acceleration():
    lb, ub = np.array([-2.0, -2.0, 0.5]), np.array([2.0, 2.0, 2.0])
    lo, hi = drive_bounds(lb, ub, [1.0, -1.9, 0.0], [10.0, 10.0, 10.0], 0.001)
    np.testing.assert_allclose(lo, [0.99, -1.91, 0.01])  # the third: a position bound asks more than a dt allows
    np.testing.assert_allclose(hi, [1.01, -1.89, 0.01])


def test_acceleration_limit_must_be_positive():
    with pytest.raises(ConfigError, match="acceleration_limit"):
        ControllerConfig(acceleration_limit=(1.0, 0.0))


def test_commands_stay_within_a_dt_and_the_stop_brakes_at_the_drive_limit():
    """The arm's flange moving at 0.3 m/s toward a still point 5 cm away (deep inside S_p): without the drive's
    limits the command reverses at once; with them it stays within a_j dt of the previous command and the speed
    toward the point falls by the most the box allows (the protective stop's slack capped at that)."""
    chain = panda()
    x = chain.flange_pose(Q_START)[0, :3, 3]
    J = chain.point_jacobians(chain.link_frames(Q_START)[0], [chain.n_joints], x)[0]
    toward = np.array([1.0, 0.0, 0.0])
    qd_prev = np.linalg.pinv(J) @ (0.3 * toward)
    point = x + 0.15 * toward  # 7 cm from the padded capsule: inside S_p
    base = ControllerConfig(separation=SEP, stop_never_approaches=True, n_rim=0)
    ideal = AvoidanceController(chain, base).step(Q_START, x, np.zeros(3), point[None], qd_prev)
    limited_ctl = AvoidanceController(chain, replace(base, acceleration_limit=ACC))
    res = limited_ctl.step(Q_START, x, np.zeros(3), point[None], qd_prev, qd_prev=qd_prev)
    step = np.asarray(ACC) * base.dt
    assert np.all(np.abs(res.qd - qd_prev) <= step + 1e-9)
    assert np.max(np.abs(ideal.qd - qd_prev)) > 10 * step.max()  # the ideal interface jumps
    g = res.inside_rows[0]
    slowest = float(np.sum(np.minimum(g * (qd_prev - step), g * (qd_prev + step))))
    assert g @ qd_prev > 0.1 and not res.feasible
    assert g @ res.qd == pytest.approx(slowest, abs=2e-4)  # braked as hard as the drive can
    assert g @ ideal.qd < 0  # the ideal interface backs away within the step


def test_braking_steps_are_a_stop_from_the_entry_within_the_stopping_time():
    stop = StoppingModel.constant_deceleration(4.0, 0.02)  # from 0.2 m/s: T_r + T_s = 0.07 s
    dt = 0.01
    inside = np.array([0, 1, 1, 1, 1, 1, 1, 1, 1, 1, 0, 1, 1, 1], dtype=bool)
    approach = np.array([0, 0.2, 0.15, 0.1, 0.05, 0.01, 0.005, 0.004, 0.003, 0.002, 0, 0.1, 0.2, 0.1])
    bad = inside & (approach > 1e-3)
    out = braking_steps(inside, bad, approach, dt, stop)
    # entry at step 1 at 0.2 m/s: steps 1..8 lie within 0.07 s; step 9 (0.08 s) no longer
    np.testing.assert_array_equal(np.flatnonzero(out), [1, 2, 3, 4, 5, 6, 7, 8, 11])
    # the second entry (step 11, 0.1 m/s) counts; it speeds up at step 12: not a stop from there on
    assert not out[12] and not out[13] and out[11]


def test_all_directions_bounds_the_speed_across_the_normal_near_a_point_only():
    """A still point 0.3 m beyond the flange (inside the ramp, outside S_p): with all_directions the QP has the
    normal row and four tangent rows with the same bound, each tangent row orthogonal to the normal one in
    Cartesian space; a point 3 m away (the ramp saturated) adds none."""
    chain = panda()
    x = chain.flange_pose(Q_START)[0, :3, 3]
    base = ControllerConfig(separation=SEP, n_rim=0)
    ctl = AvoidanceController(chain, replace(base, all_directions=True))
    near = ctl.problem(Q_START, x, np.zeros(3), (x + [0.3, 0.0, 0.0])[None])
    plain = AvoidanceController(chain, base).problem(Q_START, x, np.zeros(3), (x + [0.3, 0.0, 0.0])[None])
    assert plain.G.shape[0] == 1 and near.G.shape[0] == 5
    assert 0 < plain.h[0] < 0.9 * base.v_max
    np.testing.assert_allclose(near.h, plain.h[0])
    np.testing.assert_allclose(near.G[1:3], -near.G[3:5])
    J = chain.point_jacobians(chain.link_frames(Q_START)[0], [chain.n_joints], x)[0]
    normal = np.linalg.lstsq(J.T, plain.G[0], rcond=None)[0]  # n with n^T J = G (the flange is the nearest point)
    tangents = np.linalg.lstsq(J.T, near.G[1:3].T, rcond=None)[0].T
    np.testing.assert_allclose(tangents @ normal, 0.0, atol=1e-6)
    far = ctl.problem(Q_START, x, np.zeros(3), (x + [3.0, 0.0, 0.0])[None])
    assert far.G.shape[0] == 1


def test_feedback_speed_caps_the_way_back_to_the_reference():
    chain = panda()
    x = chain.flange_pose(Q_START)[0, :3, 3]
    far = x + np.array([0.0, 0.2, 0.0])  # K = 10/s: 2 m/s uncapped
    capped = AvoidanceController(chain, ControllerConfig(feedback_speed=0.5)).problem(Q_START, far, np.zeros(3), [])
    free = AvoidanceController(chain, ControllerConfig()).problem(Q_START, far, np.zeros(3), [])
    np.testing.assert_allclose(capped.c, 0.25 * free.c)  # c = -J^T xd_cmd: the feedback scaled to 0.5 m/s
    with pytest.raises(ConfigError, match="feedback_speed"):
        ControllerConfig(feedback_speed=0.0)


def test_a_drive_limited_joint_stops_before_its_position_limit():
    """Joint 2 of the Panda at 2 rad/s toward its upper limit, 0.3 rad short of the margin: each step the command
    stays within the box and within a_j dt of the previous one (as the torque robot's drive does); it must come to
    rest before ``upper - margin``. With the one-step bound alone the drive cannot brake in time and runs past it
    (``lower``, Panda, torque: into the stop at 2 rad/s; simulated)."""
    chain = panda()
    acc, dt, margin = np.asarray(ACC), 0.001, 0.05
    q = Q_START.copy()
    q[1] = chain.joint_upper[1] - margin - 0.3
    qd = np.zeros(chain.n_joints)
    qd[1] = 2.0
    assert qd[1] ** 2 / (2 * acc[1]) < 0.3  # braking at a_2 from 2 rad/s fits in 0.3 rad when begun at once
    top = q[1]
    for _ in range(400):
        lb, ub = joint_velocity_bounds(chain, q, dt, margin=margin, acceleration=acc)
        lo, hi = drive_bounds(lb, ub, qd, acc, dt)
        qd = np.clip(np.full(chain.n_joints, 10.0), lo, hi)  # as fast up as allowed
        q = q + qd * dt
        top = max(top, q[1])
    assert top <= chain.joint_upper[1] - margin + acc[1] * dt**2  # (within one step's a dt^2: the discretisation)
    assert top > chain.joint_upper[1] - margin - 0.01  # and it does get there (not a bound that stops far short)
    lb, ub = joint_velocity_bounds(chain, Q_START, dt, margin=margin)
    lb_a, ub_a = joint_velocity_bounds(chain, Q_START, dt, margin=margin, acceleration=acc)
    np.testing.assert_array_equal((lb, ub), (lb_a, ub_a))  # far from the limits: the velocity limits, as before


def test_drive_limited_commands_do_not_build_up_null_space_speed():
    """The Panda's flange sent to a point 10 cm away (feedback 1 m/s) from rest, each command within a_j dt of the
    previous one: the commands approach the ideal interface's, whose null-space speed is ~0, joint by joint, so the
    arm's null-space speed ``|(I - J^+ J) qd|`` stays small. Minimising the tracking objective in the drive's box
    directly picked its corners and drove it to 1.99 rad/s here (0.60 now; in ``hand``, Panda, torque: joints 1, 3
    and 6 at 1.3-2.2 rad/s with the flange nearly still; simulated)."""
    chain = panda()
    cfg = ControllerConfig(acceleration_limit=ACC)
    ctl = AvoidanceController(chain, cfg)
    q = Q_START.copy()
    target = chain.flange_pose(q)[0, :3, 3] + np.array([0.07, -0.07, 0.0])
    qd, null_speed = np.zeros(chain.n_joints), 0.0
    for _ in range(300):
        res = ctl.step(q, target, np.zeros(3), np.zeros((0, 3)), qd_prev=qd)
        assert np.all(np.abs(res.qd - qd) <= np.asarray(ACC) * cfg.dt + 1e-9)
        qd = res.qd
        x = chain.flange_pose(q)[0, :3, 3]
        J = chain.point_jacobians(chain.link_frames(q)[0], [chain.n_joints], x)[0]
        null_speed = max(null_speed, float(np.linalg.norm(qd - np.linalg.pinv(J) @ (J @ qd))))
        q = q + qd * cfg.dt
    assert null_speed < 0.75
    assert np.linalg.norm(chain.flange_pose(q)[0, :3, 3] - target) < 0.01  # and the flange gets there
