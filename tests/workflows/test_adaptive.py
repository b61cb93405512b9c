"""The adaptive loop in simulation (skincal.workflows.adaptive) and the next best motion on a real
streaming calibrator fed by a simulated robot (skincal.calib.online.design)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from skincal.calib.online.design import (
    DesignOptions,
    build_segment,
    excitable,
    motion_gain,
    next_motion,
    segment_config,
    unit_weights,
)
from skincal.protocol.limits import check_limits, position_bounds
from skincal.workflows.adaptive import SimulatedRobot, run_simulated, start_pose
from skincal.workflows.live import Target, make_calibrator
from skincal.workflows.session import make_session

TARGET = Target(3e-4, 0.05)


@pytest.fixture(scope="module")
def loop_run():
    records = []
    run = run_simulated("panda", "paper", None, "realistic", seed=0, max_motion_s=120.0, on_segment=records.append)
    return run, records


def test_loop_converges_in_simulation(loop_run):
    run, records = loop_run
    assert run.loop.reached
    assert [r.index for r in records] == list(range(1, len(records) + 1))  # progress once per segment
    # the motion time is the executed motion's, segment by segment
    assert run.motion_s == pytest.approx(sum(r.candidate.duration for r in records))
    assert run.motion_s == pytest.approx(run.trajectory.duration)
    assert records[-1].t_end == pytest.approx(run.motion_s)
    assert 0 < run.motion_s < 120.0
    # every unit on its true link, the TRUE error below 3x the target std
    units = run.errors["units"]
    assert len(units) == 6
    for name, e in units.items():
        assert e["link_estimated"] == e["link_true"], name
        assert e["position_error_mm"] < 3 * TARGET.position_m * 1e3, name
        assert e["rotation_error_deg"] < 3 * TARGET.rotation_deg, name
    # the result's std is what the loop stopped on
    for unit in run.result.units.values():
        assert np.all(unit.position_std_m <= TARGET.position_m)
        assert np.all(unit.rotation_std_deg <= TARGET.rotation_deg)


def test_every_chosen_segment_stays_within_the_limits(loop_run):
    run, records = loop_run
    from skincal.kinematics import get_robot

    chain = get_robot("panda")
    config = segment_config(chain)
    for r in records:
        traj = r.candidate.trajectory
        check_limits(chain, traj.t, traj.q, traj.qd, margin=config.limit_margin)  # raises if outside
    whole = run.trajectory
    check_limits(chain, whole.t, whole.q, whole.qd, margin=config.limit_margin)


def test_unit_errors_are_drawn_once_for_all_segments():
    """The simulated robot re-simulates the growing motion: each unit's IMU errors (the truth) never change."""
    session = make_session("panda", "paper", None, "realistic", "fast", 3, joints="controller")
    chain = session.chain
    q0 = start_pose(chain, np.random.default_rng(1))
    config = segment_config(chain)
    sim = SimulatedRobot(session, q0)
    sim.execute(build_segment(chain, config, q0, q0, 3))
    first = sim.dataset
    sim.execute(build_segment(chain, config, q0, q0, 5))
    second = sim.dataset
    assert second.joint_states.t[-1] > first.joint_states.t[-1] + 1.0
    for unit, truth in first.truth_sensor.items():
        for key, value in truth.items():
            np.testing.assert_array_equal(second.truth_sensor[unit][key], value, err_msg=f"{unit} {key}")
    bias = np.array([first.truth_sensor[u]["accel_bias"] for u in first.truth_sensor])
    assert np.abs(bias).max() > 0.05  # realistic IMUs: the bias is there, and kept


@pytest.fixture(scope="module")
def low_units():
    """A calibrator fed two segments of a robot whose units sit on links 2-4 only (joints 5-7 move none)."""
    session = make_session("panda", "random", None, "realistic", "fast", 5, joints="controller", links=[2, 3, 4])
    chain = session.chain
    q0 = start_pose(chain, np.random.default_rng(2))
    cal = make_calibrator(chain, list(session.placements), session.gravity, TARGET)
    sim = SimulatedRobot(session, q0, cal)
    config = segment_config(chain)
    q = q0
    for j in (1, 3, 2, 1, 0, 3):
        assert excitable(chain, config, q)[0, j]
        sim.execute(build_segment(chain, config, q, q, j))
    cal.finish()
    return chain, cal, q, config


def test_gain_of_a_joint_that_moves_no_unit_is_zero(low_units):
    chain, cal, q, config = low_units
    status = cal.status()
    assert all(s.link in (2, 3, 4) and s.pose is not None for s in status.values())
    weights = unit_weights(status, 1.0)
    options = DesignOptions()
    rest = replace(config, excited_joints=(4,), amplitude=1e-12)  # same timeline, no motion
    still = build_segment(chain, rest, q, q, 4, check=False)
    gain_still = motion_gain(cal, still, weights, options)
    for j in (4, 5, 6):  # joints 5-7 move links 5-7: no unit
        if not excitable(chain, config, q)[0, j]:
            continue
        traj = build_segment(chain, config, q, q, j, check=False)
        assert traj.duration == pytest.approx(still.duration)
        assert motion_gain(cal, traj, weights, options) - gain_still == pytest.approx(0.0, abs=1e-9)
    # and a joint that moves them gains
    traj = build_segment(chain, config, q, q, 1, check=False)
    assert motion_gain(cal, traj, weights, options) > gain_still + 0.1


def test_a_candidate_outside_the_limits_is_never_chosen(low_units):
    chain, cal, q, config = low_units
    lower, upper = position_bounds(chain)
    # joints 2 and 4 pushed against their upper limits: their excitation (q_j grows) would leave the limits
    q_edge = q.copy()
    q_edge[1] = upper[1] - config.limit_margin - 1e-3
    q_edge[3] = upper[3] - config.limit_margin - 1e-3
    ok = excitable(chain, config, q_edge)[0]
    assert not ok[1] and not ok[3]
    rng = np.random.default_rng(0)
    for _ in range(4):
        cand = next_motion(cal, chain, q_edge, rng, config=config, options=DesignOptions(pose_candidates=3))
        if not cand.moves:
            assert cand.joint not in (1, 3)
        traj = cand.trajectory
        check_limits(chain, traj.t, traj.q, traj.qd, margin=config.limit_margin)
