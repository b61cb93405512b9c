"""Faults of real sessions injected into simulated datasets, each with the truth it records.

Pure functions ``Dataset -> Dataset`` (the input is never modified) and two simulation wrappers
(a knocked unit, a gravity mismatch). Each records what it did in ``Dataset.truth_sensor[unit]``
(numbers only, so that the dataset still writes to HDF5; keys listed in ``docs/interfaces.md``).
Time ``t`` is the IMU stream's own stamp (s); the session is ``[t0, t1]``, the joint stream's span.

* :func:`shift_imu_stamps`, fixed clock offset: ``t' = t + offset_s``; truth ``time_offset_s += offset_s``.
* :func:`saturate_accel`, small full-scale range: ``a' = clip(a, -r, r)`` per axis; truth
  ``accel_range_mps2 = r``.
* :func:`stick_axis`, one accelerometer axis stuck: ``a'_i(t) = a_i(t_k*)`` for ``t >= t_s``; truth
  ``accel_stuck_axis``, ``accel_stuck_from_s``, ``accel_stuck_value_mps2``.
* :func:`drift_bias`, accelerometer bias drift: ``a'(t) = a(t) + d (t - t0) / (t1 - t0)``; truth
  ``accel_bias_drift_mps2 = d``.
* :func:`splice_knock`, unit knocked at ``t_s``: the stream of ``before`` for ``t < t_s``, of ``after``
  from ``t_s``; truth: the pose at the majority of the session, both poses and ``knock_t_s``.
* :func:`declare_gravity`, wrong gravity in the file: the ``gravity`` field replaced; truth
  ``gravity_true_mps2``.
* :func:`misstate_units`, a stream in the wrong unit (:data:`UNIT_MISTAKES`): ``x' = round(k x)``
  (rounded only for raw counts) with ``k`` the factor from SI to the unit the stream really is in:
  ``gyro-deg`` (a gyroscope in deg/s stored as rad/s: ``w' = (180 / pi) w``, 57.3x), ``accel-g``
  (an accelerometer in g stored as m/s^2: ``a' = a / 9.80665``), ``raw-counts`` (both as 16-bit
  register counts of a +-4 g / +-2000 deg/s part: ``a' = round(a / lsb_a)``, ``w' = round(w / lsb_g)``,
  clipped to +-32767); truth ``accel_unit_factor`` and ``gyro_unit_factor`` = ``k`` (1 when untouched).

The pose truth (``Dataset.truth``) a calibration is judged against is the unit's pose, unchanged by
every fault but the knock; for a knocked unit it is the pose it had over the larger part of the
session (:func:`splice_knock`).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping
from dataclasses import replace

import numpy as np
from numpy.typing import ArrayLike

from skincal.data.dataset import Dataset, ImuStream
from skincal.errors import ConfigError
from skincal.skin.imu import STANDARD_GRAVITY
from skincal.skin.pose import SkinUnitPose

GRAVITY_TRUE_MPS2 = 9.796
"""Default true gravity of :func:`simulate_gravity_mismatch`, m/s^2 (a plausible local value)."""

GRAVITY_DECLARED_MPS2 = 9.81
"""Default gravity the dataset states in :func:`simulate_gravity_mismatch`, m/s^2 (skincal's convention)."""


def _units(ds: Dataset, units: Iterable[str] | None) -> list[str]:
    names = ds.units if units is None else list(units)
    unknown = [u for u in names if u not in ds.imu]
    if unknown:
        raise ConfigError(f"fault: unknown unit(s) {', '.join(unknown)} (dataset has: {', '.join(ds.units)})")
    return names


def _with_streams(
    ds: Dataset, streams: Mapping[str, ImuStream], truth: Mapping[str, Mapping[str, object]]
) -> Dataset:
    """``ds`` with some IMU streams replaced and truth entries added (copies; ``ds`` is untouched)."""
    imu = {name: streams.get(name, s) for name, s in ds.imu.items()}
    truth_sensor = {name: dict(values) for name, values in ds.truth_sensor.items()}
    for name, values in truth.items():
        truth_sensor.setdefault(name, {}).update(values)
    return replace(ds, imu=imu, truth_sensor=truth_sensor)


def session_span(ds: Dataset) -> tuple[float, float]:
    """The session ``[t0, t1]``, s: the span of the joint stream."""
    t = np.asarray(ds.joints.t, dtype=float)
    if t.size < 2:
        raise ConfigError("fault: the dataset's joint stream has fewer than two samples")
    return float(t[0]), float(t[-1])


def shift_imu_stamps(ds: Dataset, offset_s: float, units: Iterable[str] | None = None) -> Dataset:
    """A fixed clock offset: every IMU stamp of ``units`` (default all) moved by ``offset_s`` s.

    ``t' = t + offset_s``; the readings are unchanged, so the sample stamped ``t'`` measured the
    motion at ``t' - (time_offset_s + offset_s)``. Truth: ``time_offset_s`` grows by ``offset_s``
    (created at ``offset_s`` when absent). Time-of-flight streams are left alone.
    """
    offset_s = float(offset_s)
    if not np.isfinite(offset_s):
        raise ConfigError(f"shift_imu_stamps: offset_s must be finite (s), got {offset_s}")
    streams, truth = {}, {}
    for name in _units(ds, units):
        s = ds.imu[name]
        streams[name] = replace(s, t=np.asarray(s.t, dtype=float) + offset_s)
        truth[name] = {"time_offset_s": float(ds.truth_sensor.get(name, {}).get("time_offset_s", 0.0)) + offset_s}
    return _with_streams(ds, streams, truth)


def saturate_accel(ds: Dataset, range_mps2: float, units: Iterable[str] | None = None) -> Dataset:
    """An accelerometer of full scale ``range_mps2`` (m/s^2): ``a'_i = clip(a_i, -r, r)`` on every axis.

    Applied to readings that a sensor model may already have clipped (clipping twice is clipping
    at the smaller range). Truth: ``accel_range_mps2`` = the smaller of ``r`` and any range
    recorded before.
    """
    r = float(range_mps2)
    if not (r > 0 and np.isfinite(r)):
        raise ConfigError(f"saturate_accel: range_mps2 must be positive and finite (m/s^2), got {range_mps2}")
    streams, truth = {}, {}
    for name in _units(ds, units):
        s = ds.imu[name]
        streams[name] = replace(s, accel=np.clip(np.asarray(s.accel, dtype=float), -r, r))
        before = float(ds.truth_sensor.get(name, {}).get("accel_range_mps2", np.inf))
        truth[name] = {"accel_range_mps2": min(r, before)}
    return _with_streams(ds, streams, truth)


def stick_axis(ds: Dataset, unit: str, axis: int, t_s: float) -> Dataset:
    """Accelerometer axis ``axis`` (0, 1, 2 = x, y, z) of ``unit`` stuck from stamp ``t_s`` on.

    ``a'_axis(t_k) = a_axis(t_k*)`` for every sample with ``t_k >= t_s``, where ``k*`` is the last
    sample before ``t_s`` (the first sample at or after it when there is none): the register keeps
    its last value. The other axes, the gyroscope and the samples before ``t_s`` are unchanged.
    Truth: ``accel_stuck_axis`` (float), ``accel_stuck_from_s`` = ``t_s``, ``accel_stuck_value_mps2``.
    """
    if axis not in (0, 1, 2):
        raise ConfigError(f"stick_axis: axis must be 0, 1 or 2 (x, y, z), got {axis!r}")
    (name,) = _units(ds, [unit])
    s = ds.imu[name]
    t = np.asarray(s.t, dtype=float)
    accel = np.array(s.accel, dtype=float)
    stuck = t >= float(t_s)
    if not np.any(stuck):
        raise ConfigError(f"stick_axis: unit '{unit}' has no sample at or after t = {t_s} s")
    first = int(np.argmax(stuck))
    value = float(accel[max(first - 1, 0), axis])
    accel[stuck, axis] = value
    truth = {"accel_stuck_axis": float(axis), "accel_stuck_from_s": float(t_s), "accel_stuck_value_mps2": value}
    return _with_streams(ds, {name: replace(s, accel=accel)}, {name: truth})


def random_directions(n: int, rng: np.random.Generator) -> np.ndarray:
    """``(n, 3)`` unit vectors uniform on the sphere."""
    v = rng.normal(size=(n, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def drift_bias(
    ds: Dataset,
    total_mps2: float,
    directions: Mapping[str, ArrayLike] | None = None,
    rng: np.random.Generator | None = None,
    units: Iterable[str] | None = None,
) -> Dataset:
    """A linear accelerometer bias drift of size ``total_mps2`` (m/s^2) over the session.

    ``a'(t) = a(t) + d * clip((t - t0) / (t1 - t0), 0, 1)`` in the unit frame, with ``[t0, t1]`` the
    session (:func:`session_span`) and ``d = total_mps2 * u``, ``u`` the unit's direction: given in
    ``directions`` (normalised) or drawn uniform on the sphere from ``rng`` (one per unit, in unit
    order). The gyroscope is unchanged; the drift is added after the sensor model (no re-quantisation).
    Truth: ``accel_bias_drift_mps2`` = ``d`` ``(3,)``, the change of the bias from ``t0`` to ``t1``;
    ``accel_bias`` stays the bias at ``t0``.
    """
    names = _units(ds, units)
    total = float(total_mps2)
    if not np.isfinite(total):
        raise ConfigError(f"drift_bias: total_mps2 must be finite (m/s^2), got {total_mps2}")
    if directions is None:
        if rng is None:
            raise ConfigError("drift_bias: give the drift directions or an rng to draw them")
        drawn = random_directions(len(names), rng)
        directions = {name: drawn[k] for k, name in enumerate(names)}
    t0, t1 = session_span(ds)
    streams, truth = {}, {}
    for name in names:
        u = np.asarray(directions[name], dtype=float)
        if u.shape != (3,) or not np.linalg.norm(u) > 0:
            raise ConfigError(f"drift_bias: the direction of unit '{name}' must be a non-zero (3,) vector")
        d = total * u / np.linalg.norm(u)
        s = ds.imu[name]
        frac = np.clip((np.asarray(s.t, dtype=float) - t0) / (t1 - t0), 0.0, 1.0)
        streams[name] = replace(s, accel=np.asarray(s.accel, dtype=float) + frac[:, None] * d)
        truth[name] = {"accel_bias_drift_mps2": d}
    return _with_streams(ds, streams, truth)


def knocked_pose(
    pose: SkinUnitPose, translation_m: float, rotation_deg: float, rng: np.random.Generator
) -> SkinUnitPose:
    """The pose of a unit knocked by ``translation_m`` m and ``rotation_deg`` deg in random directions.

    ``p' = p + translation_m * u`` (``u`` uniform unit vector, link frame) and
    ``R' = R Exp(rotation_deg * w)`` (``w`` uniform unit axis, unit frame); same link.
    """
    from scipy.spatial.transform import Rotation

    u, w = random_directions(2, rng)
    dR = Rotation.from_rotvec(np.radians(float(rotation_deg)) * w).as_matrix()
    return SkinUnitPose(pose.link, pose.R_link_su @ dR, pose.p_link_su + float(translation_m) * u)


def splice_knock(before: Dataset, after: Dataset, unit: str, t_s: float) -> Dataset:
    """``unit`` knocked at stamp ``t_s``: its IMU stream from ``before`` for ``t < t_s``, from ``after`` on.

    ``before`` and ``after`` must be simulations with the same seed that differ only in the pose of
    ``unit`` (checked: the unit's stamps are identical), so that the spliced stream is the one of a
    unit that moved at ``t_s``; every other stream and field is ``before``'s.

    Truth: ``Dataset.truth[unit]`` is the pose over the larger part of the session ``[t0, t1]``:
    ``before``'s if ``t_s - t0 >= t1 - t_s``, else ``after``'s. ``truth_sensor[unit]`` gets
    ``knock_t_s`` and both poses, ``knock_T_link_su_before`` and ``knock_T_link_su_after`` ``(4, 4)``.
    """
    (name,) = _units(before, [unit])
    if name not in after.imu:
        raise ConfigError(f"splice_knock: the 'after' dataset has no unit '{unit}'")
    a, b = before.imu[name], after.imu[name]
    if a.t.shape != b.t.shape or not np.array_equal(a.t, b.t):
        raise ConfigError(
            f"splice_knock: unit '{unit}' is sampled at other instants in the two simulations (not the same seed?)"
        )
    if name not in before.truth or name not in after.truth:
        raise ConfigError(f"splice_knock: both datasets need the true pose of unit '{unit}'")
    late = np.asarray(a.t, dtype=float) >= float(t_s)
    accel = np.where(late[:, None], b.accel, a.accel)
    gyro = None if a.gyro is None or b.gyro is None else np.where(late[:, None], b.gyro, a.gyro)
    t0, t1 = session_span(before)
    pose_before, pose_after = before.truth[name], after.truth[name]
    majority = pose_before if float(t_s) - t0 >= t1 - float(t_s) else pose_after
    truth = {
        "knock_t_s": float(t_s),
        "knock_T_link_su_before": pose_before.T_link_su,
        "knock_T_link_su_after": pose_after.T_link_su,
    }
    out = _with_streams(before, {name: ImuStream(t=np.array(a.t), accel=accel, gyro=gyro)}, {name: truth})
    return replace(out, truth={**out.truth, name: majority})


def simulate_knock(
    simulate: Callable[[Mapping[str, SkinUnitPose]], Dataset],
    placements: Mapping[str, SkinUnitPose],
    unit: str,
    t_s: float,
    knocked: SkinUnitPose,
) -> Dataset:
    """A session in which ``unit`` is knocked from ``placements[unit]`` to ``knocked`` at stamp ``t_s``.

    ``simulate(placements) -> Dataset`` must be deterministic (the same seed on every call): it is
    called with the original placements and with ``unit`` moved, and the two are spliced by
    :func:`splice_knock` (which also says what truth is recorded).
    """
    if unit not in placements:
        raise ConfigError(f"simulate_knock: unknown unit '{unit}'")
    if knocked.link != placements[unit].link:
        raise ConfigError("simulate_knock: a knock moves a unit on its own link")
    before = simulate(dict(placements))
    after = simulate({**placements, unit: knocked})
    return splice_knock(before, after, unit, t_s)


def declare_gravity(ds: Dataset, gravity: ArrayLike) -> Dataset:
    """The dataset states ``gravity`` ``(3,)`` m/s^2 (base frame) while its streams keep the gravity
    they were simulated with. Truth: ``gravity_true_mps2`` ``(3,)`` (the old field) on every unit."""
    g = np.asarray(gravity, dtype=float)
    if g.shape != (3,) or not np.all(np.isfinite(g)):
        raise ConfigError(f"declare_gravity: gravity must be a finite (3,) vector in m/s^2, got shape {g.shape}")
    true = np.asarray(ds.gravity, dtype=float).copy()
    out = _with_streams(ds, {}, {name: {"gravity_true_mps2": true} for name in ds.units})
    return replace(out, gravity=g)


def simulate_gravity_mismatch(
    simulate: Callable[[np.ndarray], Dataset],
    g_true: float = GRAVITY_TRUE_MPS2,
    g_declared: float = GRAVITY_DECLARED_MPS2,
) -> Dataset:
    """A session simulated under gravity ``[0, 0, -g_true]`` whose dataset states ``[0, 0, -g_declared]``.

    ``simulate(gravity (3,)) -> Dataset`` runs the simulation with the given base-frame gravity;
    the result goes through :func:`declare_gravity`. A unit at rest then reads ``|a| = g_true``.
    """
    simulated = simulate(np.array([0.0, 0.0, -float(g_true)]))
    return declare_gravity(simulated, np.array([0.0, 0.0, -float(g_declared)]))


RAW_ACCEL_LSB_MPS2 = 4.0 * STANDARD_GRAVITY / 2**15
"""Accelerometer LSB of :data:`UNIT_MISTAKES` ``raw-counts``, m/s^2 (+-4 g at 16 bit, 8192 counts per g)."""
RAW_GYRO_LSB_RPS = np.radians(2000.0) / 2**15
"""Gyroscope LSB of ``raw-counts``, rad/s (+-2000 deg/s at 16 bit, 16.4 counts per deg/s)."""
RAW_COUNT_LIMIT = 2**15 - 1

UNIT_MISTAKES: dict[str, tuple[float, float, bool]] = {
    "gyro-deg": (1.0, 180.0 / np.pi, False),
    "accel-g": (1.0 / STANDARD_GRAVITY, 1.0, False),
    "raw-counts": (1.0 / RAW_ACCEL_LSB_MPS2, 1.0 / RAW_GYRO_LSB_RPS, True),
}
"""Unit mistake name -> ``(accel factor, gyro factor, rounded to counts)``: the stream is ``factor x``
the SI value (:func:`misstate_units`)."""


def misstate_units(ds: Dataset, mistake: str, units: Iterable[str] | None = None) -> Dataset:
    """The streams of ``units`` (default all) written in another unit than the file says (SI).

    ``a' = k_a a``, ``w' = k_g w`` with ``(k_a, k_g)`` of :data:`UNIT_MISTAKES`; ``raw-counts`` rounds
    to whole counts and clips to ``+-32767`` (``a' = clip(round(a / lsb_a))``). Stamps, poses and
    ToF are unchanged. Truth: ``accel_unit_factor`` and ``gyro_unit_factor`` multiplied by ``k``
    (a unit of factor 1 is in SI); a unit without a gyroscope records only the accelerometer's.
    """
    try:
        k_a, k_g, counts = UNIT_MISTAKES[mistake]
    except KeyError:
        raise ConfigError(f"unknown unit mistake '{mistake}' (known: {', '.join(UNIT_MISTAKES)})") from None

    def convert(x: np.ndarray, k: float) -> np.ndarray:
        y = np.asarray(x, dtype=float) * k
        return np.clip(np.round(y), -RAW_COUNT_LIMIT, RAW_COUNT_LIMIT) if counts else y

    streams, truth = {}, {}
    for name in _units(ds, units):
        s = ds.imu[name]
        before = ds.truth_sensor.get(name, {})
        entry = {"accel_unit_factor": float(before.get("accel_unit_factor", 1.0)) * k_a}
        gyro = None
        if s.gyro is not None:
            gyro = convert(s.gyro, k_g)
            entry["gyro_unit_factor"] = float(before.get("gyro_unit_factor", 1.0)) * k_g
        streams[name] = replace(s, accel=convert(s.accel, k_a), gyro=gyro)
        truth[name] = entry
    return _with_streams(ds, streams, truth)
