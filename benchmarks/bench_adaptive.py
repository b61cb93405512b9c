"""Adaptive motion vs the fixed ``fast`` protocol: robot motion time to 0.3 mm / 0.05 deg std (issue 16; run by hand).

    python benchmarks/bench_adaptive.py --robots panda sawyer ur5e --seeds 0

A thin script over :mod:`skincal.bench.adaptive`: per robot and seed, 6 units (paper
placement), ``realistic`` IMUs and ``controller`` joint states, the streaming calibrator fed by the
adaptive loop and by the whole ``fast`` protocol; prints the motion times and the true (worst-unit)
errors, optionally JSON.
"""

from __future__ import annotations

import dataclasses
import json

from rich.console import Console

from skincal.bench import options
from skincal.bench.harness import parse_args, run_harness, values
from skincal.bench.script import run_script


def main() -> None:
    from skincal.bench.adaptive import HARNESS as harness

    args = parse_args(__doc__.splitlines()[0], options.ADAPTIVE)
    config = harness.config(values(args, options.ADAPTIVE))
    console = Console(width=200)
    doc, run = run_harness(
        harness, config, progress=lambda r: console.print(f"{r.robot} seed {r.seed} done", highlight=False)
    )
    for part in harness.report(config, doc, run):
        console.print(part)
    if args.json is not None:
        args.json.write_text(json.dumps([dataclasses.asdict(r) for r in doc["rows"]], indent=2))


if __name__ == "__main__":
    raise SystemExit(run_script(main))
