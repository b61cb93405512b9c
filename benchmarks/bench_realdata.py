"""Repeatability across recordings of one mount: ``python benchmarks/bench_realdata.py DIR [--no-om]
[--json out.json]`` (the figures of ``skincal benchmark realdata``; a thin script over
:mod:`skincal.bench.realdata`). ``DIR``: folders with ``recording.h5`` (or ``.h5`` files)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from rich.console import Console

from skincal.bench.realdata import METHODS, realdata_report, run_realdata_benchmark
from skincal.io.atomic import write_bytes_atomic
from skincal.workflows.script import run_script


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("folder", type=Path, help="folder of recordings sharing a mount")
    ap.add_argument("--no-om", dest="om", action="store_false", help="do not run the paper's OM")
    ap.add_argument("--json", type=Path, default=None, help="also write the figures as JSON")
    args = ap.parse_args()
    console = Console()
    methods = METHODS if args.om else tuple(m for m in METHODS if m != "om")
    with console.status("benchmarking recordings...") as status:
        doc = run_realdata_benchmark(args.folder, methods, progress=status.update)
    for part in realdata_report(doc):
        console.print(part, highlight=False)
    if args.json is not None:
        write_bytes_atomic(args.json, json.dumps(doc, indent=1).encode())


if __name__ == "__main__":
    raise SystemExit(run_script(main))
