"""``skincal benchmark table1|core|mle``: the paper's Table I beside the paper's numbers, throughput, the
default calibrator's targets (``robustness`` is in :mod:`skincal.cli.bench_robustness`)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import typer

from skincal.cli.app import app, console, err_console
from skincal.errors import ConfigError

benchmark_app = typer.Typer(help="Reproduce the paper's benchmarks.", no_args_is_help=True)
app.add_typer(benchmark_app, name="benchmark")


def _write_json(doc: dict, path: Path | None) -> None:
    if path is not None:
        from skincal.data.atomic import write_bytes_atomic

        write_bytes_atomic(path, json.dumps(doc, indent=2).encode())
        console.print(f"wrote {path}")


def _cell(stat: list[float] | None, scale: float = 1.0, digits: int = 2) -> str:
    if stat is None:
        return "-"
    return f"{stat[0] * scale:.{digits}f} ± {stat[1] * scale:.{digits}f}"


def table1_table(config, summary: dict[str, Any]):
    """A rich table laid out like the paper's Table I, with the paper's rows beside ours."""
    from rich.table import Table

    from skincal.workflows.table1 import PAPER_RUNTIME_S, PAPER_TABLE_I

    n_units = len(config.links)
    table = Table(
        title=f"Table I: {config.sets} placement sets x {config.runs} runs, {config.robot}, noise-free "
        f"(quaternion distance x 10 as in the paper)"
    )
    table.add_column("metric")
    table.add_column("method")
    for k in range(n_units):
        table.add_column(f"SU{k + 1} (link {config.links[k]})", justify="right")
    table.add_column("average", justify="right")
    table.add_column("wall time / set (s)", justify="right")
    metrics = (
        ("position_cm", "position (cm)", 1.0, 2),
        ("quaternion_distance", "quat. dist. x10", 10.0, 3),
        ("rotation_deg", "rotation (deg)", 1.0, 2),
    )
    for key, label, scale, digits in metrics:
        for method in config.methods:
            s = summary["methods"][method]
            cells = [_cell(u[key], scale, digits) for u in s["units"].values()]
            cells += ["-"] * (n_units - len(cells))
            runtime = _cell(s["runtime_s"], 1.0, 1)
            table.add_row(label, method, *cells, _cell(s["average"][key], scale, digits), runtime)
            paper = PAPER_TABLE_I.get(method, {}).get(key)
            if paper is not None and n_units == 6:
                ptime = f"{PAPER_RUNTIME_S[method]:.0f}" if method in PAPER_RUNTIME_S else ""
                table.add_row(
                    "", f"{method} (paper)", *[_cell(list(p), scale, digits) for p in paper], ptime, style="dim"
                )
        table.add_section()
    return table


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
) -> None:
    """Reproduce the paper's Table I: per-unit position error and quaternion distance per method."""
    import time

    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    from skincal.data.atomic import write_bytes_atomic
    from skincal.workflows.table1 import Table1Config, config_dict, jobs, run_dask, run_local, summarise

    names = tuple(m.strip() for m in methods.split(",") if m.strip())
    if workers < 1:
        raise ConfigError(f"--workers must be at least 1, got {workers}")
    overrides: dict[str, Any] = {"methods": names, "seed": seed}
    if runs is not None:
        overrides["runs"] = runs
    if sets is not None:
        overrides["sets"] = sets
    config = Table1Config.quick(**overrides) if quick else Table1Config(**overrides)
    total = len(jobs(config))
    start = time.perf_counter()
    columns = (
        TextColumn("[progress.description]{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
    )
    with Progress(*columns, console=console, transient=True) as progress:
        task = progress.add_task(f"table1 ({', '.join(names)})", total=total)
        advance = lambda _record: progress.advance(task)  # noqa: E731
        if dask is not None:
            records = run_dask(config, dask, progress=advance)
        else:
            records = run_local(config, workers=workers, progress=advance)
    wall = time.perf_counter() - start
    records.sort(key=lambda r: (r["set"], r["run"]))
    summary = summarise(config, records)
    console.print(table1_table(config, summary))
    console.print(f"{total} jobs in {wall:.1f} s wall ({'dask ' + dask if dask else f'{workers} local process(es)'})")
    if json_out is not None:
        doc = {"config": config_dict(config), "summary": summary, "records": records, "wall_time_s": wall}
        write_bytes_atomic(json_out, (json.dumps(doc, indent=1) + "\n").encode())
        console.print(f"wrote {json_out}")


@benchmark_app.command("core")
def core(
    robot: str = typer.Option("panda", help="robot preset"),
    json_out: Path | None = typer.Option(None, "--json", help="also write the figures as JSON"),
) -> None:
    """Forward-kinematics and simulation throughput at 1, 10 and 100 units."""
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn
    from rich.table import Table

    from skincal.workflows.bench_core import run_core_benchmark

    columns = (
        TextColumn("[progress.description]{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
    )
    with Progress(*columns, console=err_console, transient=True) as bar:
        task = bar.add_task("benchmark core", total=None)
        doc = run_core_benchmark(
            robot, progress=lambda done, total, what: bar.update(task, completed=done, total=total, description=what)
        )
    fk = doc["fk"]
    console.print(
        f"FK ({fk['joints']} joints): {fk['samples_per_s']:.3g} configurations/s "
        f"({fk['ratio_to_matmul_floor']:.2f}x the floor of {fk['joints']} batched 4x4 matmuls); "
        f"link motion (frames, velocities, accelerations): {doc['link_motion']['samples_per_s']:.3g} /s"
    )
    table = Table(title=f"analytic simulation, {doc['protocol']} ({doc['protocol_duration_s']:.0f} s of motion)")
    for col in ("units", "wall time (s)", "IMU samples", "samples/s"):
        table.add_column(col, justify="right")
    for row in doc["simulation"]:
        table.add_row(
            str(row["units"]), f"{row['seconds']:.2f}", str(row["imu_samples"]), f"{row['samples_per_s']:.3g}"
        )
    console.print(table)
    _write_json(doc, json_out)


@benchmark_app.command("mle")
def mle(
    runs: int = typer.Option(20, help="random placements per robot"),
    quick: bool = typer.Option(False, help="short protocol, for a smoke test"),
    om: bool = typer.Option(True, help="also time the paper's OM on the same data"),
    json_out: Path | None = typer.Option(None, "--json", help="also write the figures as JSON"),
) -> None:
    """The default calibrator's accuracy, uncertainty calibration and speed targets."""
    from skincal.workflows.bench_mle import run_mle_benchmark

    with console.status("benchmarking mle...") as status:
        doc = run_mle_benchmark(runs=runs, quick=quick, with_om=om, progress=lambda m: status.update(m))
    console.print_json(json.dumps(doc))
    _write_json(doc, json_out)
