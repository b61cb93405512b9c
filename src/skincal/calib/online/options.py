"""The streaming calibrator's parameters (:class:`OnlineOptions`) and what it says about a unit
(:class:`UnitStatus`, :func:`is_settled`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from skincal.errors import ConfigError
from skincal.kinematics.transforms import FloatArray
from skincal.skin.pose import SkinUnitPose


@dataclass(frozen=True)
class OnlineOptions:
    """Parameters of :class:`~skincal.calib.online.estimator.OnlineCalibrator` (SI units).

    Attributes:
        block_s: the joint stream is conditioned and absorbed in blocks of this length, s.
        margin_s: joint data each side of a block used to condition it (edge effects of the
            acceleration filter), s.
        lookback_s: joint data before a block used to condition it: the conditioning's decisions (stamps
            back on their grid, accelerations from positions or velocities, the noise levels) are made
            on this much of the stream, not on one short block, so that they do not change from block
            to block, s.
        max_delay_s: joint states may arrive out of order up to this late; a block is processed
            when the joint stream has reached its end plus ``margin_s + max_delay_s``.
        grid_hz: rate of the link-signal grid the units' samples are interpolated on, Hz.
        history_s: how long the grid (and each unit's per-chunk statistics, for :meth:`restart_unit`)
            is kept, s.
        align_s: span of a unit's stream (with motion) before its time offset is estimated, s.
        target_position_m, target_rotation_deg: std a unit must reach on every axis.
        links: candidate links (None: all of the chain's).
        accel_sigma, gyro_sigma: starting noise levels (m/s^2, rad/s); the fits' residual std take over.
        solve_every_s: each unit's estimate is refreshed during :meth:`update` after this much new data, s
            (its link decision, outlier gate and residual statistics follow it).
        consistency: the split check (:mod:`skincal.calib.online.split`) in the status and the result.
    """

    block_s: float = 1.0
    margin_s: float = 0.5
    lookback_s: float = 10.0
    max_delay_s: float = 0.5
    grid_hz: float = 125.0
    history_s: float = 60.0
    align_s: float = 10.0
    target_position_m: float = 3e-4
    target_rotation_deg: float = 0.05
    links: tuple[int, ...] | None = None
    accel_sigma: float = 0.05
    gyro_sigma: float = 0.005
    solve_every_s: float = 2.0
    consistency: bool = True

    def __post_init__(self) -> None:
        for name in ("block_s", "grid_hz", "history_s", "align_s", "target_position_m", "target_rotation_deg"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v > 0):
                raise ConfigError(f"online calibrator: {name} must be a positive number, got {v}")
        for name in ("margin_s", "max_delay_s", "lookback_s"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v >= 0):
                raise ConfigError(f"online calibrator: {name} must be a non-negative number, got {v}")
        if not isinstance(self.consistency, bool):
            raise ConfigError(f"online calibrator: consistency must be true or false, got {self.consistency!r}")
        if self.history_s < 2 * self.align_s:
            raise ConfigError("online calibrator: history_s must be at least twice align_s")


@dataclass(frozen=True)
class UnitStatus:
    """What the stream says about one unit now (see :class:`~skincal.calib.online.estimator.OnlineCalibrator`).

    Attributes:
        unit: name; link: the best link so far (None: undecided or no data); link_margin: cost of
            the second-best link over the best's (inf: no rival left, nan: nothing fitted).
        pose: the estimate (None: none yet); position_std_m ``(3,)`` m, rotation_std_deg ``(3,)``
            deg (link axes; inf: undetermined).
        samples, moving_samples: samples absorbed (on the best link), those while its link moved.
        missing: '' when the pose is determined, else why not.
        best_joint: 0-based joint whose excitation would help most (None: nothing to gain).
        reached: std within the target on every axis; t_last: newest absorbed instant, s.
        aligned: the unit's time offset is known (its samples are being absorbed).
    """

    unit: str
    link: int | None
    link_margin: float
    pose: SkinUnitPose | None
    position_std_m: FloatArray
    rotation_std_deg: FloatArray
    samples: int
    moving_samples: int
    missing: str
    best_joint: int | None
    reached: bool
    t_last: float
    aligned: bool


SETTLED_POSITION_M = 1e-3
SETTLED_ROTATION_DEG = 0.2
"""Std (every axis) from which a unit's estimate is stable enough to gate outliers and to be watched
for a move (looser than a calibration target: a unit that never reaches 0.3 mm is still watched)."""


def is_settled(status: UnitStatus) -> bool:
    """The unit's link is decided and its pose known to :data:`SETTLED_POSITION_M` / :data:`SETTLED_ROTATION_DEG`."""
    return bool(
        status.pose is not None
        and not status.missing
        and np.all(status.position_std_m <= SETTLED_POSITION_M)
        and np.all(status.rotation_std_deg <= SETTLED_ROTATION_DEG)
    )
