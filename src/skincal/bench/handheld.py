"""Benchmark of the IMU-only unit-to-unit calibration (issue 18) on simulated hand-held sessions
(:func:`skincal.workflows.handheld.handheld_dataset`); ``benchmarks/bench_imu_only.py``. All figures SIMULATED."""

from __future__ import annotations

import time
from dataclasses import replace
from typing import Any

import numpy as np

from skincal.calib.imu_only import calibrate_relative
from skincal.skin.imu import get_imu_model
from skincal.workflows.handheld import handheld_dataset, relative_errors


def bench_relative(
    runs: int = 20,
    duration_s: float = 60.0,
    spacing: float = 0.2,
    imu: str = "real",
    clock: str = "driver",
    seed: int = 0,
    scale_free: bool = False,
    holds: int | None = None,
) -> dict[str, Any]:
    """The IMU-only calibration of two units ``spacing`` apart over ``runs`` simulated hand-held sessions:
    position and rotation errors (max, median), RMS of error / std per axis, run time. The reported
    std includes the reference accelerometer's scale and misalignment std of the IMU preset where its
    scale is not fitted from rests (``holds``: of the hand's motion, as :func:`handheld_dataset`)."""
    p_err, r_err, z_p, z_r, times, fitted = [], [], [], [], [], 0
    for k in range(runs):
        ds = handheld_dataset(2, spacing, duration_s, imu, clock, seed + k, scale_free=scale_free, holds=holds)
        start = time.perf_counter()
        model = (
            replace(get_imu_model(imu), accel_scale_std=0.0, misalignment_std=0.0) if scale_free else get_imu_model(imu)
        )
        result = calibrate_relative(
            ds, "su1", reference_scale_std=model.accel_scale_std, reference_misalignment_std=model.misalignment_std
        )
        times.append(time.perf_counter() - start)
        fitted += result.extras["accel_scale_fit"]["model"] != "none"
        for e in relative_errors(result, ds).values():
            p_err.append(float(np.linalg.norm(e["position_error_m"])))
            r_err.append(float(np.degrees(np.linalg.norm(e["rotation_error_rad"]))))
            z_p.append(e["position_error_m"] / e["position_std_m"])
            z_r.append(np.degrees(e["rotation_error_rad"]) / e["rotation_std_deg"])
    return {
        "runs": runs,
        "duration_s": duration_s,
        "imu": imu,
        "clock": clock,
        "scale_free": scale_free,
        "holds": "as fit" if holds is None else holds,
        "runs_with_scale_fitted": fitted,
        "position_error_mm_max": 1e3 * max(p_err),
        "position_error_mm_median": 1e3 * float(np.median(p_err)),
        "rotation_error_deg_max": max(r_err),
        "rotation_error_deg_median": float(np.median(r_err)),
        "position_error_over_std_rms": float(np.sqrt(np.mean(np.square(z_p)))),
        "rotation_error_over_std_rms": float(np.sqrt(np.mean(np.square(z_r)))),
        "runtime_s_median": float(np.median(times)),
    }
