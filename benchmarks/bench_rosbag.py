"""Bag path vs HDF5 path: same calibration accuracy within 10 % (issue 8 target; run by hand).

    python benchmarks/bench_rosbag.py --seeds 0 1 2 --joint-rate 200 --ros 2 --storage mcap

For each seed: simulate the paper-sim protocol (Panda, paper placement, 6 units, realistic IMU)
with the joint stream at ``--joint-rate`` Hz (a typical ``/joint_states`` rate), then

* HDF5 path: write/read the dataset with the simulator's protocol segments, calibrate with mle;
* bag path: write a real bag with rosbags (accelerations in g, rates in deg/s, as the paper's skin
  sent them), ``read_bag`` (unit detection), ``segment_dataset`` (automatic segments), mle.

Both are evaluated against the simulation truth; prints per-seed errors, timings and the ratio of
the mean errors (bag / HDF5), and optionally writes JSON.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
from rich.console import Console
from rich.table import Table

from skincal.calib import calibrate, evaluate
from skincal.data.hdf5 import read_dataset, write_dataset
from skincal.data.rosbag import read_bag, write_bag
from skincal.data.segment import segment_dataset
from skincal.kinematics import get_robot
from skincal.protocol import build_trajectory, get_protocol
from skincal.sim.analytic import simulate
from skincal.skin.imu import get_imu_model
from skincal.skin.placement import paper_placement


def run_seed(seed: int, args: argparse.Namespace, workdir: Path) -> dict:
    chain = get_robot("panda")
    rng = np.random.default_rng(seed)
    config = replace(get_protocol(args.protocol), rate_hz=float(args.joint_rate))
    ds = simulate(chain, paper_placement(chain), build_trajectory(chain, config, rng), get_imu_model(args.noise), rng)
    h5 = workdir / f"s{seed}.h5"
    bag = workdir / (f"s{seed}.bag" if args.ros == 1 else f"s{seed}_bag")
    t = time.perf_counter()
    write_dataset(ds, h5)
    ref = calibrate(read_dataset(h5), "mle", seed=seed)
    t_h5 = time.perf_counter() - t
    t = time.perf_counter()
    write_bag(ds, bag, ros_version=args.ros, storage=args.storage, accel_unit="g", gyro_unit="deg")
    t_write = time.perf_counter() - t
    t = time.perf_counter()
    imported, report = read_bag(bag, "panda")
    t_read = time.perf_counter() - t
    t = time.perf_counter()
    imported, seg = segment_dataset(imported)
    t_seg = time.perf_counter() - t
    t = time.perf_counter()
    res = calibrate(imported, "mle", seed=seed)
    t_cal = time.perf_counter() - t
    shifted = replace(ds, joints=replace(ds.joints, t=ds.joints.t - ds.joints.t[0]))  # the bag's time origin
    ev_ref, ev_bag = evaluate(ref, ds), evaluate(res, shifted)
    n_msgs = sum(report.counts.values())
    return {
        "seed": seed, "duration_s": ds.duration, "messages": n_msgs,
        "segments_true": len(ds.segments), "segments_found": len(seg.segments), "rejected": len(seg.rejected),
        "hdf5": {k: ev_ref[k] for k in ("mean_position_error_mm", "mean_rotation_error_deg", "links_correct")},
        "bag": {k: ev_bag[k] for k in ("mean_position_error_mm", "mean_rotation_error_deg", "links_correct")},
        "units_total": ev_ref["units_total"],
        "time_s": {"hdf5_total": t_h5, "bag_write": t_write, "bag_read": t_read, "segment": t_seg,
                   "bag_calibrate": t_cal},
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--joint-rate", type=float, default=200.0, help="joint state rate, Hz")
    parser.add_argument("--protocol", default="paper-sim")
    parser.add_argument("--noise", default="realistic")
    parser.add_argument("--ros", type=int, choices=(1, 2), default=2)
    parser.add_argument("--storage", choices=("sqlite3", "mcap"), default="mcap")
    parser.add_argument("--json", type=Path, default=None, help="write the numbers here")
    args = parser.parse_args()
    console = Console(width=170)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for seed in args.seeds:
            rows.append(run_seed(seed, args, Path(tmp)))
            console.print(f"seed {seed} done", highlight=False)
    table = Table(title=f"bag (ROS {args.ros}{'' if args.ros == 1 else ' ' + args.storage}) vs HDF5, mle, "
                        f"{args.protocol}, {args.noise} IMU, joints at {args.joint_rate:g} Hz")
    for col in ("seed", "msgs", "segments true/found/rej.", "pos err h5 [mm]", "pos err bag [mm]", "rot h5 [deg]",
                "rot bag [deg]", "links h5/bag", "write/read/seg/cal [s]"):
        table.add_column(col)
    for r in rows:
        h, b, ts = r["hdf5"], r["bag"], r["time_s"]
        table.add_row(str(r["seed"]), str(r["messages"]), f"{r['segments_true']}/{r['segments_found']}/{r['rejected']}",
                      f"{h['mean_position_error_mm']:.3f}", f"{b['mean_position_error_mm']:.3f}",
                      f"{h['mean_rotation_error_deg']:.4f}", f"{b['mean_rotation_error_deg']:.4f}",
                      f"{h['links_correct']}/{b['links_correct']} of {r['units_total']}",
                      f"{ts['bag_write']:.1f}/{ts['bag_read']:.1f}/{ts['segment']:.2f}/{ts['bag_calibrate']:.1f}")
    console.print(table)
    summary = {}
    for key in ("mean_position_error_mm", "mean_rotation_error_deg"):
        h5 = float(np.mean([r["hdf5"][key] for r in rows]))
        bag = float(np.mean([r["bag"][key] for r in rows]))
        summary[key] = {"hdf5": h5, "bag": bag, "ratio": bag / h5}
        verdict = "within 10 %" if bag <= 1.1 * h5 else "NOT within 10 %"
        console.print(f"{key}: HDF5 {h5:.4g}, bag {bag:.4g}, ratio {bag / h5:.3f} ({verdict})", highlight=False)
    if args.json:
        args.json.write_text(json.dumps({"args": {k: str(v) for k, v in vars(args).items()}, "runs": rows,
                                         "summary": summary}, indent=2))


if __name__ == "__main__":
    main()
