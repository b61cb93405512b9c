"""The default calibrator's targets: ``python benchmarks/bench_mle.py [--placements 20] [--quick] [--no-om]
[--json out.json]`` (the figures of ``skincal benchmark mle``; a thin script over
:mod:`skincal.bench.mle`)."""

from __future__ import annotations

import json

from rich.console import Console

from skincal.bench import options
from skincal.bench.harness import parse_args
from skincal.bench.mle import run_mle_benchmark
from skincal.bench.script import run_script
from skincal.io.atomic import write_bytes_atomic


def main() -> None:
    args = parse_args(__doc__.splitlines()[0], options.MLE)
    console = Console()
    with console.status("benchmarking mle...") as status:
        doc = run_mle_benchmark(runs=args.placements, quick=args.quick, with_om=args.om, progress=status.update)
    console.print_json(json.dumps(doc))
    if args.json_out is not None:
        write_bytes_atomic(args.json_out, json.dumps(doc, indent=2).encode())


if __name__ == "__main__":
    raise SystemExit(run_script(main))
