"""Bag path vs HDF5 path: same calibration accuracy within 10 % (issue 8 target; run by hand).

    python benchmarks/bench_rosbag.py --seeds 0 1 2 --joint-rate 200 --ros 2 --storage mcap

A thin script over :mod:`skincal.bench.rosbag` (what is run, per seed); prints per-seed
errors, timings and the ratio of the mean errors (bag / HDF5), and optionally writes JSON.
"""

from __future__ import annotations

import json

from rich.console import Console

from skincal.bench import options
from skincal.bench.harness import parse_args, run_harness, values
from skincal.bench.script import run_script


def main() -> None:
    from skincal.bench.rosbag import HARNESS as harness

    args = parse_args(__doc__.splitlines()[0], options.ROSBAG)
    console = Console(width=170)
    config = harness.config(values(args, options.ROSBAG))
    doc, run = run_harness(harness, config, progress=lambda r: console.print(f"seed {r['seed']} done", highlight=False))
    for part in harness.report(config, doc, run):
        console.print(part, highlight=False)
    if args.json:
        args.json.write_text(json.dumps({"args": {k: str(v) for k, v in vars(args).items()}, **doc}, indent=2))


if __name__ == "__main__":
    raise SystemExit(run_script(main))
