"""``skincal benchmark core`` and ``skincal benchmark mle`` (next to ``table1``)."""

from __future__ import annotations

import json
from pathlib import Path

import typer

from skincal.cli.app import console
from skincal.cli.benchmark import benchmark_app


def _write_json(doc: dict, path: Path | None) -> None:
    if path is not None:
        from skincal.data.atomic import write_bytes_atomic

        write_bytes_atomic(path, json.dumps(doc, indent=2).encode())
        console.print(f"wrote {path}")


@benchmark_app.command("core")
def core(
    robot: str = typer.Option("panda", help="robot preset"),
    json_out: Path | None = typer.Option(None, "--json", help="also write the figures as JSON"),
) -> None:
    """Forward-kinematics and simulation throughput at 1, 10 and 100 units."""
    from rich.table import Table

    from skincal.sim.bench_core import run_core_benchmark

    with console.status("timing forward kinematics and the simulator..."):
        doc = run_core_benchmark(robot)
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
    from skincal.calib.bench_mle import run_mle_benchmark

    with console.status("benchmarking mle...") as status:
        doc = run_mle_benchmark(runs=runs, quick=quick, with_om=om, progress=lambda m: status.update(m))
    console.print_json(json.dumps(doc))
    _write_json(doc, json_out)
