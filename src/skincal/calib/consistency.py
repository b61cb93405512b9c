"""Honest uncertainty by the data's own testimony: split a recording, calibrate each part, compare.

A calibrator's reported std is only as good as its noise model. Real recordings carry errors no model
names (a low-rate joint stream's interpolation, an IMU's unmodelled scale, a clock that steps); what
they do to the estimate shows when two independent parts of the same recording disagree more than
their std allow. Each unit's samples are split two ways:

* ``time``: the first and the second half of the recording (catches what changes over time: clocks,
  drifts, a unit that slipped);
* ``interleaved``: alternate windows of :data:`WINDOW_S` (both parts span the whole recording and
  see the same kinds of motion: catches model errors and residuals correlated beyond the model);
* ``excitation``: the calmer and the livelier half of the recording, windows of
  :data:`EXCITATION_WINDOW_S` ranked by how fast the unit's link turns (or, on a link that only
  translates, moves; for units on one rigid body without joint states, the IMU-only calibration, by
  how fast the gyroscopes turn): catches errors that grow or shrink with the motion (a low-rate joint stream
  that resolves slow motion but not fast, a delay that is not one constant offset).

Each part is calibrated with the same method on the unit's link (the full result's), and for each
split the pose difference ``d = x_A - x_B`` (position in the link frame, m; rotation
``rotvec(R_B R_A^T)`` about the link axes, rad) is compared with the parts' std::

    z_i = d_i / sqrt(s_A,i^2 + s_B,i^2),   chi2 = sum z_i^2   (~ chi-square with as many dof, if honest)

separately for the position and the rotation components of all splits (9 dof each). When a block's
chi2 exceeds its :data:`QUANTILE` quantile the data disagree with the reported std: each axis of the
block is inflated by its own observed excess ``max(1, sqrt(mean_splits z_i^2))`` (the disagreement
is usually along one axis, the lever arm along a tool's axis, say: one factor for the block would
inflate the others and not that one enough) and the unit is warned; honest data are left alone (a
false inflation in 1 % of units). The result carries a
``consistency`` block per unit (``docs/interfaces.md``).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation
from scipy.stats import chi2 as chi2_dist

from skincal.data.dataset import Dataset, ImuStream, TofStream
from skincal.data.result import REFERENCE_LINK, CalibrationResult, UnitResult
from skincal.kinematics.transforms import FloatArray
from skincal.parallel import can_fork, imap

WINDOW_S = 4.0
"""Length of the alternate windows of the ``interleaved`` split, s."""
EXCITATION_WINDOW_S = 2.0
"""Length of the windows the ``excitation`` split ranks by the link's motion, s."""
EXCITATION_RATE_HZ = 50.0
"""The joint stream is thinned to at most this rate to rank the windows."""
PART_STD_LIMIT = 10.0
"""A part whose std of a component exceeds this many times the full result's does not determine it
(a half of the data gives about 1.4 times the std): that component is not compared."""
QUANTILE = 0.99
"""A block's chi-square beyond this quantile of its distribution counts as disagreement."""
Z_NAMED = 3.0
"""Components whose split difference exceeds this many std are named."""
SPLITS = ("time", "interleaved", "excitation")
AXES = ("x", "y", "z")

Refit = Callable[[Dataset, dict[str, int]], CalibrationResult]
"""``refit(part, links)``: the method run on a part dataset with the units' links given."""


@dataclass(frozen=True)
class Consistency:
    """One unit's split check (module docstring).

    Attributes:
        chi2_position, chi2_rotation: chi-square of the position / rotation components over both splits.
        dof_position, dof_rotation: their degrees of freedom (finite components compared).
        inflation_position, inflation_rotation: the block's excess ``sqrt(chi2 / dof)`` when chi2 is beyond
            its quantile (1: consistent).
        axes_position, axes_rotation: ``(3,)`` the factors the full result's std were multiplied by,
            per link-frame axis (all 1 when the block is consistent).
        disagrees: what disagrees, e.g. ``"time: position z 12.3 mm (4.1 std)"``.
        failed: splits whose parts could not be calibrated, with why.
        chi2_time_offset, dof_time_offset, inflation_time_offset: the same for the unit's time offset, where
            the parts estimate one of their own (the streaming calibrator's; None: not compared).
    """

    chi2_position: float
    chi2_rotation: float
    dof_position: int
    dof_rotation: int
    inflation_position: float
    inflation_rotation: float
    disagrees: tuple[str, ...]
    failed: tuple[str, ...]
    axes_position: tuple[float, float, float] = (1.0, 1.0, 1.0)
    axes_rotation: tuple[float, float, float] = (1.0, 1.0, 1.0)
    chi2_time_offset: float | None = None
    dof_time_offset: int = 0
    inflation_time_offset: float = 1.0

    def to_json(self) -> dict[str, Any]:
        offset = {} if self.chi2_time_offset is None else {
            "chi2_time_offset": self.chi2_time_offset, "dof_time_offset": self.dof_time_offset,
            "inflation_time_offset": self.inflation_time_offset,
        }  # fmt: skip
        return offset | {
            "splits": list(SPLITS),
            "chi2_position": self.chi2_position,
            "dof_position": self.dof_position,
            "chi2_rotation": self.chi2_rotation,
            "dof_rotation": self.dof_rotation,
            "inflation_position": self.inflation_position,
            "inflation_rotation": self.inflation_rotation,
            "inflation_position_axes": list(self.axes_position),
            "inflation_rotation_axes": list(self.axes_rotation),
            "disagrees": list(self.disagrees),
            "failed": list(self.failed),
        }


def lively_windows(dataset: Dataset, link: int) -> np.ndarray:
    """``(W,)`` True on the :data:`EXCITATION_WINDOW_S` windows (from the joint stream's start) in
    which link ``link`` moves more than in the median window: its mean angular speed, or its
    origin's mean speed when no joint up to it turns (base frame, from the joint stream's ``q, qd``
    thinned to :data:`EXCITATION_RATE_HZ`)."""
    return lively_windows_of(dataset, [link])[link]


def lively_windows_of(dataset: Dataset, links: Iterable[int]) -> dict[int, np.ndarray]:
    """:func:`lively_windows` of each of ``links``, from one forward recursion up to the furthest."""
    j = dataset.joints
    assert j is not None
    wanted = sorted(set(int(k) for k in links))
    if not wanted:
        return {}
    t = np.asarray(j.t, dtype=float)
    step = max(1, int(round(1.0 / (EXCITATION_RATE_HZ * max(float(np.median(np.diff(t))), 1e-9))))) if t.size > 1 else 1
    q, qd = np.asarray(j.q, dtype=float)[::step], np.asarray(j.qd, dtype=float)[::step]
    motion = dataset.chain.link_motion(q, qd, np.zeros_like(q), upto=wanted[-1])
    index = np.floor((t[::step] - t[0]) / EXCITATION_WINDOW_S).astype(int)
    n = int(index.max()) + 1 if index.size else 0
    count = np.bincount(index, minlength=n)
    out: dict[int, np.ndarray] = {}
    for link in wanted:
        rotates = bool(dataset.chain.revolute[:link].any())
        speed = np.linalg.norm((motion.omega if rotates else motion.v_origin)[:, link], axis=1)
        total = np.bincount(index, weights=speed, minlength=n)
        score = np.where(count > 0, total / np.maximum(count, 1), 0.0)
        out[link] = score > np.median(score) if n else np.zeros(0, dtype=bool)
    return out


def lively_windows_from_gyro(dataset: Dataset) -> np.ndarray:
    """``(W,)`` True on the :data:`EXCITATION_WINDOW_S` windows (from :func:`recording_span`'s start) in
    which the units' mean gyroscope speed ``|w|`` exceeds the median window's: the ``excitation`` split
    of units on one rigid body without joint states (the IMU-only calibration, all on ``link 0``)."""
    t0, _ = recording_span(dataset)
    streams = [st for st in dataset.imu.values() if st.gyro is not None and len(st.t)]
    if not streams:
        return np.zeros(0, dtype=bool)
    t = np.concatenate([np.asarray(st.t, dtype=float) for st in streams])
    speed = np.concatenate([np.linalg.norm(st.gyro, axis=1) for st in streams])
    index = np.maximum(np.floor((t - t0) / EXCITATION_WINDOW_S).astype(int), 0)
    total, count = np.bincount(index, weights=speed), np.bincount(index)
    score = np.where(count > 0, total / np.maximum(count, 1), 0.0)
    return score > np.median(score)


def lively_of(dataset: Dataset, links: Iterable[int]) -> dict[int, np.ndarray]:
    """The ``excitation`` split's windows per link: :func:`lively_windows_of` from the joint stream, or
    without joint states (units on one rigid body, all on ``link 0``) :func:`lively_windows_from_gyro`."""
    if dataset.joints is not None:
        return lively_windows_of(dataset, links)
    return {REFERENCE_LINK: lively_windows_from_gyro(dataset)}


def recording_span(dataset: Dataset) -> tuple[float, float]:
    """``(t0, t1)`` of the recording, s: the joint stream's, else the IMU streams' first and last stamps."""
    if dataset.joints is not None and len(dataset.joints.t):
        return float(dataset.joints.t[0]), float(dataset.joints.t[-1])
    stamps = [np.asarray(s.t, dtype=float) for s in dataset.imu.values() if len(s.t)]
    if not stamps:
        return 0.0, 0.0
    return float(min(t[0] for t in stamps)), float(max(t[-1] for t in stamps))


def part_masks(
    t: FloatArray, t0: float, t1: float, lively: np.ndarray | None = None
) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """``{split: (mask_A, mask_B)}`` over stamps ``t`` ``(M,)`` for a recording spanning ``[t0, t1]`` s;
    ``lively``: :func:`lively_windows` of the unit's link (no ``excitation`` split without it)."""
    mid = 0.5 * (t0 + t1)
    window = np.floor((t - t0) / WINDOW_S).astype(int) % 2 == 0
    out = {"time": (t < mid, t >= mid), "interleaved": (window, ~window)}
    if lively is not None and lively.size:
        live = lively[np.clip(np.floor((t - t0) / EXCITATION_WINDOW_S).astype(int), 0, lively.size - 1)]
        out["excitation"] = (~live, live)
    return out


def _part(
    dataset: Dataset, split: str, side: int, links: dict[str, int], lively: dict[int, np.ndarray] | None = None
) -> Dataset:
    """``dataset`` with every unit's IMU (and ToF) samples restricted to one part of ``split``
    (``links``: each unit's link, which the ``excitation`` split ranks the windows by; ``lively``: their
    :func:`lively_windows_of`, when already computed)."""
    t0, t1 = recording_span(dataset)
    if split != "excitation":
        lively = {}
    elif lively is None:
        lively = lively_of(dataset, links.values())

    def mask(name: str, t: FloatArray) -> np.ndarray:
        masks = part_masks(np.asarray(t, dtype=float), t0, t1, lively.get(links.get(name, -1)))
        return masks[split][side] if split in masks else np.zeros(len(t), dtype=bool)

    imu: dict[str, ImuStream] = {}
    for name, s in dataset.imu.items():
        m = mask(name, s.t)
        imu[name] = ImuStream(s.t[m], s.accel[m], None if s.gyro is None else s.gyro[m])
    tof: dict[str, TofStream] = {}
    for name, r in dataset.tof.items():
        m = mask(name, r.t)
        tof[name] = TofStream(r.t[m], r.range[m])
    return replace(dataset, imu=imu, tof=tof)


def pose_vector(unit: UnitResult) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Position (m), rotation matrix, and the 6 std (m, rad; NaN: undetermined) of a unit result."""
    def std(x: FloatArray | None, scale: float) -> FloatArray:
        return np.full(3, np.nan) if x is None else np.asarray(x, dtype=float) * scale

    s = np.r_[std(unit.position_std_m, 1.0), std(unit.rotation_std_deg, np.pi / 180.0)]
    s[~np.isfinite(s) | (s <= 0)] = np.nan
    return np.asarray(unit.pose.p_link_su, dtype=float), np.asarray(unit.pose.R_link_su, dtype=float), s


def compare(
    parts: dict[str, tuple[UnitResult, UnitResult]], full: UnitResult | None = None
) -> tuple[FloatArray, list[str]]:
    """``(len(SPLITS), 6)`` normalised differences ``z`` per split (rows in :data:`SPLITS` order; NaN where not
    determined) and the components beyond :data:`Z_NAMED` std, named. With the ``full`` result, a
    component is compared only where both parts determine it to within :data:`PART_STD_LIMIT` times
    the full result's std (a part without the motion that determines it, such as the calm half of a
    recording for a unit only one joint turns, measures nothing there)."""
    z = np.full((len(SPLITS), 6), np.nan)
    limit = None if full is None else PART_STD_LIMIT * pose_vector(full)[2]
    named: list[str] = []
    for k, split in enumerate(SPLITS):
        if split not in parts:
            continue
        a, b = parts[split]
        if a.pose.link != b.pose.link or not (a.observable and b.observable):
            continue
        pa, Ra, sa = pose_vector(a)
        pb, Rb, sb = pose_vector(b)
        d = pose_difference(pa, Ra, pb, Rb)
        z[k], names = normalised_difference(split, d, sa, sb, limit)
        named += names
    return z, named


def pose_difference(pa: FloatArray, Ra: FloatArray, pb: FloatArray, Rb: FloatArray) -> FloatArray:
    """``(6,)`` pose B minus pose A: position ``pb - pa`` (m) then the rotation vector of ``Rb Ra^T`` (rad),
    both in the link frame."""
    return np.r_[pb - pa, Rotation.from_matrix(Rb @ Ra.T).as_rotvec()]


def normalised_difference(
    split: str, d: FloatArray, sa: FloatArray, sb: FloatArray, limit: FloatArray | None = None
) -> tuple[FloatArray, list[str]]:
    """``(6,)`` normalised difference ``z = d / sqrt(sa^2 + sb^2)`` of two parts' poses (``d`` position m
    then rotation vector rad, link frame; ``sa``, ``sb`` their std) and the components of ``split`` beyond
    :data:`Z_NAMED` std, named; NaN where a part's std exceeds ``limit`` (``(6,)``, None: no limit)."""
    scale = np.sqrt(sa**2 + sb**2)
    with np.errstate(divide="ignore", invalid="ignore"):
        z = np.where(scale > 0, d / scale, np.nan)  # no std on a component (held by a prior): not compared
    if limit is not None:
        with np.errstate(invalid="ignore"):
            z[~((sa <= limit) & (sb <= limit))] = np.nan
    named = []
    for i in np.flatnonzero(np.abs(np.nan_to_num(z)) > Z_NAMED):
        if i < 3:
            what, size = "position", f"{d[i] * 1e3:+.1f} mm"
        else:
            what, size = "rotation", f"{np.degrees(d[i]):+.2f} deg"
        named.append(f"{split}: {what} {AXES[i % 3]} {size} ({abs(z[i]):.1f} std)")
    return z, named


def block_inflation(z: FloatArray) -> tuple[float, int, float]:
    """``(chi2, dof, inflation)`` of normalised differences ``z`` (any shape; NaN ignored): inflation
    ``sqrt(chi2 / dof)`` when chi2 exceeds its :data:`QUANTILE` quantile, else 1."""
    v = z[np.isfinite(z)]
    dof = int(v.size)
    c2 = float(np.sum(v * v))
    if dof == 0 or c2 <= chi2_dist.ppf(QUANTILE, dof):
        return c2, dof, 1.0
    return c2, dof, float(np.sqrt(c2 / dof))


def axis_inflation(z: FloatArray, block: float) -> tuple[float, float, float]:
    """Per-axis factors of a block of normalised differences ``z`` ``(splits, 3)`` (NaN ignored):
    ``max(1, sqrt(mean_splits z_i^2))`` when the block is inflated (``block > 1``), else all 1."""
    if block <= 1.0:
        return (1.0, 1.0, 1.0)
    out = []
    for i in range(3):
        v = z[:, i][np.isfinite(z[:, i])]
        out.append(max(1.0, float(np.sqrt(np.mean(v * v)))) if v.size else 1.0)
    return (out[0], out[1], out[2])


def judge(z: FloatArray, named: list[str], failed: list[str], z_offset: FloatArray | None = None) -> Consistency:
    """The :class:`Consistency` of normalised differences ``z`` ``(len(SPLITS), 6)`` (NaN: not compared),
    with the components ``named`` beyond :data:`Z_NAMED` std and the parts that ``failed``; ``z_offset``
    ``(len(SPLITS),)`` those of the time offset, where the parts estimate their own (None: not compared)."""
    cp, dp, fp = block_inflation(z[:, :3])
    cr, dr, fr = block_inflation(z[:, 3:])
    ap, ar = axis_inflation(z[:, :3], fp), axis_inflation(z[:, 3:], fr)
    if z_offset is None:
        return Consistency(cp, cr, dp, dr, fp, fr, tuple(named), tuple(failed), ap, ar)
    ct, dt, ft = block_inflation(z_offset)
    return Consistency(cp, cr, dp, dr, fp, fr, tuple(named), tuple(failed), ap, ar, ct, dt, ft)


ANOTHER_BASIN = "its fit is another basin"
"""The words of a part not compared because its fit lies far from the whole's (a streamed part: its rotation
30 deg or more away, :data:`~skincal.calib.online.split.FAR_RAD`); :func:`apply` warns of it."""


def apply(unit: UnitResult, c: Consistency) -> UnitResult:
    """``unit`` with its split check ``c`` (``extras["consistency"]``), its std and pose covariance inflated
    per axis where the parts disagree, and a warning saying so; a part whose fit fell into another basin (not
    compared) is warned of too: the data do not single out one pose."""
    fp, fr, ap, ar = c.inflation_position, c.inflation_rotation, c.axes_position, c.axes_rotation
    warnings = list(unit.warnings)
    basins = [f for f in c.failed if ANOTHER_BASIN in f]
    if basins:
        warnings.append(f"a part of the recording fits a pose far from the whole's ({'; '.join(basins[:2])}): the "
                        "data may not single out one pose; check the rotation against another recording")  # fmt: skip
    if fp > 1.0 or fr > 1.0:
        def said(what: str, f: tuple[float, float, float]) -> str:
            return f"{what} " + " ".join(f"{a} x{v:.1f}" for a, v in zip(AXES, f, strict=True))

        parts = [said("position", ap)] * (fp > 1.0) + [said("rotation", ar)] * (fr > 1.0)
        which = f" ({'; '.join(c.disagrees[:3])})" if c.disagrees else " (jointly, no component alone)"
        warnings.append(
            f"independent parts of the recording disagree beyond their std{which}: std inflated by the observed "
            "excess, " + ", ".join(parts)
        )
    imu = unit.imu
    if imu is not None and imu.time_offset_std_s is not None and c.inflation_time_offset > 1.0:
        imu = replace(imu, time_offset_std_s=imu.time_offset_std_s * c.inflation_time_offset)
        warnings.append(f"independent parts of the recording disagree on the time offset beyond its std: std "
                        f"inflated x{c.inflation_time_offset:.1f}")  # fmt: skip
    pos = None if unit.position_std_m is None else np.asarray(unit.position_std_m, dtype=float) * np.asarray(ap)
    rot = None if unit.rotation_std_deg is None else np.asarray(unit.rotation_std_deg, dtype=float) * np.asarray(ar)
    extras = {**unit.extras, "consistency": c.to_json()}
    cov = unit.pose_covariance
    if cov is not None and (fp > 1.0 or fr > 1.0):
        T = np.diag([*ap, *ar])
        cov = T @ cov @ T
    return replace(unit, position_std_m=pos, rotation_std_deg=rot, warnings=tuple(warnings), extras=extras,
                   pose_covariance=cov, imu=imu)  # fmt: skip


def check(
    dataset: Dataset, result: CalibrationResult, refit: Refit, workers: int = 1,
    done: Callable[[], None] | None = None,
) -> CalibrationResult:  # fmt: skip
    """``result`` with each unit's :class:`Consistency` (``extras["consistency"]``) and its std inflated
    where the parts disagree (module docstring); ``refit`` runs the method on each part. With ``workers``
    > 1 (and :func:`~skincal.parallel.can_fork`) the six parts are calibrated in forked processes (the same
    results: each part's fit depends on its data and seed only); ``done()`` is called here once per unit of
    each part as the part's result comes (a progress bar's step)."""
    if not result.units:
        return result
    links = {name: int(u.pose.link) for name, u in result.units.items() if u.observable}
    if not links or (dataset.joints is None and set(links.values()) != {REFERENCE_LINK}):
        return result  # without joint states only units on one rigid body (the IMU-only fit) can be split
    outcomes: dict[str, dict[str, list[UnitResult | None]]] = {u: {} for u in links}
    errors: dict[str, list[str]] = {u: [] for u in links}
    try:  # the excitation split's windows, once for both sides (a failure: each part's own, below)
        lively: dict[int, np.ndarray] | None = lively_of(dataset, links.values())
    except Exception:  # noqa: BLE001
        lively = None
    jobs = [(split, side) for split in SPLITS for side in (0, 1)]

    def one(job: tuple[str, int]) -> tuple[CalibrationResult | None, str]:
        try:
            return refit(_part(dataset, job[0], job[1], links, lively), links), ""
        except Exception as exc:  # noqa: BLE001 - a part that cannot be calibrated is a finding, not a crash
            return None, str(exc)

    n = min(int(workers), len(jobs)) if can_fork() else 1
    for k, (part, failure) in imap(one, jobs, n, fork=True, one_blas_thread=True):
        split, side = jobs[k]
        if done is not None:
            for _ in links:
                done()
        if part is None:
            for u in links:
                errors[u].append(f"{split} part {side + 1}: {failure}")
        for u in links:
            got = None if part is None else part.units.get(u)
            if part is not None and got is None:
                reason = part.failed_units.get(u, "not calibrated")
                errors[u].append(f"{split} part {side + 1}: {reason}")
            outcomes[u].setdefault(split, []).append(got)
    units = dict(result.units)
    for name in links:
        pairs = {s: (v[0], v[1]) for s, v in outcomes[name].items() if v[0] is not None and v[1] is not None}
        z, named = compare(pairs, result.units[name])  # type: ignore[arg-type]
        units[name] = apply(units[name], judge(z, named, errors[name]))
    return replace(result, units=units)
