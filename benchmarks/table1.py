"""Reproduce the paper's Table I (the figures of ``skincal benchmark table1``; a thin script over
:mod:`skincal.bench.table1`).

Usage: ``python benchmarks/table1.py [--quick] [--runs 10] [--sets 4] [--methods om,om-joint,mmm,mm]
[--workers 2] [--dask tcp://host:8786] [--seed 0] [--json table1.json]``
"""

from __future__ import annotations

import json

from rich.console import Console

from skincal.bench import table1 as t1
from skincal.bench.harness import parse_args, run_harness, values
from skincal.bench.script import run_script
from skincal.data.atomic import write_bytes_atomic


def main() -> None:
    harness = t1.HARNESS
    v = values(parse_args(__doc__.splitlines()[0], harness.options), harness.options)
    console = Console(width=140)
    config = harness.config(v)
    doc, run = run_harness(harness, config, workers=v["workers"], dask=v["dask"])
    for part in harness.report(config, doc, run):
        console.print(part)
    if v["json_out"] is not None:
        write_bytes_atomic(v["json_out"], (json.dumps(doc, indent=1) + "\n").encode())


if __name__ == "__main__":
    raise SystemExit(run_script(main))
