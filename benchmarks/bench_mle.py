"""The default calibrator's targets: ``python benchmarks/bench_mle.py [--runs 20] [--quick] [--no-om]
[--json out.json]`` (the figures of ``skincal benchmark mle``; a thin script over
:mod:`skincal.workflows.bench_mle`)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from rich.console import Console

from skincal.io.atomic import write_bytes_atomic
from skincal.workflows.bench_mle import run_mle_benchmark
from skincal.workflows.script import run_script


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=20, help="random placements per robot")
    ap.add_argument("--quick", action="store_true", help="short protocol, for a smoke test")
    ap.add_argument("--no-om", dest="om", action="store_false", help="do not time the paper's OM on the same data")
    ap.add_argument("--json", type=Path, default=None, help="also write the figures as JSON")
    args = ap.parse_args()
    console = Console()
    with console.status("benchmarking mle...") as status:
        doc = run_mle_benchmark(runs=args.runs, quick=args.quick, with_om=args.om, progress=status.update)
    console.print_json(json.dumps(doc))
    if args.json is not None:
        write_bytes_atomic(args.json, json.dumps(doc, indent=2).encode())


if __name__ == "__main__":
    raise SystemExit(run_script(main))
