"""``skincal avoid``: run a human-approach scenario with the QP avoidance controller in MuJoCo."""

from __future__ import annotations

import json
from pathlib import Path

import typer

from skincal.cli.app import app, console


@app.command()
def avoid(
    scenario: str = typer.Option("hand", help="none, arm, hand, walk or fast"),
    placement: str = typer.Option("ring", help="simulated skin: ring (dense, 49 units) or paper (Table II, 6 units)"),
    result: Path | None = typer.Option(None, help="calibration result (JSON) whose poses the controller uses"),
    truth: bool = typer.Option(False, "--truth", help="use the true unit poses (the default)"),
    degrade: str | None = typer.Option(None, help="truth degraded by 'METRES,DEGREES' per unit, e.g. 0.05,5"),
    blind: bool = typer.Option(False, "--blind", help="no perception at all (baseline)"),
    duration: float | None = typer.Option(None, help="run length, s (default: the scenario's)"),
    seed: int = typer.Option(0, help="random seed (sensor noise, degradation)"),
    plot: Path | None = typer.Option(None, help="write a Fig.-4-like plot (.png also writes .svg)"),
    as_json: bool = typer.Option(False, "--json", help="print the metrics as JSON"),
) -> None:
    """Track a circle with the Panda's flange while a person approaches; the skin (simulated at its
    true poses: the dense ring skin, or the paper's Table II six units) feeds the controller through
    the chosen calibration (a result file must come from a dataset of the same --placement)."""
    import numpy as np

    from skincal.kinematics import panda
    from skincal.perception.body import RobotBody
    from skincal.workflows.avoid_metrics import summarize
    from skincal.workflows.avoidance import believed_poses, run_scenario, simulated_skin
    from skincal.workflows.scenarios import get_scenario

    chain = panda()
    true_poses = simulated_skin(placement, chain)
    poses, label = believed_poses(true_poses, result, degrade, blind, seed)
    sc = get_scenario(scenario, chain, duration)
    log = run_scenario(chain, sc, true_poses, poses, np.random.default_rng(seed))
    metrics = summarize(log, RobotBody.of(chain), label)
    written = []
    if plot is not None:
        from skincal.workflows.avoid_plot import plot_run

        written = [str(p) for p in plot_run(log, plot)]
    if as_json:
        typer.echo(json.dumps(metrics.to_dict() | {"plots": written}, indent=2))
        return
    m = metrics
    console.print(
        f"scenario {m.scenario} ({sc.description}), poses: {label}\n"
        f"  min clearance {m.min_clearance_m:.3f} m, contacts {m.contacts}, infeasible steps {m.infeasible_steps}\n"
        f"  EE error max {1e3 * m.max_tracking_error_m:.1f} mm, rms {1e3 * m.rms_tracking_error_m:.2f} mm, "
        f"recovery {m.recovery_s:.2f} s after the person left\n"
        f"  QP {m.qp_median_ms:.3f} ms median / {m.qp_p95_ms:.3f} ms p95; loop {m.loop_median_ms:.3f} ms median",
        highlight=False,
    )
    for p in written:
        console.print(f"  wrote {p}", highlight=False)
