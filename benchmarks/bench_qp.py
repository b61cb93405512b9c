"""Benchmark of one avoidance-controller step: 7 DoF, 100 obstacle points with covariances (issue 17's target:
<= 1 ms median on one core), with the fixed critical distance and with the ISO/TS 15066 protective separation.

Usage: ``python benchmarks/bench_qp.py [--points 100] [--repeats 2000] [--json out.json [--force]]``

A thin script over :mod:`skincal.workflows.bench_qp` (what is measured and how). Prints median/p95 of the
step's CPU time (``time.process_time``) and wall time, and of the QP solve, per mode, and the ratio.
"""

from __future__ import annotations

import argparse
import json

from skincal.io.atomic import check_output, write_bytes_atomic
from skincal.workflows.bench_qp import format_qp_benchmark, qp_step_benchmark
from skincal.workflows.script import run_script


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", type=int, default=100)
    ap.add_argument("--repeats", type=int, default=2000)
    ap.add_argument("--json", default=None, help="also write the figures here")
    ap.add_argument("--force", action="store_true", help="overwrite an existing --json file")
    args = ap.parse_args()
    if args.json:
        check_output(args.json, force=args.force)
    res = qp_step_benchmark(args.points, args.repeats)
    print(format_qp_benchmark(res))
    if args.json:
        write_bytes_atomic(args.json, (json.dumps(res, indent=2) + "\n").encode())


if __name__ == "__main__":
    raise SystemExit(run_script(main))
