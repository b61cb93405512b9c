"""Throughput of forward kinematics and of the analytic simulator (``skincal benchmark core``).

Figures are samples per second measured in this process, with the NumPy baseline of the same run
(one batched 4x4 ``matmul`` per joint over the same samples) for a machine-independent ratio.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import numpy as np

from skincal.kinematics import get_robot
from skincal.protocol import build_trajectory, get_protocol
from skincal.sim.analytic import simulate
from skincal.skin.imu import get_imu_model
from skincal.skin.placement import random_placement


def _best_of(fn: Callable[[], Any], repeat: int) -> float:
    best = np.inf
    for _ in range(repeat):
        start = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - start)
    return best


def run_core_benchmark(
    robot: str = "panda", units: tuple[int, ...] = (1, 10, 100), protocol: str = "paper-sim", repeat: int = 3
) -> dict[str, Any]:
    """FK samples/s (N = 100k configurations) and simulation IMU samples/s for each unit count."""
    chain = get_robot(robot)
    rng = np.random.default_rng(0)
    N = 100_000
    q = rng.uniform(-1.0, 1.0, size=(N, chain.n_joints))
    t_fk = _best_of(lambda: chain.link_frames(q), repeat)
    A = rng.normal(size=(N, 4, 4))

    def floor() -> None:  # one batched 4x4 product per joint: what any DH product must do
        for _ in range(chain.n_joints):
            A @ A

    t_matmul = _best_of(floor, repeat)
    qd, qdd = rng.normal(size=q.shape), rng.normal(size=q.shape)
    t_motion = _best_of(lambda: chain.link_motion(q, qd, qdd), repeat)
    traj = build_trajectory(chain, get_protocol(protocol), np.random.default_rng(1))
    sims = []
    for k in units:
        placements = random_placement(chain, k, np.random.default_rng(k))
        model = get_imu_model("realistic")
        holder: dict[str, Any] = {}

        def run(placements=placements, model=model, holder=holder) -> None:
            holder["ds"] = simulate(chain, placements, traj, model, np.random.default_rng(2))

        elapsed = _best_of(run, 1 if k >= 100 else repeat)
        n_samples = sum(len(s.t) for s in holder["ds"].imu.values())
        sims.append({"units": k, "seconds": elapsed, "imu_samples": n_samples, "samples_per_s": n_samples / elapsed})
    return {
        "robot": chain.name,
        "protocol": protocol,
        "protocol_duration_s": traj.duration,
        "fk": {
            "configurations": N,
            "seconds": t_fk,
            "samples_per_s": N / t_fk,
            "ratio_to_matmul_floor": t_fk / t_matmul,
            "joints": chain.n_joints,
        },
        "link_motion": {"seconds": t_motion, "samples_per_s": N / t_motion},
        "simulation": sims,
    }
