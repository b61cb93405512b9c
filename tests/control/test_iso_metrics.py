"""ISO/TS 15066 run metrics as functions of arrays (skincal.control.iso_metrics): no simulator."""

from __future__ import annotations

import numpy as np
import pytest

from skincal.control.iso_metrics import (
    NEAR_BAND,
    TERMS,
    clearance,
    obstacle_segments,
    summarize_run,
    task_time_lost,
)
from skincal.errors import ConfigError
from skincal.kinematics import panda
from skincal.kinematics.points import Q_START
from skincal.perception import RobotBody
from skincal.skin import tof


def test_clearance_is_the_gap_to_the_nearest_capsule_surface():
    """A sphere on the flange's axis: growing it by dr shrinks the clearance by exactly dr; the segments of a
    sphere are its centre twice; no solids is infinite clearance."""
    chain = panda()
    body = RobotBody.of(chain)
    S = 5
    t, q = np.arange(S) * 1e-3, np.tile(Q_START, (S, 1))
    centre = chain.flange_pose(Q_START)[0, :3, 3] + [0.0, 0.0, -0.4]  # below the tool
    small = clearance(t, q, body, lambda tt: [tof.Sphere(centre, 0.05)])
    large = clearance(t, q, body, lambda tt: [tof.Sphere(centre, 0.15)])
    assert np.all(np.isfinite(small)) and np.all(small > 0.1)
    np.testing.assert_allclose(small - large, 0.1, atol=1e-12)
    assert np.all(np.isinf(clearance(t, q, body, None)))
    a, b, r = obstacle_segments([tof.Sphere(centre, 0.05)], 3)
    assert a.shape == (3, 1, 3) and np.array_equal(a, b) and r.tolist() == [0.05]


def test_unsupported_solid_is_a_one_line_config_error():
    with pytest.raises(ConfigError, match="not supported"):
        obstacle_segments([object()], 1)


def test_task_time_lost_from_the_clocks_or_the_time_off_the_reference():
    t = 0.1 * np.arange(10)
    paused = np.concatenate([t[:5], t[5:] - 0.3])  # the task clock lost 0.3 s
    assert task_time_lost(t, np.zeros(10), paused, t, np.zeros(10), t) == pytest.approx(0.3)
    err = np.zeros(10)
    err[2:7] = 0.01  # 5 steps off the reference (> 5 mm) against 2 in the reference
    ref = np.zeros(12)
    ref[:2] = 0.01
    assert task_time_lost(t, err, None, 0.1 * np.arange(12), ref, None) == pytest.approx(0.3)
    with pytest.raises(ConfigError, match="shorter"):
        task_time_lost(t, err, None, t[:5], ref[:5], None)


def test_summary_takes_min_clearance_minus_sp_and_its_parts_at_the_worst_step():
    S = 6
    t = 1e-3 * np.arange(S)
    clear = np.array([0.9, 0.5, 0.3, 0.35, 0.8, np.inf])
    margin = np.array([0.2, 0.2, 0.4, 0.2, 0.2, 0.2])  # worst gap -0.1 at step 2
    terms = {name: np.full(S, float(i)) for i, name in enumerate(TERMS)}
    m = summarize_run(
        scenario="s", poses="p", t=t, clear=clear, margin=margin, terms=terms, tracking_error=np.zeros(S),
        t_leave=0.0, protective_stop=np.array([0, 0, 1, 1, 0, 0], bool), feasible=np.ones(S, bool),
        n_obstacles=np.array([0, 1, 1, 1, 0, 0]), solve_time_s=np.full(S, 1e-4), step_time_s=np.full(S, 2e-4),
        loop_time_s=np.full(S, 3e-4),
    )  # fmt: skip
    assert m.min_clearance_m == pytest.approx(0.3) and m.min_clearance_minus_sp_m == pytest.approx(-0.1)
    assert m.margin_m == pytest.approx(0.4) and m.steps_below_sp == 1 and m.contacts == 0
    assert m.margin_terms == {name: float(i) for i, name in enumerate(TERMS)}
    assert m.protective_stop_s == pytest.approx(2e-3) and m.active_time_s == pytest.approx(3e-3)
    gap = clear - margin
    assert m.near_time_s == pytest.approx(1e-3 * np.sum(np.isfinite(gap) & (gap < NEAR_BAND)))
    assert m.to_dict()["task_time_lost_s"] is None  # NaN without a reference
