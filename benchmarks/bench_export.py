"""Export of a large result (issue 27, "no size bounds": ``export -f yaml`` of 10,000 units took 17.6 s, over
60 s before): CPU seconds of ``skincal export RESULT -f FORMAT`` per format on a simulated result.

    python benchmarks/bench_export.py [--units 10000] [--formats yaml json csv] [--target 2.0]

The result is made here (``--units`` units with random poses and per-axis std, the ``panda``), written as
a result file, and each format exported by the real command in a fresh process (reading the result
included), timed as that process's CPU time. Target: ``yaml`` within ``--target`` times ``json``'s CPU
time (the two build the same document); exit 1 when missed.
"""

from __future__ import annotations

import argparse
import resource
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from skincal.data.result import CalibrationResult, UnitResult, write_result
from skincal.skin.pose import SkinUnitPose


def make_result(n_units: int, seed: int = 0) -> CalibrationResult:
    """``n_units`` units on the Panda's links 1-7: random positions within 0.1 m, random rotations, std."""
    rng = np.random.default_rng(seed)
    units = {}
    for k in range(n_units):
        q = rng.normal(size=4)
        pose = SkinUnitPose.from_quaternion(k % 7 + 1, rng.uniform(-0.1, 0.1, 3), q / np.linalg.norm(q))
        units[f"su{k}"] = UnitResult(pose=pose, observable=True, position_std_m=rng.uniform(1e-5, 1e-3, 3),
                                     rotation_std_deg=rng.uniform(1e-3, 1e-1, 3))  # fmt: skip
    return CalibrationResult(method="mle", robot="panda", dataset_sha256="", runtime_s=0.0, units=units)


def cpu_of(argv: list[str]) -> float:
    """CPU seconds (user + system) of one ``skincal`` process."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    subprocess.run([sys.executable, "-m", "skincal", *argv], check=True, capture_output=True)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--units", type=int, default=10_000)
    p.add_argument("--formats", nargs="+", default=["yaml", "json", "csv"])
    p.add_argument("--target", type=float, default=2.0, help="yaml's CPU time at most this times json's")
    args = p.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        result = Path(tmp) / "result.json"
        write_result(make_result(args.units), result)
        cpu = {}
        for fmt in args.formats:
            cpu[fmt] = cpu_of(["export", str(result), "-f", fmt, "-o", str(Path(tmp) / f"out.{fmt}")])
            print(f"export -f {fmt:5s} {args.units} units: {cpu[fmt]:.2f} CPU s (simulated result)")
    if "yaml" in cpu and "json" in cpu:
        ratio = cpu["yaml"] / cpu["json"]
        ok = ratio <= args.target
        print(f"yaml / json CPU: {ratio:.2f} (target <= {args.target:g}): {'met' if ok else 'MISSED'}")
        return 0 if ok else 1
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
