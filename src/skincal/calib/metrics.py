"""Errors of a calibration result against the truth (``docs/interfaces.md``, "Evaluation").

* ``position_error_mm``: ``|p_est - p_true|`` in the link frame, mm.
* ``rotation_error_deg``: the angle of ``R_true^T R_est``, degrees.
* ``quaternion_distance``: the paper's ``min(|q1 - q2|, |q1 + q2|)`` on unit quaternions.
* A unit assigned to the wrong link is compared in the base frame at the dataset's first sample.
* Means are over observable units that were calibrated.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from skincal.data.dataset import Dataset
from skincal.data.result import CalibrationResult, check_links
from skincal.errors import DatasetError
from skincal.kinematics.transforms import quat_wxyz_from_matrix, quaternion_distance, rotation_angle
from skincal.skin.pose import SkinUnitPose


def pose_errors(chain, q0: np.ndarray, est: SkinUnitPose, true: SkinUnitPose) -> tuple[float, float, float]:
    """(position error mm, rotation error deg, quaternion distance) between two unit poses.

    Same link: compared in that link frame. Different links: both mapped to the base frame at
    joint angles ``q0`` (``T_base_su = T_base_link(q0) T_link_su``).
    """
    if est.link == true.link:
        T_est, T_true = est.T_link_su, true.T_link_su
    else:
        frames = chain.link_frames(q0)[0]
        T_est = frames[est.link] @ est.T_link_su
        T_true = frames[true.link] @ true.T_link_su
    pos_mm = 1e3 * float(np.linalg.norm(T_est[:3, 3] - T_true[:3, 3]))
    rot_deg = float(np.degrees(rotation_angle(T_true[:3, :3], T_est[:3, :3])))
    qd = float(quaternion_distance(quat_wxyz_from_matrix(T_est[:3, :3]), quat_wxyz_from_matrix(T_true[:3, :3])))
    return pos_mm, rot_deg, qd


def evaluate(result: CalibrationResult, truth: Dataset) -> dict[str, Any]:
    """The evaluation document of ``docs/interfaces.md`` for ``result`` against ``truth``."""
    if not truth.truth:
        raise DatasetError("the truth dataset has no /truth group (only simulated datasets carry truth)")
    missing = [u for u in result.units if u not in truth.truth]
    if missing:
        raise DatasetError(f"the truth dataset has no truth for unit(s) {', '.join(missing)}")
    check_links(result, truth.robot, "result")
    q0 = np.asarray(truth.joint_states.q[0], dtype=float)
    units: dict[str, Any] = {}
    for name, unit in result.units.items():
        true = truth.truth[name]
        pos_mm, rot_deg, qdist = pose_errors(truth.robot, q0, unit.pose, true)
        units[name] = {
            "link_true": true.link,
            "link_estimated": unit.pose.link,
            "observable": bool(unit.observable),
            "position_error_mm": pos_mm,
            "rotation_error_deg": rot_deg,
            "quaternion_distance": qdist,
        }
    observable = [u for u in units.values() if u["observable"]]

    def mean(key: str) -> float | None:
        return float(np.mean([u[key] for u in observable])) if observable else None

    return {
        "units": units,
        "mean_position_error_mm": mean("position_error_mm"),
        "mean_rotation_error_deg": mean("rotation_error_deg"),
        "mean_quaternion_distance": mean("quaternion_distance"),
        "links_correct": int(sum(u["link_true"] == u["link_estimated"] for u in units.values())),
        "units_total": len(units),
        "units_failed": sorted(result.extras.get("failed_units", {})),
    }
