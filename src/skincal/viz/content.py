"""Everything a report shows, computed once from a result and its dataset (HTML and markdown share it)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from skincal.calib.metrics import evaluate
from skincal.calib.preprocess import JointInterpolator
from skincal.data.dataset import Dataset
from skincal.data.result import CalibrationResult, failed_units
from skincal.errors import DatasetError
from skincal.kinematics.transforms import FloatArray
from skincal.viz.residuals import UnitResiduals, activity_matrix, sensor_model, unit_residuals


@dataclass(frozen=True)
class UnitRow:
    """One line of the per-unit table (SI units; ``scale`` is the diagonal of the scale/misalignment
    matrix, ``None`` where the method did not estimate it; ``time_offset_s`` None likewise)."""

    name: str
    link: int
    position_m: FloatArray
    quaternion_wxyz: FloatArray
    observable: bool
    position_std_m: FloatArray | None
    rotation_std_deg: FloatArray | None
    bias_mps2: FloatArray | None
    scale: FloatArray | None
    time_offset_s: float | None
    residual_rms_mps2: float
    warnings: tuple[str, ...]


@dataclass(frozen=True)
class ReportContent:
    """Inputs of a calibration report.

    Attributes:
        result: the calibration result.
        dataset: the dataset it was computed from.
        rows: per-unit table rows, in the result's unit order.
        residuals: per-unit accelerometer residuals (:func:`unit_residuals`).
        activity: ``(units, n)`` data coverage (:func:`activity_matrix`), rows in ``rows`` order.
        evaluation: the ``skincal evaluate`` document when the dataset has truth for every unit, else None.
        failed: units the method could not calibrate, with the reason.
    """

    result: CalibrationResult
    dataset: Dataset
    rows: list[UnitRow]
    residuals: dict[str, UnitResiduals]
    activity: FloatArray
    evaluation: dict[str, Any] | None
    failed: dict[str, str]


def collect(result: CalibrationResult, dataset: Dataset, *, use_dataset_qdd: bool = False) -> ReportContent:
    """Recompute residuals and coverage for every unit of ``result`` on ``dataset``.

    ``use_dataset_qdd``: predict with the dataset's joint accelerations instead of estimating them
    from the velocities (as ``skincal calibrate --use-dataset-qdd`` does)."""
    missing = [u for u in result.units if u not in dataset.imu]
    if missing:
        raise DatasetError(f"dataset has no IMU data for unit(s) {', '.join(missing)} of the result")
    if result.robot and dataset.robot.name and result.robot != dataset.robot.name:
        raise DatasetError(f"result is for robot '{result.robot}' but the dataset is of '{dataset.robot.name}'")
    interp = JointInterpolator(dataset.joints, use_dataset_qdd=use_dataset_qdd)
    residuals = {name: unit_residuals(dataset, name, unit, interp) for name, unit in result.units.items()}
    rows = []
    for name, unit in result.units.items():
        ex = unit.extras
        A, b, tau = sensor_model(unit)
        rows.append(
            UnitRow(
                name=name,
                link=unit.pose.link,
                position_m=unit.pose.p_link_su,
                quaternion_wxyz=unit.pose.quaternion_wxyz,
                observable=unit.observable,
                position_std_m=unit.position_std_m,
                rotation_std_deg=unit.rotation_std_deg,
                bias_mps2=b if "accel_bias_mps2" in ex else None,
                scale=np.diag(A).copy() if ex.get("scale_estimated", "accel_scale_misalignment" in ex) else None,
                time_offset_s=tau if ex.get("time_offset_s") is not None else None,
                residual_rms_mps2=residuals[name].rms,
                warnings=unit.warnings,
            )
        )
    evaluation = evaluate(result, dataset) if dataset.truth and all(u in dataset.truth for u in result.units) else None
    failed = failed_units(result)
    return ReportContent(
        result, dataset, rows, residuals, activity_matrix(dataset, list(result.units), interp), evaluation, failed
    )
