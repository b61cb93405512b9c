"""How time-of-flight readings become obstacle points: :class:`PerceptionConfig` (used by
:mod:`skincal.perception.points`, :mod:`~skincal.perception.tracker` and :mod:`~skincal.perception.uncertainty`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from skincal.errors import ConfigError


@dataclass(frozen=True)
class PerceptionConfig:
    """How readings become obstacle points; SI units.

    Attributes:
        min_range, max_range: readings outside this window are dropped, m. Tracking reaches beyond
            the controller's notice distance (1 m) so that an approach speed is known when it matters.
        self_margin: drop points closer than this to the robot's own link capsules, m.
        window: per unit, the published position is the median of the last ``window`` valid points.
        max_age_s: readings older than this leave the median window, s.
        fov_deg: full cone angle of the sensor, deg (VL53L1X: 27).
        rate_window_s: the ray velocity is the least-squares slope over this span of readings, s.
        predict_s, coast_m: a point is extrapolated along its velocity at most ``predict_s`` after its
            filter instant and at most ``coast_m`` far (then it stands still), s and m.
        max_speed: velocity estimates are clipped to this, m/s.
        memory_s: a point no unit has seen for this long is forgotten, s.
        jump: a reading this far from a track's prediction starts a new track (the old one is
            remembered), and a reading passing a memory point by this much clears it, m.
        n_memory: memory points kept at most.
        assumed_position_std_m, assumed_rotation_std_deg: the pose std assumed, per link axis, for a unit
            whose calibration gives none (or leaves an axis undetermined), m and deg: a point's
            covariance is never silently zero (:mod:`skincal.perception.uncertainty`). 5 mm and 2 deg
            are a unit placed by hand from a drawing.
    """

    min_range: float = 0.01
    max_range: float = 1.5
    self_margin: float = 0.02
    window: int = 3
    max_age_s: float = 0.1
    fov_deg: float = 27.0
    rate_window_s: float = 0.1
    predict_s: float = 1.0
    coast_m: float = 0.3
    max_speed: float = 2.5
    memory_s: float = 1.5
    jump: float = 0.1
    n_memory: int = 4
    assumed_position_std_m: float = 0.005
    assumed_rotation_std_deg: float = 2.0

    def __post_init__(self) -> None:
        if not (0 <= self.min_range < self.max_range) or not np.isfinite(self.max_range):
            raise ConfigError(f"perception: need 0 <= min_range < max_range, got {self.min_range}, {self.max_range} m")
        if self.self_margin < 0 or self.max_age_s <= 0 or int(self.window) != self.window or self.window < 1:
            raise ConfigError("perception: self_margin >= 0 m, max_age_s > 0 s and an integer window >= 1 are needed")
        if not (0 < self.fov_deg < 180) or self.memory_s < self.max_age_s or self.rate_window_s <= 0:
            raise ConfigError("perception: need 0 < fov_deg < 180, memory_s >= max_age_s s and rate_window_s > 0 s")
        if min(self.predict_s, self.coast_m) < 0 or min(self.max_speed, self.jump) <= 0:
            raise ConfigError("perception: need predict_s >= 0 s, coast_m >= 0 m, max_speed > 0 m/s and jump > 0 m")
        if int(self.n_memory) != self.n_memory or self.n_memory < 0:
            raise ConfigError(f"perception: n_memory must be a non-negative integer, got {self.n_memory}")
        for name in ("assumed_position_std_m", "assumed_rotation_std_deg"):
            if not (np.isfinite(getattr(self, name)) and getattr(self, name) >= 0):
                raise ConfigError(f"perception: {name} must be a finite non-negative number, got {getattr(self, name)}")
