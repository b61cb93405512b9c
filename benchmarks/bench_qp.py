"""Benchmark of one avoidance-controller step: 7 DoF, 100 obstacle points with covariances (issue 17's target:
<= 1 ms median on one core), with the fixed critical distance and with the ISO/TS 15066 protective separation.

Usage: ``python benchmarks/bench_qp.py [--points 100] [--repeats 2000] [--json out.json [--force]]``

A thin script over :mod:`skincal.bench.qp` (what is measured and how). Prints median/p95 of the
step's CPU time (``time.process_time``) and wall time, and of the QP solve, per mode, and the ratio.
"""

from __future__ import annotations

import json

from skincal.bench import options
from skincal.bench.harness import parse_args
from skincal.bench.qp import format_qp_benchmark, qp_step_benchmark
from skincal.bench.script import run_script
from skincal.data.atomic import check_output, write_bytes_atomic


def main() -> None:
    args = parse_args(__doc__.splitlines()[0], options.QP)
    if args.json:
        check_output(args.json, force=args.force)
    res = qp_step_benchmark(args.points, args.repeats)
    print(format_qp_benchmark(res))
    if args.json:
        write_bytes_atomic(args.json, (json.dumps(res, indent=2) + "\n").encode())


if __name__ == "__main__":
    raise SystemExit(run_script(main))
