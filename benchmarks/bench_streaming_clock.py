"""The streaming calibrator on drifting and re-synced clocks against mle (issue 25's target; SIMULATED).

    nice python benchmarks/bench_streaming_clock.py [--quick] [--robots panda,ur5e] [--protocols fast,paper-sim]
        [--clocks wifi,wifi-resync] [--seeds 0 1 2] [--workers 1] [--json out.json] [--force]

A thin script over :mod:`skincal.bench.streaming_clock` (one job per robot, protocol, clock and seed: mle and
``calibrate --follow`` to the data's end on the same simulated session); prints the per-cell table and one
verdict per (robot, protocol, clock), and optionally writes JSON.
"""

from __future__ import annotations

import json

from rich.console import Console

from skincal.bench.harness import parse_args, run_harness, values
from skincal.bench.script import run_script
from skincal.errors import ConfigError
from skincal.io.atomic import write_bytes_atomic


def main() -> None:
    from skincal.bench.streaming_clock import HARNESS as harness

    v = values(parse_args(__doc__.splitlines()[0], harness.options), harness.options)
    if v["json"] is not None and v["json"].exists() and not v["force"]:
        raise ConfigError(f"{v['json']} exists; give --force to overwrite it")
    console = Console(width=170)
    config = harness.config(v)

    def progress(r: dict) -> None:
        console.print(f"{r['robot']} {r['protocol']} {r['clock']} seed {r['seed']}: mle {r['mle']['position_mm']:.3f} "
                      f"mm, online {r['online']['position_mm']:.3f} mm ({r['mle_s']:.0f} s / {r['online_s']:.0f} s)",
                      highlight=False)  # fmt: skip

    doc, run = run_harness(harness, config, workers=v["workers"], progress=progress)
    for part in harness.report(config, doc, run):
        console.print(part, highlight=False)
    if v["json"] is not None:
        write_bytes_atomic(v["json"], (json.dumps(doc, indent=1) + "\n").encode())


if __name__ == "__main__":
    raise SystemExit(run_script(main))
