"""``skincal benchmark table1|core|mle``: the paper's Table I beside the paper's numbers, throughput, the
default calibrator's targets (``robustness`` is in :mod:`skincal.cli.bench_robustness`)."""

from __future__ import annotations

import json
from pathlib import Path

import typer

from skincal.cli.app import app, console, err_console, shown

benchmark_app = typer.Typer(help="Reproduce the paper's benchmarks.", no_args_is_help=True)
app.add_typer(benchmark_app, name="benchmark")


FORCE = typer.Option(False, "--force", help="overwrite the --json file if it exists")


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


@benchmark_app.command("table1")
def table1(
    quick: bool = typer.Option(False, help="tiny run for tests: 1 set x 1 run, 2 units, short protocol"),
    runs: int | None = typer.Option(None, help="optimiser runs per set (default 10; quick 1)"),
    sets: int | None = typer.Option(None, help="random placement sets (default 4; quick 1)"),
    methods: str = typer.Option("om,mmm,mm", help="comma-separated methods, e.g. om,om-joint,mmm,mm"),
    workers: int = typer.Option(1, help="local worker processes (ignored with --dask)"),
    dask: str | None = typer.Option(None, "--dask", help="address of an existing dask.distributed scheduler"),
    seed: int = typer.Option(0, help="base seed of the placement sets"),
    json_out: Path | None = typer.Option(None, "--json", help="write the records and summary here"),
    force: bool = FORCE,
) -> None:
    """Reproduce the paper's Table I: per-unit position error and quaternion distance per method."""
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    from skincal.workflows import table1 as t1

    _check_json(json_out, force)

    config = t1.config_from_options(quick, runs, sets, methods, seed)
    columns = (
        TextColumn("[progress.description]{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn()
    )  # fmt: skip
    with Progress(*columns, console=console, transient=True) as progress:
        task = progress.add_task(f"table1 ({', '.join(config.methods)})", total=len(t1.jobs(config)))
        doc = t1.run_benchmark(config, workers, dask, progress=lambda _record: progress.advance(task))
    for part in t1.report(config, doc, workers, dask):
        console.print(part)
    _write_json(doc, json_out)


@benchmark_app.command("core")
def core(
    robot: str = typer.Option("panda", help="robot preset"),
    json_out: Path | None = typer.Option(None, "--json", help="also write the figures as JSON"),
    force: bool = FORCE,
) -> None:
    """Forward-kinematics and simulation throughput at 1, 10 and 100 units."""
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    from skincal.workflows.bench_core import core_report, run_core_benchmark

    _check_json(json_out, force)

    columns = (
        TextColumn("[progress.description]{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
    )
    with Progress(*columns, console=err_console, transient=True, disable=not err_console.is_terminal) as bar:
        task = bar.add_task("benchmark core", total=None)
        doc = run_core_benchmark(
            robot, progress=lambda done, total, what: bar.update(task, completed=done, total=total, description=what)
        )
    for part in core_report(doc):
        console.print(part)
    _write_json(doc, json_out)


@benchmark_app.command("mle")
def mle(
    runs: int = typer.Option(20, help="random placements per robot"),
    quick: bool = typer.Option(False, help="short protocol, for a smoke test"),
    om: bool = typer.Option(True, help="also time the paper's OM on the same data"),
    json_out: Path | None = typer.Option(None, "--json", help="also write the figures as JSON"),
    force: bool = FORCE,
) -> None:
    """The default calibrator's accuracy, uncertainty calibration and speed targets."""
    from skincal.workflows.bench_mle import run_mle_benchmark

    _check_json(json_out, force)

    with console.status("benchmarking mle...") as status:
        doc = run_mle_benchmark(runs=runs, quick=quick, with_om=om, progress=lambda m: status.update(m))
    console.print_json(json.dumps(doc))
    _write_json(doc, json_out)
