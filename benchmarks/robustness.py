"""The calibrator under faults of real robots and IMUs (the figures of ``skincal benchmark robustness``; a
thin script over :mod:`skincal.workflows.robustness`).

Usage: ``python benchmarks/robustness.py [--quick] [--robots panda,sawyer,ur5e] [--backends analytic,mujoco]
[--faults knock,gravity] [--seeds 5] [--protocol paper-sim] [--seed 0] [--workers 2] [--dask tcp://host:8786]
[--out robustness.json]`` (``--list`` lists the faults).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from rich.console import Console

from skincal.io.atomic import check_output, write_bytes_atomic
from skincal.workflows import robustness as rb
from skincal.workflows.script import run_script


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--robots", default=None, help="comma-separated robots (default panda,sawyer,ur5e)")
    ap.add_argument("--backends", default=None, help="analytic, mujoco, mujoco-dynamic (default analytic,mujoco)")
    ap.add_argument("--faults", default=None, help="comma-separated faults (default all of them; see --list)")
    ap.add_argument("--seeds", type=int, default=None, help="random placements per cell (default 5; quick 1)")
    ap.add_argument("--quick", action="store_true", help="1 seed and the short fast protocol")
    ap.add_argument("--protocol", default=None, help="protocol preset (default paper-sim; quick fast)")
    ap.add_argument("--seed", type=int, default=0, help="first placement seed")
    ap.add_argument("--workers", type=int, default=1, help="local worker processes (ignored with --dask)")
    ap.add_argument("--dask", default=None, help="address of an existing dask.distributed scheduler")
    ap.add_argument("--out", type=Path, default=None, help="write every cell and job record here (JSON)")
    ap.add_argument("--force", action="store_true", help="overwrite --out if it exists")
    ap.add_argument("--list", action="store_true", help="list the faults and exit")
    args = ap.parse_args()
    console = Console(width=140)
    if args.list:
        for line in rb.fault_lines():
            console.print(line, highlight=False, soft_wrap=True)
        return
    if args.out is not None:
        check_output(args.out, force=args.force)
    config = rb.config_from_options(
        args.robots, args.backends, args.faults, args.seeds, args.quick, args.protocol, args.seed
    )
    doc = rb.run_benchmark(config, workers=args.workers, dask=args.dask)
    for part in rb.report(config, doc):
        console.print(part, highlight=False)
    if args.out is not None:
        write_bytes_atomic(args.out, (json.dumps(doc, indent=1) + "\n").encode())


if __name__ == "__main__":
    raise SystemExit(run_script(main))
