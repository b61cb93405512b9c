"""``skincal benchmark robustness``: the default calibrator under faults of real robots and IMUs."""

from __future__ import annotations

import json
from typing import Any

from skincal.bench import options
from skincal.bench.harness import typer_command
from skincal.cli.app import console, err_console
from skincal.cli.benchmark import benchmark_app


def robustness(v: dict[str, Any]) -> None:
    """Calibrate simulated sessions with faults of real robots and IMUs (each alone and all together);
    per cell: errors, links right, z RMS, warnings and silent errors against targets."""
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    from skincal.bench import robustness as rb
    from skincal.bench.harness import run_harness
    from skincal.io.atomic import check_output, write_bytes_atomic

    harness, out, workers, dask = rb.HARNESS, v["out"], v["workers"], v["dask"]
    if v["list_faults"]:
        for line in rb.fault_lines():
            console.print(line, highlight=False, soft_wrap=True)
        return
    if out is not None:
        check_output(out, force=v["force"])
    config = harness.config(v)
    columns = (
        TextColumn("[progress.description]{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn()
    )  # fmt: skip
    total = len(rb.jobs(config))
    done = 0
    with Progress(*columns, console=console, transient=True) as progress:
        task = progress.add_task(f"robustness ({rb.where(workers, dask)})", total=total)

        def advance(record: dict[str, Any]) -> None:
            nonlocal done
            done += 1
            what = f"robustness: {record['robot']} {record['backend']} {record['fault']}"
            progress.update(task, advance=1, description=what)
            if not console.is_terminal:  # a pipe or a log: no bar is drawn, so one line per finished job
                err_console.print(f"{done}/{total} {what}", markup=False, highlight=False, soft_wrap=True)

        doc, run = run_harness(harness, config, workers=workers, dask=dask, progress=advance)
    for part in harness.report(config, doc, run):
        console.print(part, highlight=False)
    if out is not None:
        write_bytes_atomic(out, (json.dumps(doc, indent=1) + "\n").encode())
        console.print(f"wrote {out}")


typer_command(benchmark_app, "robustness", options.ROBUSTNESS, robustness)
