"""Benchmark of the avoidance controller (issue 7; ``benchmarks/bench_avoid.py``): scenarios x calibrations,
and the QP step time.

For every scenario the MuJoCo closed loop (:func:`skincal.workflows.avoidance.run_scenario`) runs with
the controller believing

* ``truth``: the true unit poses of the simulated skin (the dense ring skin,
  :func:`skincal.skin.placement.ring_placement`, or the Table II six);
* ``mle``: a calibration result from ``skincal``'s default method on a simulated session
  (:func:`skincal.workflows.session.simulate_dataset`: same placement, realistic IMU noise, paper-sim
  protocol, seed 0);
* ``degraded 5cm/5deg``: the truth moved by 5 cm and turned by 5 deg per unit;
* ``blind``: no perception (what happens without the skin).

Separately it times one controller step with 7 DoF and 10 obstacle points (the issue's target:
<= 1 ms median).
"""

from __future__ import annotations

import itertools
import time
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from skincal.control import AvoidanceController, ControllerConfig
from skincal.kinematics import panda
from skincal.perception import ObstaclePoints, RobotBody
from skincal.workflows.avoid_metrics import AvoidMetrics, summarize
from skincal.workflows.avoidance import RunLog, run_scenario, simulated_skin
from skincal.workflows.scenarios import Q_START, degrade_poses, get_scenario
from skincal.workflows.session import simulate_dataset


def mle_poses(truth, placement: str, quick: bool, report: Callable[[str], None] = print):
    """Poses from the default calibration (mle) of a simulated session with ``placement``."""
    from skincal.calib import calibrate

    ds = simulate_dataset("panda", placement, None, "realistic", "fast" if quick else "paper-sim", 0, "analytic")
    t0 = time.perf_counter()
    res = calibrate(ds, "mle", seed=0)
    err = np.array([np.linalg.norm(r.pose.p_link_su - truth[u].p_link_su) for u, r in res.units.items()])
    links = sum(r.pose.link == truth[u].link for u, r in res.units.items())
    report(
        f"mle calibration of {len(err)} units: {time.perf_counter() - t0:.1f} s, links {links}/{len(err)}, "
        f"position error mean {1e3 * err.mean():.3f} mm, max {1e3 * err.max():.3f} mm"
    )
    return {u: r.pose for u, r in res.units.items()}


def qp_step_time(chain, n_points: int = 10, repeats: int = 2000) -> dict:
    """Median/p95 time of one controller step (perception excluded; cone candidates and velocities
    included) and of its QP solve, ms."""
    rng = np.random.default_rng(0)
    ctl = AvoidanceController(chain, ControllerConfig())
    x = chain.flange_pose(Q_START)[0, :3, 3]
    p = x + rng.uniform(-0.4, 0.4, size=(n_points, 3))
    axes = rng.normal(size=(n_points, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    r = rng.uniform(0.2, 1.0, n_points)  # moving points with the cone's spread: every row feature is exercised
    pts = ObstaclePoints(p, ("su1",) * n_points, np.zeros(n_points), r, -0.5 * axes, axes, r * np.sin(np.deg2rad(13.5)))
    step, solve = [], []
    for k in range(repeats):
        q = Q_START + 0.01 * np.sin(0.01 * k)
        t0 = time.perf_counter()
        res = ctl.step(q, x, np.array([0.0, 0.1, 0.0]), pts)
        step.append(time.perf_counter() - t0)
        solve.append(res.solve_time_s)
    ms = lambda v, p: float(np.percentile(v, p) * 1e3)  # noqa: E731
    return {
        "points": n_points,
        "rows": res.n_obstacles,
        "step_median_ms": ms(step, 50),
        "step_p95_ms": ms(step, 95),
        "qp_median_ms": ms(solve, 50),
        "qp_p95_ms": ms(solve, 95),
    }


def beliefs(placement: str = "ring", quick: bool = False, report: Callable[[str], None] = print):
    """``(true poses, {belief label: poses})`` of the module docstring for the simulated skin ``placement``."""
    truth = simulated_skin(placement, panda())
    return truth, {
        "truth": truth,
        "mle": mle_poses(truth, placement, quick, report),
        "degraded 5cm/5deg": degrade_poses(truth, 0.05, 5.0, np.random.default_rng(1)),
        "blind": {},
    }


def run_avoid_benchmark(
    scenarios: Sequence[str],
    truth: dict,
    believed: dict[str, dict],
    placement: str = "ring",
    seeds: Sequence[int] = (0,),
    on_run: Callable[[str, str, int, AvoidMetrics, RunLog], None] | None = None,
) -> list[dict[str, Any]]:
    """Every ``(scenario, belief, seed)`` run's metrics (dicts with ``seed`` and ``placement``) for the skin
    ``truth`` and the beliefs ``believed`` (:func:`beliefs`), in order; ``on_run(scenario, belief, seed,
    metrics, log)`` after each run."""
    chain = panda()
    body = RobotBody.of(chain)
    rows = []
    for name in scenarios:
        sc = get_scenario(name, chain)
        for (label, poses), seed in itertools.product(believed.items(), seeds):
            log = run_scenario(chain, sc, truth, poses, np.random.default_rng(seed))
            m = summarize(log, body, label)
            rows.append(m.to_dict() | {"seed": seed, "placement": placement})
            if on_run is not None:
                on_run(name, label, seed, m, log)
    return rows
