"""The calibrator under faults of real robots and IMUs (the figures of ``skincal benchmark robustness``; a
thin script over :mod:`skincal.bench.robustness`).

Usage: ``python benchmarks/robustness.py [--quick] [--robots panda,sawyer,ur5e] [--backends analytic,mujoco]
[--faults knock,gravity] [--placements 5] [--protocol paper-sim] [--seed 0] [--workers 2] [--dask tcp://host:8786]
[--out robustness.json]`` (``--list`` lists the faults).
"""

from __future__ import annotations

import json

from rich.console import Console

from skincal.bench import robustness as rb
from skincal.bench.harness import parse_args, run_harness, values
from skincal.bench.script import run_script
from skincal.io.atomic import check_output, write_bytes_atomic


def main() -> None:
    harness = rb.HARNESS
    v = values(parse_args(__doc__.splitlines()[0], harness.options), harness.options)
    console = Console(width=140)
    if v["list_faults"]:
        for line in rb.fault_lines():
            console.print(line, highlight=False, soft_wrap=True)
        return
    if v["out"] is not None:
        check_output(v["out"], force=v["force"])
    config = harness.config(v)
    doc, run = run_harness(harness, config, workers=v["workers"], dask=v["dask"])
    for part in harness.report(config, doc, run):
        console.print(part, highlight=False)
    if v["out"] is not None:
        write_bytes_atomic(v["out"], (json.dumps(doc, indent=1) + "\n").encode())


if __name__ == "__main__":
    raise SystemExit(run_script(main))
