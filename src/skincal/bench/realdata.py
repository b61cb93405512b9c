"""Repeatability on recordings that share a mount (``skincal benchmark realdata DIR``).

Real recordings have no ground truth; what they do have is repetition: every recording of one IMU
on one mount must give the same pose within the reported uncertainty. ``DIR`` holds the recordings
(each a folder with ``recording.h5``, or ``.h5`` files directly); they are grouped by IMU (the part
of the folder name after the last ``_S<n>_``, as in ``V500_S3_MPU9150``, else the unit name in the
dataset) and each is calibrated with ``mle``, with the streaming calibrator (``online``: the recording
replayed as ``skincal calibrate --follow --speed 0`` replays it, to the data's end) and, where the data
allow it, the paper's ``om``.

Per group and method, over the recordings calibrated on the group's most common link:

* positions ``p_link_su`` (link frame axes, mm): std across recordings per axis (``ddof = 1``) and the
  pairwise spread per axis (largest difference between two recordings, ``max_ij |p_i - p_j|``), over the
  recordings that determine a position (a unit calibrated from rests only has none,
  :func:`~skincal.data.result.has_position`: counted in ``position_undetermined``);
* rotations (deg): each recording's deviation from the chordal mean ``R_bar`` as a rotation vector
  about the link frame's axes, ``delta_i = log(R_i R_bar^T)``: std per axis, largest pairwise angle
  ``max_ij angle(R_i^T R_j)``;
* spread over the reported uncertainty: the std across recordings divided by the median reported
  std, per axis (1 when the reported std is honest; ``null`` where no std was reported), and the RMS of
  each recording's deviation from the weighted mean in its own std (:func:`normalised_spread`: fair to
  a recording that pins little and says so with a large std, which the median hides);
* motion kept: the moving samples the calibration used over the unit's samples not at rest;
* time offsets (ms), their spread and the RMS of each one's deviation from the weighted mean in its own
  std (``time_offset_deviation_rms_std``); links chosen; failures (recording and reason);
* ``position_weak``: the recordings whose position the calibration calls weakly determined (a std
  above :data:`~skincal.calib.position.POSITION_WEAK_STD_M` on some axis; kept in every figure above;
  ``position_std_firm_mm`` and ``position_spread_over_std_firm`` are the spread without them).

Recordings made at once by several IMUs (one folder per IMU with the same ``V.._S.._`` stem, or one
dataset with several units) share everything the robot and the host did: their *paired* differences
per session (:func:`paired`: position and time offset of one IMU minus the other's, judged by the two
std combined) tell what varies with the recording (the same in both IMUs) from what the calibration of
each sensor gets wrong (the difference).

Every figure is marked ``simulated`` when the recordings carry a simulation's truth, else ``real``.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from skincal.errors import ConfigError, DatasetError, SkincalError

RECORDING_FILE = "recording.h5"
"""Name of the dataset file inside a recording folder."""
METHODS = ("mle", "online", "om")
"""Methods the benchmark runs on every recording (``online``: the streaming calibrator to the data's end;
``om``: the paper's, where the data allow it)."""
STREAMING = "online"
"""The method name under which the streaming calibrator's results are reported."""


def chosen_methods(om: bool = True, online: bool = True) -> tuple[str, ...]:
    """:data:`METHODS` less those switched off (the ``--no-om`` and ``--no-online`` options)."""
    on = {"om": om, STREAMING: online}
    return tuple(m for m in METHODS if on.get(m, True))


_GROUP = re.compile(r"_S\d+_(.+)$")


@dataclass(frozen=True)
class Recording:
    """One recording of the folder: its name (folder or file stem) and dataset path."""

    name: str
    path: Path


def find_recordings(folder: Path) -> list[Recording]:
    """The recordings of ``folder``, sorted by name: sub-folders holding :data:`RECORDING_FILE`, and
    ``.h5`` files directly in it; fewer than two is a :class:`ConfigError` (nothing to compare)."""
    folder = Path(folder)
    if not folder.is_dir():
        raise ConfigError(f"{folder}: not a folder of recordings")
    found = [Recording(p.name, p / RECORDING_FILE) for p in folder.iterdir() if (p / RECORDING_FILE).is_file()]
    found += [Recording(p.stem, p) for p in folder.glob("*.h5") if p.is_file()]
    if not found:
        raise ConfigError(f"{folder}: no recordings (folders with {RECORDING_FILE}, or .h5 files)")
    if len(found) < 2:
        raise ConfigError(
            f"{folder}: repeatability needs at least two recordings of one mount, found one (give the folder "
            "that holds the recordings)"
        )
    return sorted(found, key=lambda r: r.name)


def group_name(recording: str, unit: str, n_units: int) -> str:
    """The IMU a unit's recording belongs to: the folder name's part after the last ``_S<n>_`` for a
    one-unit recording named so, else the unit name."""
    match = _GROUP.search(recording)
    return match.group(1) if match and n_units == 1 else unit


def _moving_counts(dataset: Any) -> dict[str, int]:
    """Per unit, the IMU samples not inside a rest (static segment; the dataset's, or found as
    ``calibrate`` finds them) and inside the joint stream."""
    from skincal.calib.api import METHODS as SPECS
    from skincal.calib.api import segment_automatically
    from skincal.data.dataset import STATIC

    tagged = dataset
    if dataset.segments is None or len(dataset.segments) == 0:
        tagged, _ = segment_automatically(dataset, SPECS["mle"])
    tj = np.asarray(dataset.joint_states.t, dtype=float)
    out = {}
    for name, imu in dataset.imu.items():
        t = np.asarray(imu.t, dtype=float)
        moving = (t >= tj[0]) & (t <= tj[-1])
        seg = tagged.segments
        if seg is not None and len(seg) > 0:
            for t0, t1, kind in zip(seg.t_start, seg.t_end, seg.kind, strict=True):
                if kind == STATIC:
                    moving &= ~((t >= t0) & (t <= t1))
        out[name] = int(np.count_nonzero(moving))
    return out


def _unit_record(unit: Any) -> dict[str, Any]:
    """The figures of one calibrated unit (positions in mm, rotations as matrices, offsets in ms)."""
    from skincal.calib.position import is_weak
    from skincal.data.result import has_position

    imu = unit.imu
    offset = None if imu is None or imu.time_offset_s is None else 1e3 * float(imu.time_offset_s)
    offset_std = None if imu is None or imu.time_offset_std_s is None else 1e3 * float(imu.time_offset_std_s)
    p_std = None if unit.position_std_m is None else 1e3 * np.asarray(unit.position_std_m, dtype=float)
    positioned = has_position(unit)  # rests only: no position (written as null)
    r_std = None if unit.rotation_std_deg is None else np.asarray(unit.rotation_std_deg, dtype=float)
    return {
        "calibrated": True,
        "link": int(unit.pose.link),
        "observable": bool(unit.observable),
        "position_mm": 1e3 * np.asarray(unit.pose.p_link_su, dtype=float) if positioned else None,
        "R": np.asarray(unit.pose.R_link_su, dtype=float),
        "position_std_mm": p_std,
        "rotation_std_deg": r_std,
        "time_offset_ms": offset,
        "time_offset_std_ms": offset_std,
        "position_weak": positioned and is_weak(unit.position_std_m),
        "n_moving_samples": unit.extras.get("n_moving_samples"),
        "joint_rate": unit.extras.get("joint_rate"),
        "covariance_sandwich": _finite_or_none(unit.extras.get("covariance_sandwich")),
        "warnings": list(unit.warnings),
    }


def calibrate_recording(
    recording: Recording, methods: Sequence[str] = METHODS, workers: int = 1
) -> dict[str, Any]:
    """Calibrate one recording with each method; a method that fails (for one unit or all) is a
    failure with its reason, never an exception."""
    from skincal.calib import calibrate
    from skincal.data.hdf5 import read_dataset

    record: dict[str, Any] = {"recording": recording.name, "path": str(recording.path), "error": None}
    try:
        ds = read_dataset(recording.path)
    except SkincalError as exc:
        record["error"] = str(exc)
        return record
    record["simulated"] = bool(ds.truth)
    record["units"] = list(ds.units)
    record["groups"] = {u: group_name(recording.name, u, len(ds.units)) for u in ds.units}
    try:
        moving = _moving_counts(ds)
    except SkincalError:
        moving = {}
    record["moving_samples"] = moving
    record["methods"] = {}
    for method in methods:
        units: dict[str, Any] = {}
        try:
            result = _streamed(ds) if method == STREAMING else calibrate(ds, method, workers=workers)
        except SkincalError as exc:
            units = {u: {"calibrated": False, "reason": str(exc)} for u in ds.units}
        else:
            failed = dict(result.failed_units)
            for u in ds.units:
                if u in result.units:
                    units[u] = _unit_record(result.units[u])
                    n_mov = units[u]["n_moving_samples"]
                    total = moving.get(u)
                    units[u]["motion_kept"] = (
                        None if n_mov is None or not total else float(min(1.0, int(n_mov) / total))
                    )
                else:
                    units[u] = {"calibrated": False, "reason": failed.get(u, "no result")}
        record["methods"][method] = units
    return record


def _streamed(ds: Any) -> Any:
    """The streaming calibrator's result on ``ds`` replayed as fast as possible to the data's end
    (:func:`skincal.workflows.live.follow_dataset`, no stop at a target)."""
    from skincal.workflows.live import follow_dataset

    return follow_dataset(ds, speed=None, stop_at_target=False).result


def _finite_or_none(x: Any) -> Any:
    if x is None:
        return None
    arr = np.asarray(x, dtype=float)
    if arr.ndim == 0:
        return float(arr) if math.isfinite(float(arr)) else None
    return [_finite_or_none(v) for v in arr]


def weighted_mean(x: np.ndarray, s: np.ndarray) -> np.ndarray:
    """Inverse-variance weighted mean over rows of ``x`` ``(K, m)`` with std ``s`` (same shape; a NaN or
    zero std gives its row no weight)."""
    with np.errstate(all="ignore"):
        w = np.where(np.isfinite(s) & (s > 0), 1.0 / s**2, 0.0)
        return np.sum(w * x, axis=0) / np.sum(w, axis=0)


def normalised_spread(x: np.ndarray, std: list[Any]) -> np.ndarray:
    """RMS over recordings of ``(x_i - x_w) / s_i`` per axis: each estimate's deviation from the
    inverse-variance weighted mean ``x_w`` in its own reported std ``s_i`` (``x`` ``(K, m)``, ``std``
    ``K`` entries of ``m`` values; about 1 when the recordings agree within their std, whatever each
    one's size; NaN with fewer than 2). The weighted mean is fitted, so the expectation is
    ``sqrt((K - 1) / K)``, not 1."""
    x = np.asarray(x, dtype=float)
    m = x.shape[1] if x.ndim == 2 else 1
    if len(x) < 2 or any(s is None for s in std):
        return np.full(m, np.nan)
    x = x.reshape(len(x), m)
    s = np.asarray(std, dtype=float).reshape(x.shape)
    mean = weighted_mean(x, s)
    with np.errstate(all="ignore"):
        z = np.where(np.isfinite(s) & (s > 0), (x - mean) / s, np.nan)
        return np.sqrt(np.nanmean(z * z, axis=0))


def repeatability(entries: list[dict[str, Any]]) -> dict[str, Any]:
    """The spread across recordings of one group and method (module docstring); ``entries`` are the
    per-recording unit records (:func:`calibrate_recording`), each with ``recording``."""
    from scipy.spatial.transform import Rotation

    from skincal.kinematics.transforms import nearest_rotation

    ok = [e for e in entries if e.get("calibrated")]
    failures = [{"recording": e["recording"], "reason": e["reason"]} for e in entries if not e.get("calibrated")]
    out: dict[str, Any] = {"recordings": len(entries), "calibrated": len(ok), "failures": failures}
    links = [e["link"] for e in ok]
    out["links"] = {str(k): links.count(k) for k in sorted(set(links))}
    if not ok:
        return out
    link = max(set(links), key=lambda k: (links.count(k), -k))
    same = [e for e in ok if e["link"] == link]
    out["link"] = link
    out["on_link"] = len(same)
    out["observable"] = sum(1 for e in same if e["observable"])
    placed = [e for e in same if e["position_mm"] is not None]
    out["position_undetermined"] = len(same) - len(placed)
    out["position_weak"] = sum(1 for e in placed if e.get("position_weak"))
    P = np.array([e["position_mm"] for e in placed]).reshape(-1, 3)
    Rs = np.array([e["R"] for e in same])
    R_bar = nearest_rotation(Rs.sum(axis=0))  # the chordal L2 mean of the rotations
    delta = np.degrees(Rotation.from_matrix(Rs @ R_bar.T).as_rotvec())
    K, KP = len(same), len(P)
    p_std = P.std(axis=0, ddof=1) if KP > 1 else np.full(3, np.nan)
    r_std = delta.std(axis=0, ddof=1) if K > 1 else np.full(3, np.nan)
    pair_p = np.ptp(P, axis=0) if KP > 1 else np.full(3, np.nan)
    pair_dist = max((float(np.linalg.norm(P[i] - P[j])) for i in range(KP) for j in range(i)), default=math.nan)
    pair_angle = max(
        (float(np.degrees(Rotation.from_matrix(Rs[i].T @ Rs[j]).magnitude())) for i in range(K) for j in range(i)),
        default=math.nan,
    )

    def median_std(key: str, among: list[dict[str, Any]]) -> np.ndarray:
        rows = [e[key] for e in among if e[key] is not None]
        if not rows:
            return np.full(3, np.nan)
        arr = np.array(rows, dtype=float)
        with np.errstate(all="ignore"):
            return np.array([np.median(c[np.isfinite(c)]) if np.any(np.isfinite(c)) else np.nan for c in arr.T])

    p_rep, r_rep = median_std("position_std_mm", placed), median_std("rotation_std_deg", same)
    firm = [e for e in placed if not e.get("position_weak")]  # the same figures without the weak positions
    P_firm = np.array([e["position_mm"] for e in firm]).reshape(-1, 3)
    p_std_firm = P_firm.std(axis=0, ddof=1) if len(firm) > 1 else np.full(3, np.nan)
    with np.errstate(all="ignore"):
        p_ratio_firm = p_std_firm / median_std("position_std_mm", firm)
    with np.errstate(all="ignore"):
        p_ratio, r_ratio = p_std / p_rep, r_std / r_rep
    timed = [e for e in same if e["time_offset_ms"] is not None]
    offsets = [e["time_offset_ms"] for e in timed]
    t_z = normalised_spread(
        np.array(offsets, dtype=float).reshape(-1, 1), [e.get("time_offset_std_ms") for e in timed]
    )[0]
    kept = [e["motion_kept"] for e in same if e.get("motion_kept") is not None]
    p_z = normalised_spread(P, [e["position_std_mm"] for e in placed])
    r_z = normalised_spread(delta, [e["rotation_std_deg"] for e in same])
    out.update(
        {
            "position_mean_mm": _finite_or_none(P.mean(axis=0)),
            "position_std_mm": _finite_or_none(p_std),
            "position_pairwise_mm": _finite_or_none(pair_p),
            "position_pairwise_max_mm": _finite_or_none(pair_dist),
            "rotation_std_deg": _finite_or_none(r_std),
            "rotation_pairwise_max_deg": _finite_or_none(pair_angle),
            "median_reported_position_std_mm": _finite_or_none(p_rep),
            "median_reported_rotation_std_deg": _finite_or_none(r_rep),
            "position_spread_over_std": _finite_or_none(p_ratio),
            "position_std_firm_mm": _finite_or_none(p_std_firm),
            "position_spread_over_std_firm": _finite_or_none(p_ratio_firm),
            "rotation_spread_over_std": _finite_or_none(r_ratio),
            "position_deviation_rms_std": _finite_or_none(p_z),
            "rotation_deviation_rms_std": _finite_or_none(r_z),
            "time_offsets_ms": _finite_or_none(offsets),
            "time_offset_spread_ms": _finite_or_none(np.ptp(offsets)) if offsets else None,
            "time_offset_deviation_rms_std": _finite_or_none(t_z),
            "motion_kept": _finite_or_none(kept),
            "median_motion_kept": _finite_or_none(np.median(kept)) if kept else None,
            "per_recording": [
                {
                    "recording": e["recording"],
                    "position_mm": _finite_or_none(e["position_mm"]),
                    "rotation_from_mean_deg": _finite_or_none(d),
                    "position_std_mm": _finite_or_none(e["position_std_mm"]),
                    "rotation_std_deg": _finite_or_none(e["rotation_std_deg"]),
                    "time_offset_ms": _finite_or_none(e["time_offset_ms"]),
                    "time_offset_std_ms": _finite_or_none(e.get("time_offset_std_ms")),
                    "position_weak": bool(e.get("position_weak")),
                    "motion_kept": _finite_or_none(e.get("motion_kept")),
                    "joint_rate": e.get("joint_rate"),
                }
                for e, d in zip(same, delta, strict=True)
            ],
        }
    )
    return out


def session_name(recording: str, group: str) -> str:
    """The session a group's recording belongs to: the folder name without its IMU part (``V500_S3``
    of ``V500_S3_MPU9150``); a dataset holding several units is one session."""
    suffix = "_" + group
    return recording[: -len(suffix)] if recording.endswith(suffix) and len(recording) > len(suffix) else recording


def _difference(x: np.ndarray, s: np.ndarray) -> dict[str, Any]:
    """Weighted mean, std across sessions and the RMS deviation over its own std of paired
    differences ``x`` ``(K, m)`` with std ``s`` (:func:`normalised_spread`)."""
    return {
        "mean": _finite_or_none(weighted_mean(x, s)),
        "std": _finite_or_none(x.std(axis=0, ddof=1) if len(x) > 1 else np.full(x.shape[1], np.nan)),
        "deviation_rms_std": _finite_or_none(normalised_spread(x, list(s))),
    }


def paired(a_name: str, a: dict[str, Any], b_name: str, b: dict[str, Any]) -> dict[str, Any] | None:
    """Per session recorded by both groups ``a`` and ``b`` (their :func:`repeatability` blocks, same
    method, same link), ``a``'s estimate minus ``b``'s: position (link axes, mm; std the two combined,
    ``sqrt(s_a^2 + s_b^2)``), rotation (each one's rotation vector from its group's mean about the link
    axes, deg: the two mounts differ by a fixed rotation, which the means take out; small angles) and
    time offset (ms). What the robot's stream and the host did is common to
    both and cancels; a deviation over own std near 1 says each sensor's part of the std is honest.
    ``None`` when fewer than two sessions are shared."""
    if a.get("link") is None or a.get("link") != b.get("link"):
        return None
    ea = {session_name(e["recording"], a_name): e for e in a.get("per_recording", [])}
    eb = {session_name(e["recording"], b_name): e for e in b.get("per_recording", [])}
    both = sorted(set(ea) & set(eb))
    pos = [k for k in both if ea[k]["position_mm"] is not None and eb[k]["position_mm"] is not None]
    tim = [k for k in both if ea[k]["time_offset_ms"] is not None and eb[k]["time_offset_ms"] is not None]
    if len(both) < 2:
        return None

    def diff(keys: list[str], key: str, std_key: str) -> tuple[np.ndarray, np.ndarray]:
        x = np.array([np.subtract(ea[k][key], eb[k][key]) for k in keys], dtype=float).reshape(len(keys), -1)
        sa = np.array([np.nan if ea[k].get(std_key) is None else ea[k][std_key] for k in keys], dtype=float)
        sb = np.array([np.nan if eb[k].get(std_key) is None else eb[k][std_key] for k in keys], dtype=float)
        return x, np.hypot(sa, sb).reshape(x.shape)

    out: dict[str, Any] = {"groups": [a_name, b_name], "sessions": both}
    if len(pos) > 1:
        x, s = diff(pos, "position_mm", "position_std_mm")
        out["position_difference_mm"] = _difference(x, s)
    rot = [k for k in both if None not in (ea[k].get("rotation_from_mean_deg"), eb[k].get("rotation_from_mean_deg"))]
    if len(rot) > 1:  # each IMU's rotation from its own mean (the mounts differ by a fixed rotation)
        x, s = diff(rot, "rotation_from_mean_deg", "rotation_std_deg")
        out["rotation_difference_deg"] = _difference(x, s)
    if len(tim) > 1:
        x, s = diff(tim, "time_offset_ms", "time_offset_std_ms")
        scalar = _difference(x, s)
        out["time_offset_difference_ms"] = {k: v[0] if isinstance(v, list) else v for k, v in scalar.items()}
    return out


def run_realdata_benchmark(
    folder: Path,
    methods: Sequence[str] = METHODS,
    workers: int = 1,
    progress: Callable[[str], None] | None = None,
) -> dict[str, Any]:
    """Calibrate every recording of ``folder`` with each method and report the repeatability per
    IMU group (module docstring). A recording that cannot be read is listed under ``errors``."""
    recordings = find_recordings(folder)
    records = []
    for rec in recordings:
        if progress is not None:
            progress(rec.name)
        records.append(calibrate_recording(rec, methods, workers=workers))
    if all(r["error"] is not None for r in records):
        reasons = "; ".join(f"{r['recording']}: {r['error']}" for r in records[:3])
        raise DatasetError(f"{folder}: no readable recording ({reasons}{'; ...' if len(records) > 3 else ''})")
    groups: dict[str, dict[str, list[dict[str, Any]]]] = {}
    for r in records:
        if r["error"] is not None:
            continue
        for method, units in r["methods"].items():
            for unit, entry in units.items():
                groups.setdefault(r["groups"][unit], {}).setdefault(method, []).append(
                    {**entry, "recording": r["recording"]}
                )
    simulated = sorted({bool(r.get("simulated")) for r in records if r["error"] is None})
    reps = {name: {m: repeatability(v) for m, v in by_m.items()} for name, by_m in sorted(groups.items())}
    names = list(reps)
    return {
        "folder": str(folder),
        "data": "simulated" if simulated == [True] else "real" if simulated == [False] else "mixed",
        "methods": list(methods),
        "recordings": len(records),
        "errors": [{"recording": r["recording"], "reason": r["error"]} for r in records if r["error"] is not None],
        "groups": reps,
        "paired": [
            {"method": m, **pair}
            for i, a in enumerate(names)
            for b in names[i + 1 :]
            for m in methods
            if m in reps[a] and m in reps[b] and (pair := paired(a, reps[a][m], b, reps[b][m])) is not None
        ],
    }


def _fmt(values: Any, digits: int = 1) -> str:
    if values is None:
        return "-"
    if isinstance(values, list):
        return " ".join(_fmt(v, digits) for v in values)
    return f"{values:.{digits}f}"


def realdata_report(doc: dict[str, Any]) -> list[Any]:
    """Rich output of :func:`run_realdata_benchmark`'s document: a table per group (a row per figure, a
    column per method), a line per distinct failure reason (with its count) and per recording that could not be
    read (names, reasons and paths shown escaped)."""
    from rich.markup import escape
    from rich.table import Table

    from skincal.names import printable

    def shown(text: object) -> str:
        return escape(printable(str(text)))

    rows: list[tuple[str, Callable[[dict[str, Any]], str]]] = [
        ("recordings calibrated", lambda g: f"{g['calibrated']}/{g['recordings']}"),
        ("link (recordings on it)", lambda g: f"{g.get('link', '-')} ({g.get('on_link', 0)})"),
        ("position std x y z (mm)", lambda g: _fmt(g.get("position_std_mm"))),
        ("position pairwise x y z (mm)", lambda g: _fmt(g.get("position_pairwise_mm"))),
        ("position spread / median std", lambda g: _fmt(g.get("position_spread_over_std"))),
        ("position deviation / own std", lambda g: _fmt(g.get("position_deviation_rms_std"))),
        ("weakly determined positions", lambda g: str(g.get("position_weak", "-"))),
        ("without them: spread / median std", lambda g: _fmt(g.get("position_spread_over_std_firm"))),
        ("rotation std x y z (deg)", lambda g: _fmt(g.get("rotation_std_deg"), 2)),
        ("rotation pairwise max (deg)", lambda g: _fmt(g.get("rotation_pairwise_max_deg"), 2)),
        ("rotation spread / median std", lambda g: _fmt(g.get("rotation_spread_over_std"))),
        ("rotation deviation / own std", lambda g: _fmt(g.get("rotation_deviation_rms_std"))),
        ("motion kept (median)", lambda g: _fmt(g.get("median_motion_kept"), 2)),
        ("time offsets (ms)", lambda g: "-" if not g.get("time_offsets_ms") else
            f"{min(g['time_offsets_ms']):.0f}..{max(g['time_offsets_ms']):.0f}"),
        ("time offset deviation / own std", lambda g: _fmt(g.get("time_offset_deviation_rms_std"))),
        ("failures", lambda g: str(len(g["failures"]))),
    ]  # fmt: skip
    tables: list[Any] = []
    failures: list[str] = []
    for name, by_method in doc["groups"].items():
        # one table per IMU, a column per method: readable at any terminal width
        table = Table(title=f"{shown(name)}: repeatability across recordings ({doc['data']}): {shown(doc['folder'])}")
        table.add_column("figure")
        for method in by_method:
            table.add_column(method)
        for label, cell in rows:
            table.add_row(label, *(cell(g) for g in by_method.values()))
        tables.append(table)
        for method, g in by_method.items():
            for reason in sorted({str(f["reason"]) for f in g["failures"]}):
                count = sum(1 for f in g["failures"] if f["reason"] == reason)
                failures.append(f"{shown(name)} {method}: {count} x {shown(reason)}")
    parts: list[Any] = [*tables, *failures]
    for pair in doc.get("paired", []):
        a, b = (shown(n) for n in pair["groups"])
        text = f"paired {a} - {b} ({pair['method']}, {len(pair['sessions'])} sessions recorded by both):"
        if "position_difference_mm" in pair:
            d = pair["position_difference_mm"]
            text += (
                f" position mean {_fmt(d['mean'])} mm, std {_fmt(d['std'])} mm, dev/own std "
                f"{_fmt(d['deviation_rms_std'])};"
            )
        if "rotation_difference_deg" in pair:
            d = pair["rotation_difference_deg"]
            text += f" rotation std {_fmt(d['std'], 2)} deg, dev/own std {_fmt(d['deviation_rms_std'])};"
        if "time_offset_difference_ms" in pair:
            d = pair["time_offset_difference_ms"]
            text += (
                f" time offset mean {_fmt(d['mean'])} ms, std {_fmt(d['std'])} ms, dev/own std "
                f"{_fmt(d['deviation_rms_std'])}"
            )
        parts.append(text)
    for e in doc["errors"]:
        parts.append(f"[red]error[/]: {shown(e['recording'])}: {shown(e['reason'])}")
    return parts
