"""Repeatability across recordings of one mount: ``python benchmarks/bench_realdata.py DIR [--no-om]
[--no-online] [--json out.json]`` (the figures of ``skincal benchmark realdata``; a thin script over
:mod:`skincal.bench.realdata`). ``DIR``: folders with ``recording.h5`` (or ``.h5`` files)."""

from __future__ import annotations

import json

from rich.console import Console

from skincal.bench import options
from skincal.bench.harness import parse_args
from skincal.bench.realdata import chosen_methods, realdata_report, run_realdata_benchmark
from skincal.bench.script import run_script
from skincal.io.atomic import write_bytes_atomic


def main() -> None:
    args = parse_args(__doc__.splitlines()[0], options.REALDATA)
    console = Console()
    methods = chosen_methods(args.om, args.online)
    with console.status("benchmarking recordings...") as status:
        doc = run_realdata_benchmark(args.folder, methods, workers=args.workers, progress=status.update)
    for part in realdata_report(doc):
        console.print(part, highlight=False)
    if args.json_out is not None:
        write_bytes_atomic(args.json_out, json.dumps(doc, indent=1).encode())


if __name__ == "__main__":
    raise SystemExit(run_script(main))
