"""Speed figures of issue 26: ``python benchmarks/bench_speed.py [--quick | --full] [--workers 2] [--json out.json]``
(the figures of ``skincal benchmark speed``; a thin script over :mod:`skincal.bench.speed`)."""

from __future__ import annotations

import json

from skincal.bench import options
from skincal.bench.harness import parse, run_harness
from skincal.bench.script import run_script
from skincal.bench.speed import HARNESS
from skincal.io.atomic import write_bytes_atomic


def main() -> None:
    v = parse(__doc__.splitlines()[0], options.SPEED)
    config = HARNESS.config(v)
    doc, run = run_harness(HARNESS, config, workers=1)
    for line in HARNESS.report(config, doc, run):
        print(line)
    if v["json_out"] is not None:
        write_bytes_atomic(v["json_out"], (json.dumps(doc, indent=1) + "\n").encode())


if __name__ == "__main__":
    raise SystemExit(run_script(main))
