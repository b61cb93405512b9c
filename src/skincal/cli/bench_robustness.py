"""``skincal benchmark robustness``: the default calibrator under faults of real robots and IMUs."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import typer

from skincal.cli.app import console
from skincal.cli.benchmark import benchmark_app


@benchmark_app.command("robustness")
def robustness(
    robots: str | None = typer.Option(None, help="comma-separated robots (default panda,sawyer,ur5e)"),
    backends: str | None = typer.Option(
        None, help="comma-separated backends: analytic, mujoco (kinematic), mujoco-dynamic (default analytic,mujoco)"
    ),
    faults: str | None = typer.Option(None, help="comma-separated faults (default all of them; see --list)"),
    seeds: int | None = typer.Option(None, help="random placements of 6 units per cell (default 5; quick 1)"),
    quick: bool = typer.Option(False, help="1 seed and the short fast protocol"),
    protocol: str | None = typer.Option(None, help="protocol preset (default paper-sim; quick fast)"),
    seed: int = typer.Option(0, help="first placement seed"),
    workers: int = typer.Option(1, help="local worker processes (ignored with --dask)"),
    dask: str | None = typer.Option(None, "--dask", help="address of an existing dask.distributed scheduler"),
    out: Path | None = typer.Option(None, "--out", help="write every cell and job record here (JSON)"),
    force: bool = typer.Option(False, help="overwrite --out if it exists"),
    list_faults: bool = typer.Option(False, "--list", help="list the faults and exit"),
) -> None:
    """Calibrate simulated sessions with faults of real robots and IMUs (each alone and all together);
    per cell: errors, links right, z RMS, warnings and silent errors against targets."""
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    from skincal.io.atomic import check_output, write_bytes_atomic
    from skincal.workflows import robustness as rb

    if list_faults:
        for line in rb.fault_lines():
            console.print(line, highlight=False, soft_wrap=True)
        return
    if out is not None:
        check_output(out, force=force)
    config = rb.config_from_options(robots, backends, faults, seeds, quick, protocol, seed)
    columns = (
        TextColumn("[progress.description]{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn()
    )  # fmt: skip
    with Progress(*columns, console=console, transient=True) as progress:
        task = progress.add_task(f"robustness ({rb.where(workers, dask)})", total=len(rb.jobs(config)))

        def advance(record: dict[str, Any]) -> None:
            progress.update(
                task, advance=1, description=f"robustness: {record['robot']} {record['backend']} {record['fault']}"
            )

        doc = rb.run_benchmark(config, workers=workers, dask=dask, progress=advance)
    for part in rb.report(config, doc):
        console.print(part, highlight=False)
    if out is not None:
        write_bytes_atomic(out, (json.dumps(doc, indent=1) + "\n").encode())
        console.print(f"wrote {out}")
