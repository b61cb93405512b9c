"""FK and simulation throughput at 1, 10 and 100 units: ``python benchmarks/bench_core.py [--robot panda]
[--json out.json]`` (the figures of ``skincal benchmark core``; a thin script over
:mod:`skincal.bench.core`)."""

from __future__ import annotations

import json

from rich.console import Console

from skincal.bench import options
from skincal.bench.core import core_report, run_core_benchmark
from skincal.bench.harness import parse_args
from skincal.bench.script import run_script
from skincal.data.atomic import write_bytes_atomic


def main() -> None:
    args = parse_args(__doc__.splitlines()[0], options.CORE)
    console = Console()
    doc = run_core_benchmark(args.robot)
    for part in core_report(doc):
        console.print(part)
    if args.json_out is not None:
        write_bytes_atomic(args.json_out, json.dumps(doc, indent=2).encode())


if __name__ == "__main__":
    raise SystemExit(run_script(main))
