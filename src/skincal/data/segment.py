"""Automatic segmentation of a continuous recording into STATIC and single-joint DYNAMIC segments.

A recording without ``/segments`` (a ROS bag, a live skin recording) is cut from its joint stream:

* a joint sample is *at rest* when every joint speed, averaged over a centred window of
  ``smooth_s`` (a controller's velocity noise of a few mrad/s would otherwise break every rest
  into pieces), is below ``rest_velocity`` (rad/s);
* runs of rest shorter than ``bridge_s`` inside a motion are zero crossings of an oscillating
  joint (``qd_j = A sin(2 pi f t)`` passes 0 twice a period) and belong to the motion;
* a run of rest is trimmed to the samples whose configuration stays within ``static_tolerance``
  (rad, max-abs) of the run's median (a rest-to-rest move creeps in and out below any speed
  threshold: its speed grows as the square of time), then by ``static_margin_s`` at both ends
  (where the IMUs may still settle or lag); if it still lasts ``min_static_s`` it is a STATIC
  segment, else it is rejected;
* a run of motion in which exactly one joint moves (position range above ``min_excursion`` and
  peak speed above ``rest_velocity``; every other joint stays within ``min_excursion``) and lasting
  at least ``min_dynamic_s`` is a DYNAMIC segment of that joint; motions of several joints (moves
  between poses) and short ones are rejected, each with its reason;
* pose index: static joint configurations (mean ``q`` of a segment) closer than ``pose_tolerance``
  (max-abs, rad) to an earlier one share its index; a dynamic segment takes the index of the
  configuration it starts from.

Where the joint stream has a gap (no joint state for longer than ``gap_factor`` times its median
sampling interval), the accelerometers decide: the gap joins the rest around it only if the robot
was at rest on both sides in the same configuration and every unit's specific force stayed within
``accel_tolerance`` (m/s^2) of its value just before the gap; otherwise segments end at the gap.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from skincal.data.dataset import DYNAMIC, STATIC, Dataset, Segments
from skincal.errors import ConfigError, DatasetError
from skincal.kinematics.transforms import FloatArray


@dataclass(frozen=True)
class SegmentationConfig:
    """Thresholds of :func:`segment_dataset` (SI units: s, rad, rad/s, m/s^2).

    The defaults accept every preset protocol (:data:`skincal.protocol.PROTOCOLS`): its shortest rest
    (``fast``: 0.4 s) less the two ``static_margin_s`` leaves 0.3 s, above ``min_static_s`` = 0.25 s;
    its shortest excitation (``fast``: 1 s) is detected a little shorter (speeds below
    ``rest_velocity`` at both ends), above ``min_dynamic_s`` = 0.8 s. ``tests/data/test_segment.py`` checks
    both margins for every preset.
    """

    rest_velocity: float = 0.01
    min_static_s: float = 0.25
    min_dynamic_s: float = 0.8
    bridge_s: float = 0.1
    static_margin_s: float = 0.05
    static_tolerance: float = 1e-3
    min_excursion: float = 0.01
    pose_tolerance: float = 0.02
    gap_factor: float = 5.0
    accel_tolerance: float = 0.3
    accel_reference_s: float = 0.2
    smooth_s: float = 0.04

    def __post_init__(self) -> None:
        for name, value in self.__dict__.items():
            if not (np.isfinite(value) and value >= 0):
                raise ConfigError(f"segmentation: {name} must be a finite non-negative number, got {value!r}")
        if self.rest_velocity <= 0 or self.gap_factor <= 1:
            raise ConfigError("segmentation: rest_velocity (rad/s) must be > 0 and gap_factor > 1")


@dataclass(frozen=True)
class Rejected:
    """An interval that did not become a segment: ``t_start``/``t_end`` in s, the ``reason``
    (``too short``, ``multi-joint motion``, ``no joint moved``, ``joint states missing``) and the
    0-based ``joints`` that moved in it."""

    t_start: float
    t_end: float
    reason: str
    joints: tuple[int, ...] = ()
    detail: str = ""


@dataclass(frozen=True)
class SegmentationReport:
    """What :func:`segment_dataset` found and rejected, and the thresholds it used."""

    segments: Segments
    rejected: tuple[Rejected, ...]
    config: SegmentationConfig
    n_poses: int
    gaps_bridged: int = 0
    gaps_broken: int = 0
    notes: tuple[str, ...] = field(default_factory=tuple)

    @property
    def n_static(self) -> int:
        return int(np.sum(np.asarray(self.segments.kind) == STATIC))

    @property
    def n_dynamic(self) -> int:
        return int(np.sum(np.asarray(self.segments.kind) == DYNAMIC))


def _moving_average(x: FloatArray, t: FloatArray, window_s: float) -> FloatArray:
    """Centred moving average of ``x`` ``(N, n)`` over ``window_s`` seconds (in samples of the median
    interval of ``t``; shorter at the ends)."""
    dt = np.median(np.diff(t)) if t.shape[0] > 1 else 0.0
    half = int(round(0.5 * window_s / dt)) if dt > 0 else 0
    if half < 1:
        return x
    c = np.concatenate([np.zeros((1, x.shape[1])), np.cumsum(x, axis=0)])
    i = np.arange(x.shape[0])
    lo, hi = np.clip(i - half, 0, x.shape[0]), np.clip(i + half + 1, 0, x.shape[0])
    return (c[hi] - c[lo]) / (hi - lo)[:, None]


def _runs(label: np.ndarray, connected: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Start and end (inclusive) sample indices of the maximal runs of equal ``label`` ``(N,)``
    whose neighbours are ``connected`` ``(N-1,)``."""
    cut = (label[1:] != label[:-1]) | ~connected
    starts = np.concatenate([[0], np.flatnonzero(cut) + 1])
    ends = np.concatenate([starts[1:] - 1, [label.shape[0] - 1]])
    return starts, ends


def _imu_still(ds: Dataset, t_a: float, t_b: float, cfg: SegmentationConfig) -> bool:
    """True when every unit's specific force over ``(t_a, t_b)`` stays within ``accel_tolerance``
    of its median over ``[t_a - accel_reference_s, t_a]`` (no unit with samples there = unknown)."""
    seen = False
    for imu in ds.imu.values():
        t = np.asarray(imu.t)
        accel = np.asarray(imu.accel)
        ref = accel[(t >= t_a - cfg.accel_reference_s) & (t <= t_a)]
        inside = accel[(t > t_a) & (t < t_b)]
        ref = ref[np.all(np.isfinite(ref), axis=1)]
        inside = inside[np.all(np.isfinite(inside), axis=1)]
        if len(ref) == 0 or len(inside) == 0:
            continue
        seen = True
        if np.max(np.linalg.norm(inside - np.median(ref, axis=0), axis=1)) > cfg.accel_tolerance:
            return False
    return seen


def _gap_links(ds: Dataset, rest: np.ndarray, cfg: SegmentationConfig) -> tuple[np.ndarray, list[Rejected], int]:
    """``connected`` ``(N-1,)``: False across joint-stream gaps the IMUs do not show as rest."""
    t, q = ds.joint_states.t, ds.joint_states.q
    dt = np.diff(t)
    connected = np.ones(dt.shape[0], dtype=bool)
    rejected: list[Rejected] = []
    if dt.size == 0:
        return connected, rejected, 0
    gaps = np.flatnonzero(dt > cfg.gap_factor * np.median(dt))
    bridged = 0
    for g in gaps:  # few gaps; each a short look at the IMU streams
        t_a, t_b = float(t[g]), float(t[g + 1])
        same_pose = np.max(np.abs(q[g + 1] - q[g])) <= cfg.pose_tolerance
        if rest[g] and rest[g + 1] and same_pose and _imu_still(ds, t_a, t_b, cfg):
            bridged += 1
            continue
        connected[g] = False
        rejected.append(Rejected(t_a, t_b, "joint states missing", (),
                                 f"{t_b - t_a:.3g} s without joint states and the accelerometers show motion"))
    return connected, rejected, bridged


def segment_dataset(ds: Dataset, config: SegmentationConfig | None = None) -> tuple[Dataset, SegmentationReport]:
    """Find STATIC and single-joint DYNAMIC segments in ``ds`` (see the module docstring).

    Returns a copy of ``ds`` whose ``segments`` are the ones found (any previous ones are replaced)
    and the report. Raises :class:`DatasetError` when the joint stream is too short or no segment
    is found.
    """
    cfg = config or SegmentationConfig()
    t = np.asarray(ds.joint_states.t, dtype=float)
    q = np.asarray(ds.joint_states.q, dtype=float)
    qd = np.asarray(ds.joint_states.qd, dtype=float)
    if t.shape[0] < 3:
        raise DatasetError(f"segmentation: /joints/t has {t.shape[0]} samples, at least 3 needed")
    rest = np.all(np.abs(_moving_average(qd, t, cfg.smooth_s)) < cfg.rest_velocity, axis=1)
    connected, rejected, bridged = _gap_links(ds, rest, cfg)

    # Short rests inside a motion (zero crossings of a sine) become motion.
    starts, ends = _runs(rest, connected)
    dur = t[ends] - t[starts]
    inner = (starts > 0) & (ends < t.shape[0] - 1)
    inner &= connected[np.clip(starts - 1, 0, None)] & connected[np.clip(ends, None, connected.shape[0] - 1)]
    flip = rest[starts] & (dur < cfg.bridge_s) & inner
    if np.any(flip):
        idx = np.repeat(np.arange(starts.shape[0]), ends - starts + 1)
        rest = rest & ~flip[idx]
        starts, ends = _runs(rest, connected)
        dur = t[ends] - t[starts]

    # Per-run joint excursion and peak speed (vectorised over runs).
    q_range = np.maximum.reduceat(q, starts, axis=0) - np.minimum.reduceat(q, starts, axis=0)
    v_peak = np.maximum.reduceat(np.abs(qd), starts, axis=0)
    q_mean = np.add.reduceat(q, starts, axis=0) / (ends - starts + 1)[:, None]
    moving = (q_range > cfg.min_excursion) & (v_peak > cfg.rest_velocity)

    rows: list[tuple[float, float, int, int, np.ndarray]] = []  # t0, t1, kind, joint, q_config
    for r in range(starts.shape[0]):  # loop over runs (tens to hundreds), not samples
        t0, t1 = float(t[starts[r]]), float(t[ends[r]])
        if rest[starts[r]]:
            q_run = q[starts[r]:ends[r] + 1]
            still = np.flatnonzero(np.max(np.abs(q_run - np.median(q_run, axis=0)), axis=1) <= cfg.static_tolerance)
            if still.size == 0:
                still = np.array([0, q_run.shape[0] - 1])
            a = float(t[starts[r] + still[0]]) + cfg.static_margin_s
            b = float(t[starts[r] + still[-1]]) - cfg.static_margin_s
            if b - a >= cfg.min_static_s and b > a:
                rows.append((a, b, STATIC, -1, q_mean[r]))
            else:
                rejected.append(Rejected(t0, t1, "too short", (),
                                         f"rest of {t1 - t0:.3g} s < {cfg.min_static_s:g} s (+ 2 x margin)"))
            continue
        joints = tuple(int(j) for j in np.flatnonzero(moving[r]))
        if len(joints) > 1:
            rejected.append(Rejected(t0, t1, "multi-joint motion", joints,
                                     f"joints {', '.join(str(j + 1) for j in joints)} moved together"))
        elif not joints:
            rejected.append(Rejected(t0, t1, "no joint moved", (),
                                     f"speed above {cfg.rest_velocity:g} rad/s but no excursion > "
                                     f"{cfg.min_excursion:g} rad"))
        elif t1 - t0 < cfg.min_dynamic_s:
            rejected.append(Rejected(t0, t1, "too short", joints,
                                     f"motion of joint {joints[0] + 1} for {t1 - t0:.3g} s < {cfg.min_dynamic_s:g} s"))
        else:
            start_config = q[max(starts[r] - 1, 0)]
            rows.append((t0, t1, DYNAMIC, joints[0], start_config))
    if not rows:
        raise DatasetError(
            f"segmentation: no static or single-joint dynamic segment found ({len(rejected)} interval(s) rejected; "
            f"rest below {cfg.rest_velocity:g} rad/s)"
        )
    pose, n_poses = _cluster_poses(rows, cfg.pose_tolerance)
    segments = Segments(
        t_start=np.array([r[0] for r in rows]),
        t_end=np.array([r[1] for r in rows]),
        kind=np.array([r[2] for r in rows], dtype=np.int8),
        pose=pose,
        joint=np.array([r[3] for r in rows], dtype=np.int32),
    )
    report = SegmentationReport(
        segments=segments,
        rejected=tuple(sorted(rejected, key=lambda x: x.t_start)),
        config=cfg,
        n_poses=n_poses,
        gaps_bridged=bridged,
        gaps_broken=sum(1 for x in rejected if x.reason == "joint states missing"),
    )
    return replace(ds, segments=segments), report


def _cluster_poses(rows: list[tuple[float, float, int, int, FloatArray]], tol: float) -> tuple[np.ndarray, int]:
    """Pose index per segment: static configurations first (in time order), then each dynamic
    segment's start configuration matched to them (a new index when none is within ``tol``)."""
    centres: list[FloatArray] = []
    pose = np.full(len(rows), -1, dtype=np.int32)

    def match(config: FloatArray) -> int:
        if centres:
            dist = np.max(np.abs(np.asarray(centres) - config), axis=1)
            k = int(np.argmin(dist))
            if dist[k] <= tol:
                return k
        centres.append(config)
        return len(centres) - 1

    for kind in (STATIC, DYNAMIC):
        for i, row in enumerate(rows):
            if row[2] == kind:
                pose[i] = match(row[4])
    return pose, len(centres)
