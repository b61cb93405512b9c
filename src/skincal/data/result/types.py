"""The result types (:class:`UnitResult`, :class:`CalibrationResult`) with their typed facts, the file's
field names, and what is asked of a result (:func:`has_position`, :func:`with_events`, :func:`check_links`)."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from skincal.data.events import MoveEvent, check_events
from skincal.data.imu_calibration import ImuCalibration
from skincal.errors import DatasetError
from skincal.kinematics.transforms import FloatArray
from skincal.skin.pose import SkinUnitPose

FORMAT = "skincal-result"
VERSION = 1
FAILED_UNITS = "failed_units"
REFERENCE = "reference"
"""Top-level field of a relative (IMU-only) result: the unit whose frame every pose is given in."""
REFERENCE_LINK = 0
"""``link`` of a pose in the reference unit's frame (allowed only in a result with ``reference``)."""
EVENTS = "events"
"""Top-level field: the moved-unit events of the session, a list of objects (:class:`MoveEvent`)."""
MOVED_AT = "moved_at_s"
"""Per-unit field: the change times of the unit's moved-unit events, s (a list of numbers)."""
NOTES = "notes"
"""Top-level and per-unit field: what was found in the data and done about it (a list of strings)."""
LINK_CONFIDENCE = "link_confidence"
"""Per-unit field: the link discovery's confidence in [0, 1]."""
POSE_COVARIANCE = "pose_covariance"
"""Per-unit field: the 6x6 covariance of ``(x, y, z, rx, ry, rz)`` in the link frame's axes, m^2 and rad^2."""
TYPED_TOP = (REFERENCE, FAILED_UNITS, NOTES, EVENTS)
TYPED_UNIT = (LINK_CONFIDENCE, NOTES, POSE_COVARIANCE, MOVED_AT)


def check_moved_at(value: Any, where: str) -> None:
    items = value.tolist() if isinstance(value, np.ndarray) else value
    if not isinstance(items, list | tuple) or not all(
        isinstance(x, int | float) and not isinstance(x, bool) and math.isfinite(x) for x in items
    ):
        raise DatasetError(f"{where}.{MOVED_AT} must be a list of finite numbers (s), got {short_repr(value)}")


def check_pose_covariance(value: Any, where: str) -> FloatArray:
    """``value`` as a ``(6, 6)`` float covariance (NaN/``null`` where undetermined), symmetric (to 1e-9 of
    ``sqrt(C_ii C_jj)``) with a non-negative diagonal where known; else a one-line :class:`DatasetError`
    starting with ``where``."""
    try:
        arr = None if isinstance(value, str) else np.array(none_to_nan(value), dtype=float)
    except (TypeError, ValueError):
        arr = None
    if arr is None or arr.shape != (6, 6):
        raise DatasetError(f"{where} must be a 6x6 matrix of numbers (null where undetermined)")
    known = np.isfinite(arr)
    both = known & known.T
    diag = np.abs(np.where(np.isfinite(np.diag(arr)), np.diag(arr), 0.0))
    with np.errstate(over="ignore"):  # variances of 1e200: the product is inf, any asymmetry passes
        scale = np.sqrt(np.outer(diag, diag))  # asymmetry measured against the std product: rounding, not data
    asym = np.abs(np.where(both, arr - arr.T, 0.0))
    if np.any(np.diag(arr)[np.diag(known)] < 0) or np.any(asym > 1e-9 * scale):
        raise DatasetError(f"{where} must be symmetric with a non-negative diagonal")
    return arr


def checked_notes(value: Any, where: str) -> tuple[str, ...]:
    if not isinstance(value, list | tuple) or not all(isinstance(n, str) for n in value):
        raise DatasetError(f"{where} must be a list of strings, got {short_repr(value)}")
    return tuple(value)


def _readonly(value: Any) -> FloatArray:
    arr = np.array(value, dtype=float)
    arr.setflags(write=False)
    return arr


@dataclass(frozen=True)
class UnitResult:
    """Calibrated pose of one skin unit.

    Attributes:
        pose: the estimated pose in its link frame (link, ``R_link_su``, ``p_link_su`` in m).
        observable: False where the data cannot determine the full pose (e.g. a unit on link 1).
        position_std_m: ``(3,)`` standard deviation of ``p_link_su`` per axis, m, or None; NaN in a
            component the data cannot determine (``null`` in JSON).
        rotation_std_deg: ``(3,)`` standard deviation of the rotation about the link axes, deg, or
            None; NaN in an undetermined component.
        warnings: human-readable notes (which part is unobservable and why, poor fit, ...).
        extras: further per-unit fields of the method written next to the contract fields (numbers,
            strings, lists, arrays, nested dicts), e.g. ``dh6``; not the fields of ``imu``
            (:data:`~skincal.data.imu_calibration.IMU_KEYS`) nor the typed fields below.
        imu: the unit's IMU calibration (bias, scale/misalignment, time offset, clock drift, ...),
            or None where the method estimates none.
        link_confidence: the link discovery's confidence in [0, 1] (``link_confidence``), None where the
            link was given (NaN: written ``null``).
        pose_covariance: ``(6, 6)`` covariance of ``(x, y, z, rx, ry, rz)`` in the link frame's axes,
            m^2 and rad^2 (``pose_covariance``; NaN where undetermined), or None (only the std).
        notes: what was found in the unit's data and corrected (``notes``); unlike ``warnings``,
            nothing the estimate or its std has to answer for.
        moved_at_s: change times of the unit's moved-unit events, s (``moved_at_s``).
    """

    pose: SkinUnitPose
    observable: bool = True
    position_std_m: FloatArray | None = None
    rotation_std_deg: FloatArray | None = None
    warnings: tuple[str, ...] = ()
    extras: dict[str, Any] = field(default_factory=dict)
    imu: ImuCalibration | None = None
    link_confidence: float | None = None
    pose_covariance: FloatArray | None = None
    notes: tuple[str, ...] = ()
    moved_at_s: tuple[float, ...] = ()

    def __post_init__(self) -> None:
        for name in ("position_std_m", "rotation_std_deg", "pose_covariance"):
            value = getattr(self, name)
            if value is not None:
                object.__setattr__(self, name, _readonly(value))
        if self.link_confidence is not None:
            object.__setattr__(self, "link_confidence", float(self.link_confidence))
        object.__setattr__(self, "warnings", tuple(self.warnings))
        object.__setattr__(self, "notes", tuple(self.notes))
        object.__setattr__(self, "moved_at_s", tuple(float(t) for t in self.moved_at_s))


@dataclass(frozen=True)
class CalibrationResult:
    """Result of one calibration run.

    Attributes:
        method: method name (``mle``, ``om``, ``mmm``, ``mm``, ``online``, ``imu-only``).
        robot: robot name of the dataset.
        dataset_sha256: SHA-256 hex digest of the dataset file (:func:`sha256_file`), or ``""``.
        runtime_s: wall-clock time of the calibration, s.
        units: per-unit results keyed by unit name (every one has a pose).
        extras: further top-level fields of the method (e.g. ``seed``, ``cpu_s``, ``accel_scale_fit``);
            not the typed fields below.
        failed_units: units that could not be calibrated, name -> reason (``failed_units``); the JSON
            file also lists each one not in ``units`` under ``units`` with ``null`` pose fields and
            ``observable: false``.
        notes: what was done to the whole dataset (``notes``), e.g. segments found automatically.
        events: the session's moved-unit events (``events``).
        reference: the unit whose frame every pose is given in (a relative, IMU-only result:
            ``reference``; poses at link :data:`REFERENCE_LINK`), or None (poses in link frames).
    """

    method: str
    robot: str
    dataset_sha256: str
    runtime_s: float
    units: dict[str, UnitResult]
    extras: dict[str, Any] = field(default_factory=dict)
    failed_units: Mapping[str, str] = field(default_factory=dict)
    notes: tuple[str, ...] = ()
    events: tuple[MoveEvent, ...] = ()
    reference: str | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "failed_units", {str(k): str(v) for k, v in self.failed_units.items()})
        object.__setattr__(self, "notes", tuple(self.notes))
        object.__setattr__(self, "events", tuple(self.events))


POSITION_DETERMINED = "position_determined"
"""Per-unit extra: ``False`` for a unit whose position the data do not determine at all (rests only)."""


def has_position(unit: UnitResult) -> bool:
    """False for a unit whose position the data do not determine at all (``extras["position_determined"]
    is False``, e.g. from static poses only; never for an observable unit). Its ``position_m`` is written
    as ``null`` (link and rotation kept) and read back as ``p_link_su = 0`` with NaN std."""
    return unit.observable or unit.extras.get(POSITION_DETERMINED, True) is not False


def with_events(result: CalibrationResult, events: Sequence[MoveEvent | Mapping[str, Any]]) -> CalibrationResult:
    """``result`` with the moved-unit events recorded (``docs/interfaces.md``): ``events`` (each checked,
    :func:`~skincal.data.events.move_event`) and each moved unit's ``moved_at_s`` (the input is kept)."""
    typed = check_events(list(events), EVENTS)
    units = dict(result.units)
    for name in dict.fromkeys(e.unit for e in typed):
        if name in units:
            units[name] = replace(units[name], moved_at_s=tuple(e.t_change_s for e in typed if e.unit == name))
    return replace(result, units=units, events=typed)


# ---------------------------------------------------------------------- JSON <-> Python values
def short_repr(value: object) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def none_to_nan(value: Any) -> Any:
    if isinstance(value, list):
        return [none_to_nan(v) for v in value]
    return math.nan if value is None else value


def check_links(result: CalibrationResult, chain: Any, source: str = "<result>") -> None:
    """Refuse a result whose units sit on links ``chain`` does not have (``1..chain.n_joints``), with
    a one-line :class:`DatasetError`; call it where a result meets a robot (evaluation, viewers)."""
    n = int(chain.n_joints)
    for name, unit in result.units.items():
        link = unit.pose.link
        if not 1 <= link <= n:
            raise DatasetError(f"{source}: units.{name}.link is {link}; robot '{chain.name}' has links 1..{n}")
