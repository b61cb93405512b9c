"""Benchmark of the avoidance controller (issue 7): scenarios x calibrations, and the QP step time.

Usage: ``python benchmarks/bench_avoid.py [--scenarios arm,hand,walk,fast] [--placement ring|paper]
[--seeds 0,1] [--quick] [--json out.json] [--plots docs]``

For every scenario it runs the MuJoCo closed loop with the controller believing

* ``truth``: the true unit poses of the simulated skin (default the dense ring skin,
  :func:`skincal.skin.placement.ring_placement`; ``--placement paper``: the Table II six);
* ``mle``: a calibration result from ``skincal``'s default method on a simulated session
  (same placement, realistic IMU noise, paper-sim protocol, seed 0);
* ``degraded``: the truth moved by 5 cm and turned by 5 deg per unit;
* ``blind``: no perception (what happens without the skin),

and prints min clearance, contacts, max tracking error, recovery time after the person left, QP
solve time (median, p95) and whole-loop time per 1 ms step. Separately it times one controller step
with 7 DoF and 10 obstacle points (the issue's target: <= 1 ms median).
"""

from __future__ import annotations

import argparse
import itertools
import json
import time

import numpy as np

from skincal.control import AvoidanceController, ControllerConfig, get_scenario
from skincal.kinematics import panda
from skincal.perception import RobotBody
from skincal.skin.placement import paper_placement, ring_placement
from skincal.workflows.avoid_metrics import summarize
from skincal.workflows.avoidance import run_scenario
from skincal.workflows.scenarios import Q_START, degrade_poses


def mle_poses(truth, placement: str, quick: bool):
    """Poses from the default calibration (mle) of a simulated session with ``placement``."""
    from skincal.calib import calibrate
    from skincal.workflows.session import simulate_dataset

    ds = simulate_dataset("panda", placement, None, "realistic", "fast" if quick else "paper-sim", 0, "analytic")
    t0 = time.perf_counter()
    res = calibrate(ds, "mle", seed=0)
    err = np.array([np.linalg.norm(r.pose.p_link_su - truth[u].p_link_su) for u, r in res.units.items()])
    links = sum(r.pose.link == truth[u].link for u, r in res.units.items())
    print(
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
    from skincal.perception import ObstaclePoints

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


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenarios", default="arm,hand,walk,fast")
    ap.add_argument("--placement", default="ring", choices=["ring", "paper"], help="the simulated skin")
    ap.add_argument("--seeds", default="0", help="sensor-noise seeds, comma separated (each run once)")
    ap.add_argument("--quick", action="store_true", help="fast calibration protocol for the mle poses")
    ap.add_argument("--json", default=None)
    ap.add_argument("--plots", default=None, help="folder for docs/avoid_<scenario>.png (mle poses, first seed)")
    args = ap.parse_args()

    chain = panda()
    truth = (ring_placement if args.placement == "ring" else paper_placement)(chain)
    body = RobotBody.of(chain)
    step = qp_step_time(chain)
    print(
        f"controller step, 7 DoF, {step['points']} points: {step['step_median_ms']:.3f} ms median "
        f"({step['step_p95_ms']:.3f} p95); QP solve {step['qp_median_ms']:.3f} ms median ({step['qp_p95_ms']:.3f} p95)"
    )
    beliefs = {
        "truth": truth,
        "mle": mle_poses(truth, args.placement, args.quick),
        "degraded 5cm/5deg": degrade_poses(truth, 0.05, 5.0, np.random.default_rng(1)),
        "blind": {},
    }
    rows = []
    header = (
        f"{'scenario':8} {'poses':18} {'seed':>4} {'clear[m]':>8} {'contacts':>8} {'maxerr[mm]':>10} {'recov[s]':>8} "
        f"{'infeas':>6} {'qp med/p95[ms]':>15} {'loop med/p95[ms]':>17}"
    )
    print(header)
    for name in args.scenarios.split(","):
        sc = get_scenario(name, chain)
        seeds = [int(x) for x in args.seeds.split(",")]
        for (label, poses), seed in itertools.product(beliefs.items(), seeds):
            log = run_scenario(chain, sc, truth, poses, np.random.default_rng(seed))
            m = summarize(log, body, label)
            rows.append(m.to_dict() | {"seed": seed, "placement": args.placement})
            print(
                f"{name:8} {label:18} {seed:4d} {m.min_clearance_m:8.3f} {m.contacts:8d} "
                f"{1e3 * m.max_tracking_error_m:10.1f} {m.recovery_s:8.2f} {m.infeasible_steps:6d} "
                f"{m.qp_median_ms:7.3f}/{m.qp_p95_ms:.3f} {m.loop_median_ms:8.3f}/{m.loop_p95_ms:.3f}",
                flush=True,
            )
            if args.plots and label == "mle" and seed == seeds[0]:
                from skincal.workflows.avoid_plot import plot_run

                plot_run(log, f"{args.plots}/avoid_{name}.png")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump({"step": step, "runs": rows}, fh, indent=2)


if __name__ == "__main__":
    main()
