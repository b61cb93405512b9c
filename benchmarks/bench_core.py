"""FK and simulation throughput at 1, 10 and 100 units: ``python benchmarks/bench_core.py [--robot panda]
[--json out.json]`` (the figures of ``skincal benchmark core``; a thin script over
:mod:`skincal.workflows.bench_core`)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from rich.console import Console

from skincal.io.atomic import write_bytes_atomic
from skincal.workflows.bench_core import core_report, run_core_benchmark
from skincal.workflows.script import run_script


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--robot", default="panda", help="robot preset")
    ap.add_argument("--json", type=Path, default=None, help="also write the figures as JSON")
    args = ap.parse_args()
    console = Console()
    doc = run_core_benchmark(args.robot)
    for part in core_report(doc):
        console.print(part)
    if args.json is not None:
        write_bytes_atomic(args.json, json.dumps(doc, indent=2).encode())


if __name__ == "__main__":
    raise SystemExit(run_script(main))
