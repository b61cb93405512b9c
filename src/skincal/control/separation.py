"""Protective separation distance of speed and separation monitoring (ISO/TS 15066:2016, Sec. 5.5.4).

The standard's protective separation distance at one instant is (its equation (1), in the
constant-speed form of its equation (2))::

    S_p = S_h + S_r + S_s + C + Z_d + Z_r

with, per obstacle point (a part of a person the skin sees), all in m:

* ``S_h = v_h (T_r + T_s)``: how far the person moves while the robot reacts and stops. ``v_h`` m/s is
  the person's speed toward the robot (ISO 13855: 1.6 m/s walking, 2.0 m/s for a hand near the
  robot), ``T_r`` s the reaction time (sensing, filtering, control latency) and ``T_s`` s the robot's
  stopping time from its current speed (stop category 2: braking along the commanded path).
* ``S_r = v_r T_r``: how far the robot moves toward the person during the reaction time; ``v_r`` m/s
  is the speed of the robot point nearest the person along the line to the person (clipped at 0: a
  robot moving away does not shrink the margin).
* ``S_s``: the robot's stopping distance from ``v_r`` (a measured table, :class:`StoppingModel`).
* ``C``: intrusion distance, how far a part of the body can reach toward the robot before it is
  detected (ISO 13855); for the skin, the part of a person outside every sensor cone.
* ``Z_d``: position uncertainty of the sensed person; here per point ``sigma_level`` standard
  deviations of the point's position along the robot-to-point normal,
  ``Z_d = sigma_level sqrt(n^T Cov n)`` (the covariance from the unit's calibrated pose, the ToF
  noise and the joint noise: :mod:`skincal.perception.uncertainty`).
* ``Z_r``: position uncertainty of the robot (encoders, model, capsule fit).

The controller (:mod:`skincal.control.qp`) keeps ``d_i >= S_p,i`` for every point ``i`` with the
smooth approach bound ``b(d) = v_max tanh((d - S_p) / w)``: below ``S_p`` the bound is negative and
the robot backs away.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from skincal.errors import ConfigError
from skincal.kinematics.transforms import FloatArray
from skincal.names import printable

WALKING_SPEED_MPS = 1.6
"""ISO 13855 approach speed of a walking person, m/s."""
HAND_SPEED_MPS = 2.0
"""ISO 13855 approach speed of a hand or arm near the machine, m/s."""


def _table(name: str, value: Any) -> FloatArray:
    try:
        arr = np.array(value, dtype=float)
    except (TypeError, ValueError):
        raise ConfigError(f"stopping model: {name} must be a list of numbers") from None
    if arr.ndim != 1 or not np.all(np.isfinite(arr)) or np.any(arr < 0):
        raise ConfigError(f"stopping model: {name} must be a list of finite non-negative numbers")
    arr.setflags(write=False)
    return arr


def _number(where: str, value: Any, positive: bool = False) -> float:
    ok = isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool)
    if not ok or not math.isfinite(float(value)) or float(value) < 0 or (positive and float(value) == 0):
        need = "a finite positive number" if positive else "a finite non-negative number"
        raise ConfigError(f"{where} must be {need}, got {value!r}")
    return float(value)


@dataclass(frozen=True)
class StoppingModel:
    """How far and how long the robot takes to stop from a speed (stop category 2 from the controller's
    command).

    Attributes:
        speeds: ``(K,)`` speeds of the robot point, m/s, strictly ascending from 0.
        times: ``(K,)`` stopping times ``T_s`` from each speed, s (0 at speed 0).
        distances: ``(K,)`` stopping distances ``S_s`` from each speed, m (0 at speed 0).
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
        object.__setattr__(self, "reaction_time_s", _number("stopping model: reaction_time_s", self.reaction_time_s))

    def _interp(self, v: ArrayLike, y: FloatArray) -> FloatArray:
        v = np.maximum(np.asarray(v, dtype=float), 0.0)
        slope = (y[-1] - y[-2]) / (self.speeds[-1] - self.speeds[-2])
        beyond = y[-1] + slope * (v - self.speeds[-1])
        return np.where(v > self.speeds[-1], beyond, np.interp(v, self.speeds, y))

    def stopping_time(self, v: ArrayLike) -> FloatArray:
        """``T_s`` (s) from speeds ``v`` m/s (any shape; negative speeds count as 0)."""
        return self._interp(v, self.times)

    def stopping_distance(self, v: ArrayLike) -> FloatArray:
        """``S_s`` (m) from speeds ``v`` m/s (any shape; negative speeds count as 0)."""
        return self._interp(v, self.distances)

    @classmethod
    def constant_deceleration(
        cls, decel_mps2: float, reaction_time_s: float, v_max: float = 3.0, n: int = 16
    ) -> StoppingModel:
        """The table of braking at a constant ``decel_mps2`` m/s^2: ``T_s = v / a``, ``S_s = v^2 / (2 a)``
        at ``n`` speeds from 0 to ``v_max`` m/s."""
        a = _number("stopping model: decel_mps2", decel_mps2, positive=True)
        if int(n) != n or n < 2:
            raise ConfigError(f"stopping model: n must be an integer >= 2, got {n!r}")
        v = np.linspace(0.0, _number("stopping model: v_max", v_max, positive=True), int(n))
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
    :func:`skincal.workflows.stopping.measure_stopping`."""
    return StoppingModel.constant_deceleration(4.0, 0.05)


@dataclass(frozen=True)
class SeparationParams:
    """ISO/TS 15066 Sec. 5.5.4 terms other than the per-point ones; SI units.

    Attributes:
        human_speed_mps: ``v_h``, the design speed of the person toward the robot, m/s (ISO 13855:
            1.6 walking, 2.0 for a hand near the robot); a point seen approaching faster uses its own
            speed.
        intrusion_m: ``C``, m: how far a part of the person may reach toward the robot unseen (the part
            outside every cone; the fixed controller's 5 cm allowance for it).
        robot_position_uncertainty_m: ``Z_r``, m (encoder and model error; the capsule model's own
            padding is separate).
        sigma_level: ``Z_d`` is this many standard deviations of a point's position along its normal.
        stopping: the robot's stopping model (``T_r``, ``T_s(v)``, ``S_s(v)``).
    """

    human_speed_mps: float = WALKING_SPEED_MPS
    intrusion_m: float = 0.05
    robot_position_uncertainty_m: float = 0.01
    sigma_level: float = 3.0
    stopping: StoppingModel = field(default_factory=default_stopping)

    def __post_init__(self) -> None:
        for name in ("human_speed_mps", "intrusion_m", "robot_position_uncertainty_m", "sigma_level"):
            object.__setattr__(self, name, _number(f"separation: {name}", getattr(self, name)))
        if not isinstance(self.stopping, StoppingModel):
            raise ConfigError(f"separation: stopping must be a StoppingModel, got {type(self.stopping).__name__}")

    def to_dict(self) -> dict:
        """JSON-ready, the stopping model nested (:meth:`StoppingModel.to_dict`)."""
        return {
            "human_speed_mps": self.human_speed_mps,
            "intrusion_m": self.intrusion_m,
            "robot_position_uncertainty_m": self.robot_position_uncertainty_m,
            "sigma_level": self.sigma_level,
            "stopping": self.stopping.to_dict(),
        }

    @classmethod
    def from_dict(cls, d: Any) -> SeparationParams:
        """Parameters of :meth:`to_dict`'s form (any field may be left out for its default); a one-line
        :class:`ConfigError` on anything else."""
        keys = ("human_speed_mps", "intrusion_m", "robot_position_uncertainty_m", "sigma_level", "stopping")
        if not isinstance(d, dict):
            raise ConfigError("separation parameters must be a mapping")
        extra = sorted(printable(str(k)) for k in d if k not in keys)
        if extra:
            raise ConfigError(f"separation: unknown field(s) {', '.join(extra)} (fields: {', '.join(keys)})")
        kw = {k: d[k] for k in keys[:-1] if k in d}
        if "stopping" in d:
            kw["stopping"] = StoppingModel.from_dict(d["stopping"])
        return cls(**kw)


@dataclass(frozen=True)
class SeparationTerms:
    """The terms of ``S_p`` per obstacle point, each ``(K,)``, m (module docstring)."""

    S_h: FloatArray
    S_r: FloatArray
    S_s: FloatArray
    C: FloatArray
    Z_d: FloatArray
    Z_r: FloatArray

    @property
    def total(self) -> FloatArray:
        """``S_p = S_h + S_r + S_s + C + Z_d + Z_r``, ``(K,)`` m."""
        return self.S_h + self.S_r + self.S_s + self.C + self.Z_d + self.Z_r

    def at(self, i: int) -> dict[str, float]:
        """Point ``i``'s terms and ``S_p`` as floats (for logs and reports)."""
        out = {k: float(getattr(self, k)[i]) for k in ("S_h", "S_r", "S_s", "C", "Z_d", "Z_r")}
        return out | {"S_p": float(self.total[i])}


def _human_speed(params: SeparationParams, measured: ArrayLike | None, K: int) -> FloatArray:
    """``(K,)`` ``v_h``: the design speed, or a point's measured approach speed when larger, m/s."""
    v_h = np.full(K, params.human_speed_mps)
    if measured is not None:
        v_h = np.maximum(v_h, np.asarray(measured, dtype=float).reshape(-1))
    return v_h


def protective_separation(
    params: SeparationParams,
    robot_speed_toward: ArrayLike,
    human_speed_toward: ArrayLike | None,
    z_d: ArrayLike,
) -> SeparationTerms:
    """The terms of ``S_p`` for ``K`` points (module docstring).

    Args:
        params: the fixed terms and the stopping model.
        robot_speed_toward: ``(K,)`` speed of each point's nearest robot point toward it, m/s (negative:
            moving away, counted as 0).
        human_speed_toward: ``(K,)`` measured approach speed of each point, m/s, or None; the speed used
            is ``max(params.human_speed_mps, measured)``.
        z_d: ``(K,)`` sensor position uncertainty of each point along its normal, m.
    """
    v_r = np.maximum(np.asarray(robot_speed_toward, dtype=float).reshape(-1), 0.0)
    K = v_r.size
    v_h = _human_speed(params, human_speed_toward, K)
    stop = params.stopping
    T_r = stop.reaction_time_s
    return SeparationTerms(
        S_h=v_h * (T_r + stop.stopping_time(v_r)),
        S_r=v_r * T_r,
        S_s=stop.stopping_distance(v_r),
        C=np.full(K, params.intrusion_m),
        Z_d=np.broadcast_to(np.asarray(z_d, dtype=float).reshape(-1), (K,)).copy(),
        Z_r=np.full(K, params.robot_position_uncertainty_m),
    )


def allowed_approach_speed(
    params: SeparationParams,
    distance: ArrayLike,
    robot_speed_now: ArrayLike,
    human_speed_toward: ArrayLike | None,
    z_d: ArrayLike,
    bound: Callable[[FloatArray], FloatArray],
    iterations: int = 14,
) -> FloatArray:
    """The largest speed ``v`` (m/s, ``(K,)``) at which each robot point may approach its obstacle point:

        v <= bound(d - S_p(max(v, v_now)))

    with ``S_p(v_r)`` of :func:`protective_separation` and ``bound`` the increasing approach-speed ramp
    (``b(d - S_p)``). ``S_p`` grows with the robot's speed, so the right-hand side falls as ``v`` rises and
    the allowed set is ``v <= v*``, ``v*`` its fixed point. Taking ``S_p`` at the speed being commanded
    (and at least at the robot's present speed ``v_now``, from which it would have to stop) rather than
    at the previous command alone keeps the margin from chattering: an explicit ``S_p(v_prev)`` swings
    between a large margin (robot fast -> retreat) and a small one (robot slow -> fast approach) at
    every step when ``b'(.) dS_p/dv > 1`` (about 3 with a 0.1 s reaction time and the tanh ramp).

    ``v*`` is found by bisection (``iterations`` halvings of ``[max(v_now, 0), bound(d - S_p(v_now))]``);
    the value returned is the lower end, never above ``v*``. Where even the present speed's ``S_p`` gives
    a bound below that speed, the bound itself (negative inside ``S_p``: retreat).
    """
    d = np.asarray(distance, dtype=float).reshape(-1)
    K = d.size
    v0 = np.maximum(np.broadcast_to(np.asarray(robot_speed_now, dtype=float).reshape(-1), (K,)), 0.0)
    v_h = _human_speed(params, human_speed_toward, K)
    const = params.intrusion_m + np.asarray(z_d, dtype=float).reshape(-1) + params.robot_position_uncertainty_m
    stop = params.stopping
    T_r = stop.reaction_time_s

    def s_p(v: FloatArray) -> FloatArray:
        return v_h * (T_r + stop.stopping_time(v)) + v * T_r + stop.stopping_distance(v) + const

    b0 = bound(d - s_p(v0))
    lo, hi = v0, np.maximum(b0, v0)
    for _ in range(int(iterations)):
        mid = 0.5 * (lo + hi)
        ok = mid <= bound(d - s_p(mid))
        lo = np.where(ok, mid, lo)
        hi = np.where(ok, hi, mid)
    return np.where(b0 <= v0, b0, lo)
