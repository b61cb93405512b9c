"""``skincal benchmark robustness``: the default calibrator under faults of real robots and IMUs."""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any

import typer

from skincal.cli.app import console
from skincal.cli.benchmark import benchmark_app
from skincal.errors import ConfigError


def _names(text: str | None) -> tuple[str, ...] | None:
    if text is None:
        return None
    return tuple(x.strip() for x in text.split(",") if x.strip())


def _num(x: float | None, digits: int) -> str:
    return "-" if x is None else f"{x:.{digits}f}"


def robustness_table(config, cells: list[dict[str, Any]]):
    """A rich table with one row per cell (robot, backend, fault)."""
    from rich.table import Table

    table = Table(title=f"robustness: mle, {config.protocol} protocol, {config.seeds} placement(s) of "
                        f"{config.n_units} units per cell")
    for col, justify in (("robot", "left"), ("backend", "left"), ("fault", "left"), ("pos mean/max mm", "right"),
                         ("rot mean/max deg", "right"), ("links", "right"), ("z rms", "right"),
                         ("calibrated", "right"), ("warned", "right"), ("beyond", "right"), ("silent", "right"),
                         ("targets", "left")):
        table.add_column(col, justify=justify, no_wrap=col in ("backend", "fault"))
    previous = None
    for c in cells:
        if previous is not None and (c["robot"], c["backend"]) != previous:
            table.add_section()
        previous = (c["robot"], c["backend"])
        n = c["units_total"]
        verdict = "ok" if c["pass"] else "[red]" + ", ".join(c["failed_targets"]) + "[/red]"
        table.add_row(
            c["robot"], c["backend"], c["fault"],
            f"{_num(c['mean_position_error_mm'], 3)} / {_num(c['max_position_error_mm'], 2)}",
            f"{_num(c['mean_rotation_error_deg'], 3)} / {_num(c['max_rotation_error_deg'], 2)}",
            f"{c['links_correct']}/{n}", _num(c["z_rms"], 2), f"{c['units_calibrated']}/{n}",
            str(c["warned"]), str(c["beyond_3sigma"]),
            ("[red]" + str(c["silent"]) + "[/red]") if c["silent"] else "0", verdict,
        )
    return table


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

    from skincal.data.atomic import write_bytes_atomic
    from skincal.workflows.robustness import FAULTS, RobustnessConfig, config_dict, jobs, run, summarise

    if list_faults:
        for f in FAULTS.values():
            target = f"mean <= {f.target_mean_mm:g} mm" if f.target_mean_mm is not None else "no mean target"
            console.print(f"{f.name:14s} {f.description} ({target})", highlight=False, soft_wrap=True)
        return
    if workers < 1:
        raise ConfigError(f"--workers must be at least 1, got {workers}")
    if out is not None:
        from skincal.data.atomic import check_output

        check_output(out, force=force)
    overrides: dict[str, Any] = {"seed": seed}
    for key, value in (("robots", _names(robots)), ("backends", _names(backends)), ("faults", _names(faults))):
        if value is not None:
            overrides[key] = value
    if seeds is not None:
        overrides["seeds"] = seeds
    if protocol is not None:
        overrides["protocol"] = protocol
    config = RobustnessConfig.quick(**overrides) if quick else RobustnessConfig(**overrides)
    total = len(jobs(config))
    where = f"dask {dask}" if dask else f"{workers} local process(es)"
    start = time.perf_counter()
    columns = (TextColumn("[progress.description]{task.description}"), BarColumn(), MofNCompleteColumn(),
               TimeElapsedColumn())
    with Progress(*columns, console=console, transient=True) as progress:
        task = progress.add_task(f"robustness ({where})", total=total)

        def advance(record: dict[str, Any]) -> None:
            progress.update(task, advance=1,
                            description=f"robustness: {record['robot']} {record['backend']} {record['fault']}")

        records = run(config, workers=workers, dask=dask, progress=advance)
    wall = time.perf_counter() - start
    cells = summarise(config, records)
    console.print(robustness_table(config, cells))
    console.print(
        "errors of calibrated units (means over observable ones); z = position error / reported std per link axis; "
        "warned: units with any warning; beyond: units on a wrong link or beyond 3 sigma (any axis, or sum z^2 > "
        "chi2_3(0.9973)); silent: beyond and not warned. Targets: mean <= 0.3 mm (qd-*), <= 1 mm (imu-real, "
        "clock-*); all links right and no silent error in every cell.", highlight=False
    )
    passed = sum(c["pass"] for c in cells)
    console.print(f"{passed}/{len(cells)} cells meet their targets; {total} jobs in {wall:.1f} s wall ({where})")
    if out is not None:
        doc = {"config": config_dict(config), "cells": cells, "records": records, "wall_time_s": wall,
               "workers": None if dask else workers, "dask": dask}
        write_bytes_atomic(out, (json.dumps(doc, indent=1) + "\n").encode())
        console.print(f"wrote {out}")
