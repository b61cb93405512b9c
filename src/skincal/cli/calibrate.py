"""``skincal calibrate`` and ``skincal evaluate``."""

from __future__ import annotations

import json
from pathlib import Path

import typer

from skincal.cli.app import LiveMeter, app, console, console_warning, require_file, seed_option, shown
from skincal.errors import ConfigError
from skincal.io.files import DATASET_FILE, RESULT_FILE

NO_UNIT_EXIT = 1
"""Exit code of ``calibrate`` when the result was written but no unit could be calibrated (each unit
is listed in it with its reason and ``observable: false``); 2 stays for usage and data errors, where
nothing is written (``docs/interfaces.md``, exit codes)."""


def read_links_file(path: Path) -> dict[str, int]:
    """A mapping ``unit -> 1-based link`` from a YAML or JSON file."""
    from skincal.io.jsonio import load_yaml

    doc = load_yaml(path, "links file", ConfigError)  # JSON is YAML
    if not isinstance(doc, dict) or not all(isinstance(v, int) and not isinstance(v, bool) for v in doc.values()):
        raise ConfigError(f"{path}: a links file maps unit names to 1-based link numbers, e.g. 'su1: 3'")
    return {str(k): int(v) for k, v in doc.items()}


def std_cell(values, scale: float = 1.0) -> str:
    """The largest std component as text: ``-`` without a std; undetermined (NaN) components are
    left out and counted, e.g. ``0.660 (1 undetermined)``, or ``- (3 undetermined)``."""
    import numpy as np

    if values is None:
        return "-"
    arr = np.asarray(values, dtype=float).ravel()
    known = arr[np.isfinite(arr)]
    text = f"{scale * float(known.max()):.3f}" if known.size else "-"
    missing = arr.size - known.size
    return f"{text} ({missing} undetermined)" if missing else text


def unit_table(result, title: str):
    """The per-unit table; units without a pose (``failed_units``) get a row saying why. The link is its
    number and, where the result names it, its name (a URDF's link); the last column holds the warnings
    (the notes, what was found and corrected, are in the result file). Names and warnings are shown
    escaped (:func:`skincal.cli.app.shown`)."""
    from rich.table import Table

    from skincal.data.result import has_position

    table = Table(title=shown(title))
    for col in ("unit", "link", "position (m)", "quaternion (w,x,y,z)", "pos std (mm)", "rot std (deg)", "warnings"):
        table.add_column(col)
    for name, unit in result.units.items():
        std_p = std_cell(unit.position_std_m, 1e3)
        std_r = std_cell(unit.rotation_std_deg)
        notes = ("unobservable; " if not unit.observable else "") + "; ".join(unit.warnings)
        link_name = unit.extras.get("link_name")
        table.add_row(
            shown(name),
            f"{unit.pose.link} ({shown(link_name)})" if isinstance(link_name, str) else str(unit.pose.link),
            " ".join(f"{x:+.4f}" for x in unit.pose.p_link_su) if has_position(unit) else "- (not determined)",
            " ".join(f"{x:+.4f}" for x in unit.pose.quaternion_wxyz),
            std_p,
            std_r,
            shown(notes or ""),
        )
    for name, reason in result.failed_units.items():
        if name not in result.units:
            table.add_row(shown(name), "-", "-", "-", "-", "-", shown(f"not calibrated: {reason}"))
    return table


@app.command()
def calibrate(
    datasets: list[Path] = typer.Argument(..., help="dataset file (.h5); several: a fleet, --out is then a folder"),
    out: Path = typer.Option(
        ..., "--out", "-o", help="result file to write (.json); with several datasets a folder (<stem>.json each)"
    ),
    method: str = typer.Option("mle", help="mle (default), om (paper), om-joint, mmm, mm"),
    seed: int = typer.Option(0, callback=seed_option, help="seed for methods with random starts"),
    links: Path | None = typer.Option(None, help="YAML/JSON file mapping unit -> 1-based link"),
    use_truth_links: bool = typer.Option(False, help="take each unit's link from the dataset truth"),
    use_dataset_qdd: bool = typer.Option(False, help="use the dataset's qdd instead of estimating it"),
    unit: list[str] | None = typer.Option(None, help="calibrate only this unit (repeatable)"),
    workers: int = typer.Option(
        2, min=1, help="units calibrated at once (forked processes on Linux, else threads); with several datasets: "
        "datasets at once"
    ),
    dask: str | None = typer.Option(None, "--dask", help="several datasets: address of a dask.distributed scheduler"),
    option: list[str] | None = typer.Option(
        None, "--option", help="method option name=value (repeatable), e.g. scale=false (mle), maxeval_static=500 "
        "(with --method om)"
    ),
    force: bool = typer.Option(False, "--force", help="overwrite --out if it exists"),
    reference: str | None = typer.Option(
        None,
        "--reference",
        help="IMU-only: pose every unit in this unit's frame from the IMUs alone (joints not needed)",
    ),
    compare_with: Path | None = typer.Option(
        None, "--compare-with", help="with --reference: a joint-based result (e.g. mle) of the dataset to compare with"
    ),
    follow: bool = typer.Option(
        False, "--follow", help="stream the dataset (or a ROS bag) into the online calibrator with a live meter; stop "
        "when every unit reaches --target (or at the data's end) and write the result"
    ),
    speed: float | None = typer.Option(
        None, "--speed", help="--follow: data seconds per wall second (default 1: real speed; 0: as fast as possible)"
    ),
    target: str | None = typer.Option(
        None, "--target", help="--follow: std to reach on every axis, position and rotation with units "
        "(default 0.3mm,0.05deg)"
    ),
    robot: str | None = typer.Option(
        None, "--robot", help="--follow of a ROS bag: robot preset, .urdf or chain file (default: the bag's "
        "/robot_description; without one, required)"
    ),
    watch: bool = typer.Option(
        False, "--watch", help="--follow: keep following to the data's end and watch every calibrated unit: one "
        "that moved on its link is flagged, re-calibrated from the data after the change and recorded in the "
        "result's events"
    ),
) -> None:
    """Calibrate the skin units of a dataset (or of many: a fleet) and write the result JSON."""
    if compare_with is not None and reference is None:
        raise ConfigError("--compare-with needs --reference (it compares an IMU-only result with a joint-based one)")
    if follow:
        if len(datasets) > 1 or dask is not None or reference is not None:
            raise ConfigError("--follow streams one dataset or bag; give one, without --dask or --reference")
        if method != "mle" or option or links is not None or use_truth_links or use_dataset_qdd:
            raise ConfigError("--follow uses the online calibrator: --method, --option, --links, --use-truth-links "
                              "and --use-dataset-qdd do not apply")  # fmt: skip
        _calibrate_follow(datasets[0], out, speed, target, robot, unit, force, watch)
        return
    for given, name in ((speed, "--speed"), (target, "--target"), (robot, "--robot"), (watch or None, "--watch")):
        if given is not None:
            raise ConfigError(f"{name} applies to --follow only")
    if reference is not None:
        if len(datasets) > 1 or dask is not None:
            raise ConfigError("--reference calibrates one dataset; give one dataset with it")
        _calibrate_relative(datasets[0], out, reference, unit, compare_with, force, option or [])
        return
    if len(datasets) == 1 and dask is None:  # a missing dataset is refused before calib and h5py are loaded
        require_file(datasets[0], DATASET_FILE)
    options = _method_options(method, option or [])  # refused before any dataset is read
    if len(datasets) > 1 or dask is not None:
        _calibrate_fleet(datasets, out, method, seed, links, use_truth_links, use_dataset_qdd, unit, workers, dask,
                         options, force)  # fmt: skip
        return
    from rich.progress import Progress

    from skincal.calib import calibrate as run
    from skincal.data.hdf5 import read_dataset
    from skincal.data.result import sha256_file, write_result
    from skincal.io.atomic import check_output

    dataset = datasets[0]
    check_output(out, force=force, inputs=(dataset, *((links,) if links is not None else ())))
    ds = read_dataset(dataset)
    link_map = read_links_file(links) if links is not None else None
    names = unit or ds.units
    with Progress(console=console, transient=True, disable=not console.is_terminal) as progress:
        task = progress.add_task(f"{method}: preparing the dataset", total=None)

        def step(done: int, total: int, stage: str) -> None:  # the bar moves with the work (WorkSteps)
            progress.update(task, completed=done, total=total, description=f"{method}: {stage}")

        result = run(
            ds, method, seed=seed, links=link_map, use_truth_links=use_truth_links,
            use_dataset_qdd=use_dataset_qdd, units=list(names), dataset_sha256=sha256_file(dataset),
            workers=workers, work=step, **options,
        )
    write_result(result, out)
    console.print(unit_table(result, f"{method}: {len(result.units)} units in {result.runtime_s:.2f} s"))
    for note in result.notes:
        console.print(f"note: {shown(note)}", highlight=False)
    for name, reason in result.failed_units.items():
        console.print(f"[yellow]warning[/]: unit {shown(name)} not calibrated: {shown(reason)}", highlight=False)
    console.print(f"wrote {shown(out)}", highlight=False)
    if not result.units:  # a result, not an error: written, each unit's reason in it; exit NO_UNIT_EXIT
        console_warning(f"no unit could be calibrated ({len(names)} unit(s), each with its reason in {out})")
        raise typer.Exit(NO_UNIT_EXIT)


def _calibrate_follow(
    source: Path, out: Path, speed: float | None, target_text: str | None, robot: str | None,
    unit: list[str] | None, force: bool, watch: bool = False,
) -> None:  # fmt: skip
    """``--follow``: replay ``source`` (a dataset or a ROS bag) into the online calibrator at ``speed``
    with the live meter (a rich table on a terminal, a line per second otherwise), stop at the target
    or the data's end and write the result atomically. The first Ctrl-C (or SIGTERM) stops the follow and
    writes the result of the data until then (a note in it says so); a second one aborts, writing nothing."""
    import math
    import signal

    from skincal.cli.signals import stop_on_signals
    from skincal.data.result import sha256_file, write_result
    from skincal.io.atomic import check_output
    from skincal.workflows.live import (
        Target,
        follow_dataset,
        is_bag,
        load_source,
        outside_target,
        parse_target,
    )

    target = parse_target(target_text) if target_text is not None else Target()
    speed = 1.0 if speed is None else speed
    if not math.isfinite(speed) or speed < 0:
        raise ConfigError(f"--speed {speed}: a finite number >= 0 (0: as fast as possible)")
    robot_file = (Path(robot),) if robot is not None and Path(robot).suffix.lower() in (".urdf", ".yaml", ".yml",
                                                                                        ".json") else ()  # fmt: skip
    check_output(out, force=force, inputs=(source, *robot_file))
    ds = load_source(source, robot)
    digest = "" if is_bag(source) and source.is_dir() else sha256_file(source)
    meter = LiveMeter(target, f"follow {source.name}")

    def moved(event: dict) -> None:
        console.print(f"[yellow]moved[/]: unit {shown(str(event.get('unit')))} changed at "
                      f"{float(event.get('t_change_s', math.nan)):.1f} s (flagged at "
                      f"{float(event.get('t_detected_s', math.nan)):.1f} s); re-calibrating it from the data "
                      "after the change", highlight=False)  # fmt: skip

    def progress(line: str) -> None:
        console.print(line, markup=False, highlight=False)

    with meter, stop_on_signals() as stop:
        outcome = follow_dataset(ds, target, speed=None if speed == 0 else speed, units=list(unit) if unit else None,
                                 on_meter=meter.show, dataset_sha256=digest, watch=watch, on_event=moved,
                                 stop=stop, on_progress=progress)  # fmt: skip
        meter.show(outcome.statuses, outcome.t_data, outcome.t_end, force_draw=True)
        write_result(outcome.result, out)  # a second signal aborts the write too (atomic: nothing or all)
    what = "Ctrl-C" if stop.signum == signal.SIGINT else "SIGTERM"
    notes = outcome.result.notes
    spacing_cut = any(n.startswith("report-spacing term") and "stopped by the user" in n for n in notes)
    if outcome.stopped:
        console.print(f"[yellow]stopped[/] ({what}) after {outcome.t_data:.1f} s of data (of {outcome.t_end or 0.0:.1f}"
                      " s): the result of the data so far", highlight=False)  # fmt: skip
    elif watch:
        events = outcome.result.events
        console.print(f"watched to the data's end: {len(events)} unit move(s) recorded in the result", highlight=False)
    elif outcome.reached:
        console.print(f"target {target.text()} reached by every unit after {outcome.t_data:.1f} s of data "
                      f"(of {outcome.t_end:.1f} s)", highlight=False)  # fmt: skip
    elif outcome.t_end is not None and outcome.t_data < outcome.t_end:  # stopped by the live std, judged again
        missing = len(outside_target(outcome.result, target))
        console.print(f"[yellow]warning[/]: the live std reached the target {target.text()} after {outcome.t_data:.1f}"
                      f" s of data and the follow stopped, but the std written for {missing} of "
                      f"{len(outcome.statuses)} units exceed it (the last samples absorbed, the report-spacing "
                      "term of a slow joint stream)", highlight=False)  # fmt: skip
    else:
        missing = sum(1 for s in outcome.statuses.values() if not s.reached)
        console.print(f"[yellow]warning[/]: the data ended ({outcome.t_data:.1f} s) before the target "
                      f"{target.text()}: {missing} of {len(outcome.statuses)} units not there", highlight=False)
    if spacing_cut and not outcome.stopped:
        console.print(f"[yellow]stopped[/] ({what}) before the report-spacing term of the slow joint stream was made: "
                      "the result written without it", highlight=False)  # fmt: skip
    elif stop.is_set() and not outcome.stopped:
        console.print(f"{what} after the data's end: the result is complete", highlight=False)
    for name, why in outcome.result.failed_units.items():
        console.print(f"not calibrated: {shown(name)}: {shown(why)}", highlight=False)
    console.print(f"wrote {shown(out)}", highlight=False)
    if not outcome.result.units:  # written, with each unit's reason: exit 1 as for the batch methods
        raise typer.Exit(NO_UNIT_EXIT)


def _calibrate_relative(
    dataset: Path, out: Path, reference: str, unit: list[str] | None, compare_with: Path | None, force: bool,
    option: list[str],
) -> None:  # fmt: skip
    """``--reference``: the IMU-only unit-to-unit calibration (joints or not), and with ``--compare-with``
    the disagreement with a joint-based result per unit on the reference's link. ``--option`` takes the
    options of :class:`skincal.calib.imu_only.RelativeOptions`."""
    import dataclasses

    from skincal.calib.imu_only import RelativeOptions, calibrate_relative, compare_with_joint_result
    from skincal.calib.options import parse_option_strings, parse_options
    from skincal.data.hdf5 import read_dataset
    from skincal.data.result import read_result, sha256_file, write_result
    from skincal.io.atomic import check_output

    options = dataclasses.asdict(parse_options(RelativeOptions, parse_option_strings(option), "imu-only"))
    inputs = (dataset,) if compare_with is None else (dataset, compare_with)
    check_output(out, force=force, inputs=inputs)
    joint = read_result(compare_with) if compare_with is not None else None
    ds = read_dataset(dataset)
    result = calibrate_relative(
        ds, reference, units=list(unit) if unit else None, dataset_sha256=sha256_file(dataset), **options
    )
    write_result(result, out)
    title = f"imu-only (frame of {reference}): {len(result.units)} units in {result.runtime_s:.2f} s"
    console.print(unit_table(result, title))
    if "accel_scale_fit" in result.extras:  # the positions' scale: fitted from rests, or what is missing
        console.print(f"note: {shown(result.extras['accel_scale_fit']['note'])}", highlight=False)
    for name, reason in result.failed_units.items():
        console.print(f"[yellow]warning[/]: unit {shown(name)} not calibrated: {shown(reason)}", highlight=False)
    if joint is not None:
        differences = compare_with_joint_result(result, joint)
        if not differences:
            console.print(f"note: {shown(str(compare_with))} puts no other unit on {shown(reference)}'s link",
                          highlight=False)  # fmt: skip
        for name, (mm, deg) in differences.items():
            console.print(
                f"{shown(name)}: IMU-only vs {shown(joint.method)} differ by {mm:.2f} mm, {deg:.3f} deg",
                highlight=False,
            )
    console.print(f"wrote {shown(out)}", highlight=False)


def _method_options(method: str, option: list[str]) -> dict[str, str]:
    """``--option name=value`` strings of ``method``, checked (known method, known options, typed
    values) so that a mistake is refused before any dataset is read; returned as given."""
    from skincal.calib import METHODS
    from skincal.calib.options import parse_option_strings, parse_options

    if method not in METHODS:
        raise ConfigError(f"unknown method '{method}' (available: {', '.join(sorted(METHODS))})")
    options = parse_option_strings(option)
    parse_options(METHODS[method].options, options, method)
    return options


def _calibrate_fleet(
    datasets: list[Path], out: Path, method: str, seed: int, links: Path | None, use_truth_links: bool,
    use_dataset_qdd: bool, unit: list[str] | None, workers: int, dask: str | None, options: dict[str, str],
    force: bool,
) -> None:
    """Several datasets: one result each in the folder ``out``, on the sweep runner; a dataset that
    fails is named and the others are written; exit 2 when any failed, else :data:`NO_UNIT_EXIT`
    when a result has no calibrated unit."""
    from rich.progress import Progress
    from rich.table import Table

    from skincal.io.atomic import check_output
    from skincal.workflows.fleet import calibrate_fleet, fleet_jobs

    if unit:
        raise ConfigError("--unit selects units of one dataset; give one dataset with it")
    jobs = fleet_jobs(
        datasets, out, method=method, seed=seed, links=read_links_file(links) if links is not None else None,
        use_truth_links=use_truth_links, use_dataset_qdd=use_dataset_qdd, options=options,
    )  # fmt: skip
    for job in jobs:
        check_output(job.out, force=force, inputs=(*datasets, *((links,) if links is not None else ())))
    with Progress(console=console, transient=True, disable=not console.is_terminal) as progress:
        task = progress.add_task(f"calibrating {len(jobs)} datasets ({method})", total=len(jobs))
        records = calibrate_fleet(jobs, workers=workers, dask=dask, progress=lambda _r: progress.advance(task))
    table = Table(title=f"{method}: {len(jobs)} datasets")
    for col in ("dataset", "units", "not calibrated", "runtime (s)", "result"):
        table.add_column(col)
    for r in records:
        table.add_row(
            shown(r.dataset), str(r.units), str(r.failed), f"{r.runtime_s:.2f}",
            shown(r.out) if r.error is None else f"[red]error[/]: {shown(r.error)}",
        )  # fmt: skip
    console.print(table)
    failed = [r for r in records if r.error is not None]
    if failed:
        raise ConfigError(f"{len(failed)} of {len(records)} datasets could not be calibrated (see the table)")
    empty = [r for r in records if r.units == 0]
    if empty:
        console_warning(f"{len(empty)} of {len(records)} results have no calibrated unit (each unit's reason is in "
                        "its result)")  # fmt: skip
        raise typer.Exit(NO_UNIT_EXIT)


@app.command()
def evaluate(
    result: Path = typer.Argument(..., help="calibration result (.json)"),
    truth: Path = typer.Option(..., help="the simulated dataset the result was computed from, with /truth (.h5)"),
    as_json: bool = typer.Option(False, "--json", help="print JSON for scripts instead of a table"),
    allow_other: bool = typer.Option(
        False, "--allow-other-dataset", help="compare even if --truth is not the result's dataset (other file or robot)"
    ),
) -> None:
    """Compare a calibration result with the true poses of the simulated dataset it was computed from."""
    require_file(result, RESULT_FILE)  # before calib and h5py are loaded
    require_file(truth, DATASET_FILE)

    from rich.table import Table

    from skincal.calib.metrics import error_text
    from skincal.calib.metrics import evaluate as run
    from skincal.data.hdf5 import read_dataset
    from skincal.data.provenance import check_result_dataset
    from skincal.data.result import read_result

    res, ds = read_result(result), read_dataset(truth)
    if res.reference is not None:
        _evaluate_relative(res, result, ds, truth, as_json, allow_other)
        return
    ds.require_joints("evaluate (a wrong link is measured at the first joint sample)", source=str(truth))
    for warning in check_result_dataset(res, result, ds, truth, allow_other=allow_other)[1]:
        console_warning(warning)
    ev = run(res, ds)
    if as_json:
        typer.echo(json.dumps(ev.to_dict(), indent=2))
        return
    table = Table(title=f"{shown(result.name)} vs truth")
    for col in ("unit", "link true/est", "position error (mm)", "rotation error (deg)", "quat. distance"):
        table.add_column(col, justify="right")
    for name, u in ev.units.items():
        mark = "" if u.observable else " (unobservable)"
        table.add_row(
            shown(name) + mark,
            f"{u.link_true}/{u.link_estimated}",
            error_text(u.position_error_mm),
            f"{u.rotation_error_deg:.4f}",
            f"{u.quaternion_distance:.5f}",
        )
    for name in ev.units_failed:  # a unit the result could not calibrate is listed, never dropped silently
        table.add_row(shown(name) + " (not calibrated)", "-", "-", "-", "-")
    if ev.mean_position_error_mm is not None:
        table.add_row(
            "mean",
            f"{ev.links_correct}/{ev.units_total} ok",
            f"{ev.mean_position_error_mm:.3f}",
            f"{ev.mean_rotation_error_deg:.4f}",
            f"{ev.mean_quaternion_distance:.5f}",
            style="bold",
        )
    console.print(table)


def _evaluate_relative(res, result: Path, ds, truth: Path, as_json: bool, allow_other: bool) -> None:
    """``evaluate`` of an IMU-only result: ``T_ref_su`` against the truth (bodies or links)."""
    from rich.table import Table

    from skincal.calib.imu_only import evaluate_relative
    from skincal.data.provenance import check_result_dataset
    from skincal.data.result import sha256_file

    if ds.robot is not None:
        for warning in check_result_dataset(res, result, ds, truth, allow_other=allow_other)[1]:
            console_warning(warning)
    elif res.dataset_sha256 and res.dataset_sha256 != sha256_file(truth) and not allow_other:
        raise ConfigError(f"{result} was computed from another file than {truth} (--allow-other-dataset to compare)")
    doc = evaluate_relative(res, ds)
    if as_json:
        typer.echo(json.dumps(doc, indent=2))
        return
    table = Table(title=f"{shown(result.name)} vs truth (frame of {shown(doc['reference'])})")
    for col in ("unit", "position error (mm)", "rotation error (deg)"):
        table.add_column(col, justify="right")
    for name, u in doc["units"].items():
        if not u["same_body"]:
            table.add_row(shown(name), "other body", "-")
            continue
        mark = "" if u["observable"] else " (unobservable)"
        table.add_row(shown(name) + mark, f"{u['position_error_mm']:.3f}", f"{u['rotation_error_deg']:.4f}")
    console.print(table)
