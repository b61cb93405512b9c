"""Bag path vs HDF5 path: the same calibration accuracy within 10 % (issue 8 target;
``benchmarks/bench_rosbag.py``).

For each seed: a simulated session from :func:`skincal.workflows.session.make_session` (Panda, paper
placement, 6 units, ideal joint states and clocks) with the joint stream at ``joint_rate`` Hz (a typical
``/joint_states`` rate), then

* HDF5 path: write/read the dataset with the simulator's protocol segments, calibrate with mle;
* bag path: write a real bag with rosbags (accelerations in g, rates in deg/s, as the paper's skin
  sent them), ``read_bag`` (unit detection), ``segment_dataset`` (automatic segments), mle.

Both are evaluated against the simulation truth.
"""

from __future__ import annotations

import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from skincal.bench.harness import RunInfo
from skincal.bench.options import ROSBAG

ERROR_KEYS = ("mean_position_error_mm", "mean_rotation_error_deg")


def run_seed(
    seed: int,
    workdir: Path,
    *,
    joint_rate: float = 200.0,
    protocol: str = "paper-sim",
    noise: str = "realistic",
    ros: int = 2,
    storage: str = "mcap",
) -> dict[str, Any]:
    """Both paths for one seed: errors, segments found, messages and timings."""
    from skincal.calib import calibrate, evaluate
    from skincal.data.hdf5 import read_dataset, write_dataset
    from skincal.data.ros import read_bag, write_bag
    from skincal.data.segment import segment_dataset
    from skincal.protocol import get_protocol
    from skincal.sim import simulate
    from skincal.workflows.session import make_session

    config = replace(get_protocol(protocol), rate_hz=float(joint_rate))
    ds = simulate(make_session("panda", "paper", None, noise, config, seed, joints="ideal", clock="ideal"))
    h5 = workdir / f"s{seed}.h5"
    bag = workdir / (f"s{seed}.bag" if ros == 1 else f"s{seed}_bag")
    t = time.perf_counter()
    write_dataset(ds, h5)
    ref = calibrate(read_dataset(h5), "mle", seed=seed)
    t_h5 = time.perf_counter() - t
    t = time.perf_counter()
    write_bag(ds, bag, ros_version=ros, storage=storage, accel_unit="g", gyro_unit="deg")
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
    js = ds.joint_states
    shifted = replace(ds, joints=replace(js, t=js.t - js.t[0]))  # the bag's time origin
    ev_ref, ev_bag = evaluate(ref, ds), evaluate(res, shifted)
    keys = (*ERROR_KEYS, "links_correct")
    return {
        "seed": seed,
        "duration_s": ds.duration,
        "messages": sum(report.counts.values()),
        "segments_true": len(ds.segments),
        "segments_found": len(seg.segments),
        "rejected": len(seg.rejected),
        "hdf5": {k: getattr(ev_ref, k) for k in keys},
        "bag": {k: getattr(ev_bag, k) for k in keys},
        "units_total": ev_ref.units_total,
        "time_s": {
            "hdf5_total": t_h5,
            "bag_write": t_write,
            "bag_read": t_read,
            "segment": t_seg,
            "bag_calibrate": t_cal,
        },
    }


def summarise(rows: Sequence[dict[str, Any]]) -> dict[str, dict[str, float]]:
    """Mean error of each path over the seeds and their ratio (bag / HDF5), per error kind."""
    out = {}
    for key in ERROR_KEYS:
        h5 = float(np.mean([r["hdf5"][key] for r in rows]))
        bag = float(np.mean([r["bag"][key] for r in rows]))
        out[key] = {"hdf5": h5, "bag": bag, "ratio": bag / h5}
    return out


@dataclass(frozen=True)
class RosbagConfig:
    """The seeds and the session/bag settings of :func:`run_seed` (the options of ``benchmarks/bench_rosbag.py``)."""

    seeds: tuple[int, ...] = (0, 1, 2)
    joint_rate: float = 200.0
    protocol: str = "paper-sim"
    noise: str = "realistic"
    ros: int = 2
    storage: str = "mcap"


@dataclass(frozen=True)
class RosbagJob:
    """One seed of a :class:`RosbagConfig`."""

    config: RosbagConfig
    seed: int


def run_rosbag_job(job: RosbagJob) -> dict[str, Any]:
    """:func:`run_seed` of one job in a folder of its own (removed afterwards)."""
    import tempfile

    c = job.config
    with tempfile.TemporaryDirectory() as tmp:
        return run_seed(job.seed, Path(tmp), joint_rate=c.joint_rate, protocol=c.protocol, noise=c.noise, ros=c.ros,
                        storage=c.storage)  # fmt: skip


class RosbagHarness:
    """The bag-vs-HDF5 benchmark as a :class:`~skincal.bench.harness.Harness`: one job per seed."""

    options = ROSBAG
    run_job = staticmethod(run_rosbag_job)

    def config(self, values: Mapping[str, Any]) -> RosbagConfig:
        """The configuration of the parsed options."""
        v = values
        return RosbagConfig(tuple(v["seeds"]), v["joint_rate"], v["protocol"], v["noise"], v["ros"], v["storage"])

    def jobs(self, config: RosbagConfig) -> list[RosbagJob]:
        """One job per seed, in order."""
        return [RosbagJob(config, seed) for seed in config.seeds]

    def summary(self, config: RosbagConfig, records: list[dict[str, Any]], run: RunInfo) -> dict[str, Any]:
        """``{"runs": per-seed records, "summary": :func:`summarise`}``."""
        return {"runs": records, "summary": summarise(records)}

    def report(self, config: RosbagConfig, doc: Mapping[str, Any], run: RunInfo) -> list[Any]:
        """The per-seed table and one verdict line per error kind (bag within 10 % of HDF5)."""
        from rich.table import Table

        c = config
        table = Table(
            title=f"bag (ROS {c.ros}{'' if c.ros == 1 else ' ' + c.storage}) vs HDF5, mle, "
            f"{c.protocol}, {c.noise} IMU, joints at {c.joint_rate:g} Hz"
        )
        for col in ("seed", "msgs", "segments true/found/rej.", "pos err h5 [mm]", "pos err bag [mm]", "rot h5 [deg]",
                    "rot bag [deg]", "links h5/bag", "write/read/seg/cal [s]"):  # fmt: skip
            table.add_column(col)
        for r in doc["runs"]:
            h, b, ts = r["hdf5"], r["bag"], r["time_s"]
            table.add_row(
                str(r["seed"]), str(r["messages"]), f"{r['segments_true']}/{r['segments_found']}/{r['rejected']}",
                f"{h['mean_position_error_mm']:.3f}", f"{b['mean_position_error_mm']:.3f}",
                f"{h['mean_rotation_error_deg']:.4f}", f"{b['mean_rotation_error_deg']:.4f}",
                f"{h['links_correct']}/{b['links_correct']} of {r['units_total']}",
                f"{ts['bag_write']:.1f}/{ts['bag_read']:.1f}/{ts['segment']:.2f}/{ts['bag_calibrate']:.1f}",
            )  # fmt: skip
        out: list[Any] = [table]
        for key, s in doc["summary"].items():
            h5, bag = s["hdf5"], s["bag"]
            verdict = "within 10 %" if bag <= 1.1 * h5 else "NOT within 10 %"
            out.append(f"{key}: HDF5 {h5:.4g}, bag {bag:.4g}, ratio {bag / h5:.3f} ({verdict})")
        return out


HARNESS = RosbagHarness()
