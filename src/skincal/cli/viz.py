"""``skincal view`` (browser 3D viewer, loopback by default) and ``skincal report`` (HTML / markdown)."""

from __future__ import annotations

from pathlib import Path

import typer

from skincal.cli.app import Throttle, app, console, console_warning, err_console, require_file, seed_option, shown
from skincal.errors import ConfigError
from skincal.io.files import DATASET_FILE, RESULT_FILE


def _finite(value: float | None) -> float | None:
    """Option callback: NaN and infinity are usage errors (``--duration nan``)."""
    import math

    if value is not None and not math.isfinite(value):
        raise typer.BadParameter(f"{value} is not a finite number")
    return value


@app.command()
def view(
    result: Path | None = typer.Argument(None, help="calibration result (.json); optional with --scenario"),
    truth: Path | None = typer.Option(None, help="simulated dataset with /truth: show the true poses too"),
    play: Path | None = typer.Option(None, help="dataset to play back (joint motion, ToF rays and points)"),
    robot: str | None = typer.Option(
        None, help="robot preset, .urdf or chain file when no dataset is given (default: the result's preset)"
    ),
    base_link: str | None = typer.Option(None, help="URDF link the chain starts from (with --robot arm.urdf)"),
    tip_link: str | None = typer.Option(None, help="URDF link the chain ends at (with --robot arm.urdf)"),
    port: int = typer.Option(0, min=0, max=65535, help="TCP port (0: any free port)"),
    host: str = typer.Option("127.0.0.1", help="interface to serve on; anything but loopback needs --public"),
    public: bool = typer.Option(False, "--public", help="allow a non-loopback --host (the viewer has no login)"),
    duration: float | None = typer.Option(
        None, min=0.0, callback=_finite, help="stop after this many seconds (default: until Ctrl-C)"
    ),
    scenario: str | None = typer.Option(
        None, help="run this avoidance scenario (skincal avoid) with the result's poses (or truth) and play it"
    ),
    seed: int = typer.Option(0, callback=seed_option, help="sensor-noise seed of the --scenario run"),
    placement: str = typer.Option("ring", help="the --scenario run's skin: ring (dense) or paper (Table II)"),
    allow_other: bool = typer.Option(
        False, "--allow-other-dataset",
        help="show even if --truth is not the result's dataset (other file or robot), or --play another robot",
    ),
    package_path: list[Path] = typer.Option(
        [], "--package-path", "--mesh-dir",
        help="folder holding ROS packages (or a package itself) for a URDF robot's package:// meshes; "
        "repeatable; searched before the URDF's folder and its parents, then ROS_PACKAGE_PATH",
    ),
    follow: Path | None = typer.Option(
        None, "--follow", help="live: replay this dataset (or ROS bag) into the online calibrator and show the units "
        "and their uncertainty ellipsoids converging (no result file needed)"
    ),
    speed: float = typer.Option(1.0, "--speed", help="--follow: data seconds per wall second (0: as fast as possible)"),
    target: str | None = typer.Option(
        None, "--target", help="--follow: std to reach on every axis (default 0.3mm,0.05deg); the replay stops there"
    ),
) -> None:
    """Show a calibration result on the robot in the browser (viser); with --scenario, play an avoidance run.

    A URDF robot is drawn with its visual meshes when they are found (else as capsules, with a note)."""
    for given, what in ((result, RESULT_FILE), (truth, DATASET_FILE), (play, DATASET_FILE)):
        if given is not None:  # refused before viser, h5py and the viewer are loaded
            require_file(given, what)

    import dataclasses
    import os

    from skincal.data.hdf5 import read_dataset
    from skincal.data.provenance import check_result_dataset
    from skincal.data.result import read_result
    from skincal.hw.net import check_bind
    from skincal.names import printable
    from skincal.viz.meshes import MeshResolver
    from skincal.viz.model import Recording
    from skincal.viz.viewer import serve_forever, start_viewer

    host = host[1:-1] if host.startswith("[") and host.endswith("]") else host  # [::1] as in a URL
    check_bind(host, public)  # one rule with skincal record: loopback unless --public
    meshes = MeshResolver.from_options(None, package_path)  # (a --package-path that is no folder: refused now)
    if follow is not None:
        if result is not None or play is not None or truth is not None or scenario is not None:
            raise ConfigError("--follow draws the online calibrator's estimates: give no result, --play, --truth or "
                              "--scenario with it")  # fmt: skip
        _view_follow(follow, robot, host, port, speed, target, duration, meshes)
        return
    if scenario is not None:
        if play is not None or truth is not None:
            raise ConfigError("--scenario plays its own run: give no --play or --truth with it")
        _view_scenario(scenario, result, seed, placement, host, port, duration)
        return
    if result is None:
        raise ConfigError("give a calibration result (or --scenario NAME)")
    res = read_result(result)
    truth_ds = read_dataset(truth) if truth is not None else None
    play_ds = read_dataset(play) if play is not None else None
    for given, path, what in ((truth_ds, truth, "view --truth"), (play_ds, play, "view --play")):
        if given is not None:  # the robot is drawn at the dataset's joint positions
            given.require_joints(what, source=str(path))
    warnings: list[str] = []
    if truth_ds is not None:
        warnings += check_result_dataset(res, result, truth_ds, truth, allow_other=allow_other)[1]
    if play_ds is not None:  # another recording of the same robot is fine
        warnings += check_result_dataset(res, result, play_ds, play, allow_other=allow_other, same_file=False)[1]
    for warning in warnings:
        console_warning(warning)
    if (base_link is not None or tip_link is not None) and robot is None:
        raise ConfigError("--base-link and --tip-link apply to a URDF robot given with --robot")
    source = play_ds or truth_ds
    urdf_dir = None  # a dataset's URDF has no folder: its meshes are looked up in the package paths only
    if source is not None:
        chain = source.robot
    else:
        from skincal.data.provenance import result_robot

        # never a file the user did not name: the result's robot only when it is a preset (and its links)
        found = result_robot(res, robot, base_link=base_link, tip_link=tip_link)
        if found is None:
            raise ConfigError(
                f"{printable(str(result))}: robot '{printable(res.robot)}' is not a preset: give its description "
                "with --robot arm.urdf, or the dataset with --play or --truth"
            )
        chain = found
        if robot is not None and Path(robot).suffix.lower() == ".urdf":
            urdf_dir = Path(os.path.abspath(Path(robot).parent))
    meshes = dataclasses.replace(meshes, urdf_dir=urdf_dir)
    recording = Recording.from_dataset(play_ds) if play_ds is not None else None
    viewer = start_viewer(
        res, chain, truth=None if truth_ds is None else truth_ds.truth, recording=recording, host=host, port=port,
        q0=None if truth_ds is None or recording is not None else truth_ds.joints.q[0], meshes=meshes,
    )
    for note in viewer.notes:
        err_console.print(f"note: {printable(note)}", markup=False, highlight=False, soft_wrap=True)
    console.print(f"skincal viewer: [bold]{shown(viewer.url)}[/]  (Ctrl-C to stop)", highlight=False)
    serve_forever(viewer, duration=duration)


def _view_follow(
    source: Path, robot: str | None, host: str, port: int, speed: float, target_text: str | None,
    duration: float | None, meshes,
) -> None:  # fmt: skip
    """``view --follow``: the live viewer fed by a replay into the online calibrator (the robot moves with the
    replayed joints, the units converge), then served until Ctrl-C or ``--duration`` (counted from the start)."""
    import math
    import time

    import numpy as np

    from skincal.data.interp import interp_rows
    from skincal.viz.meter import meter_line
    from skincal.viz.viewer import serve_forever, start_live_viewer, update_live
    from skincal.workflows.live import Target, data_span, follow_dataset, load_source, parse_target

    target = parse_target(target_text) if target_text is not None else Target()
    if not math.isfinite(speed) or speed < 0:
        raise ConfigError(f"--speed {speed}: a finite number >= 0 (0: as fast as possible)")
    ds = load_source(source, robot)
    joints = ds.joint_states
    t0, _ = data_span(ds)
    start = time.monotonic()
    viewer = start_live_viewer(ds.chain, host=host, port=port, q0=joints.q[0], meshes=meshes)
    for note in viewer.notes:
        err_console.print(f"note: {shown(note)}", highlight=False, soft_wrap=True)
    console.print(f"skincal viewer: [bold]{shown(viewer.url)}[/]  (following {shown(source.name)}; Ctrl-C to stop)",
                  highlight=False)  # fmt: skip
    throttle = Throttle(0.25)

    class _DurationOver(Exception):
        """``--duration`` ran out during the replay (it counts from the start, replay included)."""

    def on_meter(statuses, t_data: float, t_end: float | None) -> None:
        if duration is not None and time.monotonic() - start >= duration:
            raise _DurationOver
        if not throttle.due():
            return
        q = interp_rows(np.asarray([t0 + t_data]), joints.t, joints.q)[0]
        update_live(viewer, statuses, q, meter_line(statuses, target.position_m, target.rotation_deg, t_data, t_end))

    try:
        outcome = follow_dataset(ds, target, speed=None if speed == 0 else speed, on_meter=on_meter,
                                 on_progress=lambda line: console.print(line, markup=False, highlight=False))
        line = meter_line(outcome.statuses, target.position_m, target.rotation_deg, outcome.t_data, outcome.t_end)
        update_live(viewer, outcome.statuses, None, line)
        console.print(line, markup=False, highlight=False, soft_wrap=True)
    except _DurationOver:
        viewer.close()
        console.print(f"--duration {duration:g} s over during the replay: stopped", highlight=False)
        return
    except BaseException:
        viewer.close()
        raise
    serve_forever(viewer, duration=None if duration is None else duration - (time.monotonic() - start))


def _view_scenario(
    name: str, result: Path | None, seed: int, placement: str, host: str, port: int, duration: float | None
) -> None:
    """Run avoidance scenario ``name`` with the result's poses (truth if none) and serve its playback."""

    import numpy as np

    from skincal.data.result import CalibrationResult, UnitResult
    from skincal.kinematics import panda
    from skincal.sim.scenarios import get_scenario
    from skincal.viz.viewer import serve_forever, start_viewer
    from skincal.workflows.avoidance import believed_poses, run_scenario, simulated_skin
    from skincal.workflows.playback import recording_from_run

    chain = panda()
    true_poses = simulated_skin(placement, chain)
    poses, label = believed_poses(true_poses, result, None, False, seed)
    sc = get_scenario(name, chain)
    console.print(f"running scenario {name} ({sc.duration:.1f} s) with poses: {label}", highlight=False)
    log = run_scenario(chain, sc, true_poses, poses, np.random.default_rng(seed))
    believed = CalibrationResult(label, chain.name, "", 0.0, {u: UnitResult(p) for u, p in poses.items()})
    viewer = start_viewer(believed, chain, truth=true_poses, recording=recording_from_run(log), host=host, port=port)
    console.print(f"skincal viewer: [bold]{shown(viewer.url)}[/]  (Ctrl-C to stop)", highlight=False)
    serve_forever(viewer, duration=duration)


@app.command()
def report(
    result: Path = typer.Argument(..., help="calibration result (.json)"),
    dataset: Path = typer.Option(..., help="the dataset the result was computed from (.h5)"),
    out: Path | None = typer.Option(
        None, "--out", "-o", help="file to write (default: print the markdown summary on stdout)"
    ),
    fmt: str | None = typer.Option(
        None, "--format", show_default=False,
        help="html (one self-contained file; needs --out) or md (markdown summary); default: html with --out, "
        "md without",
    ),
    use_dataset_qdd: bool = typer.Option(False, help="predict with the dataset's qdd (as calibrate --use-dataset-qdd)"),
    force: bool = typer.Option(False, "--force", help="overwrite --out if it exists"),
    allow_other: bool = typer.Option(
        False, "--allow-other-dataset",
        help="report even if --dataset is not the result's dataset (other file or robot)",
    ),
    workers: int = typer.Option(
        2, min=1, help="units whose residuals are computed at once (forked processes on Linux; same report)"
    ),
) -> None:
    """Write a calibration report: per-unit table, residuals, sensor parameters, coverage, errors."""
    require_file(result, RESULT_FILE)  # before h5py and the report's libraries are loaded
    require_file(dataset, DATASET_FILE)

    from skincal.data.hdf5 import open_dataset
    from skincal.data.provenance import check_result_dataset
    from skincal.data.result import read_result
    from skincal.viz.content import collect
    from skincal.viz.summary import render_markdown

    if fmt is None:
        fmt = "md" if out is None else "html"
    if fmt not in ("html", "md"):
        raise ConfigError(f"--format must be 'html' or 'md', got '{fmt}'")
    if out is None and fmt == "html":
        raise typer.BadParameter(
            "html needs --out FILE (without --out the markdown summary is printed)", param_hint="'--format'"
        )
    if out is not None:
        from skincal.io.atomic import check_output

        check_output(out, force=force, inputs=(result, dataset))
    from rich.markup import escape

    from skincal.names import printable

    # the dataset is streamed: its joints at once, one unit's IMU data at a time (issue 19, report memory)
    with (
        err_console.status("reading the result and the dataset") as status,  # transient, on stderr
        open_dataset(dataset) as ds,
    ):
        progress = lambda message: status.update(escape(printable(f"report: {message}")))  # noqa: E731
        res = read_result(result)
        ds.require_joints("report (its residuals are predicted from the joint stream)", source=str(dataset))
        digest, warnings = check_result_dataset(res, result, ds, dataset, allow_other=allow_other)
        for warning in warnings:
            console_warning(warning)
        if out is None:
            text = render_markdown(
                collect(res, ds, use_dataset_qdd=use_dataset_qdd, shown=0, progress=progress, workers=workers)
            )
        else:
            from skincal.viz.report import write_report

            write_report(
                res, ds, out, fmt, dataset_sha256=digest, use_dataset_qdd=use_dataset_qdd, progress=progress,
                workers=workers,
            )
    if out is None:
        typer.echo(text, nl=False)
        return
    console.print(f"wrote {shown(out)}", highlight=False)
