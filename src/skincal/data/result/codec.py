"""A result to and from its JSON document, checked both ways (:func:`result_to_dict`,
:func:`result_from_dict`), and its file (:func:`write_result`, :func:`read_result`, :func:`sha256_file`;
the format in the package docstring)."""

from __future__ import annotations

import hashlib
import json
import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from skincal.data.events import MAX_POSITION_M, MoveEvent, check_events
from skincal.data.imu_calibration import IMU_KEYS, IMU_SHAPES, INTEGER_KEYS, ImuCalibration, imu_to_fields
from skincal.data.result.types import (
    EVENTS,
    FAILED_UNITS,
    FORMAT,
    LINK_CONFIDENCE,
    MOVED_AT,
    NOTES,
    POSE_COVARIANCE,
    POSITION_DETERMINED,
    REFERENCE,
    REFERENCE_LINK,
    TYPED_TOP,
    TYPED_UNIT,
    VERSION,
    CalibrationResult,
    UnitResult,
    check_moved_at,
    check_pose_covariance,
    checked_notes,
    has_position,
    none_to_nan,
    short_repr,
)
from skincal.errors import ConfigError, DatasetError
from skincal.io.atomic import write_bytes_atomic
from skincal.io.files import RESULT_FILE, regular_file
from skincal.io.jsonio import load_json
from skincal.kinematics.transforms import FloatArray
from skincal.names import MAX_NAME_CHARS, name_problem
from skincal.skin.pose import SkinUnitPose

_NO_REASON = "no pose (the result file gives no reason)"
_TOP_KEYS = ("format", "version", "method", "robot", "dataset_sha256", "runtime_s", "units")
_UNIT_KEYS = ("link", "position_m", "quaternion_wxyz", "observable", "position_std_m", "rotation_std_deg", "warnings")
_QUAT_NORM_TOL = 1e-3


def sha256_file(path: str | Path) -> str:
    """SHA-256 hex digest of a regular file's bytes (streamed, any size; a FIFO or device is refused)."""
    if Path(path).exists():  # a missing file keeps its message below
        regular_file(path, "file", DatasetError)
    try:
        with open(path, "rb") as fh:
            return hashlib.file_digest(fh, "sha256").hexdigest()
    except OSError as exc:
        raise DatasetError(f"{path}: cannot read file ({exc.strerror or exc})") from None


def _to_json(value: Any, source: str, where: str) -> Any:
    """Plain JSON value of ``value``: arrays and NumPy scalars to lists/numbers, non-finite floats to None."""
    if isinstance(value, dict):
        out = {}
        for k, v in value.items():
            if not isinstance(k, str):
                raise DatasetError(f"{source}: {where} has a non-string key {short_repr(k)}")
            out[k] = _to_json(v, source, f"{where}.{k}")
        return out
    if isinstance(value, np.ndarray):
        if value.dtype.kind not in "biuf":
            raise DatasetError(f"{source}: {where} is an array of dtype {value.dtype}, not numbers")
        return _to_json(value.tolist(), source, where)
    if isinstance(value, list | tuple):
        return [_to_json(v, source, f"{where}[{i}]") for i, v in enumerate(value)]
    if isinstance(value, bool | np.bool_):
        return bool(value)
    if isinstance(value, int | np.integer):
        return int(value)
    if isinstance(value, float | np.floating):
        return float(value) if math.isfinite(value) else None
    if value is None or isinstance(value, str):
        return value
    raise DatasetError(f"{source}: {where} has a value of type {type(value).__name__} that JSON cannot hold")


def _numeric_leaves(value: Any) -> tuple[bool, bool]:
    """(all leaves are numbers or None, at least one leaf is a number) for nested lists."""
    if isinstance(value, list):
        flags = [_numeric_leaves(v) for v in value]
        return all(f[0] for f in flags), any(f[1] for f in flags)
    if value is None:
        return True, False
    is_num = isinstance(value, int | float) and not isinstance(value, bool)
    return is_num, is_num


def _from_json(value: Any) -> Any:
    """Inverse of :func:`_to_json` for extras: numeric (possibly nested, rectangular) lists -> float arrays."""
    if isinstance(value, dict):
        return {k: _from_json(v) for k, v in value.items()}
    if isinstance(value, list):
        all_numeric, any_number = _numeric_leaves(value)
        if all_numeric and any_number:
            try:
                return np.array(none_to_nan(value), dtype=float)
            except ValueError:  # ragged
                pass
        return [_from_json(v) for v in value]
    return value


# ---------------------------------------------------------------------- validation of the JSON document
class _Checker:
    def __init__(self, source: str) -> None:
        self.source = source

    def fail(self, where: str, problem: str) -> DatasetError:
        return DatasetError(f"{self.source}: {where} {problem}")

    def get(self, obj: dict, key: str, where: str) -> Any:
        if key not in obj:
            raise self.fail(f"{where}.{key}".lstrip("."), "is missing")
        return obj[key]

    def string(self, value: Any, where: str) -> str:
        if not isinstance(value, str):
            raise self.fail(where, f"must be a string, got {short_repr(value)}")
        return value

    def name(self, value: Any, where: str) -> str:
        problem = name_problem(value)
        if problem is not None:
            raise self.fail(where, f"{problem} (names: 1-{MAX_NAME_CHARS} characters, no '/', no control characters)")
        return value

    def vector(self, value: Any, n: int, where: str, *, nonneg: bool = False, nulls: bool = False) -> FloatArray:
        """``value`` as a float array of ``n`` finite numbers; with ``nulls``, ``None`` components are
        allowed and become NaN."""

        def number(v: Any) -> bool:
            return isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)

        ok = isinstance(value, list) and len(value) == n and all(number(v) or (nulls and v is None) for v in value)
        if not ok:
            what = f"{n} finite numbers or null (undetermined)" if nulls else f"{n} finite numbers"
            raise self.fail(where, f"must be a list of {what}, got {short_repr(value)}")
        arr = np.array([math.nan if v is None else v for v in value], dtype=float)
        if nonneg and np.any(arr < 0):
            raise self.fail(where, f"must not be negative, got {short_repr(value)}")
        return arr

    def document(self, doc: Any) -> None:
        if not isinstance(doc, dict):
            raise DatasetError(f"{self.source}: top level must be a JSON object, got {type(doc).__name__}")
        fmt = self.get(doc, "format", "")
        if fmt != FORMAT:
            raise self.fail("format", f"is {short_repr(fmt)}, expected '{FORMAT}'")
        version = self.get(doc, "version", "")
        if isinstance(version, bool) or not isinstance(version, int):
            raise self.fail("version", f"must be an integer, got {short_repr(version)}")
        if version != VERSION:
            raise self.fail("version", f"is {version}; this skincal reads version {VERSION}")
        if not self.string(self.get(doc, "method", ""), "method"):
            raise self.fail("method", "is empty")
        self.name(self.get(doc, "method", ""), "method")
        self.name(self.string(self.get(doc, "robot", ""), "robot"), "robot")
        sha = self.string(self.get(doc, "dataset_sha256", ""), "dataset_sha256")
        if sha and (len(sha) != 64 or any(c not in "0123456789abcdefABCDEF" for c in sha)):
            raise self.fail("dataset_sha256", f"must be 64 hex digits or empty, got {short_repr(sha)}")
        runtime = self.get(doc, "runtime_s", "")
        number = isinstance(runtime, int | float) and not isinstance(runtime, bool)
        if not number or not math.isfinite(runtime) or runtime < 0:
            raise self.fail("runtime_s", f"must be a non-negative number of seconds, got {short_repr(runtime)}")
        units = self.get(doc, "units", "")
        if not isinstance(units, dict):
            raise self.fail("units", f"must be an object of unit name -> result, got {short_repr(units)}")
        if not units:
            raise self.fail("units", "is empty (a result lists every unit of its dataset, calibrated or not)")
        reference = doc.get(REFERENCE)
        if reference is not None:
            self.name(self.string(reference, REFERENCE), REFERENCE)
            if reference not in units:
                raise self.fail(REFERENCE, f"names unit {short_repr(reference)}, which is not in units")
        for name, unit in units.items():
            self.name(name, f"units key {short_repr(name)}")
            self.unit(unit, f"units.{name}", relative=reference is not None)
        links = self.robot_links(doc["robot"])
        if links is not None:
            for name, unit in units.items():
                if unit["link"] is not None and unit["link"] > links:
                    problem = f"is {unit['link']}; robot '{doc['robot']}' has links 1..{links}"
                    raise self.fail(f"units.{name}.link", problem)

    @staticmethod
    def robot_links(robot: str) -> int | None:
        """Number of links of a preset robot name, None for other names (checked against the chain where
        the result meets a dataset: :func:`check_links`)."""
        from skincal.kinematics.presets import PRESETS

        return PRESETS[robot]().n_joints if robot in PRESETS else None

    def unit(self, unit: Any, where: str, relative: bool = False) -> None:
        if not isinstance(unit, dict):
            raise self.fail(where, f"must be an object, got {short_repr(unit)}")
        link = self.get(unit, "link", where)
        position = self.get(unit, "position_m", where)
        quaternion = self.get(unit, "quaternion_wxyz", where)
        posed = position is not None and quaternion is not None
        if relative and link == REFERENCE_LINK and not isinstance(link, bool):
            pass  # a relative result: the pose is in the reference unit's frame
        elif not (link is None and not posed) and (isinstance(link, bool) or not isinstance(link, int) or link < 1):
            also = "" if posed else " or null"
            raise self.fail(f"{where}.link", f"must be a positive integer (1-based link){also}, got {short_repr(link)}")
        if position is not None:
            p = self.vector(position, 3, f"{where}.position_m")
            if np.any(np.abs(p) > MAX_POSITION_M):
                problem = f"has a component beyond {MAX_POSITION_M:g} m, got {short_repr(position)}"
                raise self.fail(f"{where}.position_m", problem)
        if quaternion is not None:
            quat = self.vector(quaternion, 4, f"{where}.quaternion_wxyz")
            norm = float(np.linalg.norm(quat))
            if abs(norm - 1.0) > _QUAT_NORM_TOL:
                raise self.fail(f"{where}.quaternion_wxyz", f"is not a unit quaternion (norm {norm:.6g})")
        observable = self.get(unit, "observable", where)
        if not isinstance(observable, bool):
            raise self.fail(f"{where}.observable", f"must be true or false, got {short_repr(observable)}")
        if observable and not posed:
            raise self.fail(
                f"{where}.observable", "must be false for a unit without a pose (position_m or quaternion_wxyz is null)"
            )
        for key in ("position_std_m", "rotation_std_deg"):
            value = self.get(unit, key, where)
            if value is not None:
                self.vector(value, 3, f"{where}.{key}", nonneg=True, nulls=True)
        warnings = self.get(unit, "warnings", where)
        if not isinstance(warnings, list) or not all(isinstance(w, str) for w in warnings):
            raise self.fail(f"{where}.warnings", f"must be a list of strings, got {short_repr(warnings)}")
        self.imu(unit, where)

    def imu(self, unit: dict, where: str) -> ImuCalibration | None:
        """The :class:`ImuCalibration` of a unit entry, None when it has none of its fields: arrays are
        lists of numbers (``null``: undetermined, NaN), numbers a finite number or ``null`` (not
        estimated, None)."""
        if not any(k in unit for k in IMU_KEYS):
            return None
        values: dict[str, Any] = {}
        for key in IMU_KEYS:
            value, shape = unit.get(key), IMU_SHAPES[key]
            if value is None:
                continue
            if key in INTEGER_KEYS:
                if isinstance(value, bool) or not isinstance(value, int) or value < 0:
                    raise self.fail(f"{where}.{key}", f"must be a whole number >= 0 or null, got {short_repr(value)}")
                values[key] = value
            elif shape == ():
                if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
                    raise self.fail(f"{where}.{key}", f"must be a finite number or null, got {short_repr(value)}")
                values[key] = float(value)
            elif len(shape) == 1:
                values[key] = self.vector(value, shape[0], f"{where}.{key}", nulls=True)
            else:
                if not isinstance(value, list) or len(value) != shape[0]:
                    problem = f"must be {shape[0]} rows of {shape[1]} numbers, got {short_repr(value)}"
                    raise self.fail(f"{where}.{key}", problem)
                rows = [self.vector(row, shape[1], f"{where}.{key}[{i}]", nulls=True) for i, row in enumerate(value)]
                values[key] = np.array(rows)
        return ImuCalibration(**values)


# ---------------------------------------------------------------------- conversions
def result_to_dict(result: CalibrationResult, source: str = "<result>") -> dict[str, Any]:
    """The JSON document of ``result`` (plain Python values), validated against the contract."""
    doc: dict[str, Any] = {
        "format": FORMAT,
        "version": VERSION,
        "method": result.method,
        "robot": result.robot,
        "dataset_sha256": result.dataset_sha256,
        "runtime_s": _to_json(result.runtime_s, source, "runtime_s"),
    }
    _no_clash(result.extras, _TOP_KEYS, TYPED_TOP, source, "extras", "CalibrationResult")
    if result.reference is not None:
        doc[REFERENCE] = result.reference
    doc.update(_to_json(result.extras, source, "extras"))
    if result.failed_units:
        doc[FAILED_UNITS] = dict(result.failed_units)
    if result.notes:
        doc[NOTES] = list(checked_notes(result.notes, f"{source}: {NOTES}"))
    if result.events:
        events = check_events(result.events, f"{source}: {EVENTS}")
        doc[EVENTS] = _to_json([e.fields() for e in events], source, EVENTS)
    units: dict[str, Any] = {}
    for name, unit in result.units.items():
        where = f"units.{name}"
        if not isinstance(unit, UnitResult):
            raise DatasetError(f"{source}: {where} must be a UnitResult, got {type(unit).__name__}")
        _no_clash(unit.extras, _UNIT_KEYS, TYPED_UNIT, source, f"{where} extras", "UnitResult")
        clash = sorted(set(unit.extras) & set(IMU_KEYS))
        if clash:
            raise DatasetError(
                f"{source}: {where} extras may not hold {', '.join(clash)}: the IMU calibration goes in UnitResult.imu"
            )
        entry = {
            "link": unit.pose.link,
            "position_m": _to_json(unit.pose.p_link_su, source, f"{where}.position_m") if has_position(unit) else None,
            "quaternion_wxyz": _to_json(unit.pose.quaternion_wxyz, source, f"{where}.quaternion_wxyz"),
            "observable": _to_json(unit.observable, source, f"{where}.observable"),
            "position_std_m": _to_json(unit.position_std_m, source, f"{where}.position_std_m"),
            "rotation_std_deg": _to_json(unit.rotation_std_deg, source, f"{where}.rotation_std_deg"),
            "warnings": list(unit.warnings),
        }
        if unit.imu is not None:
            entry.update(_to_json(imu_to_fields(unit.imu), source, where))
        if unit.link_confidence is not None:
            entry[LINK_CONFIDENCE] = _to_json(unit.link_confidence, source, f"{where}.{LINK_CONFIDENCE}")
        entry.update(_to_json(unit.extras, source, f"{where}"))
        if unit.pose_covariance is not None:
            cov = check_pose_covariance(unit.pose_covariance, f"{source}: {where}.{POSE_COVARIANCE}")
            entry[POSE_COVARIANCE] = _to_json(cov, source, f"{where}.{POSE_COVARIANCE}")
        if unit.notes:
            entry[NOTES] = list(checked_notes(unit.notes, f"{source}: {where}.{NOTES}"))
        if unit.moved_at_s:
            entry[MOVED_AT] = _to_json(list(unit.moved_at_s), source, f"{where}.{MOVED_AT}")
        units[name] = entry
    for name, reason in result.failed_units.items():  # units without a pose are listed too (never lose a unit)
        if name not in units:
            units[name] = {
                "link": None,
                "position_m": None,
                "quaternion_wxyz": None,
                "observable": False,
                "position_std_m": None,
                "rotation_std_deg": None,
                "warnings": [reason],
            }
    doc["units"] = units
    _Checker(source).document(doc)
    _check_event_fields(doc, source)
    return doc


def _no_clash(
    extras: Mapping[str, Any], contract: tuple[str, ...], typed: tuple[str, ...], source: str, where: str, owner: str
) -> None:
    """Refuse extras that redefine a contract field or hold a typed field (its one place is ``owner``'s field)."""
    clash = sorted(set(extras) & set(contract))
    if clash:
        raise DatasetError(f"{source}: {where} may not redefine contract field(s) {', '.join(clash)}")
    clash = sorted(set(extras) & set(typed))
    if clash:
        fields = ", ".join(f"{owner}.{k}" for k in clash)
        raise DatasetError(f"{source}: {where} may not hold {', '.join(clash)}: they go in {fields}")


def _check_event_fields(doc: dict[str, Any], source: str) -> tuple[MoveEvent, ...]:
    """The moved-unit fields of a result document: top-level ``events`` (units of the document) and
    per-unit ``moved_at_s``; returns the events (none without ``events``)."""
    for name, entry in doc["units"].items():
        if MOVED_AT in entry:
            check_moved_at(entry[MOVED_AT], f"{source}: units.{name}")
    if EVENTS not in doc:
        return ()
    return check_events(doc[EVENTS], f"{source}: {EVENTS}", units=set(doc["units"]))


def _failed_units(doc: dict[str, Any], source: str, unposed: bool) -> dict[str, str]:
    """The top-level ``failed_units``: an object of unit name -> reason, or (hand-written, in a file
    without ``null``-pose unit entries) a list of names, each then ``"not calibrated"``."""
    listed = doc.get(FAILED_UNITS)
    if listed is None:
        return {}
    if isinstance(listed, dict):
        return {k: str(v) for k, v in listed.items()}
    if not unposed and isinstance(listed, list) and all(isinstance(k, str) for k in listed):
        return dict.fromkeys(listed, "not calibrated")
    raise DatasetError(f"{source}: {FAILED_UNITS} must be an object of unit name -> reason, got {short_repr(listed)}")


def _unit_fields(entry: dict[str, Any], source: str, where: str) -> dict[str, Any]:
    """The typed per-unit fields of a unit entry (those it has), checked."""
    out: dict[str, Any] = {}
    if LINK_CONFIDENCE in entry:
        value = entry[LINK_CONFIDENCE]
        number = isinstance(value, int | float) and not isinstance(value, bool)
        if value is not None and not (number and 0.0 <= value <= 1.0):
            raise DatasetError(
                f"{source}: {where}.{LINK_CONFIDENCE} must be a number in [0, 1] or null, got {short_repr(value)}"
            )
        out["link_confidence"] = math.nan if value is None else float(value)
    if entry.get(POSE_COVARIANCE) is not None:
        out["pose_covariance"] = check_pose_covariance(entry[POSE_COVARIANCE], f"{source}: {where}.{POSE_COVARIANCE}")
    if entry.get(NOTES) is not None:
        out["notes"] = checked_notes(entry[NOTES], f"{source}: {where}.{NOTES}")
    if MOVED_AT in entry:
        out["moved_at_s"] = tuple(float(t) for t in entry[MOVED_AT])
    return out


def result_from_dict(doc: Any, source: str = "<result>") -> CalibrationResult:
    """Validate a parsed JSON document and build the :class:`CalibrationResult`."""
    _Checker(source).document(doc)
    events = _check_event_fields(doc, source)
    units = {}
    unposed: dict[str, str] = {}
    skip = (*_UNIT_KEYS, *IMU_KEYS, *TYPED_UNIT)
    for name, entry in doc["units"].items():
        rotation_only = entry["position_m"] is None and entry["link"] is not None  # no position (has_position)
        if entry["quaternion_wxyz"] is None or (entry["position_m"] is None and not rotation_only):
            unposed[name] = "; ".join(entry["warnings"]) or _NO_REASON
            continue
        try:
            position = np.zeros(3) if rotation_only else entry["position_m"]
            pose = SkinUnitPose.from_quaternion(entry["link"], position, entry["quaternion_wxyz"])
        except ConfigError as exc:
            raise DatasetError(f"{source}: units.{name} is not a valid pose: {exc}") from None
        stds = {k: None if entry[k] is None else np.array(none_to_nan(entry[k]), dtype=float) for k in _UNIT_KEYS[4:6]}
        extras_pos: dict[str, Any] = {}
        if rotation_only:
            stds["position_std_m"] = np.full(3, np.nan)
            extras_pos[POSITION_DETERMINED] = False
        units[name] = UnitResult(
            pose=pose,
            observable=entry["observable"],
            warnings=tuple(entry["warnings"]),
            extras={**{k: _from_json(v) for k, v in entry.items() if k not in skip}, **extras_pos},
            imu=_Checker(source).imu(entry, f"units.{name}"),
            **stds,
            **_unit_fields(entry, source, f"units.{name}"),
        )
    listed = _failed_units(doc, source, bool(unposed))
    return CalibrationResult(
        method=doc["method"],
        robot=doc["robot"],
        dataset_sha256=doc["dataset_sha256"],
        runtime_s=float(doc["runtime_s"]),
        units=units,
        extras={k: _from_json(v) for k, v in doc.items() if k not in _TOP_KEYS and k not in TYPED_TOP},
        failed_units={**listed, **unposed},
        notes=checked_notes(doc[NOTES], f"{source}: {NOTES}") if doc.get(NOTES) is not None else (),
        events=events,
        reference=doc.get(REFERENCE),
    )


def write_result(result: CalibrationResult, path: str | Path) -> None:
    """Validate ``result`` and write it as indented JSON to ``path`` atomically."""
    doc = result_to_dict(result, source=str(path))
    text = json.dumps(doc, indent=2, allow_nan=False) + "\n"
    write_bytes_atomic(path, text.encode("utf-8"))


def read_result(path: str | Path) -> CalibrationResult:
    """Read and validate a result file.

    Raises:
        DatasetError: missing file, not a regular file, too large, not JSON (or JSON that
            :func:`skincal.io.jsonio.load_json` refuses: duplicate keys, nesting deeper than 64,
            NaN/Infinity, overflowing numbers), wrong format or version, a malformed field, a bad
            unit or robot name (:func:`skincal.names.name_problem`), no units, a position
            beyond :data:`MAX_POSITION_M`, or a link beyond a preset robot's links; one line naming
            the file and the field (``units.su1.position_m``).
    """
    doc = load_json(path, RESULT_FILE, DatasetError)
    return result_from_dict(doc, source=str(path))
