"""Benchmark of the avoidance controller (issue 7): scenarios x calibrations, and the QP step time.

Usage: ``python benchmarks/bench_avoid.py [--scenarios arm,hand,walk,fast] [--placement ring|paper]
[--seeds 0,1] [--quick] [--json out.json] [--plots docs]``

A thin script over :mod:`skincal.workflows.bench_avoid` (what runs: the beliefs ``truth``, ``mle``,
``degraded``, ``blind`` per scenario). Prints min clearance, contacts, max tracking error, recovery time
after the person left, QP solve time (median, p95) and whole-loop time per 1 ms step, and the time of one
controller step with 7 DoF and 10 obstacle points (the issue's target: <= 1 ms median).
"""

from __future__ import annotations

import argparse
import json

from skincal.kinematics import panda
from skincal.workflows.bench_avoid import beliefs, qp_step_time, run_avoid_benchmark
from skincal.workflows.script import run_script


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenarios", default="arm,hand,walk,fast")
    ap.add_argument("--placement", default="ring", choices=["ring", "paper"], help="the simulated skin")
    ap.add_argument("--seeds", default="0", help="sensor-noise seeds, comma separated (each run once)")
    ap.add_argument("--quick", action="store_true", help="fast calibration protocol for the mle poses")
    ap.add_argument("--json", default=None)
    ap.add_argument("--plots", default=None, help="folder for docs/avoid_<scenario>.png (mle poses, first seed)")
    args = ap.parse_args()

    step = qp_step_time(panda())
    print(
        f"controller step, 7 DoF, {step['points']} points: {step['step_median_ms']:.3f} ms median "
        f"({step['step_p95_ms']:.3f} p95); QP solve {step['qp_median_ms']:.3f} ms median ({step['qp_p95_ms']:.3f} p95)"
    )
    truth, believed = beliefs(args.placement, args.quick)
    print(
        f"{'scenario':8} {'poses':18} {'seed':>4} {'clear[m]':>8} {'contacts':>8} {'maxerr[mm]':>10} {'recov[s]':>8} "
        f"{'infeas':>6} {'qp med/p95[ms]':>15} {'loop med/p95[ms]':>17}"
    )
    seeds = [int(x) for x in args.seeds.split(",")]

    def show(name, label, seed, m, log) -> None:
        print(
            f"{name:8} {label:18} {seed:4d} {m.min_clearance_m:8.3f} {m.contacts:8d} "
            f"{1e3 * m.max_tracking_error_m:10.1f} {m.recovery_s:8.2f} {m.infeasible_steps:6d} "
            f"{m.qp_median_ms:7.3f}/{m.qp_p95_ms:.3f} {m.loop_median_ms:8.3f}/{m.loop_p95_ms:.3f}",
            flush=True,
        )
        if args.plots and label == "mle" and seed == seeds[0]:
            from skincal.workflows.avoid_plot import plot_run

            plot_run(log, f"{args.plots}/avoid_{name}.png")

    rows = run_avoid_benchmark(args.scenarios.split(","), truth, believed, args.placement, seeds, on_run=show)
    if args.json:
        with open(args.json, "w") as fh:
            json.dump({"step": step, "runs": rows}, fh, indent=2)


if __name__ == "__main__":
    raise SystemExit(run_script(main))
