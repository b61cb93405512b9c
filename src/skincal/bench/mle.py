"""The default calibrator's targets, measured (``skincal benchmark mle``).

* accuracy, noise-free: the paper's protocol and configuration;
* accuracy under the ``realistic`` sensor preset with ``controller`` joint states (encoder steps,
  velocity noise, stamp jitter, no accelerations): random placements on the Panda, the Sawyer and
  the UR5e, links found from the data, the mean reported position std beside the error (the
  Cramer-Rao bound of the data, as the calibrator computes it from the information at its
  solution) and the calibration of the reported std (RMS of error / std per axis);
* the ``real`` IMU preset (figures of a real recording) with ``wifi-resync`` clocks (offsets up to
  0.5 s, drift and periodic re-sync steps): errors, and time offset and drift recovered;
* the ``fast`` protocol under ``realistic`` sensors;
* run time for 6 and 100 units (one worker, and two workers as ``skincal calibrate`` uses: forked processes on Linux);
* OM (the paper's method) against ``mle`` on the same data, wall-time ratio and errors.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np

from skincal.calib import calibrate, evaluate
from skincal.errors import ConfigError
from skincal.sim import simulate
from skincal.workflows.session import make_session


def simulate_session(
    robot: str,
    placement: str,
    n_units: int,
    noise: str,
    protocol: str,
    seed: int,
    joints: str = "ideal",
    clock: str = "ideal",
):
    """A simulated session (analytic simulator) with the given IMU, joint-state and clock presets."""
    units = None if placement == "paper" else n_units
    return simulate(make_session(robot, placement, units, noise, protocol, seed, joints=joints, clock=clock))


def _summary(ds, result) -> dict[str, Any]:
    ev = evaluate(result, ds)
    z, std, dtau, ddrift = [], [], [], []
    for name, unit in result.units.items():
        if unit.observable and unit.position_std_m is not None:
            z.extend((unit.pose.p_link_su - ds.truth[name].p_link_su) / unit.position_std_m)
            std.append(float(np.linalg.norm(unit.position_std_m)))
        truth = ds.truth_sensor.get(name, {})
        imu = unit.imu
        if imu is not None and imu.time_offset_s is not None and "time_offset_s" in truth:
            dtau.append(abs(imu.time_offset_s - truth["time_offset_s"]))
        if imu is not None and imu.clock_drift_ppm is not None and "clock_drift_ppm" in truth:
            ddrift.append(abs(imu.clock_drift_ppm - truth["clock_drift_ppm"]))
    z = [v for v in z if np.isfinite(v)]
    return {
        "mean_position_error_mm": ev.mean_position_error_mm,
        "max_position_error_mm": max(u.position_error_mm for u in ev.units.values()),
        "mean_rotation_error_deg": ev.mean_rotation_error_deg,
        "mean_position_std_mm": 1e3 * float(np.mean(std)) if std else None,
        "max_time_offset_error_ms": 1e3 * max(dtau) if dtau else None,
        "max_clock_drift_error_ppm": max(ddrift) if ddrift else None,
        "links_correct": ev.links_correct,
        "units_total": ev.units_total,
        "units_warned": sum(1 for u in result.units.values() if u.warnings),
        "runtime_s": result.runtime_s,
        "z_rms": float(np.sqrt(np.mean(np.square(z)))) if z else None,
    }


QUICK_RUNS = 1
"""Random placements per robot of ``--quick`` (a smoke test of every part on every robot; 20 otherwise)."""
EXTRA_DRAWS = 5
"""Placements drawn beyond those asked for, per robot and part, when a placement's session cannot be made
(no collision-free protocol for that draw): the benchmark takes the next seed instead of failing."""


def _placements(
    robot: str, count: int, first_seed: int, make: Callable[[int], Any], skipped: list[str]
) -> Iterator[Any]:
    """``count`` sessions of ``robot``, made one at a time from seeds ``first_seed, first_seed + 1, ...``;
    a seed whose session cannot be made (a :class:`~skincal.errors.SkincalError`: no protocol found for
    that draw) is noted in ``skipped`` and the next one drawn, at most :data:`EXTRA_DRAWS` more (fewer
    sessions then, never a failure of the whole benchmark)."""
    from skincal.errors import SkincalError

    made = 0
    for seed in range(first_seed, first_seed + count + EXTRA_DRAWS):
        if made == count:
            return
        try:
            session = make(seed)
        except SkincalError as exc:
            skipped.append(f"{robot} seed {seed}: {exc}")
            continue
        made += 1
        yield session


def run_mle_benchmark(
    runs: int | None = None, quick: bool = False, with_om: bool = True, progress: Callable[[str], None] | None = None
) -> dict[str, Any]:
    """All targets of the default calibrator (module docstring). ``quick`` shrinks every part (the fast
    protocol, :data:`QUICK_RUNS` placement per robot, the run time of 6 units only, no separate
    fast-protocol part: under ``quick`` every part runs the fast protocol); ``runs``: random placements
    per robot (default 20, :data:`QUICK_RUNS` with ``quick``). A placement whose session cannot be made is
    listed in ``skipped`` and replaced by the next seed (:func:`_placements`)."""
    if runs is None:
        runs = QUICK_RUNS if quick else 20
    if runs < 1:
        raise ConfigError(f"--placements must be at least 1, got {runs}")
    note = progress or (lambda _msg: None)
    skipped: list[str] = []
    out: dict[str, Any] = {"runs": runs, "quick": quick, "skipped": skipped}
    protocol = "fast" if quick else "paper-sim"
    note("noise-free, paper configuration")
    paper = simulate_session("panda", "paper", 6, "none", protocol, seed=0)
    t0 = time.perf_counter()
    paper_mle = calibrate(paper, "mle")
    t_mle = time.perf_counter() - t0
    out["noise_free_paper"] = _summary(paper, paper_mle)
    for robot in ("panda", "sawyer", "ur5e"):

        def realistic(seed: int, r: str = robot):
            return simulate_session(r, "random", 6, "realistic", protocol, seed=seed, joints="controller")

        def real(seed: int, r: str = robot):
            return simulate_session(r, "random", 6, "real", protocol, seed=seed, joints="controller",
                                    clock="wifi-resync")  # fmt: skip

        rows = []
        for k, ds in enumerate(_placements(robot, runs, 100, realistic, skipped)):
            note(f"realistic IMUs, controller joints, {robot}, placement {k + 1}/{runs}")
            rows.append(_summary(ds, calibrate(ds, "mle", workers=2)))
        out[f"realistic_{robot}"] = _aggregate(rows)
        rows = []
        n_real = max(1, runs // 4)
        for k, ds in enumerate(_placements(robot, n_real, 400, real, skipped)):
            note(f"real IMUs, controller joints, wifi-resync clocks, {robot}, placement {k + 1}/{n_real}")
            rows.append(_summary(ds, calibrate(ds, "mle", workers=2)))
        out[f"real_clock_{robot}"] = _aggregate(rows)
    if not quick:  # under quick, realistic_panda is this part already (fast protocol, realistic, controller)
        rows = []

        def fast(seed: int):
            return simulate_session("panda", "random", 6, "realistic", "fast", seed=seed, joints="controller")

        for k, ds in enumerate(_placements("panda", runs, 200, fast, skipped)):
            note(f"fast protocol, realistic, panda {k + 1}/{runs}")
            rows.append(_summary(ds, calibrate(ds, "mle")))
            out["fast_protocol_duration_s"] = float(ds.duration)
        out["fast_protocol_panda"] = _aggregate(rows)
    for n_units in (6, 100) if not quick else (6,):  # quick: the 100-unit timing alone took minutes
        for proto in ("paper-sim", "fast") if not quick else ("fast",):
            note(f"run time, {n_units} units, {proto}")
            ds = simulate_session("panda", "random", n_units, "realistic", proto, seed=300, joints="controller")
            start = time.perf_counter()
            result = calibrate(ds, "mle")
            out[f"runtime_{n_units}_units_{proto}_s"] = time.perf_counter() - start
            start = time.perf_counter()
            calibrate(ds, "mle", workers=2)
            out[f"runtime_{n_units}_units_{proto}_2_workers_s"] = time.perf_counter() - start
            out[f"runtime_{n_units}_units_{proto}_summary"] = _summary(ds, result)
    if with_om:
        note("OM vs mle on the same data")  # mle's run is the noise-free paper one above
        t0 = time.perf_counter()
        om = calibrate(paper, "om", use_truth_links=True)
        t_om = time.perf_counter() - t0
        out["om_vs_mle"] = {
            "om_s": t_om,
            "mle_s": t_mle,
            "ratio": t_om / t_mle,
            "om": _summary(paper, om),
            "mle": out["noise_free_paper"],
        }
    return out


def _aggregate(rows: list[dict[str, Any]]) -> dict[str, Any]:
    keys = (
        "mean_position_error_mm",
        "max_position_error_mm",
        "mean_rotation_error_deg",
        "mean_position_std_mm",
        "runtime_s",
        "z_rms",
    )
    agg: dict[str, Any] = {
        k: float(np.mean(vals)) if (vals := [r[k] for r in rows if r[k] is not None]) else None for k in keys
    }
    for k in ("max_time_offset_error_ms", "max_clock_drift_error_ppm"):
        vals = [r[k] for r in rows if r[k] is not None]
        agg[k] = float(max(vals)) if vals else None
    agg["units_warned"] = int(sum(r["units_warned"] for r in rows))
    agg["worst_mean_position_error_mm"] = float(max(r["mean_position_error_mm"] for r in rows)) if rows else None
    agg["links_correct"] = int(sum(r["links_correct"] for r in rows))
    agg["units_total"] = int(sum(r["units_total"] for r in rows))
    agg["runs"] = len(rows)
    return agg
