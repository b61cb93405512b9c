"""Benchmark of the avoidance controller (issue 7): scenarios x calibrations, and the QP step time.

Usage: ``python benchmarks/bench_avoid.py [--scenarios arm,hand,walk,fast] [--placement ring|paper]
[--seeds 0 1] [--quick] [--json out.json] [--plots docs]``

Issue 17 (ISO/TS 15066 separation, any robot, dynamics): ``python benchmarks/bench_avoid.py --iso
[--robots panda,ur5e,iiwa14] [--scenarios ...] [--modes kinematic,torque] [--beliefs mle,degraded]
[--duration S] [--quick] [--json out.json] [--plots folder]`` (:func:`skincal.bench.avoid.run_iso_benchmark`:
every shipped scenario at its ISO 13855 speed, S_p from the covariance and the measured stopping model,
the task clock that waits; contacts, min(clearance - S_p), time lost; the controller step with 100 points
with covariances).

A thin script over :mod:`skincal.bench.avoid` (what runs: the beliefs ``truth``, ``mle``,
``degraded``, ``blind`` per scenario). Prints min clearance, contacts, max tracking error, recovery time
after the person left, QP solve time (median, p95) and whole-loop time per 1 ms step, and the time of one
controller step with 7 DoF and 10 obstacle points (the issue's target: <= 1 ms median).
"""

from __future__ import annotations

import json

from skincal.bench import options
from skincal.bench.avoid import beliefs, qp_step_time, run_avoid_benchmark, run_iso_benchmark
from skincal.bench.harness import parse_args
from skincal.bench.script import run_script
from skincal.kinematics import panda


def main() -> None:
    args = parse_args(__doc__.splitlines()[0], options.AVOID)
    if args.iso:
        return iso(args)

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
    seeds = list(args.seeds)

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


ISO_HEADER = f"{'viol[s]':>7} {'brake[s]':>8} {'vmax':>6} {'rob/pers':>8} {'in-lim':>6} {'ISO':>4}"
"""Issue 28's pass/fail columns (:func:`iso_columns`)."""


def iso_columns(iso: dict | None) -> str:
    """Issue 28's columns: time approaching a point inside its S_p faster than allowed (s; must be 0), of it the
    time that was a stop in progress from the entry into S_p (s), the largest approach speed inside S_p (m/s),
    contacts robot-/person-initiated (robot-initiated must be 0), contacts within the body region's limits of
    all, and the verdict (ISO/TS 15066: no violation, every contact within its limits)."""
    if not iso:
        return f"{'-':>7} {'-':>8} {'-':>6} {'-':>8} {'-':>6} {'-':>4}"
    pair = f"{iso['contacts_robot_initiated']}/{iso['contacts_person_initiated']}"
    n = iso["contacts_robot_initiated"] + iso["contacts_person_initiated"]
    within = f"{iso['contacts_within_limits']}/{n}"
    brake = iso.get("sp_violation_braking_s")
    brake_text = f"{brake:8.3f}" if brake is not None else f"{'-':>8}"
    verdict = "pass" if iso["iso_pass"] else "FAIL"
    return (
        f"{iso['sp_violation_s']:7.3f} {brake_text} {iso['max_approach_inside_sp_mps']:+6.3f} {pair:>8} "
        f"{within:>6} {verdict:>4}"
    )


def iso(args) -> None:
    import time

    from skincal.control.separation import SeparationParams
    from skincal.kinematics import panda
    from skincal.workflows.experiment import StoppingModels

    stopping = StoppingModels()  # each robot's stopping model measured once for the whole run
    step = qp_step_time(panda(), n_points=100, repeats=1000, separation=SeparationParams(stopping=stopping(panda())))
    print(
        f"controller step, 7 DoF, {step['points']} points with covariances (S_p per point): "
        f"{step['step_median_ms']:.3f} ms median ({step['step_p95_ms']:.3f} p95); "
        f"QP solve {step['qp_median_ms']:.3f} ms median",
        flush=True,
    )
    labels = ["degraded 5cm/5deg" if b == "degraded" else b for b in args.beliefs.split(",")]
    print(
        f"{'robot':7} {'scenario':8} {'v_h':>4} {'poses':18} {'mode':9} {'contacts':>8} {'clear[m]':>8} "
        f"{'min(d-Sp)':>9} {'<Sp':>5} {'Sp@min':>6} {'Sp max':>6} {'Z_d':>6} {'stop[s]':>7} {'near[s]':>7} "
        f"{'lost[s]':>7} {'loop med/p95[ms]':>17} {ISO_HEADER}",
        flush=True,
    )

    def show(row, log) -> None:
        zd = (row["margin_terms"] or {}).get("Z_d")
        f = lambda v, w=6: f"{v:{w}.3f}" if v is not None else f"{'-':>{w}}"  # noqa: E731
        print(
            f"{row['robot']:7} {row['scenario']:8} {row['v_h']:4.1f} {row['poses']:18} {row['mode']:9} "
            f"{row['contacts']:8d} {f(row['min_clearance_m'], 8)} {f(row['min_clearance_minus_sp_m'], 9)} "
            f"{row['steps_below_sp']:5d} {f(row['margin_m'])} {f(row['margin_max_m'])} {f(zd)} "
            f"{row['protective_stop_s']:7.2f} {row['near_time_s']:7.2f} {f(row['task_time_lost_s'], 7)} "
            f"{row['loop_median_ms']:8.3f}/{row['loop_p95_ms']:.3f} {iso_columns(row.get('iso'))}",
            flush=True,
        )
        if args.plots and row["poses"] == "mle":
            from skincal.perception.body import RobotBody
            from skincal.workflows.avoid_plot import plot_run

            name = f"{args.plots}/avoid_iso_{row['robot']}_{row['scenario']}_{row['mode']}.png"
            plot_run(log, name, body=RobotBody.of(log_chain[row["robot"]]))

    from skincal.kinematics import get_robot

    robots = args.robots.split(",")
    log_chain = {r: get_robot(r) for r in robots}
    scenarios = args.scenarios.split(",") if args.scenarios != "arm,hand,walk,fast" else None
    t0 = time.process_time()
    rows = run_iso_benchmark(
        robots, scenarios, args.modes.split(","), labels, args.quick, args.duration, on_run=show, stopping=stopping
    )
    print(f"{len(rows)} runs, {time.process_time() - t0:.0f} s CPU", flush=True)
    if args.json:
        from skincal.io.atomic import write_bytes_atomic

        write_bytes_atomic(args.json, json.dumps({"step": step, "runs": rows}, indent=2).encode())


if __name__ == "__main__":
    raise SystemExit(run_script(main))
