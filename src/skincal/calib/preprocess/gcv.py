"""The smoothing parameter that generalised cross-validation chooses for a cubic smoothing spline, as
:func:`scipy.interpolate.make_smoothing_spline` chooses it (``lam=None``), in a fraction of its time.

SciPy (1.17) evaluates the GCV criterion (Wahba 1990; Hutchinson & de Hoog 1985)::

    GCV(lam) = (1/n) |y - f_lam(x)|^2 / (1 - tr(A_lam) / n)^2

with elementwise Python loops over the spline's banded matrices: about 25 ms per evaluation for a
few thousand reports, 40 s for the joint stream of a three-minute low-rate recording. The same
arithmetic is done here, in the same order, on whole bands where the loops are independent (the
numerator's band sums, the bands of ``X^T W Y``) and on Python floats where they are not (the
recurrence for the three central bands of ``(X^T W X + lam X^T E)^-1``): every evaluation is
bit-identical to SciPy's, so the bounded minimisation takes the same steps to the same ``lam``
(``tests/calib/test_mle_fast_paths.py`` checks it against SciPy in the same run).
"""

from __future__ import annotations

import numpy as np
from scipy.interpolate import BSpline
from scipy.linalg import cholesky_banded, solve_banded
from scipy.optimize import minimize_scalar

from skincal.kinematics.transforms import FloatArray


def _coeff_of_divided_diff(x: FloatArray) -> FloatArray:
    """Coefficients of the divided difference over ``x`` (SciPy's, same order of products)."""
    n = x.shape[0]
    res = np.zeros(n)
    for i in range(n):
        pp = 1.0
        for k in range(n):
            if k != i:
                pp *= x[i] - x[k]
        res[i] = 1.0 / pp
    return res


def _bands(x: FloatArray, w: FloatArray) -> tuple[FloatArray, FloatArray]:
    """The natural-spline design matrix ``X`` and penalty ``W^-1 E`` (5 bands each, LAPACK storage), as
    :func:`scipy.interpolate.make_smoothing_spline` builds them (its loop over the central columns done
    on whole windows: each entry the same products in the same order, bit-identical)."""
    t = np.r_[[x[0]] * 3, x, [x[-1]] * 3]
    n = x.shape[0]
    X_bspl = BSpline.design_matrix(x, t, 3)
    X = np.zeros((5, n))
    for i in range(1, 4):
        X[i, 2:-2] = X_bspl[i : i - 4, 3:-3][np.diag_indices(n - 4)]
    X[1, 1] = X_bspl[0, 0]
    X[2, :2] = ((x[2] + x[1] - 2 * x[0]) * X_bspl[0, 0], X_bspl[1, 1] + X_bspl[1, 2])
    X[3, :2] = ((x[2] - x[0]) * X_bspl[1, 1], X_bspl[2, 2])
    X[1, -2:] = (X_bspl[-3, -3], (x[-1] - x[-3]) * X_bspl[-2, -2])
    X[2, -2:] = (X_bspl[-2, -3] + X_bspl[-2, -2], (2 * x[-1] - x[-2] - x[-3]) * X_bspl[-1, -1])
    X[3, -2] = X_bspl[-1, -1]
    wE = np.zeros((5, n))
    wE[2:, 0] = _coeff_of_divided_diff(x[:3]) / w[:3]
    wE[1:, 1] = _coeff_of_divided_diff(x[:4]) / w[:4]
    if n > 4:  # the central columns j = 2 .. n - 3, all at once (the same products in the same order)
        win = np.lib.stride_tricks.sliding_window_view(x, 5)  # (n - 4, 5): x[j - 2 : j + 3]
        wins = np.lib.stride_tricks.sliding_window_view(w, 5)
        span = win[:, 4] - win[:, 0]
        for i in range(5):
            pp = np.ones(n - 4)
            for k in range(5):
                if k != i:
                    pp *= win[:, i] - win[:, k]
            wE[i, 2 : n - 2] = span * (1.0 / pp) / wins[:, i]
    wE[:-1, -2] = -_coeff_of_divided_diff(x[-4:]) / w[-4:]
    wE[:-2, -1] = _coeff_of_divided_diff(x[-3:]) / w[-3:]
    wE *= 6
    return X, wE


def _xt_w_y(X: FloatArray, w: FloatArray, Y: FloatArray) -> FloatArray:
    """The 4 unique bands of the symmetric ``X^T W Y`` of 5-banded ``X``, ``Y``: band ``j`` at column
    ``i + j`` is ``sum_r X[j + r, i] (W Y)[r, i + j]``, summed from 0 in ``r`` order (as SciPy's ``sum``)."""
    W_Y = np.copy(Y)
    W_Y[2] *= w
    for i in range(2):
        W_Y[i, 2 - i :] *= w[: -2 + i]
        W_Y[3 + i, : -1 - i] *= w[1 + i :]
    n = X.shape[1]
    res = np.zeros((4, n))
    for j in range(min(n, 4)):
        prod = X[j:, : n - j] * W_Y[: 5 - j, j:]
        acc = np.zeros(n - j)
        for r in range(5 - j):
            acc += prod[r]
        res[3 - j, j:] = acc
    return res


def _b_inv(A: FloatArray) -> FloatArray:
    """The 3 central bands of ``A^-1`` (``A`` 4 bands, LAPACK storage; first row of the result zero) by
    Hutchinson & de Hoog's recurrence, as SciPy computes them (same operations, on Python floats)."""
    U = cholesky_banded(A)
    for i in range(2, 5):
        U[-i, i - 1 :] /= U[-1, : -i + 1]
    D = 1.0 / (U[-1]) ** 2
    U[-1] /= U[-1]
    n = U.shape[1]
    u = U.tolist()
    d = D.tolist()
    b = [[0.0] * n for _ in range(4)]
    for i in range(n - 1, max(n - 4, -1), -1):  # the last rows: fewer than 3 bands below them
        rng = min(3, n - i - 1)
        for j in range(rng, -1, -1):
            s = 0.0
            if j == 0:
                for k in range(1, rng + 1):
                    s -= u[3 - k][i + k] * b[3 - k][i + k]
                s += d[i]
                b[3][i] = s
            else:
                for k in range(1, rng + 1):
                    diag = abs(k - j)
                    s -= u[3 - k][i + k] * b[3 - diag][i + min(k, j) + diag]
                b[3 - j][i + j] = s
    u0, u1, u2 = u[0], u[1], u[2]
    b0, b1, b2, b3 = b
    for i in range(n - 4, -1, -1):  # the same sums written out for three bands (k = 1, 2, 3 in order)
        x1, x2, x3 = u2[i + 1], u1[i + 2], u0[i + 3]
        b0[i + 3] = ((0.0 - x1 * b1[i + 3]) - x2 * b2[i + 3]) - x3 * b3[i + 3]
        b1[i + 2] = ((0.0 - x1 * b2[i + 2]) - x2 * b3[i + 2]) - x3 * b2[i + 3]
        b2[i + 1] = ((0.0 - x1 * b3[i + 1]) - x2 * b2[i + 2]) - x3 * b1[i + 3]
        b3[i] = (((0.0 - x1 * b2[i + 1]) - x2 * b1[i + 2]) - x3 * b0[i + 3]) + d[i]
    out = np.array(b)
    out[0] = 0.0
    return out


def _gcv(lam: float, X: FloatArray, XtWX: FloatArray, wE: FloatArray, XtE: FloatArray, y: FloatArray) -> float:
    """The GCV criterion at ``lam`` (module docstring), SciPy's arithmetic."""
    n = X.shape[1]
    c = solve_banded((2, 2), X + lam * wE, y)
    tmp = wE * c
    res = np.zeros(n)
    i = np.arange(n)
    for j in range(5):  # res[i] += tmp[j, i + 2 - j] where that column exists, in j order
        col = i + 2 - j
        ok = (col >= 0) & (col < n)
        res[ok] += tmp[j, col[ok]]
    numer = np.linalg.norm(lam * res) ** 2 / n
    lhs = XtWX + lam * XtE
    tr = _b_inv(lhs) * XtWX
    tr[:-1] *= 2
    denom = (1 - sum(sum(tr)) / n) ** 2
    return float(numer / denom)


def spline_bands(x: FloatArray) -> tuple[FloatArray, FloatArray]:
    """The bands ``(X, W^-1 E)`` of the smoothing spline over stamps ``x`` (increasing, unit weights):
    computed once, shared by :func:`gcv_lambda` and every :func:`smoothing_spline` over the same ``x``."""
    x = np.ascontiguousarray(x, dtype=float)
    if np.any(x[1:] - x[:-1] <= 0):
        raise ValueError("``x`` should be an ascending array")
    if x.shape[0] <= 4:
        raise ValueError("``x`` and ``y`` length must be at least 5")
    return _bands(x, np.ones(len(x)))


def gcv_lambda(x: FloatArray, y: FloatArray, bands: tuple[FloatArray, FloatArray] | None = None) -> float:
    """``lam`` of the cubic smoothing spline of ``y(x)`` (``x`` increasing, unit weights) that minimises
    the GCV criterion: the value :func:`scipy.interpolate.make_smoothing_spline` finds with ``lam=None``
    (pass it as ``lam`` for the same spline); ``bands``: :func:`spline_bands` of ``x`` when already built."""
    x = np.asarray(x, dtype=float)
    y = np.asarray(y, dtype=float)
    w = np.ones(len(x))
    X, wE = spline_bands(x) if bands is None else bands
    XtWX = _xt_w_y(X, w, X)
    XtE = _xt_w_y(X, w, wE)
    est = minimize_scalar(_gcv, bounds=(0, X.shape[1]), method="Bounded", args=(X, XtWX, wE, XtE, y))
    if not est.success:
        raise ValueError(f"Unable to find minimum of the GCV function: {est.message}")
    return float(est.x)


def smoothing_spline(
    x: FloatArray, y: FloatArray, lam: float, bands: tuple[FloatArray, FloatArray] | None = None
) -> BSpline:
    """:func:`scipy.interpolate.make_smoothing_spline` ``(x, y, lam=lam)`` (1-D ``y``, unit weights) from the
    :func:`spline_bands` of ``x`` (built once for every ``lam`` tried on the same stamps): the natural-spline
    coefficients ``c = (X + lam W^-1 E)^-1 y`` moved to the B-spline basis, SciPy's arithmetic (bit-identical)."""
    x = np.ascontiguousarray(x, dtype=float)
    y = np.ascontiguousarray(y, dtype=float)
    if lam < 0.0:
        raise ValueError("Regularization parameter should be non-negative")
    X, wE = spline_bands(x) if bands is None else bands
    t = np.r_[[x[0]] * 3, x, [x[-1]] * 3]
    c = solve_banded((2, 2), X + lam * wE, y)
    c0, c1 = c[0:1], c[1:2]
    cm0, cm1 = c[-1:-2:-1], c[-2:-3:-1]
    c_ = np.r_[
        c0 * (t[5] + t[4] - 2 * t[3]) + c1,
        c0 * (t[5] - t[3]) + c1,
        c[1:-1],
        cm0 * (t[-4] - t[-6]) + cm1,
        cm0 * (2 * t[-4] - t[-5] - t[-6]) + cm1,
    ]
    return BSpline.construct_fast(t, c_, 3, axis=0)
