"""Synthetic IMU streams shared by the rest-detection tests."""

from __future__ import annotations

import numpy as np


def rest_runs_stream(seed: int = 0, rate: float = 100.0):
    """An accelerometer at 100 Hz: six rest runs of 1.5 s (each at its own gravity direction, white
    noise 0.03 m/s^2) separated by 0.5 s of motion (large, varying readings)."""
    rng = np.random.default_rng(seed)
    run_s, move_s, n_runs = 1.5, 0.5, 6
    t = np.arange(int(round(n_runs * (run_s + move_s) * rate))) / rate
    rest_mask = np.zeros(t.size, dtype=bool)
    accel = np.empty((t.size, 3))
    bounds = []
    for k in range(n_runs):
        a, b = np.searchsorted(t, k * (run_s + move_s) - 1e-9), np.searchsorted(t, k * (run_s + move_s) + run_s - 1e-9)
        rest_mask[a:b] = True
        g = rng.normal(size=3)
        accel[a:b] = 9.81 * g / np.linalg.norm(g)
        bounds.append((a, b))
    motion = ~rest_mask
    accel[motion] = 3.0 * np.sin(2 * np.pi * 2 * t[motion])[:, None] + np.array([0.0, 0.0, 9.81])
    accel += rng.normal(0.0, 0.03, accel.shape)
    gyro = rng.normal(0.0, 5e-3, accel.shape)
    gyro[motion] += 1.0
    return t, rest_mask, accel, gyro, bounds
