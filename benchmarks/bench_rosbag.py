"""Bag path vs HDF5 path: same calibration accuracy within 10 % (issue 8 target; run by hand).

    python benchmarks/bench_rosbag.py --seeds 0 1 2 --joint-rate 200 --ros 2 --storage mcap

A thin script over :mod:`skincal.bench.rosbag` (what is run, per seed); prints per-seed
errors, timings and the ratio of the mean errors (bag / HDF5), and optionally writes JSON.
"""

from __future__ import annotations

import json
import tempfile
from pathlib import Path

from rich.console import Console
from rich.table import Table

from skincal.bench import options
from skincal.bench.harness import parse_args
from skincal.bench.rosbag import run_seed, summarise
from skincal.bench.script import run_script


def main() -> None:
    args = parse_args(__doc__.splitlines()[0], options.ROSBAG)
    console = Console(width=170)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for seed in args.seeds:
            rows.append(
                run_seed(
                    seed,
                    Path(tmp),
                    joint_rate=args.joint_rate,
                    protocol=args.protocol,
                    noise=args.noise,
                    ros=args.ros,
                    storage=args.storage,
                )
            )
            console.print(f"seed {seed} done", highlight=False)
    table = Table(
        title=f"bag (ROS {args.ros}{'' if args.ros == 1 else ' ' + args.storage}) vs HDF5, mle, "
        f"{args.protocol}, {args.noise} IMU, joints at {args.joint_rate:g} Hz"
    )
    for col in (
        "seed",
        "msgs",
        "segments true/found/rej.",
        "pos err h5 [mm]",
        "pos err bag [mm]",
        "rot h5 [deg]",
        "rot bag [deg]",
        "links h5/bag",
        "write/read/seg/cal [s]",
    ):
        table.add_column(col)
    for r in rows:
        h, b, ts = r["hdf5"], r["bag"], r["time_s"]
        table.add_row(
            str(r["seed"]),
            str(r["messages"]),
            f"{r['segments_true']}/{r['segments_found']}/{r['rejected']}",
            f"{h['mean_position_error_mm']:.3f}",
            f"{b['mean_position_error_mm']:.3f}",
            f"{h['mean_rotation_error_deg']:.4f}",
            f"{b['mean_rotation_error_deg']:.4f}",
            f"{h['links_correct']}/{b['links_correct']} of {r['units_total']}",
            f"{ts['bag_write']:.1f}/{ts['bag_read']:.1f}/{ts['segment']:.2f}/{ts['bag_calibrate']:.1f}",
        )
    console.print(table)
    summary = summarise(rows)
    for key, s in summary.items():
        h5, bag = s["hdf5"], s["bag"]
        verdict = "within 10 %" if bag <= 1.1 * h5 else "NOT within 10 %"
        console.print(f"{key}: HDF5 {h5:.4g}, bag {bag:.4g}, ratio {bag / h5:.3f} ({verdict})", highlight=False)
    if args.json:
        args.json.write_text(
            json.dumps({"args": {k: str(v) for k, v in vars(args).items()}, "runs": rows, "summary": summary}, indent=2)
        )


if __name__ == "__main__":
    raise SystemExit(run_script(main))
