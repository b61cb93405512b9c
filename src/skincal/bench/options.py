"""The command-line options of every benchmark, declared once (:class:`~skincal.bench.harness.Opt`).

Each tuple serves both ``skincal benchmark ...`` (typer, :func:`~skincal.bench.harness.typer_command`) and the
script in ``benchmarks/`` (argparse, :func:`~skincal.bench.harness.parse_args`). Plain data, no NumPy: the
``skincal`` command imports this module at start-up and a benchmark's module only when it runs.
"""

from __future__ import annotations

from pathlib import Path

from skincal.bench.harness import DASK, WORKERS, Opt

ISO_ROBOTS = ("panda", "ur5e", "iiwa14")
"""The robots of the issue-17 avoidance matrix (:func:`skincal.bench.avoid.run_iso_benchmark`)."""


TABLE1 = (
    Opt("quick", bool, False, "tiny run for tests: 1 set x 1 run, 2 units, short protocol"),
    Opt("runs", int | None, None, "optimiser runs per set (default 10; quick 1)"),
    Opt("sets", int | None, None, "random placement sets (default 4; quick 1)"),
    Opt("methods", str, "om,mmm,mm", "comma-separated methods, e.g. om,om-joint,mmm,mm"),
    WORKERS,
    DASK,
    Opt("seed", int, 0, "base seed of the placement sets"),
    Opt("json_out", Path | None, None, "write the records and summary here", flag="--json"),
)
"""The options of ``skincal benchmark table1`` and ``benchmarks/table1.py``."""


ROBUSTNESS = (
    Opt("robots", str | None, None, "comma-separated robots (default panda,sawyer,ur5e)"),
    Opt("backends", str | None, None,
        "comma-separated backends: analytic, mujoco (kinematic), mujoco-dynamic (default analytic,mujoco)"),
    Opt("faults", str | None, None, "comma-separated faults (default all of them; see --list)"),
    Opt("placements", int | None, None, "random placements of 6 units per cell (default 5; quick 1)",
        aliases=("--seeds",)),
    Opt("quick", bool, False, "1 placement and the short fast protocol"),
    Opt("protocol", str | None, None, "protocol preset (default paper-sim; quick fast)"),
    Opt("seed", int, 0, "first placement seed"),
    WORKERS,
    DASK,
    Opt("out", Path | None, None, "write every cell and job record here (JSON)", aliases=("--json",)),
    Opt("force", bool, False, "overwrite --out if it exists"),
    Opt("list_faults", bool, False, "list the faults and exit", flag="--list", switch=False),
)  # fmt: skip
"""The options of ``skincal benchmark robustness`` and ``benchmarks/robustness.py``."""


MLE = (
    Opt("placements", int | None, None, "random placements per robot (default 20; 1 with --quick)",
        aliases=("--runs",)),
    Opt("quick", bool, False, "fast protocol and 1 placement per robot, for a smoke test"),
    Opt("om", bool, True, "also time the paper's OM on the same data"),
    Opt("json_out", Path | None, None, "also write the figures as JSON", flag="--json"),
)
"""The options of ``skincal benchmark mle`` and ``benchmarks/bench_mle.py``."""


CORE = (
    Opt("robot", str, "panda", "robot preset"),
    Opt("json_out", Path | None, None, "also write the figures as JSON", flag="--json"),
)
"""The options of ``skincal benchmark core`` and ``benchmarks/bench_core.py``."""


QP = (
    Opt("points", int, 100),
    Opt("repeats", int, 2000),
    Opt("json", str | None, None, "also write the figures here"),
    Opt("force", bool, False, "overwrite an existing --json file", switch=False),
)
"""The options of ``benchmarks/bench_qp.py``."""


ONLINE = (
    Opt("units", int, 100, "skin units (random placement)"),
    Opt("robot", str, "panda", "robot preset"),
    Opt("joint_rate", float, 1000.0, "joint-state rate, Hz"),
    Opt("seed", int, 0, "session seed"),
    Opt("real_time", bool, False, "also replay at real speed and measure the delay", switch=False),
    Opt("json", Path | None, None, "also write the figures as JSON"),
    Opt("accuracy", bool, False, "instead: the stream's errors against the batch mle's on the same data (fast "
        "protocol and a pick-and-place work cycle, 6 units, seeds 0-2)", switch=False),
)
"""The options of ``benchmarks/bench_online.py``."""


ADAPTIVE = (
    Opt("robots", str, ["panda", "sawyer", "ur5e"], many=True),
    Opt("seeds", int, [0], many=True),
    Opt("noise", str, "realistic"),
    Opt("target", str, "0.3mm,0.05deg"),
    Opt("max_motion", float, 180.0, "motion budget of the adaptive loop, s"),
    Opt("std_factor", float, 1.0, "the adaptive loop runs to this times the target std (true errors: the target)"),
    Opt("json", Path | None, None, "write the numbers here"),
)
"""The options of ``benchmarks/bench_adaptive.py``."""


ROSBAG = (
    Opt("seeds", int, [0, 1, 2], many=True),
    Opt("joint_rate", float, 200.0, "joint state rate, Hz"),
    Opt("protocol", str, "paper-sim"),
    Opt("noise", str, "realistic"),
    Opt("ros", int, 2, choices=(1, 2)),
    Opt("storage", str, "mcap", choices=("sqlite3", "mcap")),
    Opt("json", Path | None, None, "write the numbers here"),
)
"""The options of ``benchmarks/bench_rosbag.py``."""


AVOID = (
    Opt("scenarios", str, "arm,hand,walk,fast"),
    Opt("placement", str, "ring", "the simulated skin", choices=("ring", "paper")),
    Opt("seeds", int, [0], "sensor-noise seeds, e.g. --seeds 0 1 (each run once)", many=True),
    Opt("quick", bool, False, "fast calibration protocol for the mle poses", switch=False),
    Opt("json", str | None, None),
    Opt("plots", str | None, None, "folder for docs/avoid_<scenario>.png (mle poses, first seed)"),
    Opt("iso", bool, False, "the issue-17 matrix (ISO/TS 15066 separation, any robot)", switch=False),
    Opt("robots", str, ",".join(ISO_ROBOTS)),
    Opt("modes", str, "kinematic,torque"),
    Opt("beliefs", str, "mle,degraded", "mle, degraded, truth, blind"),
    Opt("duration", float | None, None, "shorten every run to this, s"),
)
"""The options of ``benchmarks/bench_avoid.py``."""


HANDHELD = (
    Opt("runs", int, 20),
    Opt("duration", float, 60.0),
    Opt("spacing", float, 0.2),
    Opt("imu", str, "real"),
    Opt("clock", str, "driver"),
    Opt("scale_free", bool, False, "accelerometers without scale/misalignment errors", switch=False),
    Opt("holds", int | None, None, "still holds in the motion (default: 12, as fit)"),
    Opt("json", str | None, None),
)
"""The options of ``benchmarks/bench_imu_only.py``."""


MONITOR = (
    Opt("hours", float, 1.0, "simulated hours of normal work per IMU preset"),
    Opt("imu", str, None, "IMU preset (repeat; default realistic and real)", repeat=True),
    Opt("kind", str, "teleop", "work cycle: teleop or pick-place"),
    Opt("robot", str, "panda"),
    Opt("seed", int, 0),
    Opt("online_unit", str, None, "unit also knocked with the streaming calibrator (repeat; default su4)", repeat=True),
    Opt("json", Path | None, None, "also write the figures as JSON"),
)
"""The options of ``benchmarks/bench_monitor.py``."""


SPEED = (
    Opt("quick", bool, False, "a smoke run in seconds: 2 units on a 3-pose fast protocol, 4 units for the scale "
        "figure, 2 streamed units, 2 start-ups"),
    Opt("full", bool, False, "also the 1000-unit figure (fast protocol)"),
    Opt("robot", str, "panda", "robot preset"),
    Opt("seed", int, 0, "seed of the simulated sessions"),
    Opt("workers", int, 2, "worker processes of the 100- and 1000-unit figures"),
    Opt("json_out", Path | None, None, "also write the figures as JSON", flag="--json"),
)
"""The options of ``skincal benchmark speed`` and ``benchmarks/bench_speed.py``."""


REALDATA = (
    Opt("folder", Path, None, "folder of recordings sharing a mount (folders with recording.h5, or .h5 files)",
        positional=True),
    Opt("om", bool, True, "also run the paper's OM (a recording it cannot take is a failure)"),
    Opt("online", bool, True, "also run the streaming calibrator (calibrate --follow) to each recording's end"),
    Opt("workers", int, 1, "units calibrated at once per recording"),
    Opt("json_out", Path | None, None, "also write the figures as JSON", flag="--json"),
)
"""The options of ``skincal benchmark realdata`` and ``benchmarks/bench_realdata.py``."""


STREAMING_CLOCK = (
    Opt("robots", str, "panda,ur5e", "comma-separated robot presets"),
    Opt("protocols", str, "fast,paper-sim", "comma-separated protocols (fast, paper-sim); fast runs first"),
    Opt("clocks", str, "wifi,wifi-resync", "comma-separated clock presets"),
    Opt("seeds", int, [0, 1, 2], "session seeds", many=True),
    Opt("noise", str, "realistic", "IMU preset"),
    Opt("quick", bool, False, "the fast protocol and the first seed only", switch=False),
    WORKERS,
    Opt("json", Path | None, None, "also write the cells and the summary here (JSON)"),
    Opt("force", bool, False, "overwrite an existing --json file", switch=False),
)
"""The options of ``benchmarks/bench_streaming_clock.py``."""
