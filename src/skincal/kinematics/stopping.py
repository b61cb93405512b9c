"""The stopping model of a robot: how far and how long it takes to stop from a speed (a type, no simulation).

A table of speeds ``v`` (m/s) of the robot point, stopping times ``T_s(v)`` (s), stopping distances
``S_s(v)`` (m), and the reaction time ``T_r`` (s), interpolated linearly between its speeds (ISO/TS 15066
stop category 2). The separation distance ``S_p`` uses it (:mod:`skincal.control.separation`); the table
of a robot is measured on its torque-level simulation by :func:`skincal.workflows.stopping.measure_stopping`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from skincal.errors import ConfigError
from skincal.kinematics.transforms import FloatArray
from skincal.names import printable


def _table(name: str, value: Any) -> FloatArray:
    try:
        arr = np.array(value, dtype=float)
    except (TypeError, ValueError):
        raise ConfigError(f"stopping model: {name} must be a list of numbers") from None
    if arr.ndim != 1 or not np.all(np.isfinite(arr)) or np.any(arr < 0):
        raise ConfigError(f"stopping model: {name} must be a list of finite non-negative numbers")
    arr.setflags(write=False)
    return arr


def finite_number(where: str, value: Any, positive: bool = False) -> float:
    """``value`` as a float; a one-line :class:`ConfigError` naming ``where`` unless finite and >= 0 (> 0 with
    ``positive``; booleans are not numbers)."""
    ok = isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool)
    if not ok or not math.isfinite(float(value)) or float(value) < 0 or (positive and float(value) == 0):
        need = "a finite positive number" if positive else "a finite non-negative number"
        raise ConfigError(f"{where} must be {need}, got {value!r}")
    return float(value)


@dataclass(frozen=True, eq=False)
class StoppingModel:
    """How far and how long the robot takes to stop from a speed (stop category 2 from the controller's
    command).

    Attributes:
        speeds: ``(K,)`` speeds of the robot point, m/s, strictly ascending from 0.
        times: ``(K,)`` stopping times ``T_s`` from each speed, s (usually 0 at speed 0).
        distances: ``(K,)`` stopping distances ``S_s`` from each speed, m (usually 0 at speed 0).
        reaction_time_s: ``T_r``, s: sensing + filtering + control latency before braking starts.

    Between the table's speeds times and distances are interpolated linearly; beyond the last speed
    they are extrapolated with the last segment's slope (never below the last entry).
    """

    speeds: FloatArray
    times: FloatArray
    distances: FloatArray
    reaction_time_s: float

    def __post_init__(self) -> None:
        s, t, d = (_table(n, getattr(self, n)) for n in ("speeds", "times", "distances"))
        if not (s.size >= 2 and s.size == t.size == d.size):
            raise ConfigError("stopping model: speeds, times and distances need the same length, at least 2")
        if s[0] != 0 or np.any(np.diff(s) <= 0):
            raise ConfigError("stopping model: speeds must start at 0 and be strictly ascending (m/s)")
        if np.any(np.diff(t) < 0) or np.any(np.diff(d) < 0):
            raise ConfigError("stopping model: times and distances must not decrease with speed")
        object.__setattr__(self, "speeds", s)
        object.__setattr__(self, "times", t)
        object.__setattr__(self, "distances", d)
        # per segment y = c + k v (the last segment carries on beyond the table)
        k_t, k_d = np.diff(t) / np.diff(s), np.diff(d) / np.diff(s)
        object.__setattr__(self, "_coef", (t[:-1] - k_t * s[:-1], k_t, d[:-1] - k_d * s[:-1], k_d))
        T_r = finite_number("stopping model: reaction_time_s", self.reaction_time_s)
        object.__setattr__(self, "reaction_time_s", T_r)

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, StoppingModel):
            return NotImplemented
        return self.reaction_time_s == other.reaction_time_s and all(
            np.array_equal(getattr(self, f), getattr(other, f)) for f in ("speeds", "times", "distances")
        )

    def __hash__(self) -> int:
        return hash((self.reaction_time_s, self.speeds.tobytes(), self.times.tobytes(), self.distances.tobytes()))

    def segments(self, v: ArrayLike) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray]:
        """``(v, c_t, k_t, c_d, k_d)``: speeds ``v`` clipped at 0 and the affine pieces of the table at them,
        ``T_s = c_t + k_t v``, ``S_s = c_d + k_d v`` (the segment holding ``v``; the last one beyond it)."""
        speed = np.maximum(np.asarray(v, dtype=float), 0.0)
        j = np.clip(np.searchsorted(self.speeds, speed, side="right") - 1, 0, self.speeds.size - 2)
        c_t, k_t, c_d, k_d = self._coef  # type: ignore[attr-defined]
        return speed, c_t[j], k_t[j], c_d[j], k_d[j]

    def stopping_time(self, v: ArrayLike) -> FloatArray:
        """``T_s`` (s) from speeds ``v`` m/s (any shape; negative speeds count as 0)."""
        v, c, k, _, _ = self.segments(v)
        return c + k * v

    def stopping_distance(self, v: ArrayLike) -> FloatArray:
        """``S_s`` (m) from speeds ``v`` m/s (any shape; negative speeds count as 0)."""
        v, _, _, c, k = self.segments(v)
        return c + k * v

    @classmethod
    def constant_deceleration(
        cls, decel_mps2: float, reaction_time_s: float, v_max: float = 3.0, n: int = 16
    ) -> StoppingModel:
        """The table of braking at a constant ``decel_mps2`` m/s^2: ``T_s = v / a``, ``S_s = v^2 / (2 a)``
        at ``n`` speeds from 0 to ``v_max`` m/s."""
        a = finite_number("stopping model: decel_mps2", decel_mps2, positive=True)
        if int(n) != n or n < 2:
            raise ConfigError(f"stopping model: n must be an integer >= 2, got {n!r}")
        v = np.linspace(0.0, finite_number("stopping model: v_max", v_max, positive=True), int(n))
        return cls(v, v / a, v**2 / (2 * a), reaction_time_s)

    def to_dict(self) -> dict:
        """JSON-ready: ``{"speeds_mps": [...], "times_s": [...], "distances_m": [...], "reaction_time_s": T_r}``."""
        return {
            "speeds_mps": self.speeds.tolist(),
            "times_s": self.times.tolist(),
            "distances_m": self.distances.tolist(),
            "reaction_time_s": self.reaction_time_s,
        }

    @classmethod
    def from_dict(cls, d: Any) -> StoppingModel:
        """The model of :meth:`to_dict`'s form; a one-line :class:`ConfigError` on anything else."""
        keys = ("speeds_mps", "times_s", "distances_m", "reaction_time_s")
        if not isinstance(d, dict):
            raise ConfigError("stopping model must be a mapping with " + ", ".join(keys))
        missing = [k for k in keys if k not in d]
        extra = sorted(printable(str(k)) for k in d if k not in keys)
        if missing or extra:
            what = f"missing {', '.join(missing)}" if missing else f"unknown field(s) {', '.join(extra)}"
            raise ConfigError(f"stopping model: {what} (fields: {', '.join(keys)})")
        return cls(d["speeds_mps"], d["times_s"], d["distances_m"], d["reaction_time_s"])


def default_stopping() -> StoppingModel:
    """A placeholder stopping model: 4 m/s^2 braking of the robot point, ``T_r = 0.05 s`` (a 50 Hz
    reading, the 3-reading median's lag and 1 ms control). Measure the robot's own with
    :func:`skincal.workflows.stopping.measure_stopping` (on the torque robot)."""
    return StoppingModel.constant_deceleration(4.0, 0.05)
