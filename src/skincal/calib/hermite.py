"""The one cubic Hermite interpolation of a sampled signal with its time derivative: grid tables of the
link signals (``mle``'s :class:`~skincal.calib.signals.SignalTable`, the streaming grid) and the joint stream
(:class:`~skincal.calib.preprocess.JointInterpolator`, the refill of lost samples in its conditioning)."""

from __future__ import annotations

import numpy as np

from skincal.kinematics.transforms import FloatArray


def hermite(
    grid: FloatArray, y: FloatArray, dy: FloatArray, t: FloatArray, columns: np.ndarray | None = None
) -> tuple[FloatArray, FloatArray, np.ndarray]:
    """Cubic Hermite interpolation of a signal tabulated on ``grid`` ``(G,)`` (s, increasing) with its
    values ``y`` and time derivatives ``dy`` ``(G, ...)``, at instants ``t`` ``(M,)`` (clipped to the
    grid's first/last interval): ``y(t) = h00 y_i + h10 h dy_i + h01 y_{i+1} + h11 h dy_{i+1}``
    (``s = (t - g_i) / h``, ``h = g_{i+1} - g_i``), and the derivative linearly,
    ``dy(t) = (1 - s) dy_i + s dy_{i+1}``. Returns ``(y(t), dy(t), i)``: ``(M, ...)`` each and the
    interval index ``(M,)``. ``columns``: take only these entries of the table's second axis (e.g. the
    candidate links of a ``(G, n, k)`` table). The one cubic Hermite interpolation (``mle``'s
    :class:`~skincal.calib.signals.SignalTable`, the streaming calibrator's grid, the joint stream's
    :class:`~skincal.calib.preprocess.JointInterpolator` and its conditioning)."""
    i = np.clip(np.searchsorted(grid, t) - 1, 0, grid.size - 2)
    a, da, b, db = y[i], dy[i], y[i + 1], dy[i + 1]
    if columns is not None:
        a, da, b, db = a[:, columns], da[:, columns], b[:, columns], db[:, columns]
    out, d = _hermite_eval(grid, t, i, a, da, b, db)
    return out, d, i


def _hermite_eval(
    grid: FloatArray, t: FloatArray, i: np.ndarray, a: FloatArray, da: FloatArray, b: FloatArray, db: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """The arithmetic of :func:`hermite` on the gathered end values ``a, b`` and derivatives ``da, db``
    ``(M, ...)`` of each instant's interval ``i``."""
    shape = (-1,) + (1,) * (a.ndim - 1)
    g0 = grid.take(i)
    h = (grid.take(i + 1) - g0).reshape(shape)
    s = ((t - g0).reshape(shape)) / h
    s2, s3 = s * s, s * s * s
    # out = h00 a + h10 h da + h01 b + h11 h db, evaluated in place, summed left to right
    out = np.multiply(2 * s3 - 3 * s2 + 1, a)
    tmp = np.multiply((s3 - 2 * s2 + s) * h, da)
    out += tmp
    np.multiply(-2 * s3 + 3 * s2, b, out=tmp)
    out += tmp
    np.multiply((s3 - s2) * h, db, out=tmp)
    out += tmp
    d = np.multiply(1 - s, da)
    np.multiply(s, db, out=tmp)
    d += tmp
    return out, d


def hermite_rows(
    grid: FloatArray, table: FloatArray, t: FloatArray, k: int, cols: slice = slice(None)
) -> tuple[FloatArray, FloatArray]:
    """:func:`hermite` of a table whose rows ``(G, 2 k)`` hold the values (``[:k]``) and then their
    derivatives (``[k:]``): each instant's two rows gathered once (contiguous), the same arithmetic;
    ``cols``: only these of the ``k`` values (and their derivatives)."""
    i = np.clip(np.searchsorted(grid, t) - 1, 0, grid.size - 2)
    lo, hi = table.take(i, axis=0), table.take(i + 1, axis=0)
    return _hermite_eval(grid, t, i, lo[:, :k][:, cols], lo[:, k:][:, cols], hi[:, :k][:, cols], hi[:, k:][:, cols])
