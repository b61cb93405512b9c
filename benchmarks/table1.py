"""Reproduce the paper's Table I (the figures of ``skincal benchmark table1``; a thin script over
:mod:`skincal.workflows.table1`).

Usage: ``python benchmarks/table1.py [--quick] [--runs 10] [--sets 4] [--methods om,om-joint,mmm,mm]
[--workers 2] [--dask tcp://host:8786] [--seed 0] [--json table1.json]``
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from rich.console import Console

from skincal.io.atomic import write_bytes_atomic
from skincal.workflows import table1 as t1
from skincal.workflows.script import run_script


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="tiny run: 1 set x 1 run, 2 units, short protocol")
    ap.add_argument("--runs", type=int, default=None, help="optimiser runs per set (default 10; quick 1)")
    ap.add_argument("--sets", type=int, default=None, help="random placement sets (default 4; quick 1)")
    ap.add_argument("--methods", default="om,mmm,mm", help="comma-separated methods")
    ap.add_argument("--workers", type=int, default=1, help="local worker processes (ignored with --dask)")
    ap.add_argument("--dask", default=None, help="address of an existing dask.distributed scheduler")
    ap.add_argument("--seed", type=int, default=0, help="base seed of the placement sets")
    ap.add_argument("--json", type=Path, default=None, help="write the records and summary here")
    args = ap.parse_args()
    console = Console(width=140)
    config = t1.config_from_options(args.quick, args.runs, args.sets, args.methods, args.seed)
    doc = t1.run_benchmark(config, args.workers, args.dask)
    for part in t1.report(config, doc, args.workers, args.dask):
        console.print(part)
    if args.json is not None:
        write_bytes_atomic(args.json, (json.dumps(doc, indent=1) + "\n").encode())


if __name__ == "__main__":
    raise SystemExit(run_script(main))
