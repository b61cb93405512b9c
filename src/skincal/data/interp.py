"""Linear interpolation and zero-order hold of a sampled signal: the one home of "``values`` sampled at
``t_grid``, read at times ``t``" (joint angles between robot samples, obstacle time tables, the MuJoCo
run's 1 kHz states). The calibration's joint interpolation with conditioning is
:class:`skincal.calib.preprocess.JointInterpolator`, built on different needs.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from skincal.errors import DatasetError
from skincal.kinematics.transforms import FloatArray


def _grid(t: ArrayLike, t_grid: ArrayLike, values: ArrayLike) -> tuple[FloatArray, FloatArray, FloatArray]:
    tq = np.asarray(t, dtype=float)
    grid = np.asarray(t_grid, dtype=float)
    v = np.asarray(values, dtype=float)
    if grid.ndim != 1 or grid.size == 0 or v.ndim == 0 or v.shape[0] != grid.size:
        raise DatasetError(
            f"interpolation needs a non-empty (S,) time grid and (S, ...) values, got {grid.shape} and {v.shape}"
        )
    return tq, grid, v


def interp_rows(t: ArrayLike, t_grid: ArrayLike, values: ArrayLike) -> FloatArray:
    """Linear interpolation of ``values`` ``(S, ...)`` sampled at ``t_grid`` ``(S,)`` s (increasing) at
    times ``t`` (any shape) -> ``t.shape + values.shape[1:]``; held at the first / last row outside
    the grid, NaN at NaN times (a one-row grid: that row everywhere).

    Vectorised over rows and columns (one ``searchsorted``), and equal bit for bit to ``np.interp`` on
    every column: the same formula ``slope (t - t_j) + y_j`` with ``slope = (y_{j+1} - y_j) / (t_{j+1}
    - t_j)``, the grid row itself at a grid instant, and ``np.interp``'s fallbacks for non-finite
    slopes (so simulated datasets that used ``np.interp`` are reproduced exactly).
    """
    tq, grid, v = _grid(t, t_grid, values)
    S = grid.size
    flat = v.reshape(S, -1)
    x = tq.reshape(-1)
    if S == 1:  # np.interp: the one row everywhere
        return np.broadcast_to(flat[0], (x.size, flat.shape[1])).reshape(tq.shape + v.shape[1:]).copy()
    j = np.searchsorted(grid, x, side="right") - 1  # grid[j] <= x < grid[j + 1]
    k = np.clip(j, 0, S - 2)
    x0, x1 = grid[k][:, None], grid[k + 1][:, None]
    y0, y1 = flat[k], flat[k + 1]
    xc = x[:, None]
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        slope = (y1 - y0) / (x1 - x0)
        out = slope * (xc - x0) + y0
        nan = np.isnan(out)
        if nan.any():  # np.interp: if we get NaN in one direction, try the other; then a flat piece
            other = slope * (xc - x1) + y1
            out = np.where(nan, other, out)
            out = np.where(np.isnan(out) & (y0 == y1), y0, out)
    out = np.where(xc == x0, y0, out)  # a grid instant: its row exactly
    out = np.where((j < 0)[:, None], flat[0], out)
    out = np.where((j >= S - 1)[:, None], flat[-1], out)
    out = np.where(np.isnan(xc), np.nan, out)
    return out.reshape(tq.shape + v.shape[1:])


def hold_rows(t: ArrayLike, t_grid: ArrayLike, values: ArrayLike, tolerance: float = 1e-12) -> FloatArray:
    """Zero-order hold: the latest row of ``values`` ``(S, ...)`` at or before each time of ``t``
    (within ``tolerance`` s), the first row before the grid."""
    tq, grid, v = _grid(t, t_grid, values)
    k = np.clip(np.searchsorted(grid, tq + tolerance, side="right") - 1, 0, grid.size - 1)
    return v[k]
