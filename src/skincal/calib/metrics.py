"""Errors of a calibration result against the truth (``docs/interfaces.md``, "Evaluation").

* ``position_error_mm``: ``|p_est - p_true|`` in the link frame, mm.
* ``rotation_error_deg``: the angle of ``R_true^T R_est``, degrees.
* ``quaternion_distance``: the paper's ``min(|q1 - q2|, |q1 + q2|)`` on unit quaternions.
* A unit assigned to the wrong link is compared in the base frame at the dataset's first sample.
* Means are over observable units that were calibrated.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from skincal.data.dataset import Dataset
from skincal.data.result import CalibrationResult, check_links, has_position
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


@dataclass(frozen=True)
class UnitEvaluation:
    """One unit's errors against the truth (``docs/interfaces.md``, "Evaluation").

    Attributes:
        link_true, link_estimated: the unit's true and estimated 1-based link.
        observable: whether the result could determine the unit's full pose.
        position_error_mm: ``|p_est - p_true|``, mm (in the link frame; the base frame at the first
            sample when the links differ); NaN (``null`` in JSON) for a unit whose result determines no
            position (:func:`~skincal.data.result.has_position`: its ``p_link_su`` is a placeholder).
        rotation_error_deg: the angle of ``R_true^T R_est``, deg.
        quaternion_distance: ``min(|q1 - q2|, |q1 + q2|)``.
    """

    link_true: int
    link_estimated: int
    observable: bool
    position_error_mm: float
    rotation_error_deg: float
    quaternion_distance: float


@dataclass(frozen=True)
class Evaluation:
    """A calibration result's errors against the truth (``skincal evaluate``; :meth:`to_dict`: its JSON).

    Attributes:
        units: per calibrated unit, its :class:`UnitEvaluation`.
        mean_position_error_mm, mean_rotation_error_deg, mean_quaternion_distance: means over the
            observable units, None when there is none.
        links_correct: units whose estimated link is the true one.
        units_total: units evaluated (the calibrated ones).
        units_failed: names of the units the result could not calibrate, sorted.
    """

    units: Mapping[str, UnitEvaluation]
    mean_position_error_mm: float | None
    mean_rotation_error_deg: float | None
    mean_quaternion_distance: float | None
    links_correct: int
    units_total: int
    units_failed: tuple[str, ...] = ()

    def to_dict(self) -> dict[str, Any]:
        """The evaluation document of ``docs/interfaces.md`` (plain JSON values; NaN as ``null``)."""
        doc = asdict(self)
        doc["units_failed"] = list(self.units_failed)
        for unit in doc["units"].values():
            if not np.isfinite(unit["position_error_mm"]):
                unit["position_error_mm"] = None
        return doc


def error_text(value: float, digits: int = 3) -> str:
    """An error for a table: ``value`` with ``digits`` decimals, ``-`` where it is not defined (NaN: a
    position the result does not determine)."""
    return f"{value:.{digits}f}" if np.isfinite(value) else "- (not determined)"


def evaluate(result: CalibrationResult, truth: Dataset) -> Evaluation:
    """The :class:`Evaluation` of ``result`` against ``truth`` (its JSON: ``docs/interfaces.md``)."""
    if not truth.truth:
        raise DatasetError("the truth dataset has no /truth group (only simulated datasets carry truth)")
    missing = [u for u in result.units if u not in truth.truth]
    if missing:
        raise DatasetError(f"the truth dataset has no truth for unit(s) {', '.join(missing)}")
    check_links(result, truth.robot, "result")
    q0 = np.asarray(truth.joint_states.q[0], dtype=float)
    units: dict[str, UnitEvaluation] = {}
    for name, unit in result.units.items():
        true = truth.truth[name]
        pos_mm, rot_deg, qdist = pose_errors(truth.robot, q0, unit.pose, true)
        if not has_position(unit):  # its p_link_su is a placeholder, not an estimate
            pos_mm = float("nan")
        units[name] = UnitEvaluation(true.link, unit.pose.link, bool(unit.observable), pos_mm, rot_deg, qdist)
    observable = [u for u in units.values() if u.observable and np.isfinite(u.position_error_mm)]

    def mean(key: str) -> float | None:
        return float(np.mean([getattr(u, key) for u in observable])) if observable else None

    return Evaluation(
        units=units,
        mean_position_error_mm=mean("position_error_mm"),
        mean_rotation_error_deg=mean("rotation_error_deg"),
        mean_quaternion_distance=mean("quaternion_distance"),
        links_correct=int(sum(u.link_true == u.link_estimated for u in units.values())),
        units_total=len(units),
        units_failed=tuple(sorted(result.failed_units)),
    )
