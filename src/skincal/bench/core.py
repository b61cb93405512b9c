"""Throughput of forward kinematics and of the analytic simulator (``skincal benchmark core``).

Figures are samples per second measured in this process, with the NumPy baseline of the same run
(one batched 4x4 ``matmul`` per joint over the same samples) for a machine-independent ratio.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import replace
from typing import Any

import numpy as np

from skincal.kinematics import get_robot
from skincal.sim import simulate
from skincal.workflows.session import make_session

Progress = Callable[[int, int, str], None]
"""``progress(done, total, what)``: steps finished out of all, and the step now running."""


def _best_of(fn: Callable[[], Any], repeat: int) -> float:
    best = np.inf
    for _ in range(repeat):
        start = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - start)
    return best


def run_core_benchmark(
    robot: str = "panda",
    units: tuple[int, ...] = (1, 10, 100),
    protocol: str = "paper-sim",
    repeat: int = 3,
    progress: Progress | None = None,
) -> dict[str, Any]:
    """FK samples/s (N = 100k configurations) and simulation IMU samples/s for each unit count.

    The sessions come from :func:`skincal.workflows.session.make_session` (``realistic`` IMUs, ideal
    joint states and clocks): unit count ``k`` places its units with seed ``k``; every count runs the
    same motion (that of seed 1) and simulates with seed 2.
    """
    note = progress or (lambda _done, _total, _what: None)
    total = 3 + len(units)
    chain = get_robot(robot)
    rng = np.random.default_rng(0)
    N = 100_000
    q = rng.uniform(-1.0, 1.0, size=(N, chain.n_joints))
    note(0, total, "forward kinematics")
    t_fk = _best_of(lambda: chain.link_frames(q), repeat)
    A = rng.normal(size=(N, 4, 4))

    def floor() -> None:  # one batched 4x4 product per joint: what any DH product must do
        for _ in range(chain.n_joints):
            A @ A

    note(1, total, "batched matmul floor")
    t_matmul = _best_of(floor, repeat)
    qd, qdd = rng.normal(size=q.shape), rng.normal(size=q.shape)
    note(2, total, "link motion")
    t_motion = _best_of(lambda: chain.link_motion(q, qd, qdd), repeat)
    preset = dict(noise="realistic", protocol=protocol, joints="ideal", clock="ideal")
    traj = make_session(robot, "paper", **preset, seed=1).trajectory  # the paper placement draws nothing
    sims = []
    for i, k in enumerate(units):
        note(3 + i, total, f"simulating {k} unit(s)")
        session = replace(make_session(robot, "random", k, **preset, seed=k), trajectory=traj)
        holder: dict[str, Any] = {}

        def run(session=session, holder=holder) -> None:
            holder["ds"] = simulate(replace(session, rng=np.random.default_rng(2)))

        elapsed = _best_of(run, 1 if k >= 100 else repeat)
        n_samples = sum(len(s.t) for s in holder["ds"].imu.values())
        sims.append({"units": k, "seconds": elapsed, "imu_samples": n_samples, "samples_per_s": n_samples / elapsed})
    note(total, total, "done")
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


def core_report(doc: dict[str, Any]) -> list[Any]:
    """What ``skincal benchmark core`` prints: the FK line and the simulation table."""
    from rich.table import Table

    fk = doc["fk"]
    line = (
        f"FK ({fk['joints']} joints): {fk['samples_per_s']:.3g} configurations/s "
        f"({fk['ratio_to_matmul_floor']:.2f}x the floor of {fk['joints']} batched 4x4 matmuls); "
        f"link motion (frames, velocities, accelerations): {doc['link_motion']['samples_per_s']:.3g} /s"
    )
    table = Table(title=f"analytic simulation, {doc['protocol']} ({doc['protocol_duration_s']:.0f} s of motion)")
    for col in ("units", "wall time (s)", "IMU samples", "samples/s"):
        table.add_column(col, justify="right")
    for row in doc["simulation"]:
        table.add_row(
            str(row["units"]), f"{row['seconds']:.2f}", str(row["imu_samples"]), f"{row['samples_per_s']:.3g}"
        )
    return [line, table]
