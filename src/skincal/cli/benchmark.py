"""``skincal benchmark table1|core|mle|speed|realdata``: the paper's Table I beside the paper's numbers, throughput,
the default calibrator's targets, the speed figures of issue 26, the repeatability across real recordings of one
mount (``robustness`` is in :mod:`skincal.cli.bench_robustness`).

The options of every command are declared once, in :mod:`skincal.bench.options`, and serve the scripts in
``benchmarks/`` too (:mod:`skincal.bench.harness`); a benchmark's module is imported only when it runs."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import typer

from skincal.bench import options
from skincal.bench.harness import FORCE, typer_command
from skincal.cli.app import Status, app, console, err_console, shown

benchmark_app = typer.Typer(help="Reproduce the paper's benchmarks.", no_args_is_help=True)
app.add_typer(benchmark_app, name="benchmark")


def _check_json(path: Path | None, force: bool) -> None:
    """Refuse a ``--json`` path before any work (exists without ``--force``, a folder, no folder)."""
    if path is not None:
        from skincal.io.atomic import check_output

        check_output(path, force=force)


def _write_json(doc: dict, path: Path | None) -> None:
    if path is not None:
        from skincal.io.atomic import write_bytes_atomic

        write_bytes_atomic(path, (json.dumps(doc, indent=1) + "\n").encode())
        console.print(f"wrote {shown(path)}", highlight=False)


def table1(v: dict[str, Any]) -> None:
    """Reproduce the paper's Table I: per-unit position error and quaternion distance per method."""
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    from skincal.bench import table1 as t1
    from skincal.bench.harness import run_harness

    _check_json(v["json_out"], v["force"])

    harness = t1.HARNESS
    config = harness.config(v)
    columns = (
        TextColumn("[progress.description]{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn()
    )  # fmt: skip
    with Progress(*columns, console=console, transient=True) as progress:
        task = progress.add_task(f"table1 ({', '.join(config.methods)})", total=len(harness.jobs(config)))
        doc, run = run_harness(
            harness, config, workers=v["workers"], dask=v["dask"], progress=lambda _record: progress.advance(task)
        )
    for part in harness.report(config, doc, run):
        console.print(part)
    _write_json(doc, v["json_out"])


def core(v: dict[str, Any]) -> None:
    """Forward-kinematics and simulation throughput at 1, 10 and 100 units."""
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    from skincal.bench import core as bench_core

    _check_json(v["json_out"], v["force"])

    columns = (
        TextColumn("[progress.description]{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
    )
    with Progress(*columns, console=err_console, transient=True, disable=not err_console.is_terminal) as bar:
        task = bar.add_task("benchmark core", total=None)
        doc = bench_core.run_core_benchmark(
            v["robot"],
            progress=lambda done, total, what: bar.update(task, completed=done, total=total, description=what),
        )
    for part in bench_core.core_report(doc):
        console.print(part)
    _write_json(doc, v["json_out"])


def mle(v: dict[str, Any]) -> None:
    """The default calibrator's accuracy, uncertainty calibration and speed targets."""
    from skincal.bench import mle as bench_mle

    _check_json(v["json_out"], v["force"])

    with Status("benchmarking mle...") as status:
        doc = bench_mle.run_mle_benchmark(
            runs=v["placements"], quick=v["quick"], with_om=v["om"], progress=lambda m: status.update(m)
        )
    console.print_json(json.dumps(doc))
    _write_json(doc, v["json_out"])


typer_command(benchmark_app, "table1", options.TABLE1 + (FORCE,), table1)
typer_command(benchmark_app, "core", options.CORE + (FORCE,), core)
typer_command(benchmark_app, "mle", options.MLE + (FORCE,), mle)


def speed(v: dict[str, Any]) -> None:
    """Speed on simulated sessions, in CPU seconds of one run: OM's and mle's time and their ratio, CPU
    seconds per unit, 100 (and with --full 1000) units with peak memory, the command's start-up time and
    the streaming calibrator's cost per sample and latency."""
    from skincal.bench import speed as bench_speed
    from skincal.bench.harness import run_harness

    _check_json(v["json_out"], v["force"])
    harness = bench_speed.HARNESS
    config = harness.config(v)
    with Status("benchmarking speed...") as status:
        # one job after the other (workers=1): each job's CPU time, memory and latency are its own
        doc, run = run_harness(harness, config, workers=1, progress=lambda r: status.update(f"done: {r['kind']}"))
    for line in harness.report(config, doc, run):
        console.print(line, highlight=False)
    _write_json(doc, v["json_out"])


typer_command(benchmark_app, "speed", options.SPEED + (FORCE,), speed)


def realdata(v: dict[str, Any]) -> None:
    """Repeatability across recordings of one mount, per IMU: spread of positions and rotations, spread
    over the reported std, motion kept, time offsets, failures."""
    from skincal.bench.realdata import chosen_methods, realdata_report, run_realdata_benchmark

    _check_json(v["json_out"], v["force"])
    methods = chosen_methods(v["om"], v["online"])
    with Status("benchmarking recordings...") as status:
        doc = run_realdata_benchmark(
            v["folder"], methods, workers=v["workers"], progress=lambda n: status.update(shown(n))
        )
    for part in realdata_report(doc):
        console.print(part, highlight=False)
    _write_json(doc, v["json_out"])


typer_command(benchmark_app, "realdata", options.REALDATA + (FORCE,), realdata)
