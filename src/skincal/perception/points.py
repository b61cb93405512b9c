"""Time-of-flight readings + calibrated unit poses + joint states -> obstacle points in the base frame.

Each reading ``r`` of unit ``u`` (pose ``T_link_su`` on link ``l``, the controller's *belief*, e.g. a
calibration result) at instant ``t`` becomes::

    p_base_obs = T_base_link(q(t)) T_link_su [0, 0, r, 1]^T

(the VL53L1X reports the nearest target in its 27 deg cone; the point is placed on the unit's +z
axis and carries the cone's lateral uncertainty ``spread = r sin(13.5 deg)``: the target lies on the
spherical cap of radius ``r`` about the unit). The streaming tracker with velocities and memory is
:mod:`skincal.perception.tracker`.
Joint states come at 1 kHz and readings at 50 Hz on their own clocks: ``q(t)`` is linearly
interpolated to each reading's instant (:func:`interpolate_joints`).

Validity (:func:`valid_ranges`): NaN (no target), outside ``[min_range, max_range]``, and readings
explained by the robot's own body (the point lies within ``self_margin`` of a link capsule).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from skincal.errors import ConfigError
from skincal.kinematics.chain import SerialChain
from skincal.kinematics.transforms import FloatArray
from skincal.perception.body import RobotBody, closest_on_segments
from skincal.perception.config import PerceptionConfig
from skincal.perception.uncertainty import SkinUncertainty, reading_covariance
from skincal.skin.pose import SkinUnitPose


@dataclass(frozen=True)
class ObstaclePoints:
    """Obstacle points in the base frame {0}.

    Attributes:
        positions: ``(K, 3)`` m.
        units: ``(K,)`` name of the unit that saw each point.
        stamps: ``(K,)`` reading instants, s (for filtered points: the newest reading used).
        ranges: ``(K,)`` the (filtered) range readings, m.
        velocities: ``(K, 3)`` estimated point velocities, m/s (zero: unknown or still).
        axes: ``(K, 3)`` unit +z axis (the ray) of the reading unit, base frame.
        spread: ``(K,)`` lateral uncertainty of the point across the ray, m (the cone: ``r sin(fov/2)``;
            0: on the axis).
        cov: ``(K, 3, 3)`` covariance of each position, base frame, m^2 (from the unit's pose
            covariance, the ToF noise and the joint noise: :mod:`skincal.perception.uncertainty`);
            zeros when unknown (the default when not given).
    """

    positions: FloatArray
    units: tuple[str, ...]
    stamps: FloatArray
    ranges: FloatArray
    velocities: FloatArray
    axes: FloatArray
    spread: FloatArray
    cov: FloatArray | None = None

    def __post_init__(self) -> None:
        if self.cov is None:
            object.__setattr__(self, "cov", np.zeros((np.shape(self.positions)[0], 3, 3)))

    @classmethod
    def empty(cls) -> ObstaclePoints:
        """No points."""
        return cls(np.zeros((0, 3)), (), np.zeros(0), np.zeros(0), np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0))

    @classmethod
    def still(cls, positions: ArrayLike) -> ObstaclePoints:
        """Still points ``(K, 3)`` m exactly where given (no velocity, no cone), e.g. for tests."""
        p = np.asarray(positions, dtype=float).reshape(-1, 3)
        K = p.shape[0]
        return cls(p, ("",) * K, np.zeros(K), np.zeros(K), np.zeros((K, 3)), np.zeros((K, 3)), np.zeros(K))

    def __len__(self) -> int:
        return int(self.positions.shape[0])


def interpolate_joints(t_joints: ArrayLike, q_joints: ArrayLike, t: ArrayLike) -> FloatArray:
    """Joint angles ``(M, n)`` at instants ``t`` ``(M,)`` s, linear between samples ``t_joints`` ``(N,)``.

    Instants outside the joint stream hold its first/last sample.
    """
    tj = np.asarray(t_joints, dtype=float)
    qj = np.asarray(q_joints, dtype=float)
    t = np.atleast_1d(np.asarray(t, dtype=float))
    if tj.ndim != 1 or qj.shape[:1] != tj.shape or np.any(np.diff(tj) <= 0):
        raise ConfigError("joint stream: t must be strictly increasing (N,) and q (N, n)")
    k = np.clip(np.searchsorted(tj, t, side="right") - 1, 0, max(tj.size - 2, 0))
    if tj.size == 1:
        return np.repeat(qj[:1], t.size, axis=0)
    w = np.clip((t - tj[k]) / (tj[k + 1] - tj[k]), 0.0, 1.0)[:, None]
    return (1.0 - w) * qj[k] + w * qj[k + 1]


def unit_rays(chain: SerialChain, pose: SkinUnitPose, q: ArrayLike) -> tuple[FloatArray, FloatArray]:
    """Origins and +z axes ``(M, 3)`` of a unit in the base frame at joint angles ``q`` ``(M, n)``:
    ``T_base_su = T_base_link(q) T_link_su``."""
    T = chain.link_frames(q, upto=chain.check_link(pose.link))[:, pose.link] @ pose.T_link_su
    return T[:, :3, 3], T[:, :3, 2]


def valid_ranges(ranges: ArrayLike, config: PerceptionConfig) -> np.ndarray:
    """``(M,)`` bool: the reading is finite and within ``[min_range, max_range]``."""
    r = np.asarray(ranges, dtype=float)
    with np.errstate(invalid="ignore"):
        return np.isfinite(r) & (r >= config.min_range) & (r <= config.max_range)


def not_self(body: RobotBody, q: FloatArray, points: FloatArray, margin: float) -> np.ndarray:
    """``(M,)`` bool: point ``m`` (base frame) is farther than ``margin`` m from the robot at ``q[m]``."""
    if points.shape[0] == 0:
        return np.zeros(0, dtype=bool)
    T = body.chain.link_frames(q)
    a, b = body.segments(T)  # (M, C, 3)
    c, _ = closest_on_segments(points[:, None, :], a, b)
    d = np.linalg.norm(points[:, None, :] - c, axis=-1) - body.radius
    return d.min(axis=1) > margin


def unit_points(
    chain: SerialChain,
    pose: SkinUnitPose,
    q: ArrayLike,
    ranges: ArrayLike,
    config: PerceptionConfig = PerceptionConfig(),
    body: RobotBody | None = None,
) -> tuple[FloatArray, np.ndarray]:
    """Points ``(M, 3)`` (base frame, m) of one unit's readings ``(M,)`` at joint angles ``(M, n)``, and
    their validity ``(M,)`` (range window and, when ``body`` is given, not the robot itself).
    Invalid rows hold NaN."""
    r = np.asarray(ranges, dtype=float)
    origin, axis = unit_rays(chain, pose, q)
    ok = valid_ranges(r, config)
    p = origin + np.where(ok, r, np.nan)[:, None] * axis
    if body is not None and np.any(ok):
        ok[ok] = not_self(body, chain.check_q(q)[ok], p[ok], config.self_margin)
        p[~ok] = np.nan
    return p, ok


def points_from_streams(
    chain: SerialChain,
    poses: Mapping[str, SkinUnitPose],
    t_joints: ArrayLike,
    q_joints: ArrayLike,
    tof: Mapping[str, tuple[ArrayLike, ArrayLike]],
    config: PerceptionConfig = PerceptionConfig(),
    body: RobotBody | None = None,
    uncertainty=None,
) -> ObstaclePoints:
    """Every valid reading of every unit as a point (no temporal filter), e.g. from a dataset.

    ``tof``: unit -> ``(t (M,) s, range (M,) m)`` (a :class:`skincal.data.dataset.TofStream` works via
    ``(s.t, s.range)``); units without a pose are an error. Joints ``(N,)``/``(N, n)`` are
    interpolated to each reading's instant. Points are sorted by stamp. Each point's ``cov`` comes from
    ``uncertainty`` (a :class:`skincal.perception.uncertainty.SkinUncertainty`; default: none known, the
    assumed pose std of ``config``).
    """
    unc = uncertainty if uncertainty is not None else SkinUncertainty()
    pos, units, stamps, rng_, axes, covs = [], [], [], [], [], []
    for name, (t, r) in tof.items():
        if name not in poses:
            raise ConfigError(f"ToF stream of unit '{name}' has no calibrated pose")
        t = np.asarray(t, dtype=float)
        q = interpolate_joints(t_joints, q_joints, t)
        p, ok = unit_points(chain, poses[name], q, r, config, body)
        axes.append(unit_rays(chain, poses[name], q[ok])[1])
        pos.append(p[ok])
        pose = poses[name]
        k = int(ok.sum())
        covs.append(
            reading_covariance(
                chain,
                chain.link_frames(q[ok]) if k else np.zeros((0, chain.n_joints + 1, 4, 4)),
                np.full(k, pose.link),
                np.broadcast_to(pose.R_link_su, (k, 3, 3)),
                np.asarray(r, dtype=float)[ok],
                p[ok],
                np.broadcast_to(unc.unit_covariances([name], config)[0], (k, 6, 6)),
                unc,
            )
        )
        stamps.append(t[ok])
        rng_.append(np.asarray(r, dtype=float)[ok])
        units += [name] * int(ok.sum())
    if not pos:
        return ObstaclePoints.empty()
    stamps_all = np.concatenate(stamps)
    order = np.argsort(stamps_all, kind="stable")
    names = tuple(np.array(units, dtype=object)[order])
    r_all = np.concatenate(rng_)[order]
    return ObstaclePoints(
        np.concatenate(pos)[order],
        names,
        stamps_all[order],
        r_all,
        np.zeros((r_all.size, 3)),
        np.concatenate(axes)[order],
        r_all * np.sin(np.deg2rad(config.fov_deg) / 2),
        np.concatenate(covs)[order],
    )
