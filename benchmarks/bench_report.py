"""``skincal report`` at scale: wall time, peak memory and page size for a many-unit dataset (issue 19
target: 100 units in <= 20 s and <= 300 MB peak RSS; run by hand).

    python benchmarks/bench_report.py --units 100 --protocol fast --workdir /tmp/bench-report

Simulates (``skincal simulate --placement random --noise realistic``) and calibrates (``skincal
calibrate``) once into ``--workdir`` (reused when the files are there), then runs ``skincal report``
(HTML, and ``--format md``) as child processes and reads each one's peak resident set size from the
kernel (``wait4``, the figure ``/usr/bin/time -v`` prints as "Maximum resident set size"). For
reference it also measures ``skincal info`` on the same dataset: reading and validating the dataset
alone, the floor under the report's memory.

Measured 2026-11-30 on the shared 2-core machine (load ~2-5, so wall times are inflated; CPU is
user + system, of the report and its workers), 100 units, ``realistic`` IMUs, HTML report:

=============================  ===================================  ===================================
dataset                        before (5fd141f~1)                   whole-file read (3be49bb)
=============================  ===================================  ===================================
``fast`` (83 s, 50 MB file)    69 s wall, 33 s CPU, 408 MB, 6.0 MB  17 s wall, 8.9 s CPU, 248 MB, 0.8 MB
``paper-sim`` (681 s, 401 MB)  58 s wall, 61 s CPU, 1412 MB, 6.3 MB 33 s wall, 29 s CPU, 750 MB, 1.0 MB
=============================  ===================================  ===================================

Streamed (``open_dataset``: the joints, then one unit's IMU data at a time; 2 forked workers, the
default ``--workers 2``): ``fast`` 6.7 s wall, 8.8 s CPU, 212 MB; ``paper-sim`` 20.0 s wall, 31.7 s
CPU, 382 MB (one worker: 31 s, 385 MB; the peak RSS is the largest single process, the forked
workers share the parent's pages: the summed PSS of parent and workers peaks at ~420 MB). The
paper-sim peak is the joint interpolator's construction (``calib/preprocess/interpolate.py``, ~165 MB for
340k x 7 joint samples) on top of the imports (~120 MB) and the joint stream (~40 MB).

(``skincal info`` alone: 159 MB and 522 MB; the paper-sim page is the issue's 6.3 MB one.)
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

TARGET_S, TARGET_MB = 20.0, 300.0


def _skincal() -> list[str]:
    exe = shutil.which("skincal")
    return [exe] if exe else [sys.executable, "-m", "skincal"]


def measure(args: list[str]) -> dict[str, float]:
    """Run ``skincal ARGS`` and return its wall time (s), CPU time (s, user + system: less sensitive
    to other load on the machine) and peak RSS (MB, this child only)."""
    t0 = time.perf_counter()
    proc = subprocess.Popen([*_skincal(), *args], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    _, status, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - t0
    err = proc.stderr.read().decode(errors="replace") if proc.stderr else ""
    if os.waitstatus_to_exitcode(status) != 0:
        raise SystemExit(f"skincal {' '.join(args)} failed: {err.strip()}")
    return {"wall_s": wall, "cpu_s": usage.ru_utime + usage.ru_stime, "max_rss_mb": usage.ru_maxrss / 1024.0}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--units", type=int, default=100)
    parser.add_argument("--protocol", default="fast", help="simulation protocol (fast: 83 s of motion)")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--workdir", type=Path, default=Path("bench-report"), help="dataset and result (reused)")
    parser.add_argument("--repeat", type=int, default=1, help="report runs (the best is kept)")
    parser.add_argument("--json", type=Path, default=None, help="write the numbers here")
    args = parser.parse_args()
    work = args.workdir
    work.mkdir(parents=True, exist_ok=True)
    tag = f"{args.units}u-{args.protocol}-s{args.seed}"
    ds, res = work / f"ds-{tag}.h5", work / f"res-{tag}.json"
    if not ds.exists():
        print(f"simulating {ds} ...", flush=True)
        subprocess.run([*_skincal(), "simulate", "-o", str(ds), "--placement", "random", "--units", str(args.units),
                        "--protocol", args.protocol, "--noise", "realistic", "--seed", str(args.seed)],
                       check=True, stdout=subprocess.DEVNULL)
    if not res.exists():
        print(f"calibrating {res} ...", flush=True)
        subprocess.run([*_skincal(), "calibrate", str(ds), "-o", str(res)], check=True, stdout=subprocess.DEVNULL)
    runs = []
    for fmt in ("html", "md"):
        out = work / f"report-{tag}.{fmt}"
        best = None
        for _ in range(args.repeat):
            m = measure(["report", str(res), "--dataset", str(ds), "--format", fmt, "-o", str(out), "--force"])
            best = m if best is None or m["wall_s"] < best["wall_s"] else best
        runs.append({"what": f"report --format {fmt}", **best, "page_mb": out.stat().st_size / 2**20})
    runs.append({"what": "info (read the dataset only)", **measure(["info", str(ds)]), "page_mb": float("nan")})
    print(f"{args.units} units, protocol {args.protocol}, dataset {ds.stat().st_size / 2**20:.1f} MB "
          f"(targets for the HTML report: <= {TARGET_S:g} s, <= {TARGET_MB:g} MB)")
    print(f"{'command':32} {'wall [s]':>9} {'CPU [s]':>8} {'peak RSS [MB]':>14} {'output [MB]':>12}")
    for r in runs:
        print(f"{r['what']:32} {r['wall_s']:9.1f} {r['cpu_s']:8.1f} {r['max_rss_mb']:14.0f} {r['page_mb']:12.2f}")
    html = runs[0]
    verdict = {"time_ok": html["wall_s"] <= TARGET_S, "memory_ok": html["max_rss_mb"] <= TARGET_MB}
    print(f"time {'within' if verdict['time_ok'] else 'OVER'} target, memory "
          f"{'within' if verdict['memory_ok'] else 'OVER'} target")
    if args.json is not None:
        args.json.write_text(json.dumps({"units": args.units, "protocol": args.protocol, "runs": runs, **verdict},
                                        indent=2))


if __name__ == "__main__":
    main()
