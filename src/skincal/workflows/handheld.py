"""Skin without encoders: hand-held sessions (units on a rigid body moved by hand) and the benchmark of
the IMU-only unit-to-unit calibration (:func:`skincal.calib.imu_only.calibrate_relative`).

:func:`handheld_dataset` is the preset of such a session: ``units`` units ``spacing`` m apart along the
body's x axis, each with a random orientation, a hand-like "turn it over" motion with still holds in
orientations spread over the sphere (:meth:`skincal.sim.rigid_body.HandMotion.turn_over`: the motion a user
should make, so that the accelerometers' scale can be fitted), the named IMU and clock presets, and
optionally ``other_body`` units on a second, independently moved body (moved without holds).
:func:`bench_relative` runs it ``runs`` times and measures the errors against the truth and the
calibration of the reported std (RMS of error / std per axis).
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from skincal.data.dataset import Dataset
from skincal.data.result import CalibrationResult
from skincal.errors import ConfigError
from skincal.kinematics.transforms import FloatArray
from skincal.sim.rigid_body import MIN_MOVE_S, HandMotion, simulate_rigid_bodies
from skincal.skin.clock import get_clock_model
from skincal.skin.imu import get_imu_model

HOLDS = 12
"""Still holds of the preset's hand motion (9 are needed to fit an accelerometer's scale and cross-axis
terms, each orientation giving one equation |f| = g; a few more for the conditioning)."""
HOLD_S = 1.5
"""Length of each hold, s."""
BODY = "hand"
OTHER_BODY = "other"


def handheld_dataset(
    units: int = 2,
    spacing: float = 0.2,
    duration_s: float = 60.0,
    imu: str = "real",
    clock: str = "driver",
    seed: int = 0,
    other_body: int = 0,
    scale_free: bool = False,
    holds: int | None = None,
    hold_s: float = HOLD_S,
) -> Dataset:
    """A simulated hand-held session (see the module docstring); units are ``su1``, ``su2``, ...
    ``scale_free``: the IMU preset without accelerometer scale and misalignment errors (as after a
    calibration of the accelerometers), to measure what the reference's gauge costs. ``holds``: still
    periods of ``hold_s`` s in the hand's motion (``None``: as many as fit, up to ``HOLDS``, with at least
    ``MIN_MOVE_S`` of motion around each; 0: none, a motion without rests)."""
    if units < 1 or other_body < 0 or units + other_body < 2:
        raise ConfigError(f"hand-held session: need at least 2 units in all, got {units} + {other_body}")
    if not (0 < spacing < 10):
        raise ConfigError(f"hand-held session: spacing must be in (0, 10) m, got {spacing}")
    rng = np.random.default_rng(seed)
    if holds is None:
        holds = int(min(HOLDS, max(0, (duration_s - MIN_MOVE_S) // (hold_s + MIN_MOVE_S))))
    motions = {
        BODY: HandMotion.turn_over(rng, duration_s, holds=holds, hold_s=hold_s) if holds else HandMotion.random(rng)
    }
    if other_body:
        motions[OTHER_BODY] = HandMotion.random(rng)
    placement: dict[str, tuple[str, FloatArray]] = {}
    for k in range(units + other_body):
        T = np.eye(4)
        T[:3, :3] = Rotation.random(random_state=np.random.default_rng(rng.integers(2**32))).as_matrix()
        T[:3, 3] = [spacing * (k if k < units else k - units), 0.0, 0.0]
        placement[f"su{k + 1}"] = (BODY if k < units else OTHER_BODY, T)
    description = (
        f"simulated hand-held session: {units} units {spacing} m apart, {holds} holds, {imu} IMUs, {clock} clocks"
    )
    model = get_imu_model(imu)
    if scale_free:
        model = replace(model, accel_scale_std=0.0, misalignment_std=0.0)
    return simulate_rigid_bodies(
        placement, motions, duration_s, model, rng, clock_model=get_clock_model(clock),
        description=description,
    )  # fmt: skip


def relative_errors(result: CalibrationResult, dataset: Dataset) -> dict[str, dict[str, Any]]:
    """Per unit on the reference's body: position error (m, ``(3,)`` in the reference frame), rotation
    error (rad, ``(3,)`` rotation vector of ``R_true^T R_est``), and the reported std (m, deg)."""
    reference = result.reference
    truth = dataset.truth_body
    ref = truth[reference]
    out: dict[str, dict[str, Any]] = {}
    for name, unit in result.units.items():
        if name == reference or name not in truth or truth[name].body != ref.body:
            continue
        T = np.linalg.inv(ref.T_body_su) @ truth[name].T_body_su
        rot = Rotation.from_matrix(T[:3, :3].T @ unit.pose.R_link_su).as_rotvec()
        out[name] = {
            "position_error_m": unit.pose.p_link_su - T[:3, 3],
            "rotation_error_rad": T[:3, :3] @ rot,  # in the reference frame, as the std
            "position_std_m": unit.position_std_m,
            "rotation_std_deg": unit.rotation_std_deg,
        }
    return out
