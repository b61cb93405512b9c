"""Speed of the calibrators and of the command (issue 26): ``skincal benchmark speed``.

One harness run (:class:`SpeedHarness`), four kinds of job, each on simulated data made inside the job:

* ``om-vs-mle``: one session (the paper's six units on the robot, ``realistic`` IMUs, ``controller`` joint
  states, the ``paper-sim`` protocol: 11 min of data) calibrated once by the paper's OM (links from the
  truth, as the paper does) and once by ``mle`` (links found from the data), one after the other in one
  process with one BLAS thread: their CPU seconds, the ratio ``om_cpu_s / mle_cpu_s`` of that same run, CPU
  seconds per unit, the errors of both against the truth; then the session written to HDF5 and
  ``skincal calibrate`` run on it as a user runs it (its wall time and CPU seconds, start-up included).
* ``scale``: ``units`` random units (100 on ``paper-sim``; 1000 on ``fast`` with ``--full``) calibrated by
  ``mle`` on ``workers`` processes. The job runs in a forked process of its own so that its peak memory is
  its own: ``peak_rss_mb`` the job's process (dataset and calibration), ``rss_after_simulation_mb`` the same
  before calibrating (what the dataset took), ``worker_peak_rss_mb`` the largest calibration worker (forked:
  pages shared with the parent count in both, so the figures do not add up).
* ``startup``: ``python -m skincal --help`` and a failing command (``calibrate`` of a missing file) run
  ``startup_runs`` times each in a fresh interpreter: median wall time and median CPU seconds.
* ``online``: the streaming calibrator fed ``stream_units`` units at 100 Hz with joint states at 1 kHz
  (:func:`skincal.bench.online.run_online_benchmark`): CPU seconds per second of data, per IMU sample
  (joint samples included in the cost), and the result's latency after the last sample on one core.

Times are CPU seconds (``resource.getrusage``: user + system of the process and of its ended children),
ratios taken within one job, so that the figures hold on a shared, noisy machine; wall times are given
beside them for reference only. All figures are of SIMULATED sessions.
"""

from __future__ import annotations

import dataclasses
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from skincal.bench.harness import RunInfo
from skincal.bench.options import SPEED
from skincal.errors import ConfigError

QUICK_POSES = 3
"""Poses of the shortened ``fast`` protocol of ``--quick`` (about 40 s of data)."""


@dataclass(frozen=True)
class SpeedConfig:
    """What :class:`SpeedHarness` measures.

    Attributes:
        robot: robot preset.
        seed: seed of every simulated session.
        units: units of the OM-vs-mle session (``paper`` placement when 6, else random).
        protocol: its protocol preset; ``poses`` shortens it (None: the preset's).
        scale: ``(units, protocol)`` of each many-unit figure.
        workers: worker processes of the many-unit figures.
        startup_runs: fresh interpreters per start-up figure (the median is reported).
        stream_units: units of the streaming figure; ``stream_protocol``/``poses`` its session.
        quick: the smoke run (``--quick``).
    """

    robot: str = "panda"
    seed: int = 0
    units: int = 6
    protocol: str = "paper-sim"
    poses: int | None = None
    scale: tuple[tuple[int, str], ...] = ((100, "paper-sim"),)
    workers: int = 2
    startup_runs: int = 7
    stream_units: int = 100
    stream_protocol: str = "fast"
    quick: bool = False


@dataclass(frozen=True)
class Job:
    """One measurement: ``kind`` (``om-vs-mle``, ``scale``, ``startup``, ``online``) with its session."""

    kind: str
    robot: str
    seed: int
    units: int = 0
    protocol: str = "fast"
    poses: int | None = None
    workers: int = 1
    runs: int = 0


def config_from_options(values: Mapping[str, Any]) -> SpeedConfig:
    """The config of the parsed :data:`~skincal.bench.options.SPEED` options."""
    quick, full = bool(values["quick"]), bool(values["full"])
    if quick and full:
        raise ConfigError("--quick and --full exclude each other")
    workers = int(values["workers"])
    if workers < 1:
        raise ConfigError(f"--workers must be at least 1, got {workers}")
    base = {"robot": values["robot"], "seed": int(values["seed"]), "workers": workers}
    if quick:
        return SpeedConfig(**base, units=2, protocol="fast", poses=QUICK_POSES, scale=((4, "fast"),),
                           startup_runs=2, stream_units=2, quick=True)  # fmt: skip
    scale = ((100, "paper-sim"), (1000, "fast")) if full else ((100, "paper-sim"),)
    return SpeedConfig(**base, scale=scale)


def jobs(config: SpeedConfig) -> list[Job]:
    """The jobs of ``config``: OM vs mle, each scale figure, start-up, streaming."""
    c = config
    out = [Job("om-vs-mle", c.robot, c.seed, c.units, c.protocol, c.poses)]
    poses = c.poses if c.quick else None
    out += [Job("scale", c.robot, c.seed, n, proto, poses, c.workers) for n, proto in c.scale]
    out.append(Job("startup", c.robot, c.seed, runs=c.startup_runs))
    out.append(Job("online", c.robot, c.seed, c.stream_units, c.stream_protocol, poses))
    return out


def cpu_s() -> float:
    """CPU seconds so far (user + system) of this process and of its children that have ended."""
    own, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime


def _rss_mb(who: int = resource.RUSAGE_SELF) -> float:
    """Peak resident set size of this process (or of its largest ended child), MB (Linux: ru_maxrss in kB)."""
    kb = resource.getrusage(who).ru_maxrss
    return round((kb / 1024.0 if sys.platform.startswith("linux") else kb / 2**20), 1)


def _session(job: Job):
    """The simulated dataset of ``job`` (analytic simulator, ``realistic`` IMUs, ``controller`` joints)."""
    from skincal.protocol.presets import get_protocol
    from skincal.sim import simulate
    from skincal.workflows.session import make_session

    protocol: Any = job.protocol
    if job.poses is not None:
        protocol = dataclasses.replace(get_protocol(job.protocol), n_poses=job.poses)
    placement = "paper" if job.units == 6 and job.kind == "om-vs-mle" else "random"
    units = None if placement == "paper" else job.units
    session = make_session(job.robot, placement, units, "realistic", protocol, job.seed, joints="controller")
    return simulate(session)


def _errors(result, ds) -> dict[str, Any]:
    from skincal.calib import evaluate

    ev = evaluate(result, ds)
    return {"mean_position_error_mm": ev.mean_position_error_mm, "mean_rotation_error_deg": ev.mean_rotation_error_deg,
            "links_correct": ev.links_correct, "units": len(result.units)}  # fmt: skip


def _om_vs_mle(job: Job) -> dict[str, Any]:
    from threadpoolctl import threadpool_limits

    from skincal.calib import calibrate
    from skincal.data.hdf5 import write_dataset

    ds = _session(job)
    with threadpool_limits(limits=1, user_api="blas"):
        c0, w0 = cpu_s(), time.perf_counter()
        om = calibrate(ds, "om", use_truth_links=True)
        c1, w1 = cpu_s(), time.perf_counter()
        mle = calibrate(ds, "mle", workers=1)
        c2, w2 = cpu_s(), time.perf_counter()
    om_cpu, mle_cpu = c1 - c0, c2 - c1
    record: dict[str, Any] = {
        "units": len(ds.units), "data_s": round(float(ds.duration), 1),
        "imu_samples_per_unit": int(max(len(s.t) for s in ds.imu.values())),
        "om_cpu_s": round(om_cpu, 4), "mle_cpu_s": round(mle_cpu, 4),
        "om_over_mle": round(om_cpu / mle_cpu, 2) if mle_cpu > 0 else None,
        "mle_cpu_s_per_unit": round(mle_cpu / max(len(ds.units), 1), 4),
        "om_wall_s": round(w1 - w0, 3), "mle_wall_s": round(w2 - w1, 3),
        "om": _errors(om, ds), "mle": _errors(mle, ds),
    }  # fmt: skip
    with tempfile.TemporaryDirectory(prefix="skincal-speed-") as tmp:
        data, out = Path(tmp) / "session.h5", Path(tmp) / "result.json"
        write_dataset(ds, data)
        run = _timed_cli(["calibrate", str(data), "-o", str(out)])
        if run["exit_code"] != 0:
            raise ConfigError(f"skincal calibrate of the simulated session failed (exit {run['exit_code']})")
        record["calibrate_command"] = run
    return record


def _scale(job: Job) -> dict[str, Any]:
    from skincal.calib import calibrate

    start_rss = _rss_mb()
    ds = _session(job)
    sim_rss = _rss_mb()
    c0, w0 = cpu_s(), time.perf_counter()
    result = calibrate(ds, "mle", workers=job.workers)
    cpu, wall = cpu_s() - c0, time.perf_counter() - w0
    return {
        "units": len(ds.units), "protocol": job.protocol, "data_s": round(float(ds.duration), 1),
        "workers": job.workers, "cpu_s": round(cpu, 3), "cpu_s_per_unit": round(cpu / max(len(ds.units), 1), 4),
        "wall_s": round(wall, 3), "calibrated": len(result.units), "failed": len(result.failed_units),
        "rss_at_start_mb": start_rss, "rss_after_simulation_mb": sim_rss, "peak_rss_mb": _rss_mb(),
        "worker_peak_rss_mb": _rss_mb(resource.RUSAGE_CHILDREN) if job.workers > 1 else None,
    }  # fmt: skip


def _isolated(fn: Any, job: Job) -> dict[str, Any]:
    """``fn(job)`` in a forked process of its own (its peak memory and children are its own); in this
    process where the platform cannot fork."""
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    from skincal.parallel import can_fork, worker_initializer

    if not can_fork():
        return fn(job)
    context = multiprocessing.get_context("fork")
    with ProcessPoolExecutor(max_workers=1, mp_context=context, initializer=worker_initializer) as pool:
        return pool.submit(fn, job).result()


def _timed_cli(argv: list[str], cwd: str | None = None) -> dict[str, Any]:
    """``python -m skincal *argv`` in a fresh interpreter (in ``cwd``): exit code, wall and CPU seconds."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    proc = subprocess.run([sys.executable, "-m", "skincal", *argv], capture_output=True, check=False, cwd=cwd,
                          env={**os.environ, "COLUMNS": "120"})  # fmt: skip
    wall = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return {"exit_code": proc.returncode, "wall_s": round(wall, 4), "cpu_s": round(cpu, 4)}


STARTUP_COMMANDS: tuple[tuple[str, tuple[str, ...], int], ...] = (
    ("help", ("--help",), 0),
    ("failing_calibrate", ("calibrate", "missing.h5", "-o", "result.json"), 2),
)
"""The start-up figures: name, arguments (run in an empty temporary folder), expected exit code."""


def _startup(job: Job) -> dict[str, Any]:
    out: dict[str, Any] = {"runs": job.runs}
    with tempfile.TemporaryDirectory(prefix="skincal-speed-") as tmp:
        for name, argv, expected in STARTUP_COMMANDS:
            runs = [_timed_cli(list(argv), cwd=tmp) for _ in range(job.runs)]
            codes = sorted({r["exit_code"] for r in runs})
            if codes != [expected]:
                raise ConfigError(f"skincal {' '.join(argv)} exited with {codes}, expected {expected}")
            out[name] = {"command": "skincal " + " ".join(argv), "exit_code": expected,
                         "median_wall_s": round(statistics.median(r["wall_s"] for r in runs), 4),
                         "median_cpu_s": round(statistics.median(r["cpu_s"] for r in runs), 4)}  # fmt: skip
    return out


def _online(job: Job) -> dict[str, Any]:
    from skincal.bench.online import bench_dataset, run_online_benchmark

    if job.poses is None:
        ds = bench_dataset(job.units, job.seed, job.robot, 1000.0, protocol=job.protocol)
    else:
        ds = _session(job)  # the quick run's short session (controller joints at their preset rate)
    doc = run_online_benchmark(job.units, job.seed, job.robot, dataset=ds)
    samples = max(doc["imu_samples"], 1)
    keep = ("units", "imu_rate_hz", "joint_rate_hz", "data_s", "imu_samples", "joint_samples", "cpu_s",
            "cpu_s_per_data_s", "latency_s", "max_backlog_s", "finish_cpu_s", "result_cpu_s")  # fmt: skip
    return {**{k: doc[k] for k in keep}, "cpu_us_per_imu_sample": round(1e6 * doc["cpu_s"] / samples, 2)}


def run_job(job: Job) -> dict[str, Any]:
    """One job's record: ``{"kind", ...figures}`` (module docstring)."""
    if job.kind == "om-vs-mle":
        figures = _om_vs_mle(job)
    elif job.kind == "scale":
        figures = _isolated(_scale, job)
    elif job.kind == "startup":
        figures = _startup(job)
    elif job.kind == "online":
        figures = _online(job)
    else:
        raise ConfigError(f"unknown speed job '{job.kind}'")
    return {"kind": job.kind, **figures}


def summary(config: SpeedConfig, records: list[dict[str, Any]], run: RunInfo) -> dict[str, Any]:
    """The ``--json`` document: ``{"simulated": true, "config", "om_vs_mle", "scale": [...], "startup",
    "online", "wall_time_s", "cpu_count"}``."""
    by_kind: dict[str, Any] = {"scale": []}
    for record in records:
        body = {k: v for k, v in record.items() if k != "kind"}
        if record["kind"] == "scale":
            by_kind["scale"].append(body)
        else:
            by_kind[record["kind"].replace("-", "_")] = body
    cfg = dataclasses.asdict(config)
    cfg["scale"] = [list(s) for s in config.scale]
    return {"simulated": True, "config": cfg, **by_kind, "wall_time_s": round(run.wall_time_s, 2),
            "cpu_count": os.cpu_count()}  # fmt: skip


def report(config: SpeedConfig, doc: Mapping[str, Any], run: RunInfo) -> list[str]:
    """The figures as lines of text (all simulated)."""
    om = doc["om_vs_mle"]
    cmd = om["calibrate_command"]
    proto = config.protocol + (f" shortened to {config.poses} poses" if config.poses else "")
    lines = [
        f"SIMULATED sessions on {config.robot} (realistic IMUs, controller joint states); CPU seconds, one run",
        f"{om['units']} units, {proto} ({om['data_s']:.0f} s of data), one process, one BLAS thread:",
        f"  OM {om['om_cpu_s']:.3f} CPU s, mle {om['mle_cpu_s']:.3f} CPU s: OM/mle {om['om_over_mle']:.1f}x; mle "
        f"{om['mle_cpu_s_per_unit']:.3f} CPU s per unit (errors: OM {om['om']['mean_position_error_mm']:.3f} mm, "
        f"mle {om['mle']['mean_position_error_mm']:.3f} mm)",
        f"  skincal calibrate (a fresh process, default workers): {cmd['wall_s']:.2f} s wall, {cmd['cpu_s']:.2f} CPU s",
    ]
    for s in doc["scale"]:
        worker = f", largest worker {s['worker_peak_rss_mb']:.0f} MB" if s["worker_peak_rss_mb"] is not None else ""
        lines.append(
            f"{s['units']} units, {s['protocol']} ({s['data_s']:.0f} s), {s['workers']} workers: "
            f"{s['cpu_s']:.2f} CPU s ({s['cpu_s_per_unit']:.3f} per unit), {s['wall_s']:.2f} s wall; "
            f"{s['calibrated']} calibrated; peak RSS {s['peak_rss_mb']:.0f} MB "
            f"({s['rss_after_simulation_mb']:.0f} MB after simulating){worker}"
        )
    st = doc["startup"]
    for name, _argv, _code in STARTUP_COMMANDS:
        f = st[name]
        lines.append(f"start-up: {f['command']}: median {f['median_wall_s']:.3f} s wall, {f['median_cpu_s']:.3f} CPU s "
                     f"(exit {f['exit_code']}, {st['runs']} runs)")  # fmt: skip
    on = doc["online"]
    lines.append(
        f"streaming: {on['units']} units at {on['imu_rate_hz']:g} Hz, joints at {on['joint_rate_hz']:g} Hz: "
        f"{on['cpu_s_per_data_s']:.3f} CPU s per s of data ({on['cpu_us_per_imu_sample']:.1f} us per IMU sample), "
        f"result {on['latency_s']:.3f} s after the last sample"
    )
    lines.append(f"{len(jobs(config))} jobs in {run.wall_time_s:.1f} s wall")
    return lines


class SpeedHarness:
    """The speed benchmark as a :class:`~skincal.bench.harness.Harness` (jobs run one after the other: see
    :func:`skincal.cli.benchmark.speed`)."""

    options = SPEED
    jobs = staticmethod(jobs)
    run_job = staticmethod(run_job)
    summary = staticmethod(summary)
    report = staticmethod(report)

    def config(self, values: Mapping[str, Any]) -> SpeedConfig:
        """:func:`config_from_options`."""
        return config_from_options(values)


HARNESS = SpeedHarness()
