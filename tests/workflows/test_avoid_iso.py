"""Issue 17 in the closed loop: metrics like ISO/TS 15066, the task clock that waits and resumes, any robot,
the torque mode, and a wider margin from a larger pose std."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from skincal.control import ControllerConfig
from skincal.control.iso_metrics import NEAR_BAND
from skincal.control.separation import SeparationParams, StoppingModel
from skincal.kinematics import get_robot, panda
from skincal.perception import RobotBody
from skincal.perception.uncertainty import SkinUncertainty
from skincal.protocol.flange import PickPlace
from skincal.sim.scenarios import get_scenario, parse_scenario
from skincal.skin.placement import paper_placement, ring_placement
from skincal.workflows.avoidance import RunLog, degraded_uncertainty, run_scenario
from skincal.workflows.experiment import clearance, summarize, task_time_lost

pytest.importorskip("mujoco")

SEPARATION = SeparationParams(stopping=StoppingModel.constant_deceleration(4.0, 0.021))


def _at_flange(chain, speed=1.0, stay=1.0, duration=4.0, task="circle"):
    """A hand (sphere r = 5 cm) from 1 m in front of the flange's start into the circle the flange runs
    (where the flange is about 1.2 s in) at ``speed``, stays ``stay`` s, leaves at the same speed."""
    hand = {"name": "hand", "shape": "sphere", "radius": 0.05, "relative_to": "flange", "speed": speed, "start": 0.2}
    near = [0.0, -0.06, 0.07]
    hand["waypoints"] = [{"p": [1.0, -0.06, 0.07]}, {"p": near, "hold": stay}, {"p": [1.0, -0.06, 0.07]}]
    return parse_scenario({"people": [hand], "duration": duration}, "test", chain, task=task)


def _log_like(log: RunLog, **over) -> RunLog:
    return replace(log, **over)


@pytest.fixture(scope="module")
def panda_run():
    chain = panda()
    poses = ring_placement(chain)
    sc = _at_flange(chain, duration=3.0)
    config = ControllerConfig(separation=SEPARATION)
    log = run_scenario(chain, sc, poses, poses, np.random.default_rng(0), controller=config, resume=True)
    ref = run_scenario(chain, sc.without_people(), poses, poses, np.random.default_rng(0), resume=True)
    return chain, sc, log, ref


def test_metrics_like_the_standard_from_the_logged_margin(panda_run):
    """min(clearance - S_p), the steps below S_p, the time within S_p + 0.5 m and the protective stop,
    on a log whose margin and stops are set by hand."""
    chain, _, log, _ = panda_run
    body = RobotBody.of(chain)
    clear = clearance(log, body)
    S = log.t.size
    margin = np.full(S, 0.3)
    margin[1000:1100] = clear[1000:1100] + 0.02  # 100 steps 2 cm inside S_p
    stop = np.zeros(S, dtype=bool)
    stop[50:80] = True
    m = summarize(_log_like(log, margin=margin, protective_stop=stop), body)
    assert m.min_clearance_minus_sp_m == pytest.approx(min(-0.02, float(np.min(clear - 0.3))))
    assert m.steps_below_sp == int(np.sum(clear - margin < 0))
    assert m.steps_below_sp >= 100
    assert m.near_time_s == pytest.approx(np.sum(clear - margin < NEAR_BAND) * 1e-3)
    assert m.protective_stop_s == pytest.approx(0.03)
    assert m.margin_max_m == pytest.approx(max(0.3, float(np.max(margin))))


def test_task_clock_waits_while_the_hand_is_near_and_resumes(panda_run):
    chain, sc, log, ref = panda_run
    rate = np.diff(log.task_time) / 1e-3
    assert np.all(rate >= -1e-9) and np.all(rate <= 1 + 1e-9)
    assert rate.min() == pytest.approx(0.0, abs=1e-9)  # it stopped ...
    assert rate[-1] == pytest.approx(1.0)  # ... and runs again once the hand left
    np.testing.assert_array_equal(ref.task_time, ref.t)  # nobody: the clock is time
    lost = task_time_lost(log, ref)
    assert lost == pytest.approx(ref.task_time[-1] - log.task_time[-1]) and lost > 0.1
    # the reference follows the clock: position and velocity of the task at tau
    x, v = sc.task.at(log.task_time[::97])
    np.testing.assert_allclose(log.x_des[::97], x, atol=1e-12)
    m = summarize(log, RobotBody.of(chain), "truth", ref)
    assert m.task_time_lost_s == pytest.approx(lost)
    assert (
        m.contacts == 0
        and m.margin_terms is not None
        and set(m.margin_terms) == {"S_h", "S_r", "S_s", "C", "Z_d", "Z_r"}
    )


def test_task_time_lost_without_the_clock_counts_extra_time_off_the_reference(panda_run):
    _, _, log, ref = panda_run
    err = np.zeros(log.t.size)
    err[:300] = 0.01  # 0.3 s more than 5 mm off the reference
    x = log.x_des + np.c_[err, np.zeros((err.size, 2))]
    fixed = _log_like(log, task_time=log.t, x=x)
    ref_on = _log_like(ref, x=ref.x_des.copy())
    assert task_time_lost(fixed, ref_on) == pytest.approx(0.3)


def test_larger_pose_std_widens_the_margin():
    """Same poses, same readings: the covariance of a 5 cm / 5 deg degradation gives a larger Z_d (and S_p)
    than 0.5 mm / 0.05 deg, step by step."""
    chain = panda()
    poses = ring_placement(chain)
    sc = _at_flange(chain, speed=0.5, duration=2.5)
    config = ControllerConfig(separation=SEPARATION)
    runs = {}
    for name, std in (("tight", (0.0005, 0.05)), ("wide", (0.05, 5.0))):
        unc = degraded_uncertainty(poses, *std)
        runs[name] = run_scenario(chain, sc, poses, poses, np.random.default_rng(0), controller=config, uncertainty=unc)
    tight, wide = runs["tight"].terms["Z_d"], runs["wide"].terms["Z_d"]
    both = np.isfinite(tight) & np.isfinite(wide)
    assert both.sum() > 100
    assert np.nanmax(wide) > 0.05 > np.nanmax(tight)
    assert np.nanmax(runs["wide"].margin) > np.nanmax(runs["tight"].margin) + 0.04
    std = np.sqrt(np.diag(degraded_uncertainty(["a"], 0.05, 5.0).pose_cov["a"]))
    np.testing.assert_allclose(std, [0.05 / np.sqrt(3)] * 3 + [np.radians(5.0) / np.sqrt(3)] * 3)
    assert isinstance(degraded_uncertainty([], 0.0, 0.0), SkinUncertainty)


def test_ur5e_keeps_the_hand_off_where_the_blind_robot_is_touched():
    """Any robot: a UR5e with its own ring skin and start configuration; a hand comes at its flange at 1 m/s."""
    chain = get_robot("ur5e")
    poses = ring_placement(chain)
    sc = _at_flange(chain, speed=1.0, duration=2.5)
    body = RobotBody.of(chain)
    config = ControllerConfig(separation=SEPARATION)
    seeing = summarize(run_scenario(chain, sc, poses, poses, np.random.default_rng(0), controller=config), body)
    blind = summarize(run_scenario(chain, sc, poses, {}, np.random.default_rng(0), controller=config), body)
    assert blind.contacts >= 1 and blind.min_clearance_m < 0
    assert seeing.contacts == 0 and seeing.min_clearance_m > 0.05


def test_torque_mode_tracks_the_task_through_the_dynamics():
    """Nobody near: the torque robot follows the circle within 3 mm, and its joint path is not the ideal
    integration of the commands (the dynamics act)."""
    chain = panda()
    poses = paper_placement(chain)
    sc = get_scenario("none", chain, duration=1.5)
    log = run_scenario(chain, sc, poses, poses, np.random.default_rng(0), mode="torque")
    assert log.mode == "torque" and log.tracking_error.max() < 3e-3
    ideal = log.q[0] + np.cumsum(log.qd, axis=0)[:-1] * 1e-3
    assert np.abs(log.q[1:] - ideal).max() > 1e-5


def test_pick_place_task_is_tracked_with_nobody_near():
    chain = panda()
    poses = paper_placement(chain)
    sc = get_scenario("none", chain, duration=3.0, task="pick-place")
    assert isinstance(sc.task, PickPlace)
    log = run_scenario(chain, sc, poses, poses, np.random.default_rng(0))
    assert log.tracking_error.max() < 2e-3
    assert log.x[:, 1].min() < log.x[0, 1] - 0.14  # it went over to the pick point
