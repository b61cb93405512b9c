"""A unit that moved on its link during the session, found from the rest runs' residuals (:func:`find_move`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from skincal.calib.mle.solver import (
    Rows,
)
from skincal.kinematics.transforms import FloatArray, skew

MOVE_MIN_RUNS = 4
"""A move is looked for only with this many rest runs on each side of it."""


MOVE_IMPROVEMENT = 10.0
"""A before/after split must explain the rest runs this many times better than one pose..."""


MOVE_MIN_ANGLE_DEG = 1.0
"""...and the two poses' rotations differ by this much, deg."""


@dataclass(frozen=True)
class Move:
    """A unit that moved on its link during the session (knocked, peeled and re-stuck): the rest
    runs before ``t_before`` and after ``t_after`` (s) each fit one pose but not together."""

    t_before: float
    t_after: float
    angle_deg: float
    improvement: float


def turn_fit(f: FloatArray, r: FloatArray, w: FloatArray) -> tuple[float, FloatArray]:
    """Weighted least squares of rest-row residuals ``r`` by a small turn ``phi`` and bias change
    ``c`` of the unit, ``r ~ [f]x phi + c`` (``f`` the readings, unit frame): the residual sum of
    squares left and ``phi`` (rad)."""
    X = np.zeros((len(f), 3, 6))
    X[:, :, :3] = skew(f)
    X[:, :, 3:] = np.eye(3)
    sw = np.sqrt(w)[:, None, None]
    A = (X * sw).reshape(-1, 6)
    y = (r[:, :, None] * sw).reshape(-1)
    coef, *_ = np.linalg.lstsq(A, y, rcond=None)
    left = A @ coef - y
    return float(left @ left), np.asarray(coef[:3], dtype=np.float64)


def find_move(rows: Rows, residuals: FloatArray, t_c: float) -> Move | None:
    """A change of the unit's pose during the session, from the fitted model's rest-row residuals.

    A unit that moved on its link leaves rest residuals that a small turn and bias change explain,
    differently before and after the move. Each split of the time-ordered rest runs (at least
    ``MOVE_MIN_RUNS`` each side) gets its own ``phi, c`` per side (:func:`turn_fit`); the best
    split is a move when it lowers the weighted residual sum by more than ``MOVE_IMPROVEMENT``
    times and the two turns differ by more than ``MOVE_MIN_ANGLE_DEG`` (a drifting bias improves a
    split too, but turns nothing).
    """
    S = len(rows.static_u)
    if S < 2 * MOVE_MIN_RUNS or residuals is None:
        return None
    order = np.argsort(rows.static_t)
    f, w, t, r = rows.static_f[order], rows.static_weight[order], rows.static_t[order], residuals[:S][order]
    total = float(np.sum(w * np.sum(r * r, axis=1)))
    best = (np.inf, 0, np.zeros(3), np.zeros(3))
    for k in range(MOVE_MIN_RUNS, S - MOVE_MIN_RUNS + 1):
        (c1, phi1), (c2, phi2) = turn_fit(f[:k], r[:k], w[:k]), turn_fit(f[k:], r[k:], w[k:])
        if c1 + c2 < best[0]:
            best = (c1 + c2, k, phi1, phi2)
    cost, k, phi1, phi2 = best
    angle = float(np.degrees(np.linalg.norm(phi2 - phi1)))
    improvement = total / max(cost, 1e-300)
    if improvement < MOVE_IMPROVEMENT or angle < MOVE_MIN_ANGLE_DEG:
        return None
    return Move(float(t[k - 1] + t_c), float(t[k] + t_c), angle, improvement)
