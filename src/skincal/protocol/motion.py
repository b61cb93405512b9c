"""Closed-form motion pieces of the protocol.

Every piece of a protocol trajectory has, per joint, the form (local time ``tau`` in s)::

    q(tau)   = sum_{i=0..5} c_i tau^i + B (1 - cos(w tau))                      [rad]
    qd(tau)  = sum_i i c_i tau^(i-1)  + B w sin(w tau)                          [rad/s]
    qdd(tau) = sum_i i (i-1) c_i tau^(i-2) + B w^2 cos(w tau)                   [rad/s^2]

* a rest is a constant (``c_0`` only);
* a move between poses is the rest-to-rest quintic ``q_a + (q_b - q_a) s(tau / T)`` with
  ``s(u) = 10 u^3 - 15 u^4 + 6 u^5`` (zero velocity and acceleration at both ends; peak speed
  ``15/8 |q_b - q_a| / T``);
* an excitation of joint ``j`` is ``qd_j = A sin(2 pi f tau)``, i.e. ``c_0 = q0``, ``w = 2 pi f``,
  ``B = A / w`` (paper Sec. II-A), every other joint constant;
* a stop/return is the quintic Hermite from the excitation's end state ``(q, qd, qdd)`` to
  ``(q0, 0, 0)``, needed when ``f * excite_duration`` is not a whole number of periods.

Arrays: ``coef`` ``(n, 6)`` (ascending powers), ``B`` and ``w`` ``(n,)`` per piece.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
from numpy.typing import ArrayLike

from skincal.errors import ProtocolError
from skincal.kinematics.transforms import FloatArray

N_COEF = 6
"""Polynomial coefficients per joint and piece (a quintic)."""

_WHOLE_PERIOD_TOL = 1e-9
_STOP_GRID_S = np.arange(0.05, 60.0, 0.01)
"""Candidate stop/return durations, s (the shortest feasible one is used)."""
_STOP_SAMPLES = 201


def eval_piece(coef: FloatArray, B: FloatArray, w: FloatArray, tau: FloatArray) -> tuple[FloatArray, ...]:
    """Evaluate one piece at local times ``tau`` ``(m,)``: returns ``q, qd, qdd`` each ``(m, n)``."""
    tau = np.asarray(tau, dtype=float)
    powers = np.arange(N_COEF)
    V = tau[:, None] ** powers  # (m, 6)
    d1 = coef[:, 1:] * powers[1:]  # (n, 5)
    d2 = d1[:, 1:] * powers[1:-1]  # (n, 4)
    wt = tau[:, None] * w
    q = V @ coef.T + B * (1.0 - np.cos(wt))
    qd = V[:, :-1] @ d1.T + B * w * np.sin(wt)
    qdd = V[:, :-2] @ d2.T + B * w**2 * np.cos(wt)
    return q, qd, qdd


def hold_coef(q: ArrayLike) -> FloatArray:
    """Coefficients ``(n, 6)`` of a rest at ``q`` ``(n,)``."""
    q = np.asarray(q, dtype=float)
    coef = np.zeros(q.shape + (N_COEF,))
    coef[..., 0] = q
    return coef


def quintic_move_coef(q_from: ArrayLike, q_to: ArrayLike, T: float) -> FloatArray:
    """Rest-to-rest quintic from ``q_from`` to ``q_to`` (``(n,)`` rad) over ``T`` s, ``(n, 6)``."""
    q_from = np.asarray(q_from, dtype=float)
    delta = np.asarray(q_to, dtype=float) - q_from
    coef = hold_coef(q_from)
    coef[..., 3] = 10.0 * delta / T**3
    coef[..., 4] = -15.0 * delta / T**4
    coef[..., 5] = 6.0 * delta / T**5
    return coef


def hermite_quintic_coef(x0: ArrayLike, v0: ArrayLike, a0: ArrayLike, x1: ArrayLike, T: ArrayLike) -> FloatArray:
    """Quintic from state ``(x0, v0, a0)`` to rest ``(x1, 0, 0)`` in ``T`` s; broadcasts, ``(..., 6)``.

    With ``h = x1 - x0 - v0 T - a0 T^2 / 2``, ``dv = -v0 - a0 T`` and ``da = -a0``::

        c3 = (10 h - 4 dv T + da T^2 / 2) / T^3
        c4 = (-15 h + 7 dv T - da T^2) / T^4
        c5 = (6 h - 3 dv T + da T^2 / 2) / T^5
    """
    x0, v0, a0, x1, T = np.broadcast_arrays(*(np.asarray(x, dtype=float) for x in (x0, v0, a0, x1, T)))
    h = x1 - x0 - v0 * T - 0.5 * a0 * T**2
    dv = -v0 - a0 * T
    da = -a0
    return np.stack(
        [
            x0,
            v0,
            0.5 * a0,
            (10 * h - 4 * dv * T + 0.5 * da * T**2) / T**3,
            (-15 * h + 7 * dv * T - da * T**2) / T**4,
            (6 * h - 3 * dv * T + 0.5 * da * T**2) / T**5,
        ],
        axis=-1,
    )


def sine_end_state(A: float, f: float, D: float) -> tuple[float, float, float]:
    """Offset from the pose, velocity and acceleration at the end ``tau = D`` of one excitation.

    ``q - q0 = A / w (1 - cos w D)``, ``qd = A sin w D``, ``qdd = A w cos w D`` with ``w = 2 pi f``.
    """
    w = 2 * np.pi * f
    return A / w * (1 - np.cos(w * D)), A * np.sin(w * D), A * w * np.cos(w * D)


def needs_stop(f: float, D: float) -> bool:
    """True unless ``f * D`` is a whole number of periods (then the joint ends at rest on its pose)."""
    return abs(f * D - round(f * D)) > _WHOLE_PERIOD_TOL


@lru_cache(maxsize=256)
def stop_duration(A: float, f: float, D: float, joint: int = 0) -> float:
    """Shortest stop/return after an excitation that stays within the excitation's own peaks.

    The return is the Hermite quintic from :func:`sine_end_state` to the pose; its duration is the
    shortest on a 10 ms grid whose peak speed is at most ``A`` (rad/s) and peak acceleration at
    most ``2 pi f A`` (rad/s^2). Returns 0.0 when no stop is needed (:func:`needs_stop`).
    """
    if not needs_stop(f, D):
        return 0.0
    x0, v0, a0 = sine_end_state(A, f, D)
    powers = np.arange(N_COEF)
    # 0.1 % headroom for peaks between the checked instants (but never below the start state)
    v_max = max(abs(v0), 0.999 * abs(A)) * (1 + 1e-9)
    a_max = max(abs(a0), 0.999 * 2 * np.pi * f * abs(A)) * (1 + 1e-9)
    for T in np.array_split(_STOP_GRID_S, 20):  # shortest candidates first; most stops take ~1 s
        c = hermite_quintic_coef(x0, v0, a0, 0.0, T)  # (G, 6)
        tau = np.linspace(0.0, 1.0, _STOP_SAMPLES)[None, :] * T[:, None]  # (G, S)
        V = tau[..., None] ** powers  # (G, S, 6)
        v = np.einsum("gsk,gk->gs", V[..., :-1], c[:, 1:] * powers[1:])
        a = np.einsum("gsk,gk->gs", V[..., :-2], c[:, 2:] * powers[2:] * powers[1:-1])
        ok = (np.abs(v).max(axis=1) <= v_max) & (np.abs(a).max(axis=1) <= a_max)
        if ok.any():
            return round(float(T[np.argmax(ok)]), 9)
    raise ProtocolError(
        f"joint {joint + 1}: no smooth stop within {_STOP_GRID_S[-1]:.0f} s after the excitation "
        f"(A={A} rad/s, f={f} Hz)"
    )


def excitation_envelope(A: float, f: float, D: float, joint: int = 0) -> tuple[float, float]:
    """Lowest and highest offset ``q - q0`` (rad) reached during one excitation and its return.

    The sine part reaches ``A / (2 pi f) (1 - cos 2 pi f tau)``, at most ``A / (pi f)`` once
    ``f D >= 1/2``; the return is checked on a dense grid. Returns ``(lo <= 0, hi >= 0)``.
    """
    w = 2 * np.pi * f
    tau = np.linspace(0.0, D, 4001)
    offsets = [A / w * (1 - np.cos(w * tau))]
    if f * D >= 0.5:
        offsets.append(np.array([2 * A / w]))
    T = stop_duration(A, f, D, joint)
    if T > 0:
        x0, v0, a0 = sine_end_state(A, f, D)
        c = hermite_quintic_coef(x0, v0, a0, 0.0, T)
        offsets.append(np.polynomial.polynomial.polyval(np.linspace(0.0, T, 4001), c))
    allv = np.concatenate(offsets)
    return float(min(allv.min(), 0.0)), float(max(allv.max(), 0.0))


def excitation_offsets(A: float, f: float, D: float, step: float, joint: int = 0) -> FloatArray:
    """Offsets ``q - q0`` of one excitation and its return sampled every ``step`` s (ends included), ``(m,)``."""
    w = 2 * np.pi * f
    tau = np.append(np.arange(0.0, D, step), D)
    parts = [A / w * (1 - np.cos(w * tau))]
    T = stop_duration(A, f, D, joint)
    if T > 0:
        x0, v0, a0 = sine_end_state(A, f, D)
        c = hermite_quintic_coef(x0, v0, a0, 0.0, T)
        parts.append(np.polynomial.polynomial.polyval(np.append(np.arange(step, T, step), T), c))
    return np.concatenate(parts)


def quintic_move_samples(q_from: ArrayLike, q_to: ArrayLike, T: float, step: float) -> FloatArray:
    """Configurations ``(m, n)`` of the rest-to-rest quintic move sampled every ``step`` s (ends included)."""
    q_from = np.asarray(q_from, dtype=float)
    u = np.append(np.arange(0.0, T, step), T) / T
    s = 10 * u**3 - 15 * u**4 + 6 * u**5
    return q_from + s[:, None] * (np.asarray(q_to, dtype=float) - q_from)
