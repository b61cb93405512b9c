"""Benchmark of the IMU-only unit-to-unit calibration (issue 18) on simulated hand-held sessions.

Usage: ``python benchmarks/bench_imu_only.py [--runs 20] [--duration 60] [--imu real] [--clock driver]
[--scale-free] [--holds N] [--json out.json]``

A thin script over :func:`skincal.bench.handheld.bench_relative`: two units 0.2 m apart on one
hand-moved body ("turn it over": still holds in orientations spread over the sphere, from which the
accelerometers' scale is fitted; ``--holds 0``: a motion without them), errors of the second unit's pose
in the first's frame, and the RMS of error / std.
All figures are SIMULATED.
"""

from __future__ import annotations

import json

from skincal.bench import options
from skincal.bench.handheld import bench_relative
from skincal.bench.harness import parse_args


def main() -> None:
    args = parse_args(__doc__.splitlines()[0], options.HANDHELD)
    doc = bench_relative(
        args.runs, args.duration, args.spacing, args.imu, args.clock, scale_free=args.scale_free, holds=args.holds
    )
    for key, value in doc.items():
        print(f"{key:32} {value:.4g}" if isinstance(value, float) else f"{key:32} {value}")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(doc, fh, indent=2)


if __name__ == "__main__":
    main()
