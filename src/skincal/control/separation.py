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
* ``S_s``: the robot's stopping distance from ``v_r`` (a measured table,
  :class:`~skincal.kinematics.stopping.StoppingModel`).
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

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from skincal.errors import ConfigError
from skincal.kinematics.stopping import StoppingModel, default_stopping, finite_number
from skincal.kinematics.transforms import FloatArray
from skincal.names import printable

WALKING_SPEED_MPS = 1.6
"""ISO 13855 approach speed of a walking person, m/s."""
HAND_SPEED_MPS = 2.0
"""ISO 13855 approach speed of a hand or arm near the machine, m/s."""


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
            object.__setattr__(self, name, finite_number(f"separation: {name}", getattr(self, name)))
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


TRACKING_TOLERANCE_RADPS = 0.1
"""How far a measured joint velocity may lie from the command it tracks and still count as the robot's speed in
``S_p``, rad/s (:func:`separation_speed`)."""


def separation_speed(
    measured: ArrayLike, commanded: ArrayLike, tolerance: float = TRACKING_TOLERANCE_RADPS
) -> FloatArray:
    """The joint velocity ``(n,)`` rad/s whose robot-point speeds enter ``S_p`` in torque mode (a floor under the
    command being solved for): the measured velocity, as far as the previous command accounts for it, per joint

        qd_sp = clip(qd_meas, min(qd_cmd, 0) - tolerance, max(qd_cmd, 0) + tolerance).

    While the robot tracks its command (the usual case) this is the measured velocity itself. A speed the
    command does not account for, a transient of the tracking layer (the arm still moving one way after a
    retreat command the other way, or pushed), counts up to ``tolerance`` only: fed the raw measured speed,
    ``S_p`` of the Panda in ``pinch`` (torque mode) reached 0.93 m from a 1.2 m/s transient while the arm was
    commanded away at 0.2 m/s, and the larger margin asked for a harder retreat, which widened the transient
    (simulated). Never above the measured speed either (a command the arm has not followed yet is not its
    speed): the previous command itself as the floor makes ``S_p`` alternate from step to step, as an explicit
    ``S_p`` of the previous command does (:func:`allowed_approach_speed`)."""
    cmd = np.asarray(commanded, dtype=float).reshape(-1)
    meas = np.asarray(measured, dtype=float).reshape(-1)
    return np.clip(meas, np.minimum(cmd, 0.0) - tolerance, np.maximum(cmd, 0.0) + tolerance)


def _per_point(value: ArrayLike, K: int) -> FloatArray:
    """``(K,)`` float array of a number or ``(K,)`` values (a copy; ``np.broadcast_to`` is slow for small K)."""
    arr = np.array(value, dtype=float).reshape(-1)
    return arr if arr.size == K else np.full(K, arr[0]) if arr.size == 1 else arr.reshape(K)


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
    T_r = params.stopping.reaction_time_s
    _, c_t, k_t, c_d, k_d = params.stopping.segments(v_r)
    return SeparationTerms(
        S_h=v_h * (T_r + (c_t + k_t * v_r)),
        S_r=v_r * T_r,
        S_s=c_d + k_d * v_r,
        C=np.full(K, params.intrusion_m),
        Z_d=_per_point(z_d, K),
        Z_r=np.full(K, params.robot_position_uncertainty_m),
    )


def allowed_approach_speed(
    params: SeparationParams,
    distance: ArrayLike,
    robot_speed_now: ArrayLike,
    human_speed_toward: ArrayLike | None,
    z_d: ArrayLike,
    bound: Callable[[FloatArray], tuple[FloatArray, FloatArray]],
    iterations: int = 12,
) -> FloatArray:
    """The largest speed ``u`` (m/s, ``(K,)``) of each robot point toward its obstacle point that the rule allows:
    the gap may close at most at the ramp's speed for the margin the robot's own speed needs,

        u + a <= g(u) = b(d - S_p(max(u, v_now))),

    ``a = max(human_speed_toward, 0)`` the point's own approach speed (the velocity-aware row), ``S_p(v_r)``
    of :func:`protective_separation` (``v_h = max(v_h design, a)``) and ``b`` the increasing ramp
    (``bound(gap)`` returns ``b`` and ``db/dgap``). ``S_p`` grows with the robot's speed, so ``g`` falls as
    ``u`` rises and the allowed set is ``u <= u*``, ``u*`` the fixed point ``u* + a = g(u*)``. Taking ``S_p``
    at the speed being commanded (at least at the robot's present speed ``v_now``, from which it would have
    to stop) rather than at the previous command alone keeps the margin from chattering: an explicit
    ``S_p(v_prev)`` swings between a large margin (robot fast -> retreat) and a small one (robot slow ->
    fast approach) from step to step when ``b'(.) dS_p/dv > 1`` (about 3 with a 0.1 s reaction time and the
    tanh ramp).

    Where the present speed's margin already asks for less than that speed (``c0 = g(v0) - a <= v0``,
    ``v0 = max(v_now, 0)``), ``u* = c0`` (negative: retreat). Otherwise ``u*`` lies in ``(v0, c0]``: Newton
    steps on ``f(u) = u + a - g(u)`` (``f' = 1 + b' dS_p/dv >= 1``) kept inside the bracket (bisection when a
    step leaves it, and every third step), ``iterations`` of them. The value returned is ``max(lo, g(hi) -
    a)`` of the final bracket: both are at most ``u*`` (``g`` falls), so the row is never looser than the
    rule (12 iterations: within 0.005 m/s of ``u*``, 16: 1e-4, on random cases).
    """
    d = np.asarray(distance, dtype=float).reshape(-1)
    K = d.size
    a = np.zeros(K) if human_speed_toward is None else np.maximum(np.asarray(human_speed_toward, float).reshape(-1), 0)
    v_h = _human_speed(params, human_speed_toward, K)
    return _fixed_point(params, d, robot_speed_now, v_h, np.broadcast_to(a, (K,)), z_d, bound, iterations)


def _fixed_point(
    params: SeparationParams,
    d: FloatArray,
    robot_speed_now: ArrayLike,
    v_h: FloatArray,
    a: FloatArray,
    z_d: ArrayLike,
    bound: Callable[[FloatArray], tuple[FloatArray, FloatArray]],
    iterations: int,
) -> FloatArray:
    """:func:`allowed_approach_speed` with ``v_h`` and ``a`` ``(K,)`` given apart."""
    K = d.size
    v0 = np.maximum(_per_point(robot_speed_now, K), 0.0)
    const = params.intrusion_m + np.asarray(z_d, dtype=float).reshape(-1) + params.robot_position_uncertainty_m
    stop = params.stopping
    T_r = stop.reaction_time_s
    rest = v_h * T_r + const  # the part of S_p that does not grow with the robot's speed

    def g(v: FloatArray) -> tuple[FloatArray, FloatArray]:
        """``g(v) - a`` and ``f'(v) = 1 - g'(v)``."""
        v, c_t, k_t, c_d, k_d = stop.segments(v)
        b, db = bound(d - (rest + v_h * c_t + c_d + (v_h * k_t + T_r + k_d) * v))
        return b - a, 1.0 + db * (v_h * k_t + T_r + k_d)

    c0, fp = g(v0)
    search = c0 > v0
    if not np.any(search):
        return c0
    lo, hi = v0, np.where(search, c0, v0)
    g_hi = g(hi)[0]
    v, f = v0, v0 - c0
    for k in range(int(iterations)):
        step = v - f / fp
        newton = (step > lo) & (step < hi) & (k % 3 != 2)  # every third step halves the bracket
        v = np.where(newton, step, 0.5 * (lo + hi))
        gv, fp = g(v)
        f = v - gv
        left = f < 0
        lo = np.where(left, v, lo)
        hi, g_hi = np.where(left, hi, v), np.where(left, g_hi, gv)
    return np.where(search, np.maximum(lo, g_hi), c0)


class ApproachSpeedTable:
    """:func:`allowed_approach_speed` from a precomputed table, for the control loop (a few array operations
    per step instead of Newton iterations); never above it.

    For a still point and a still robot, with ``e = d - C - Z_d - Z_r`` (m), the fixed point depends only on
    ``e`` and the human speed ``v_h``: ``V(e, v_h)``, increasing in ``e`` and decreasing in ``v_h`` (``S_p`` grows
    with ``v_h``). The table holds ``V`` on a grid (``e`` from 0 to ``e_max`` in steps ``de``; ``v_h`` from the
    design speed in steps ``dvh`` over ``vh_span``); a lookup takes the grid point BELOW in ``e`` and ABOVE in
    ``v_h``, so it is never above ``V`` (at most about ``b'_max de`` below at the design speed, the usual case,
    plus the ``v_h`` step's effect above it). Outside the grid: ``e < 0`` is the closed form ``g(0)``
    (negative: retreat), ``e > e_max`` takes the last row, a ``v_h`` beyond the grid is solved exactly.

    An approaching point (``a > 0``) or a robot already moving toward it (``v0 > 0``): ``c0 = g(v0) - a``
    exactly when ``c0 <= v0`` (the usual case of a person coming: retreat), else ``max(V - a, v0)``, below
    ``u*`` too (``u* + a = g(u*)`` and ``g`` falls, so ``u* >= V - a``): cautious in the one case where a
    person comes slowly while the robot may still approach (by up to about 0.3 m/s on random cases; the
    median error over all cases is below 1 mm/s).
    """

    def __init__(
        self,
        params: SeparationParams,
        bound: Callable[[FloatArray], tuple[FloatArray, FloatArray]],
        e_max: float = 3.0,
        de: float = 0.002,
        dvh: float = 0.05,
        vh_span: float = 3.0,
    ) -> None:
        self.params, self.bound, self.de, self.dvh = params, bound, float(de), float(dvh)
        self.e = de * np.arange(int(round(e_max / de)) + 1)
        self.vh = params.human_speed_mps + dvh * np.arange(int(round(vh_span / dvh)) + 1)
        E, VH = np.meshgrid(self.e, self.vh, indexing="ij")
        stop = params.stopping
        self._T_rest = float(stop.reaction_time_s + stop.stopping_time(0.0))  # T_r + T_s(0), s
        self._S_rest = float(stop.stopping_distance(0.0))  # S_s(0), m
        vh = VH.ravel()
        # V(e, v_h): a still point (a = 0), a still robot, and Z_d = -(C + Z_r) so that S_p's constant part is 0
        self.table = _fixed_point(
            params,
            E.ravel(),
            0.0,
            vh,
            np.zeros(vh.size),
            -params.intrusion_m - params.robot_position_uncertainty_m,
            bound,
            40,
        ).reshape(E.shape)

    def __call__(
        self,
        distance: ArrayLike,
        robot_speed_now: ArrayLike | None,
        human_speed_toward: ArrayLike | None,
        z_d: ArrayLike,
    ) -> FloatArray:
        """``(K,)`` allowed speeds toward the points, m/s (arguments as :func:`allowed_approach_speed`;
        ``robot_speed_now`` None: the robot is taken as still)."""
        p = self.params
        d = np.asarray(distance, dtype=float).reshape(-1)
        K = d.size
        z = _per_point(z_d, K)
        e = d - (p.intrusion_m + p.robot_position_uncertainty_m + z)
        v_h = _human_speed(p, human_speed_toward, K)
        i = np.minimum((e / self.de).astype(int), self.e.size - 1)  # floor (e >= 0 where used)
        j = np.ceil((v_h - self.vh[0]) / self.dvh - 1e-9).astype(int)
        v = self.table[np.clip(i, 0, None), np.clip(j, 0, self.vh.size - 1)]
        a = (
            np.zeros(K)
            if human_speed_toward is None
            else np.maximum(np.asarray(human_speed_toward, float).reshape(-1), 0)
        )
        off = j >= self.vh.size
        if robot_speed_now is None:  # c0 = g(0) - a: inside the margin at rest (e < 0), or a point coming (a > 0)
            fix = ((e < 0) | (a > 0)) & ~off
            if np.any(fix):
                c0 = self.bound(e[fix] - (v_h[fix] * self._T_rest + self._S_rest))[0] - a[fix]
                v[fix] = np.where(c0 <= 0, c0, np.maximum(v[fix] - a[fix], 0.0))
            v0 = np.zeros(K)
        else:
            v0 = np.maximum(np.asarray(robot_speed_now, float).reshape(-1), 0)
            fix = ((e < 0) | (a > 0) | (v0 > 0)) & ~off
            if np.any(fix):
                s_p = protective_separation(p, v0[fix], v_h[fix], z[fix]).total
                c0 = self.bound(d[fix] - s_p)[0] - a[fix]
                v[fix] = np.where(c0 <= v0[fix], c0, np.maximum(v[fix] - a[fix], v0[fix]))
        if np.any(off):
            v[off] = allowed_approach_speed(p, d[off], v0[off], a[off], z[off], self.bound)
        return v
