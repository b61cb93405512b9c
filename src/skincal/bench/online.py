"""Update cost of the streaming calibrator (issue 16's target: 100 units at 100 Hz with joint states at
1 kHz followed in real time on one core, the result ready <= 0.5 s after the last sample).

The data: a session from :func:`skincal.workflows.session.make_session` (the one factory; random
placement of ``units`` units, ``realistic`` IMUs at 100 Hz, the ``fast`` protocol) whose joint stream
is the ``controller`` preset at ``joint_rate_hz`` (1 kHz here, 500 Hz in the preset), simulated
analytically. It is fed to :class:`skincal.calib.online.OnlineCalibrator` by
:func:`skincal.calib.online.replay` in arrival order, ``chunk_s`` of data at a time, as fast as
possible; each chunk's CPU time (``time.process_time``: every thread of the process) is measured.

Figures:

* ``cpu_s_per_data_s``: CPU seconds spent per second of data (stream, ``update`` and ``finish``);
  below 1 means the stream is followed in real time on one core.
* ``latency_s``: the delay from the last sample's arrival to the result in hand, on one core
  following the stream in real time: each chunk is processed when it has arrived and the previous
  one is done (its measured CPU time), then ``finish`` and ``result``; ``max_backlog_s`` is the
  largest delay of a chunk's end over its arrival on the way.
* ``status_cpu_s``: the CPU time of one ``status()`` of every unit (what the live meter and its stop
  test ask for every :data:`skincal.workflows.live.STATUS_EVERY_S` of data), mean over the calls;
  it is not part of ``cpu_s`` (``status_cpu_s_per_data_s`` is its share at that rate).
* ``real_time`` (``real_time=True`` only): the same stream replayed at real speed (``speed=1``): the
  measured wall delay from the last sample's arrival to the result, and the CPU seconds per second of
  data (wall time includes whatever else the machine runs; ``latency_s`` above does not).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import replace
from typing import Any

import numpy as np

Progress = Callable[[str], None]
"""``progress(message)``: the step now running."""


def bench_dataset(units: int = 100, seed: int = 0, robot: str = "panda", joint_rate_hz: float = 1000.0,
                  noise: str = "realistic", protocol: str = "fast"):  # fmt: skip
    """The benchmark's simulated dataset (module docstring)."""
    from skincal.sim import simulate
    from skincal.sim.joint_states import get_joint_model
    from skincal.workflows.session import make_session

    session = make_session(robot, "random", units, noise, protocol, seed, joints="controller")
    session = replace(session, joint_model=replace(get_joint_model("controller"), rate_hz=float(joint_rate_hz)))
    return simulate(session, "analytic")


def _schedule(arrivals: np.ndarray, costs: np.ndarray) -> tuple[np.ndarray, float]:
    """One core following the stream: chunk ``k`` starts at ``max(arrival_k, end_{k-1})`` and takes
    ``costs[k]``; returns each chunk's end and the largest backlog (end minus arrival), s."""
    ends = np.empty_like(costs)
    end = -np.inf
    for k, (a, c) in enumerate(zip(arrivals, costs, strict=True)):
        end = max(a, end) + c
        ends[k] = end
    return ends, float(np.max(ends - arrivals)) if len(ends) else 0.0


def run_online_benchmark(
    units: int = 100,
    seed: int = 0,
    robot: str = "panda",
    joint_rate_hz: float = 1000.0,
    chunk_s: float = 0.1,
    real_time: bool = False,
    progress: Progress | None = None,
    dataset: Any = None,
) -> dict[str, Any]:
    """Measure the update cost (module docstring); ``dataset`` replaces the simulated one (tests)."""
    from skincal.calib.online import OnlineCalibrator, replay
    from skincal.workflows.live import STATUS_EVERY_S

    note = progress or (lambda _m: None)
    note(f"simulating {units} units (fast protocol, joint states at {joint_rate_hz:g} Hz)")
    wall = time.perf_counter()
    ds = dataset if dataset is not None else bench_dataset(units, seed, robot, joint_rate_hz)
    sim_s = time.perf_counter() - wall
    chain, joints = ds.require_joints("the online benchmark")
    t0 = min(float(joints.t[0]), *(float(s.t[0]) for s in ds.imu.values()))
    t1 = max(float(joints.t[-1]), *(float(s.t[-1]) for s in ds.imu.values()))
    imu_rate = float(np.median([(len(s.t) - 1) / (s.t[-1] - s.t[0]) for s in ds.imu.values()]))
    joint_rate = float((len(joints.t) - 1) / (joints.t[-1] - joints.t[0]))

    note(f"following {t1 - t0:.1f} s of data as fast as possible")
    cal = OnlineCalibrator(chain, ds.units, gravity=ds.gravity)
    marks: list[tuple[float, float]] = []  # (data time of the chunk's end, process time when done)
    status_cpu: list[float] = []

    asked = [-np.inf, 0]  # last data time asked, calls

    def on_chunk(t: float) -> None:
        now = time.process_time()
        marks.append((float(t), now))
        if t - asked[0] >= STATUS_EVERY_S - 1e-9:  # as the meter asks
            asked[0], asked[1] = t, asked[1] + 1
            cal.status()
        status_cpu.append(time.process_time() - now)

    cpu_start = time.process_time()
    wall = time.perf_counter()
    replay(ds, cal, chunk_s=chunk_s, speed=None, on_chunk=on_chunk)
    cpu_replayed = time.process_time()
    result = cal.result()
    cpu_end = time.process_time()
    wall_s = time.perf_counter() - wall
    status_total = float(np.sum(status_cpu))
    status_calls = int(asked[1])
    times = np.array([m[0] for m in marks]) - t0
    done = np.array([m[1] for m in marks])
    starts = np.r_[cpu_start, done[:-1] + np.asarray(status_cpu[:-1])]  # a chunk's cost excludes the meter's
    costs = done - starts
    finish_cpu = cpu_replayed - (done[-1] + status_cpu[-1]) if len(done) else cpu_replayed - cpu_start
    result_cpu = cpu_end - cpu_replayed
    ends, backlog = _schedule(times, costs)
    last_arrival = t1 - t0
    ready = max(float(ends[-1]) if len(ends) else 0.0, last_arrival) + finish_cpu + result_cpu
    stream_cpu = float(costs.sum()) + finish_cpu
    doc: dict[str, Any] = {
        "robot": chain.name,
        "units": len(ds.units),
        "imu_rate_hz": round(imu_rate, 2),
        "joint_rate_hz": round(joint_rate, 1),
        "data_s": round(last_arrival, 3),
        "imu_samples": int(sum(len(s.t) for s in ds.imu.values())),
        "joint_samples": int(len(joints.t)),
        "chunk_s": chunk_s,
        "simulation_s": round(sim_s, 2),
        "cpu_s": round(stream_cpu, 3),
        "cpu_s_per_data_s": round(stream_cpu / last_arrival, 4),
        "finish_cpu_s": round(finish_cpu, 4),
        "result_cpu_s": round(result_cpu, 4),
        "latency_s": round(ready - last_arrival, 4),
        "max_backlog_s": round(backlog, 4),
        "max_chunk_cpu_s": round(float(costs.max()), 4) if len(costs) else 0.0,
        "max_chunk_at_s": round(float(times[int(np.argmax(costs))]), 2) if len(costs) else 0.0,
        "status_cpu_s": round(status_total / max(status_calls, 1), 5),
        "status_every_s": STATUS_EVERY_S,
        "status_cpu_s_per_data_s": round(status_total / last_arrival, 4),
        "wall_s": round(wall_s, 2),
        "units_reached": sum(1 for s in cal.status().values() if s.reached),
        "units_in_result": len(result.units),
    }
    if real_time:
        note(f"following {t1 - t0:.1f} s of data at real speed")
        cal = OnlineCalibrator(chain, ds.units, gravity=ds.gravity)
        cpu = time.process_time()
        wall = time.perf_counter()  # the replay paces itself from here: data time t arrives at wall + t - t_first
        replay(ds, cal, chunk_s=chunk_s, speed=1.0)
        cal.result()
        ready_wall = time.perf_counter()
        arrival_last = wall + (t1 - float(joints.t[0]))  # the replay's clock starts at the first joint sample
        doc["real_time"] = {
            "latency_s": round(ready_wall - arrival_last, 4),
            "cpu_s_per_data_s": round((time.process_time() - cpu) / (t1 - t0), 4),
        }
    return doc


def online_report(doc: dict[str, Any]) -> list[str]:
    """The figures as lines of text."""
    lines = [
        f"{doc['units']} units at {doc['imu_rate_hz']:g} Hz, joint states at {doc['joint_rate_hz']:g} Hz on "
        f"{doc['robot']}: {doc['data_s']:.1f} s of data ({doc['imu_samples']} IMU + {doc['joint_samples']} joint "
        f"samples), chunks of {doc['chunk_s']:g} s",
        f"CPU {doc['cpu_s']:.2f} s for {doc['data_s']:.1f} s of data: {doc['cpu_s_per_data_s']:.3f} CPU s per s of "
        f"data (finish {doc['finish_cpu_s']:.3f} s, result {doc['result_cpu_s']:.3f} s)",
        f"result ready {doc['latency_s']:.3f} s after the last sample on one core following in real time "
        f"(largest backlog on the way {doc['max_backlog_s']:.3f} s; costliest chunk {doc['max_chunk_cpu_s']:.3f} s "
        f"CPU at {doc['max_chunk_at_s']:.1f} s of data)",
        f"meter: status() of every unit {1e3 * doc['status_cpu_s']:.2f} ms CPU "
        f"({doc['status_cpu_s_per_data_s']:.3f} CPU s per s of data at one call every {doc['status_every_s']:g} s)",
        f"units at the default target at the end: {doc['units_reached']}/{doc['units']}",
    ]
    if "real_time" in doc:
        rt = doc["real_time"]
        lines.append(f"replayed at real speed: result {rt['latency_s']:.3f} s (wall) after the last sample; "
                     f"{rt['cpu_s_per_data_s']:.3f} CPU s per s of data")  # fmt: skip
    return lines


def stream_vs_batch(
    seeds: tuple[int, ...] = (0, 1, 2), robot: str = "panda", work_s: float = 120.0, progress: Progress | None = None
) -> dict[str, Any]:
    """Accuracy of the streaming calibrator against the batch ``mle`` on the same simulated data (issue 16:
    the final online estimate within 10 % of the batch error): per case (the ``fast`` protocol and a
    ``work_s`` s pick-and-place work cycle, ``realistic`` IMUs and controller joint states, six paper
    units, each seed), the mean position (mm) and rotation (deg) errors of both, the links right, and
    the RMS over units and axes of error / reported std (1 is honest)."""
    from skincal.calib import calibrate
    from skincal.calib.online import OnlineCalibrator, replay
    from skincal.kinematics.transforms import rotation_angle
    from skincal.workflows.monitoring import simulate_session, work_session
    from skincal.workflows.session import simulate_dataset

    def errors(result, ds) -> dict[str, float]:
        pos, rot, z, links = [], [], [], 0
        for u, truth in ds.truth.items():
            r = result.units.get(u)
            if r is None or r.pose.link != truth.link:
                continue
            links += 1
            dp = r.pose.p_link_su - truth.p_link_su
            pos.append(1e3 * float(np.linalg.norm(dp)))
            rot.append(float(np.degrees(rotation_angle(r.pose.R_link_su, truth.R_link_su))))
            if r.position_std_m is not None:
                z.extend((dp / np.asarray(r.position_std_m)).tolist())
        return {
            "position_mm": float(np.mean(pos)) if pos else float("nan"),
            "rotation_deg": float(np.mean(rot)) if rot else float("nan"),
            "links": links,
            "units": len(ds.truth),
            "rms_error_over_std": float(np.sqrt(np.mean(np.square(z)))) if z else float("nan"),
        }

    cases: list[dict[str, Any]] = []
    for seed in seeds:
        for kind in ("fast", "pick-place"):
            if progress is not None:
                progress(f"{kind}, seed {seed}")
            if kind == "fast":
                ds = simulate_dataset(robot, "paper", noise="realistic", protocol="fast", seed=seed)
            else:
                ds = simulate_session(work_session(robot, "realistic", "pick-place", work_s, seed=seed), seed)
            cal = OnlineCalibrator(ds.robot, list(ds.imu), ds.gravity)
            replay(ds, cal)
            cases.append({"case": kind, "seed": seed, "online": errors(cal.result(), ds),
                          "mle": errors(calibrate(ds, "mle"), ds)})  # fmt: skip
    return {"robot": robot, "cases": cases}


def stream_vs_batch_report(doc: dict[str, Any]) -> list[str]:
    """Lines of :func:`stream_vs_batch`'s figures, and the per-case means."""
    lines = [f"streaming vs batch mle on {doc['robot']} (simulated; realistic IMUs, controller joint states)"]
    for c in doc["cases"]:
        o, m = c["online"], c["mle"]
        lines.append(
            f"  {c['case']:10s} seed {c['seed']}: online {o['position_mm']:.3f} mm / {o['rotation_deg']:.4f} deg "
            f"(links {o['links']}/{o['units']}, err/std {o['rms_error_over_std']:.2f}); "
            f"mle {m['position_mm']:.3f} mm / {m['rotation_deg']:.4f} deg "
            f"(links {m['links']}/{m['units']}, err/std {m['rms_error_over_std']:.2f})"
        )
    for kind in sorted({c["case"] for c in doc["cases"]}):
        sel = [c for c in doc["cases"] if c["case"] == kind]
        op = np.mean([c["online"]["position_mm"] for c in sel])
        mp = np.mean([c["mle"]["position_mm"] for c in sel])
        orr = np.mean([c["online"]["rotation_deg"] for c in sel])
        mr = np.mean([c["mle"]["rotation_deg"] for c in sel])
        lines.append(f"  {kind}: mean online/mle position {op / mp:.2f}x ({op:.3f} / {mp:.3f} mm), "
                     f"rotation {orr / mr:.2f}x ({orr:.4f} / {mr:.4f} deg)")  # fmt: skip
    return lines
