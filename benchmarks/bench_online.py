"""Update cost of the streaming calibrator: ``python benchmarks/bench_online.py [--units 100] [--real-time]
[--json out.json]`` (100 units at 100 Hz, joint states at 1 kHz, one core; a thin script over
:mod:`skincal.workflows.bench_online`)."""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):  # one core: before NumPy loads
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import json  # noqa: E402
from pathlib import Path  # noqa: E402

from rich.console import Console  # noqa: E402

from skincal.io.atomic import write_bytes_atomic  # noqa: E402
from skincal.workflows.bench_online import online_report, run_online_benchmark, stream_vs_batch, stream_vs_batch_report  # noqa: E402
from skincal.workflows.script import run_script  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--units", type=int, default=100, help="skin units (random placement)")
    ap.add_argument("--robot", default="panda", help="robot preset")
    ap.add_argument("--joint-rate", type=float, default=1000.0, help="joint-state rate, Hz")
    ap.add_argument("--seed", type=int, default=0, help="session seed")
    ap.add_argument("--real-time", action="store_true", help="also replay at real speed and measure the delay")
    ap.add_argument("--json", type=Path, default=None, help="also write the figures as JSON")
    ap.add_argument("--accuracy", action="store_true",
                    help="instead: the stream's errors against the batch mle's on the same data (fast protocol and "
                    "a pick-and-place work cycle, 6 units, seeds 0-2)")  # fmt: skip
    args = ap.parse_args()
    console = Console()
    if args.accuracy:
        doc = stream_vs_batch(robot=args.robot, progress=lambda m: console.print(m, style="dim", highlight=False))
        for line in stream_vs_batch_report(doc):
            console.print(line, highlight=False)
        if args.json is not None:
            write_bytes_atomic(args.json, (json.dumps(doc, indent=2) + "\n").encode())
        return
    doc = run_online_benchmark(args.units, args.seed, args.robot, args.joint_rate, real_time=args.real_time,
                               progress=lambda m: console.print(m, style="dim", highlight=False))  # fmt: skip
    for line in online_report(doc):
        console.print(line, highlight=False)
    if args.json is not None:
        write_bytes_atomic(args.json, (json.dumps(doc, indent=2) + "\n").encode())


if __name__ == "__main__":
    raise SystemExit(run_script(main))
