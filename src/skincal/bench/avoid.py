"""Benchmark of the avoidance controller (issue 7; ``benchmarks/bench_avoid.py``): scenarios x calibrations,
and the QP step time.

For every scenario the MuJoCo closed loop (:func:`skincal.workflows.experiment.run_experiment`) runs with
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

**Issue 17** (:func:`run_iso_benchmark`): on several robots (``panda``, ``ur5e``, ``iiwa14``) with the
dense ring skin, every shipped scenario at the ISO 13855 speed its file names (1.6 m/s for a walking
person, 2.0 m/s for a hand), the controller with the ISO/TS 15066 protective separation (``S_p`` from
each point's covariance, the robot's speed and its measured stopping model) and the task clock that waits
and resumes, in kinematic and torque mode, believing

* ``mle``: a calibration of a ``realistic`` simulated session of that robot and skin (its covariance);
* ``degraded 5cm/5deg``: the truth moved by 5 cm and turned by 5 deg per unit, with the std such a
  degradation has (2.9 cm and 2.9 deg per axis, :func:`~skincal.workflows.avoidance.degraded_uncertainty`)
  as its covariance: the margin grows.

Each run is compared with the same run without a person for the task time lost.
"""

from __future__ import annotations

import itertools
import time
from collections.abc import Callable, Sequence
from dataclasses import replace
from typing import Any

import numpy as np

from skincal.bench.options import ISO_ROBOTS
from skincal.control import AvoidanceController, ControllerConfig
from skincal.control.iso_metrics import AvoidMetrics
from skincal.kinematics import panda
from skincal.kinematics.points import Q_START
from skincal.perception import ObstaclePoints
from skincal.sim.scenarios import degrade_poses, get_scenario
from skincal.workflows.avoidance import RunLog, simulated_skin
from skincal.workflows.experiment import ExperimentConfig, StoppingModels, run_experiment, separation_for
from skincal.workflows.session import simulate_dataset


def mle_poses(truth, placement: str, quick: bool, report: Callable[[str], None] = print, robot: str = "panda"):
    """Poses from the default calibration (mle) of a simulated session with ``placement``."""
    return mle_result(truth, placement, quick, report, robot)[0]


def mle_result(truth, placement: str, quick: bool, report: Callable[[str], None] = print, robot: str = "panda"):
    """``(poses, result)`` of the default calibration (mle) of a simulated ``realistic`` session of ``robot``
    with ``placement`` (protocol ``fast`` when ``quick``, else ``paper-sim``; seed 0)."""
    from skincal.calib import calibrate

    ds = simulate_dataset(robot, placement, None, "realistic", "fast" if quick else "paper-sim", 0, "analytic")
    t0 = time.perf_counter()
    res = calibrate(ds, "mle", seed=0)
    err = np.array([np.linalg.norm(r.pose.p_link_su - truth[u].p_link_su) for u, r in res.units.items()])
    links = sum(r.pose.link == truth[u].link for u, r in res.units.items())
    report(
        f"{robot}: mle calibration of {len(err)} units: {time.perf_counter() - t0:.1f} s, links {links}/{len(err)}, "
        f"position error mean {1e3 * err.mean():.3f} mm, max {1e3 * err.max():.3f} mm"
    )
    return {u: r.pose for u, r in res.units.items()}, res


def qp_step_time(chain, n_points: int = 10, repeats: int = 2000, separation=None) -> dict:
    """Median/p95 time of one controller step (perception excluded; cone candidates and velocities
    included; with ``separation`` (:class:`~skincal.control.separation.SeparationParams`) each point's
    ``S_p`` from a covariance too) and of its QP solve, ms."""
    rng = np.random.default_rng(0)
    ctl = AvoidanceController(chain, ControllerConfig(separation=separation) if separation else ControllerConfig())
    x = chain.flange_pose(Q_START)[0, :3, 3]
    p = x + rng.uniform(-0.4, 0.4, size=(n_points, 3))
    axes = rng.normal(size=(n_points, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    r = rng.uniform(0.2, 1.0, n_points)  # moving points with the cone's spread: every row feature is exercised
    pts = ObstaclePoints(p, ("su1",) * n_points, np.zeros(n_points), r, -0.5 * axes, axes, r * np.sin(np.deg2rad(13.5)))
    if separation is not None:  # a covariance per point: 1 cm std and some correlation
        A = 0.01 * rng.normal(size=(n_points, 3, 3))
        pts = replace(pts, cov=A @ np.swapaxes(A, 1, 2) + 1e-4 * np.eye(3))
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
    rows = []
    for name in scenarios:
        sc = get_scenario(name, chain)
        for (label, poses), seed in itertools.product(believed.items(), seeds):
            run = run_experiment(ExperimentConfig(chain, sc, truth, poses, label, seed=seed))
            m = run.metrics
            rows.append(m.to_dict() | {"seed": seed, "placement": placement})
            if on_run is not None:
                on_run(name, label, seed, m, run.log)
    return rows


# ---------------------------------------------------------------------------------------------- issue 17
ISO_BELIEFS = ("mle", "degraded 5cm/5deg")
DEGRADE = (0.05, 5.0)
"""The degradation of the issue: 5 cm, 5 deg per unit."""


def iso_beliefs(robot: str, labels: Sequence[str] = ISO_BELIEFS, quick: bool = False, report=print):
    """``(chain, truth, {label: (poses, uncertainty)})`` for ``robot`` with the dense ring skin."""
    from skincal.kinematics import get_robot
    from skincal.perception.uncertainty import SkinUncertainty
    from skincal.workflows.avoidance import degraded_uncertainty

    chain = get_robot(robot)
    truth = simulated_skin("ring", chain)
    out = {}
    for label in labels:
        if label == "mle":
            poses, res = mle_result(truth, "ring", quick, report, robot)
            out[label] = (poses, SkinUncertainty.from_result(res))
        elif label == "truth":
            out[label] = (truth, None)
        elif label.startswith("degraded"):
            poses = degrade_poses(truth, *DEGRADE, np.random.default_rng(1))
            out[label] = (poses, degraded_uncertainty(poses, *DEGRADE))
        elif label == "blind":
            out[label] = ({}, None)
        else:
            raise ValueError(f"unknown belief {label!r}")
    return chain, truth, out


def run_iso_benchmark(
    robots: Sequence[str] = ISO_ROBOTS,
    scenarios: Sequence[str] | None = None,
    modes: Sequence[str] = ("kinematic", "torque"),
    labels: Sequence[str] = ISO_BELIEFS,
    quick: bool = False,
    duration: float | None = None,
    seed: int = 0,
    report: Callable[[str], None] = print,
    on_run: Callable[[dict, RunLog], None] | None = None,
    stopping: StoppingModels | None = None,
) -> list[dict[str, Any]]:
    """The issue-17 matrix (module docstring): one row (metrics dict plus ``robot``, ``mode``, ``v_h``, the
    degraded std) per (robot, scenario, belief, mode); ``duration`` shortens every run (tests). ``stopping``:
    the stopping models measured so far (each robot's is measured once per call without it)."""
    from skincal.control.separation import protective_separation
    from skincal.sim.scenarios import shipped_scenarios

    stopping = stopping if stopping is not None else StoppingModels()

    # fast is hand at another speed: at the ISO speed both are the same run
    names = list(scenarios) if scenarios else [s for s in shipped_scenarios() if s not in ("none", "fast")]
    rows = []
    for robot in robots:
        chain, truth, believed = iso_beliefs(robot, labels, quick, report)
        stop = stopping(chain)
        report(
            f"{robot}: {len(truth)} units; stopping model T_r {stop.reaction_time_s:.3f} s, "
            + ", ".join(
                f"{v:.2f} m/s: {s:.3f} m in {t:.3f} s"
                for v, t, s in zip(stop.speeds, stop.times, stop.distances, strict=True)
                if v > 0
            )  # fmt: skip
        )
        runs = []
        for name in names:
            probe = get_scenario(name, chain)
            runs.append(get_scenario(name, chain, duration, speed=probe.human_speed))
        # nobody near: the separation model never acts, so one reference run (the longest) serves all
        longest = replace(runs[0].without_people(), duration=max(sc.duration for sc in runs))
        refs = {
            mode: run_experiment(
                ExperimentConfig(chain, longest, truth, truth, resume=True, mode=mode, seed=seed, reference=False)
            ).log
            for mode in modes
        }
        for sc in runs:
            sep = separation_for(chain, sc, stopping=stopping)
            still = float(protective_separation(sep, np.zeros(1), None, np.zeros(1)).total[0])
            for mode in modes:
                for label, (poses, unc) in believed.items():
                    config = ExperimentConfig(chain, sc, truth, poses, label, unc, "iso", True, mode, seed)
                    run = run_experiment(config, stopping=stopping, reference=refs[mode])
                    log = run.log
                    row = run.metrics.to_dict() | {
                        "robot": robot,
                        "v_h": sc.human_speed,
                        "units": len(truth),
                        "S_p_still_m": still,
                        "degraded_std": _std_text(label),
                    }
                    rows.append(row)
                    if on_run is not None:
                        on_run(row, log)
    return rows


def _std_text(label: str) -> str:
    if not label.startswith("degraded"):
        return ""
    pos, ang = DEGRADE
    return f"{100 * pos / np.sqrt(3):.1f} cm / {ang / np.sqrt(3):.1f} deg per axis"
