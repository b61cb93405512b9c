"""``skincal avoid``: run a human-approach scenario with the QP avoidance controller in MuJoCo."""

from __future__ import annotations

import json
from pathlib import Path

import typer

from skincal.cli.app import app, console, seed_option

ROBOT_HELP = "robot preset (panda, iiwa14, ur5e, ...), a .urdf file, or a DH chain file"
DESCRIPTION_SHOWN = 200
"""Characters of a scenario's description printed (the file may hold megabytes of it)."""


def _clip(text: str, limit: int = DESCRIPTION_SHOWN) -> str:
    return text if len(text) <= limit else text[: limit - 3] + "..."


@app.command()
def avoid(
    scenario: str = typer.Option(
        "hand",
        help="shipped scenario (arm, hand, walk, fast, none, elbow, lower, pinch, walk-at) or a .yaml/.json file",
    ),
    robot: str = typer.Option("panda", help=ROBOT_HELP),
    base_link: str | None = typer.Option(None, help="URDF link the chain starts from (with --robot arm.urdf)"),
    tip_link: str | None = typer.Option(None, help="URDF link the chain ends at (with --robot arm.urdf)"),
    placement: str = typer.Option(
        "ring", help="simulated skin: ring (dense, rings round the links) or paper (Table II)"
    ),
    result: Path | None = typer.Option(None, help="calibration result (JSON) whose poses the controller uses"),
    truth: bool = typer.Option(False, "--truth", help="use the true unit poses (the default)"),
    degrade: str | None = typer.Option(None, help="truth degraded by 'METRES,DEGREES' per unit, e.g. 0.05,5"),
    blind: bool = typer.Option(False, "--blind", help="no perception at all (baseline)"),
    speed: float | None = typer.Option(None, help="every person's speed, m/s (default: the scenario file's)"),
    task: str = typer.Option("circle", help="the flange's task: circle or pick-place"),
    mode: str = typer.Option("kinematic", help="kinematic (ideal velocity interface) or torque (MuJoCo dynamics)"),
    margin: str = typer.Option(
        "fixed",
        help="fixed (the legacy critical distance), iso (ISO/TS 15066 S_p from the pose covariance, "
        "the robot's speed and its measured stopping; inside S_p the robot never approaches) or iso-pfl "
        "(S_p with power and force limiting: inside it the robot may approach at the body region's Annex A speed)",
    ),
    resume: bool = typer.Option(False, "--resume", help="the task waits while a person is within S_p + a band"),
    duration: float | None = typer.Option(None, help="run length, s (default: the scenario's)"),
    seed: int = typer.Option(0, callback=seed_option, help="random seed (sensor noise, degradation)"),
    plot: Path | None = typer.Option(None, help="write a Fig.-4-like plot with clearance and S_p (.png also .svg)"),
    force: bool = typer.Option(False, "--force", help="overwrite an existing --plot"),
    as_json: bool = typer.Option(False, "--json", help="print the metrics as JSON"),
) -> None:
    """Track a circle (or a pick-and-place cycle) with the robot's flange while a person approaches; the
    skin (simulated at its true poses) feeds the controller through the chosen calibration (a result
    file must come from a dataset of the same --robot and --placement). With --resume the same run
    without anybody is made too, for the task time lost."""
    from skincal.errors import ConfigError
    from skincal.io.atomic import check_output
    from skincal.kinematics import get_robot
    from skincal.names import printable
    from skincal.protocol.flange import TASKS
    from skincal.sim.scenarios import get_scenario
    from skincal.workflows.avoidance import MODES, believed_skin, simulated_skin
    from skincal.workflows.experiment import MARGINS, ExperimentConfig, StoppingModels, run_experiment

    if mode not in MODES:
        raise ConfigError(f"unknown --mode '{printable(mode)[:40]}' (use {' or '.join(MODES)})")
    if margin not in MARGINS:
        raise ConfigError(f"unknown --margin '{printable(margin)[:40]}' (use {' or '.join(MARGINS)})")
    if task not in TASKS:
        raise ConfigError(f"unknown --task '{printable(task)[:40]}' (use {' or '.join(TASKS)})")
    plot_paths = []
    if plot is not None:
        if plot.suffix.lower() not in (".png", ".svg"):
            raise ConfigError(f"{plot}: plot file must end in .png or .svg")
        plot_paths = [plot] + ([plot.with_suffix(".svg")] if plot.suffix.lower() == ".png" else [])
        for p in plot_paths:
            check_output(p, force=force, inputs=tuple(x for x in (result,) if x is not None))
    chain = get_robot(robot, base_link=base_link, tip_link=tip_link)
    true_poses = simulated_skin(placement, chain)
    poses, label, uncertainty = believed_skin(true_poses, result, degrade, blind, seed)
    sc = get_scenario(scenario, chain, duration, speed=speed, task=task)
    config = ExperimentConfig(chain, sc, true_poses, poses, label, uncertainty, margin, resume, mode, seed)
    run = run_experiment(config, stopping=StoppingModels())
    log, reference, body, metrics = run.log, run.reference, run.body, run.metrics
    written = []
    if plot is not None:
        from skincal.workflows.avoid_plot import plot_run

        written = [str(p) for p in plot_run(log, plot, body=body)]
    if as_json:
        extra = {"robot": chain.name, "task": task, "margin": margin, "resume": resume, "plots": written}
        typer.echo(json.dumps(metrics.to_dict() | extra, indent=2))
        return
    m = metrics
    lines = [
        f"scenario {printable(m.scenario)} ({_clip(printable(sc.description))}) on {printable(chain.name)}, {task}, "
        f"{mode}, margin {margin}, poses: {printable(label)}",
        f"  min clearance {m.min_clearance_m:.3f} m, contacts {m.contacts}, infeasible steps {m.infeasible_steps}",
        f"  min(clearance - S_p) {m.min_clearance_minus_sp_m:.3f} m (S_p {m.margin_m:.3f} m there, largest "
        f"{m.margin_max_m:.3f} m); protective stop {m.protective_stop_s:.2f} s; "
        f"within S_p + 0.5 m {m.near_time_s:.2f} s",
        f"  EE error max {1e3 * m.max_tracking_error_m:.1f} mm, rms {1e3 * m.rms_tracking_error_m:.2f} mm, "
        f"recovery {m.recovery_s:.2f} s after the person left",
        f"  QP {m.qp_median_ms:.3f} ms median / {m.qp_p95_ms:.3f} ms p95; loop {m.loop_median_ms:.3f} ms median",
    ]
    if m.iso is not None:
        i = m.iso
        lines.append(
            f"  ISO/TS 15066 ({i['iso_criterion']}): {'PASS' if i['iso_pass'] else 'FAIL'}; inside S_p "
            f"{i['inside_sp_s']:.2f} s, approaching there faster than allowed {i['sp_violation_s']:.3f} s (max "
            f"approach {i['max_approach_inside_sp_mps']:.3f} m/s); contacts robot-initiated "
            f"{i['contacts_robot_initiated']}, person-initiated {i['contacts_person_initiated']}, within the "
            f"body-region limits {i['contacts_within_limits']}"
        )
    if m.margin_terms:
        lines.append("  S_p parts there: " + ", ".join(f"{k} {v:.3f}" for k, v in m.margin_terms.items()) + " m")
    if reference is not None:
        lines.append(f"  task time lost {m.task_time_lost_s:.2f} s against the run without a person")
    console.print("\n".join(lines), markup=False, highlight=False)  # names and descriptions come from the file
    for p in written:
        console.print(f"  wrote {printable(p)}", markup=False, highlight=False)
