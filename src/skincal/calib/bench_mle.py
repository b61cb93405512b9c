"""The default calibrator's targets, measured (``skincal benchmark mle``).

* accuracy, noise-free: the paper's protocol and configuration;
* accuracy under the ``realistic`` sensor preset: random placements on the Panda and the Sawyer,
  joint accelerations estimated from q/qd, links found from the data, and the calibration of the
  reported standard deviations (RMS of error / std per axis);
* the ``fast`` protocol under ``realistic`` sensors;
* run time for 6 and 100 units (one worker, and two workers as ``skincal calibrate`` uses: forked processes on Linux);
* OM (the paper's method) against ``mle`` on the same data, wall-time ratio and errors.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import replace
from typing import Any

import numpy as np

from skincal.calib import calibrate, evaluate
from skincal.kinematics import get_robot
from skincal.protocol import build_trajectory, get_protocol
from skincal.sim.analytic import simulate
from skincal.skin.imu import get_imu_model
from skincal.skin.placement import paper_placement, random_placement


def protocol_for(chain, name: str):
    """A protocol preset that respects the robot's velocity limits (the paper's 2 rad/s exceeds
    the Sawyer's joint 1-2 limits: those amplitudes are capped at 95 % of the limit)."""
    config = get_protocol(name).for_chain(chain)
    if chain.velocity_limit is not None:
        amp = np.minimum(config.amplitude_per_joint(chain.n_joints), 0.95 * chain.velocity_limit)
        config = replace(config, amplitude=tuple(float(a) for a in amp))
    return config


def simulate_session(robot: str, placement: str, n_units: int, noise: str, protocol: str, seed: int):
    chain = get_robot(robot)
    rng = np.random.default_rng(seed)
    pl = paper_placement(chain) if placement == "paper" else random_placement(chain, n_units, rng)
    traj = build_trajectory(chain, protocol_for(chain, protocol), rng)
    return simulate(chain, pl, traj, get_imu_model(noise), rng)


def _summary(ds, result) -> dict[str, Any]:
    ev = evaluate(result, ds)
    z = []
    for name, unit in result.units.items():
        if unit.observable and unit.position_std_m is not None:
            z.extend((unit.pose.p_link_su - ds.truth[name].p_link_su) / unit.position_std_m)
    return {
        "mean_position_error_mm": ev["mean_position_error_mm"],
        "max_position_error_mm": max(u["position_error_mm"] for u in ev["units"].values()),
        "mean_rotation_error_deg": ev["mean_rotation_error_deg"],
        "links_correct": ev["links_correct"],
        "units_total": ev["units_total"],
        "runtime_s": result.runtime_s,
        "z_rms": float(np.sqrt(np.mean(np.square(z)))) if z else None,
    }


def run_mle_benchmark(
    runs: int = 20, quick: bool = False, with_om: bool = True, progress: Callable[[str], None] | None = None
) -> dict[str, Any]:
    """All targets of the default calibrator (module docstring). ``quick`` shrinks every part."""
    note = progress or (lambda _msg: None)
    out: dict[str, Any] = {"runs": runs, "quick": quick}
    protocol = "fast" if quick else "paper-sim"
    note("noise-free, paper configuration")
    ds = simulate_session("panda", "paper", 6, "none", protocol, seed=0)
    out["noise_free_paper"] = _summary(ds, calibrate(ds, "mle"))
    for robot in ("panda", "sawyer"):
        rows = []
        for seed in range(runs):
            note(f"realistic, {robot}, placement {seed + 1}/{runs}")
            ds = simulate_session(robot, "random", 6, "realistic", protocol, seed=100 + seed)
            rows.append(_summary(ds, calibrate(ds, "mle")))
        out[f"realistic_{robot}"] = _aggregate(rows)
    rows = []
    for seed in range(runs):
        note(f"fast protocol, realistic, panda {seed + 1}/{runs}")
        ds = simulate_session("panda", "random", 6, "realistic", "fast", seed=200 + seed)
        rows.append(_summary(ds, calibrate(ds, "mle")))
    out["fast_protocol_panda"] = _aggregate(rows)
    out["fast_protocol_duration_s"] = float(ds.duration)
    for n_units in (6, 100):
        for proto in ("paper-sim", "fast") if not quick else ("fast",):
            note(f"run time, {n_units} units, {proto}")
            ds = simulate_session("panda", "random", n_units, "realistic", proto, seed=300)
            start = time.perf_counter()
            result = calibrate(ds, "mle")
            out[f"runtime_{n_units}_units_{proto}_s"] = time.perf_counter() - start
            start = time.perf_counter()
            calibrate(ds, "mle", workers=2)
            out[f"runtime_{n_units}_units_{proto}_2_workers_s"] = time.perf_counter() - start
            out[f"runtime_{n_units}_units_{proto}_summary"] = _summary(ds, result)
    if with_om:
        note("OM vs mle on the same data")
        ds = simulate_session("panda", "paper", 6, "none", protocol, seed=0)
        t0 = time.perf_counter()
        om = calibrate(ds, "om", use_truth_links=True)
        t_om = time.perf_counter() - t0
        t0 = time.perf_counter()
        mle = calibrate(ds, "mle")
        t_mle = time.perf_counter() - t0
        out["om_vs_mle"] = {
            "om_s": t_om,
            "mle_s": t_mle,
            "ratio": t_om / t_mle,
            "om": _summary(ds, om),
            "mle": _summary(ds, mle),
        }
    return out


def _aggregate(rows: list[dict[str, Any]]) -> dict[str, Any]:
    keys = ("mean_position_error_mm", "max_position_error_mm", "mean_rotation_error_deg", "runtime_s", "z_rms")
    agg: dict[str, Any] = {k: float(np.mean([r[k] for r in rows if r[k] is not None])) for k in keys}
    agg["worst_mean_position_error_mm"] = float(max(r["mean_position_error_mm"] for r in rows))
    agg["links_correct"] = int(sum(r["links_correct"] for r in rows))
    agg["units_total"] = int(sum(r["units_total"] for r in rows))
    agg["runs"] = len(rows)
    return agg
