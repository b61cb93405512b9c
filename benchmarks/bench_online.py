"""Update cost of the streaming calibrator: ``python benchmarks/bench_online.py [--units 100] [--real-time]
[--json out.json]`` (100 units at 100 Hz, joint states at 1 kHz, one core; a thin script over
:mod:`skincal.bench.online`)."""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):  # one core: before NumPy loads
    os.environ.setdefault(_var, "1")

import json  # noqa: E402

from rich.console import Console  # noqa: E402

from skincal.bench import options  # noqa: E402
from skincal.bench.harness import parse_args  # noqa: E402
from skincal.bench.online import online_report, run_online_benchmark, stream_vs_batch, stream_vs_batch_report  # noqa: E402
from skincal.bench.script import run_script  # noqa: E402
from skincal.data.atomic import write_bytes_atomic  # noqa: E402


def main() -> None:
    args = parse_args(__doc__.splitlines()[0], options.ONLINE)
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
