"""Benchmark of one avoidance-controller step with many obstacle points (issue 17; ``benchmarks/bench_qp.py``).

One QP step of the 7-DoF Panda with ``n_points`` obstacle points, every row feature exercised: moving
points (velocity-aware rows), the cone's spread (``n_rim`` cap candidates per point) and a position
covariance per point (from a unit pose std of 2 mm / 0.5 deg and the VL53L1X noise, first-order
propagated: :mod:`skincal.perception.uncertainty`). The same points are stepped with the fixed critical
distance (``separation = None``) and with the ISO/TS 15066 protective separation, interleaved step by step
so that both see the same machine load; the ratio comes from the same run.

Figures per mode: CPU time of the whole step (:func:`time.process_time`, the process's own time, fair on a
shared machine) and wall time (:func:`time.perf_counter`), and the wall time inside the QP solver
(``StepResult.solve_time_s``); median and 95th percentile, ms.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from skincal.control import AvoidanceController, ControllerConfig, SeparationParams
from skincal.control.body_regions import body_region
from skincal.errors import ConfigError
from skincal.kinematics import panda
from skincal.kinematics.points import Q_START
from skincal.perception import ObstaclePoints, RobotBody, SkinUncertainty, body_proximity, point_covariance
from skincal.workflows.avoidance import robot_mass_matrix


def benchmark_points(chain, n_points: int, seed: int = 0) -> ObstaclePoints:
    """``n_points`` moving obstacle points 0.25 to 0.9 m from the padded robot at ``Q_START`` (within 0.8 m of
    the flange per axis), each with a cone spread and a covariance."""
    rng = np.random.default_rng(seed)
    x = chain.flange_pose(Q_START)[0, :3, 3]
    body = RobotBody.of(chain).inflated(ControllerConfig().padding)
    # a person on one side (+y) of the arm, its surface points 0.45 to 0.9 m from the padded robot
    cand = x + rng.uniform([-0.6, 0.0, -0.6], [0.6, 1.0, 0.6], size=(50 * n_points, 3))
    prox = body_proximity(body, chain.link_frames(Q_START), cand)
    # (nearest to a moving link: a point by the base, which the robot cannot move away from, is no test)
    p = cand[(prox.distance > 0.45) & (prox.distance < 0.9) & (prox.link >= 2)][:n_points]
    if p.shape[0] < n_points:
        raise ConfigError(f"benchmark: could not place {n_points} points around the robot")
    # seen by units looking roughly toward +y (the rays within 45 deg of it), the person coming at 0.2 m/s
    axes = rng.normal(size=(n_points, 3)) * 0.5 + [0.0, 1.0, 0.0]
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    r = rng.uniform(0.2, 1.0, n_points)
    # a unit's ray along ``axes`` (R_link_su with that z column, link frame = base here), pose std 2 mm / 0.5 deg
    helper = np.where(np.abs(axes[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    e1 = np.cross(axes, helper)
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    R = np.stack([e1, np.cross(axes, e1), axes], axis=2)
    pose_cov = np.diag([0.002**2] * 3 + [np.radians(0.5) ** 2] * 3)
    unc = SkinUncertainty()
    cov = point_covariance(
        np.broadcast_to(np.eye(3), (n_points, 3, 3)),
        R,
        r,
        np.broadcast_to(pose_cov, (n_points, 6, 6)),
        unc.range_variance(r),
    )
    spread = r * np.sin(np.deg2rad(13.5))
    return ObstaclePoints(p, ("su1",) * n_points, np.zeros(n_points), r, -0.2 * axes, axes, spread, cov)


def qp_step_benchmark(n_points: int = 100, repeats: int = 2000, seed: int = 0) -> dict[str, Any]:
    """Step times with and without the protective separation (module docstring), ms, and their ratios."""
    chain = panda()
    pts = benchmark_points(chain, n_points, seed)
    ctls = {
        "fixed": AvoidanceController(chain, ControllerConfig()),
        "separation": AvoidanceController(chain, ControllerConfig(separation=SeparationParams())),
        # issue 28: power and force limiting, the effective mass of every row from MuJoCo's M(q) per step
        "pfl": AvoidanceController(
            chain,
            ControllerConfig(separation=SeparationParams(), pfl=body_region("hand"), stop_never_approaches=True),
            mass_matrix=robot_mass_matrix(chain),
        ),
    }
    x = chain.flange_pose(Q_START)[0, :3, 3]
    xd = np.array([0.0, 0.1, 0.0])
    cpu = {k: np.empty(repeats) for k in ctls}
    wall = {k: np.empty(repeats) for k in ctls}
    solve = {k: np.empty(repeats) for k in ctls}
    rows, feasible = {}, {k: 0 for k in ctls}
    for k in range(repeats):
        q = Q_START + 0.01 * np.sin(0.01 * k)
        for name, ctl in ctls.items():
            c0, w0 = time.process_time(), time.perf_counter()
            res = ctl.step(q, x, xd, pts)
            wall[name][k] = time.perf_counter() - w0
            cpu[name][k] = time.process_time() - c0
            solve[name][k] = res.solve_time_s
            rows[name] = res.n_obstacles
            feasible[name] += bool(res.feasible)

    def ms(v: np.ndarray, p: float) -> float:
        return float(np.percentile(v, p) * 1e3)

    out: dict[str, Any] = {"points": n_points, "repeats": repeats, "dof": chain.n_joints}
    for name in ctls:
        out[name] = {
            "rows": rows[name],
            "feasible_fraction": feasible[name] / repeats,
            "step_cpu_median_ms": ms(cpu[name], 50),
            "step_cpu_p95_ms": ms(cpu[name], 95),
            "step_wall_median_ms": ms(wall[name], 50),
            "step_wall_p95_ms": ms(wall[name], 95),
            "qp_median_ms": ms(solve[name], 50),
            "qp_p95_ms": ms(solve[name], 95),
        }
    out["ratio_cpu_median"] = out["separation"]["step_cpu_median_ms"] / out["fixed"]["step_cpu_median_ms"]
    out["ratio_wall_median"] = out["separation"]["step_wall_median_ms"] / out["fixed"]["step_wall_median_ms"]
    return out


def format_qp_benchmark(res: dict[str, Any]) -> str:
    """The figures of :func:`qp_step_benchmark` as a few lines of text."""
    lines = [f"controller step, {res['dof']} DoF, {res['points']} obstacle points, {res['repeats']} steps each (ms)"]
    for name in ("fixed", "separation", "pfl"):
        if name not in res:
            continue
        r = res[name]
        lines.append(
            f"  {name:10s} rows {r['rows']:3d} feasible {100 * r['feasible_fraction']:.0f} %  "
            f"step CPU median {r['step_cpu_median_ms']:.3f} p95 "
            f"{r['step_cpu_p95_ms']:.3f}  wall median {r['step_wall_median_ms']:.3f} p95 {r['step_wall_p95_ms']:.3f}"
            f"  QP solve median {r['qp_median_ms']:.3f} p95 {r['qp_p95_ms']:.3f}"
        )
    lines.append(
        f"  separation / fixed: CPU median x{res['ratio_cpu_median']:.2f}, wall median x{res['ratio_wall_median']:.2f}"
    )
    return "\n".join(lines)
