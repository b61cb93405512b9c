"""Validation of an in-memory :class:`~skincal.data.dataset.Dataset` against ``docs/interfaces.md``.

:func:`validate_dataset` runs after every read and before every write. Each failure raises one
:class:`~skincal.errors.DatasetError` whose single line names the source (file), the field as its
HDF5 path and the problem, e.g. ``data.h5: /joints/t is not strictly increasing (sample 412)``.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from skincal.data.dataset import DYNAMIC, STATIC, BodyPose, Dataset, Segments
from skincal.data.events import MAX_POSITION_M
from skincal.errors import DatasetError
from skincal.kinematics.chain import CONVENTIONS, SerialChain
from skincal.names import name_problem, printable
from skincal.skin.pose import SkinUnitPose

TRUTH_SENSOR_SHAPES: dict[str, tuple[int, ...]] = {
    "accel_bias": (3,),
    "accel_scale": (3,),
    "accel_misalignment": (3, 3),
    "gyro_bias": (3,),
    "time_offset_s": (),
    "clock_drift_ppm": (),
    "clock_resync_period_s": (),
}
"""Known optional per-unit truth attributes (simulated sensor errors) and their shapes; others may
be added (any finite numbers)."""

_TRUTH_POSE_ATTRS = ("link", "position", "quaternion_wxyz")
TRUTH_BODY_ATTRS = ("body", "T_body_su")
"""``/truth/<unit>`` attrs of an IMU-only true pose (:class:`~skincal.data.dataset.BodyPose`)."""
_BODY_ROTATION_TOL = 1e-6
MAX_DESCRIPTION_BYTES = 1 << 20
"""Largest root ``description`` (UTF-8 bytes): the contract's 1 MiB bound on any attribute, which every
reader enforces, so a longer one is refused when written rather than giving a file nobody reads."""
GRAVITY_NORM_MPS2 = (1.0, 100.0)
"""Accepted magnitude of the dataset's gravity, m/s^2: the accelerometers' only reference (zero
leaves a unit's orientation undetermined), about 9.81 on Earth."""


def _fail(source: str, field: str, problem: str) -> DatasetError:
    return DatasetError(f"{source}: {printable(field)} {printable(problem)}")


def _real_array(value: object, source: str, field: str, *, integer: bool = False) -> np.ndarray:
    """``value`` as an array of real numbers (integers when ``integer``); bools, strings, objects fail."""
    arr = np.asarray(value)
    kinds = "iu" if integer else "fiu"
    if arr.dtype.kind not in kinds:
        want = "integers" if integer else "real numbers"
        raise _fail(source, field, f"has dtype {arr.dtype}, expected {want}")
    return arr


def shape_mismatch(actual: tuple[int, ...], shape: tuple[int | None, ...]) -> str:
    """``""`` when ``actual`` fits ``shape`` (same rank, ``None`` entries free), else the complaint
    ``"has shape (4,), expected (N, 3)"``: the one wording of a wrong shape, for arrays and HDF5 datasets."""
    if len(actual) == len(shape) and all(s is None or s == a for s, a in zip(shape, actual, strict=False)):
        return ""
    want = "(" + ", ".join("N" if s is None else str(s) for s in shape) + ("," if len(shape) == 1 else "") + ")"
    return f"has shape {actual}, expected {want}"


def _check_shape(arr: np.ndarray, shape: tuple[int | None, ...], source: str, field: str) -> None:
    problem = shape_mismatch(arr.shape, shape)
    if problem:
        raise _fail(source, field, problem)


def _check_finite(arr: np.ndarray, source: str, field: str, *, allow_nan: bool = False) -> None:
    bad = np.isinf(arr) if allow_nan else ~np.isfinite(arr)
    if np.any(bad):
        where = np.argwhere(bad)[0]
        idx = f"sample {where[0]}" + (f", column {where[1]}" if len(where) > 1 else "") if where.size else "value"
        what = "infinite values" if allow_nan else "NaN or infinite values"
        raise _fail(source, field, f"contains {what} ({idx})")


def _float_field(
    value: object, shape: tuple[int | None, ...], source: str, field: str, *, allow_nan: bool = False
) -> np.ndarray:
    arr = _real_array(value, source, field)
    _check_shape(arr, shape, source, field)
    _check_finite(arr, source, field, allow_nan=allow_nan)
    return arr


def _time_field(value: object, source: str, field: str, *, min_samples: int) -> np.ndarray:
    t = _float_field(value, (None,), source, field)
    if t.shape[0] < min_samples:
        raise _fail(source, field, f"has {t.shape[0]} samples, at least {min_samples} needed")
    bad = np.flatnonzero(np.diff(t) <= 0)
    if bad.size:
        raise _fail(source, field, f"is not strictly increasing (sample {bad[0] + 1})")
    return t


def shown(value: object) -> str:
    """``repr(value)`` for a one-line message: white space collapsed, at most 60 characters, control
    characters escaped."""
    text = " ".join(repr(value).split())
    return printable(text if len(text) <= 60 else text[:57] + "...")


def check_unit_name(name: object, source: str, group: str) -> None:
    """Refuse a unit name that :func:`skincal.names.name_problem` refuses (the one rule for names)."""
    problem = name_problem(name)
    if problem is not None:
        raise _fail(source, group, f"has an invalid unit name {shown(name)}: it {problem}")


def validate_robot(robot: object, gravity: object, source: str) -> int:
    """Check the chain and gravity; returns the number of joints ``n``."""
    if not isinstance(robot, SerialChain):
        raise _fail(source, "/robot", f"must be a SerialChain, got {type(robot).__name__}")
    problem = name_problem(robot.name)
    if problem is not None:
        raise _fail(source, "/robot attr 'name'", f"{shown(robot.name)} is not a valid robot name: it {problem}")
    if robot.convention not in (*CONVENTIONS, "urdf"):
        raise _fail(source, "/robot attr 'convention'", f"is '{robot.convention}', expected {CONVENTIONS} or 'urdf'")
    n = robot.n_joints
    if n < 1:
        raise _fail(source, "/robot/axis", "is empty (a chain needs at least one joint)")
    if robot.dh is not None:
        _float_field(robot.dh, (n, 4), source, "/robot/dh")
    _float_field(robot.T_parent_joint, (n, 4, 4), source, "/robot/T_parent_joint")
    _float_field(robot.T_joint_link, (n, 4, 4), source, "/robot/T_joint_link")
    _float_field(robot.axis, (n, 3), source, "/robot/axis")
    for name in ("joint_lower", "joint_upper"):  # +-inf: a continuous joint
        value = getattr(robot, name)
        if value is not None and np.any(np.isnan(_real_array(value, source, f"/robot/{name}"))):
            raise _fail(source, f"/robot/{name}", "contains NaN")
    for name in ("velocity_limit", "acceleration_limit", "effort_limit"):
        value = getattr(robot, name)
        if value is not None:
            _float_field(value, (n,), source, f"/robot/{name}")
    _float_field(robot.T_link_flange, (4, 4), source, "/robot/T_link_flange")
    for what, names in (("joint_names", robot.joint_names), ("link_names", robot.link_names)):
        for item in names or ():
            problem = name_problem(item)
            if problem is not None:
                raise _fail(source, f"/robot attr '{what}'", f"{shown(item)} is not a valid name: it {problem}")
    validate_gravity(gravity, source, "/robot attr 'gravity'")
    return n


def validate_gravity(gravity: object, source: str, field: str) -> None:
    """Check gravity: ``(3,)``, finite, magnitude within :data:`GRAVITY_NORM_MPS2`."""
    g = _float_field(gravity, (3,), source, field)
    g_norm = float(np.linalg.norm(g))
    if not GRAVITY_NORM_MPS2[0] <= g_norm <= GRAVITY_NORM_MPS2[1]:
        raise _fail(
            source,
            field,
            f"has magnitude {g_norm:.6g} m/s^2, expected "
            f"{GRAVITY_NORM_MPS2[0]:g}..{GRAVITY_NORM_MPS2[1]:g} (about 9.81, e.g. [0, 0, -9.81])",
        )


def validate_segments(segments: Segments, n: int | None, source: str) -> None:
    """Check segment arrays: equal lengths, ``t_start < t_end``, kinds, ``joint == -1`` iff static;
    a dynamic segment's joint in ``0..n-1`` (``n = None``: a dataset without a robot, any joint >= 0)."""
    t0 = _float_field(segments.t_start, (None,), source, "/segments/t_start")
    S = t0.shape[0]
    t1 = _float_field(segments.t_end, (S,), source, "/segments/t_end")
    kind = _real_array(segments.kind, source, "/segments/kind", integer=True)
    pose = _real_array(segments.pose, source, "/segments/pose", integer=True)
    joint = _real_array(segments.joint, source, "/segments/joint", integer=True)
    for arr, field in ((kind, "/segments/kind"), (pose, "/segments/pose"), (joint, "/segments/joint")):
        _check_shape(arr, (S,), source, field)
    checks = (
        (t0 >= t1, "/segments/t_end", "is not after t_start"),
        ((kind != STATIC) & (kind != DYNAMIC), "/segments/kind", f"must be {STATIC} (static) or {DYNAMIC} (dynamic)"),
        (pose < 0, "/segments/pose", "must be a non-negative pose index"),
        ((kind == STATIC) & (joint != -1), "/segments/joint", "must be -1 for a static segment"),
        (
            (kind == DYNAMIC) & ((joint < 0) | (joint >= (np.iinfo(np.int64).max if n is None else n))),
            "/segments/joint",
            "must be >= 0 when dynamic" if n is None else f"must be in 0..{n - 1} when dynamic",
        ),
    )
    for bad, field, problem in checks:
        if np.any(bad):
            raise _fail(source, field, f"{problem} (segment {int(np.argmax(bad))})")


def validate_body_pose(pose: object, source: str, field: str) -> None:
    """Check an IMU-only true pose: ``body`` a valid name, ``T_body_su`` a finite rigid transform."""
    if not isinstance(pose, BodyPose):
        raise _fail(source, field, f"must be a BodyPose, got {type(pose).__name__}")
    problem = name_problem(pose.body)
    if problem is not None:
        raise _fail(source, f"{field} attr 'body'", f"{shown(pose.body)} is not a valid body name: it {problem}")
    T = _float_field(pose.T_body_su, (4, 4), source, f"{field} attr 'T_body_su'")
    R = T[:3, :3]
    if not np.allclose(T[3], [0.0, 0.0, 0.0, 1.0]) or not np.allclose(R.T @ R, np.eye(3), atol=_BODY_ROTATION_TOL):
        raise _fail(source, f"{field} attr 'T_body_su'", "is not a rigid transform (rotation, translation, 0 0 0 1)")
    if np.linalg.det(R) < 0:
        raise _fail(source, f"{field} attr 'T_body_su'", "is a reflection, not a rotation")
    if np.any(np.abs(T[:3, 3]) > MAX_POSITION_M):
        raise _fail(source, f"{field} attr 'T_body_su'", f"has a translation beyond {MAX_POSITION_M:g} m")


def validate_truth(ds: Dataset, n: int | None, source: str) -> None:
    """Check true poses (units exist in ``imu``, link in ``1..n``; ``n = None``: no robot, so no link
    poses), IMU-only body poses and true sensor errors."""
    for unit, body_pose in ds.truth_body.items():
        check_unit_name(unit, source, "/truth")
        field = f"/truth/{unit}"
        if unit not in ds.imu:
            raise _fail(source, field, f"names unit '{unit}' which has no /imu/{unit} stream")
        validate_body_pose(body_pose, source, field)
    for unit, pose in ds.truth.items():
        check_unit_name(unit, source, "/truth")
        field = f"/truth/{unit}"
        if unit not in ds.imu:
            raise _fail(source, field, f"names unit '{unit}' which has no /imu/{unit} stream")
        if not isinstance(pose, SkinUnitPose):
            raise _fail(source, field, f"must be a SkinUnitPose, got {type(pose).__name__}")
        if n is None:
            raise _fail(source, f"{field} attr 'link'", "needs a /robot (a dataset without one gives 'body' poses)")
        if not 1 <= pose.link <= n:
            raise _fail(source, f"{field} attr 'link'", f"is {pose.link}, expected 1..{n}")
        if np.any(np.abs(pose.p_link_su) > MAX_POSITION_M):  # as in results: distances from 1e308 overflow
            raise _fail(source, f"{field} attr 'position'", f"has a component beyond {MAX_POSITION_M:g} m")
    for unit, errors in ds.truth_sensor.items():
        field = f"/truth/{unit}"
        if unit not in ds.truth and unit not in ds.truth_body:
            pose_attrs = "link, position, quaternion_wxyz; or body, T_body_su"
            raise _fail(source, field, f"has sensor errors but no true pose ({pose_attrs})")
        if not isinstance(errors, Mapping):
            raise _fail(source, field, f"sensor errors must be a mapping, got {type(errors).__name__}")
        for key, value in errors.items():
            if not isinstance(key, str) or key in _TRUTH_POSE_ATTRS or key in TRUTH_BODY_ATTRS:
                raise _fail(source, field, f"has an invalid sensor error name {key!r}")
            attr = f"{field} attr '{key}'"
            arr = _real_array(value, source, attr)
            if key in TRUTH_SENSOR_SHAPES:
                _check_shape(arr, TRUTH_SENSOR_SHAPES[key], source, attr)
            _check_finite(arr, source, attr)


def validate_dataset(ds: Dataset, source: str = "<dataset>") -> None:
    """Check every field of ``ds`` against the dataset contract; raise :class:`DatasetError` on the first problem.

    Checked: robot (convention, ``(n, 4)`` DH, limits ``(n,)``), gravity ``(3,)``; every time base
    ``(N,)`` finite and strictly increasing; ``q``, ``qd``, ``qdd`` ``(N, n)``; IMU ``accel``/``gyro``
    ``(M, 3)``; ToF ``range`` ``(K,)`` (NaN allowed: no target; not infinite, not negative); values
    finite everywhere else; ToF units have IMU streams; segments consistent; truth units exist
    in ``imu`` with link in ``1..n``. An IMU-only dataset (``joints`` None) may have no robot (its
    gravity then checked alone; no link truth; body truth a rigid ``T_body_su``); joints need a robot.
    ``source`` (the file name) starts every message.
    """
    if not isinstance(ds, Dataset):
        raise DatasetError(f"{source}: expected a Dataset, got {type(ds).__name__}")
    n: int | None = None
    if ds.robot is not None:
        n = validate_robot(ds.robot, ds.gravity, source)
    else:
        validate_gravity(ds.gravity, source, "root attr 'gravity'")
    if not isinstance(ds.description, str):
        raise _fail(source, "root attr 'description'", "must be a string")
    size = len(ds.description.encode("utf-8", "surrogatepass"))
    if size > MAX_DESCRIPTION_BYTES:
        raise _fail(source, "root attr 'description'", f"has {size} bytes (at most {MAX_DESCRIPTION_BYTES}, 1 MiB)")

    js = ds.joints
    if js is not None:
        if n is None:
            raise _fail(source, "/robot", "is missing (a dataset with /joints needs its robot)")
        t = _time_field(js.t, source, "/joints/t", min_samples=1)
        N = t.shape[0]
        _float_field(js.q, (N, n), source, "/joints/q")
        _float_field(js.qd, (N, n), source, "/joints/qd")
        if js.qdd is not None:
            _float_field(js.qdd, (N, n), source, "/joints/qdd")
    if not ds.imu and js is None:
        raise _fail(source, "/imu", "is empty and there are no /joints: the dataset holds no stream")

    for unit, imu in ds.imu.items():
        check_unit_name(unit, source, "/imu")
        ti = _time_field(imu.t, source, f"/imu/{unit}/t", min_samples=1)
        M = ti.shape[0]
        _float_field(imu.accel, (M, 3), source, f"/imu/{unit}/accel")
        if imu.gyro is not None:
            _float_field(imu.gyro, (M, 3), source, f"/imu/{unit}/gyro")

    for unit, tof in ds.tof.items():
        check_unit_name(unit, source, "/tof")
        if unit not in ds.imu:
            raise _fail(source, f"/tof/{unit}", f"names unit '{unit}' which has no /imu/{unit} stream")
        tt = _time_field(tof.t, source, f"/tof/{unit}/t", min_samples=0)
        r = _float_field(tof.range, (tt.shape[0],), source, f"/tof/{unit}/range", allow_nan=True)
        if np.any(r < 0):
            raise _fail(source, f"/tof/{unit}/range", f"contains negative ranges (sample {int(np.argmax(r < 0))})")

    if ds.segments is not None:
        validate_segments(ds.segments, n, source)
    validate_truth(ds, n, source)
