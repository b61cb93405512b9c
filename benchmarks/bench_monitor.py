"""A unit that moved is noticed (issue 16): ``python benchmarks/bench_monitor.py [--hours 1]
[--imu realistic --imu real] [--kind teleop] [--online-unit su4] [--json out.json]``: false alarms over
simulated hours of normal work and detection delays and pose errors of 5 mm / 2 deg knocks (a thin script
over :func:`skincal.bench.monitor.bench_monitor`)."""

from __future__ import annotations

import json

from rich.console import Console

from skincal.bench import options
from skincal.bench.harness import parse_args
from skincal.bench.monitor import bench_monitor
from skincal.bench.script import run_script
from skincal.data.atomic import write_bytes_atomic


def main() -> None:
    args = parse_args(__doc__.splitlines()[0], options.MONITOR)
    console = Console()
    with console.status("benchmarking the moved-unit monitor...") as status:
        doc = bench_monitor(
            noises=tuple(args.imu or ("realistic", "real")), hours=args.hours, kind=args.kind, robot=args.robot,
            seed=args.seed, online_units=tuple(args.online_unit or ("su4",)), progress=status.update,
        )  # fmt: skip
    console.print_json(json.dumps(doc, default=float))
    if args.json is not None:
        write_bytes_atomic(args.json, json.dumps(doc, indent=2, default=float).encode())


if __name__ == "__main__":
    raise SystemExit(run_script(main))
