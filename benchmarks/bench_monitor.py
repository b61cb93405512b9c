"""A unit that moved is noticed (issue 16): ``python benchmarks/bench_monitor.py [--hours 1]
[--imu realistic --imu real] [--kind teleop] [--online-unit su4] [--json out.json]``: false alarms over
simulated hours of normal work and detection delays and pose errors of 5 mm / 2 deg knocks (a thin script
over :func:`skincal.workflows.monitoring.bench_monitor`)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from rich.console import Console

from skincal.io.atomic import write_bytes_atomic
from skincal.workflows.monitoring import bench_monitor
from skincal.workflows.script import run_script


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--hours", type=float, default=1.0, help="simulated hours of normal work per IMU preset")
    ap.add_argument("--imu", action="append", default=None, help="IMU preset (repeat; default realistic and real)")
    ap.add_argument("--kind", default="teleop", help="work cycle: teleop or pick-place")
    ap.add_argument("--robot", default="panda")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument(
        "--online-unit",
        action="append",
        default=None,
        help="unit also knocked with the streaming calibrator (repeat; default su4)",
    )
    ap.add_argument("--json", type=Path, default=None, help="also write the figures as JSON")
    args = ap.parse_args()
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
