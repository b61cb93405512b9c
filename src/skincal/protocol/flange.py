"""Flange tasks: a reference ``x(t)``, ``xd(t)`` for the robot's flange (paper Sec. V-C).

The flange tracks a circle of radius 0.1 m in the vertical y-z plane in front of the robot starting
where the flange is at the start (period 5 s, 0.126 m/s), or a pick-and-place cycle (:class:`PickPlace`:
down to a pick point 0.1 m below and 0.15 m to the right, up, across, down to the place point 0.15 m to
the left, up, back; minimum-jerk legs at 0.25 m/s peak, 0.3 s dwell at pick and place). Base frame, m, s.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np
from numpy.typing import ArrayLike

from skincal.errors import ConfigError
from skincal.kinematics.transforms import FloatArray
from skincal.names import printable

TASKS = ("circle", "pick-place")


class Task(Protocol):
    """A flange reference: ``at(t) -> (position (M, 3) m, velocity (M, 3) m/s)`` at instants ``t`` ``(M,)`` s."""

    def at(self, t: ArrayLike) -> tuple[FloatArray, FloatArray]: ...


@dataclass(frozen=True)
class Circle:
    """Flange reference ``x(t) = center + radius (u cos(w t) + v sin(w t))``, ``w = 2 pi / period``.

    ``center``, ``u``, ``v``: ``(3,)`` base frame (``u``, ``v`` orthonormal), m; ``period`` s.
    """

    center: FloatArray
    radius: float
    u: FloatArray
    v: FloatArray
    period: float

    @classmethod
    def through(cls, start: ArrayLike, radius: float = 0.1, period: float = 5.0, plane: str = "yz") -> Circle:
        """The circle whose ``t = 0`` point is ``start`` ``(3,)`` m, in the vertical ``yz`` or flat ``xy`` plane."""
        axes = {
            "yz": (np.array([0.0, 1.0, 0.0]), np.array([0.0, 0.0, 1.0])),
            "xy": (np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0])),
        }
        if plane not in axes:
            raise ConfigError(f"circle plane must be 'yz' or 'xy', got '{plane}'")
        if radius <= 0 or period <= 0:
            raise ConfigError(f"circle needs radius > 0 m and period > 0 s, got {radius}, {period}")
        u, v = axes[plane]
        return cls(np.asarray(start, dtype=float) - radius * u, float(radius), u, v, float(period))

    def at(self, t: ArrayLike) -> tuple[FloatArray, FloatArray]:
        """Position ``(M, 3)`` m and velocity ``(M, 3)`` m/s at instants ``t`` ``(M,)`` s."""
        t = np.atleast_1d(np.asarray(t, dtype=float))[:, None]
        w = 2 * np.pi / self.period
        c, s = np.cos(w * t), np.sin(w * t)
        return self.center + self.radius * (c * self.u + s * self.v), self.radius * w * (-s * self.u + c * self.v)


@dataclass(frozen=True)
class PickPlace:
    """A pick-and-place cycle through ``points`` ``(K, 3)`` (base frame, m; the first is the start and the
    cycle returns to it), each leg a minimum-jerk (quintic) move of ``durations`` ``(K,)`` s, with
    ``dwell`` s at the points flagged in ``dwell_at`` ``(K,)`` (after arriving). Periodic."""

    points: FloatArray
    durations: FloatArray
    dwell_at: np.ndarray
    dwell: float

    @classmethod
    def around(
        cls, start: ArrayLike, width: float = 0.15, depth: float = 0.1, peak_speed: float = 0.25, dwell: float = 0.3
    ) -> PickPlace:
        """The cycle of the module docstring around ``start`` ``(3,)`` m: pick at ``-width`` in y, place at
        ``+width``, both ``depth`` below; leg durations from ``peak_speed`` (a quintic's peak speed is
        1.875 times its mean)."""
        s = np.asarray(start, dtype=float)
        dy, dz = np.array([0.0, width, 0.0]), np.array([0.0, 0.0, depth])
        pts = np.array([s, s - dy, s - dy - dz, s - dy, s + dy, s + dy - dz, s + dy])
        nxt = np.roll(pts, -1, axis=0)
        L = np.linalg.norm(nxt - pts, axis=1)
        dur = np.maximum(1.875 * L / peak_speed, 0.2)
        return cls(pts, dur, np.array([False, False, True, False, False, True, False]), float(dwell))

    @property
    def period(self) -> float:
        """Length of one cycle, s."""
        return float(self.durations.sum() + self.dwell * self.dwell_at.sum())

    def at(self, t: ArrayLike) -> tuple[FloatArray, FloatArray]:
        """Position ``(M, 3)`` m and velocity ``(M, 3)`` m/s at instants ``t`` ``(M,)`` s."""
        t = np.mod(np.atleast_1d(np.asarray(t, dtype=float)), self.period)
        seg = self.durations + self.dwell * self.dwell_at  # each point's dwell, then its leg
        starts = np.concatenate([[0.0], np.cumsum(seg)[:-1]])
        k = np.clip(np.searchsorted(starts, t, side="right") - 1, 0, len(seg) - 1)
        tau = t - starts[k] - self.dwell * self.dwell_at[k]
        s = np.clip(tau / self.durations[k], 0.0, 1.0)
        blend = s**3 * (10 - 15 * s + 6 * s * s)
        rate = np.where((s > 0) & (s < 1), 30 * s * s * (1 - s) ** 2 / self.durations[k], 0.0)
        a, b = self.points[k], self.points[(k + 1) % len(self.points)]
        return a + blend[:, None] * (b - a), rate[:, None] * (b - a)


def make_task(kind: str, start: ArrayLike) -> Circle | PickPlace:
    """The task ``circle`` or ``pick-place`` starting at the flange position ``start`` ``(3,)`` m."""
    if kind == "circle":
        return Circle.through(start)
    if kind == "pick-place":
        return PickPlace.around(start)
    raise ConfigError(f"unknown task '{printable(str(kind))}' (use {' or '.join(TASKS)})")
