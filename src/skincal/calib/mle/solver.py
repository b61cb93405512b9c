"""Robust Gauss-Newton for one unit: pose, accelerometer bias, scale/misalignment, time offset.

Measurement model for sample ``i`` (unit frame)::

    a_i = A R^T v_i + b + noise,    v_i = u(t_i - tau) + K(t_i - tau) p       (link frame)

with ``R = R_link_su``, ``p = p_link_su``, ``b`` the bias, ``A = I + E`` a symmetric
scale/misalignment matrix (the antisymmetric part of a misalignment is a rotation and is
absorbed in ``R``: the unit frame is the accelerometer's polar frame) and ``tau`` the IMU's
latency. ``u``, ``K`` come from :mod:`skincal.calib.mle.signals`.

The solver works on the manifold (``R <- R Exp(dtheta)``, ``dtheta`` in the unit frame), linearises
the time dependence around the current ``tau_k`` (``v(tau) ~ v_k - (tau - tau_k) dv/dt``) and
re-evaluates the signals at the new ``tau`` in an outer loop. Outliers are handled by Huber
iteratively re-weighted least squares on the residual norm; directions the data cannot
determine (a unit on link 1) are left at their start values (pseudo-inverse on the scaled normal
equations) and reported.

Parameter vector order: ``dtheta (3), p (3), b (3), e (6: xx, yy, zz, xy, xz, yz), tau (1)``;
``e`` and ``tau`` only when estimated.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np
from scipy.spatial.transform import Rotation

from skincal.kinematics.transforms import FloatArray, skew

HUBER_K = 3.0
"""Huber threshold in robust standard deviations of the residual norm."""
NULL_RATIO = 1e-9
"""Eigenvalues of the scaled normal matrix below this fraction of the largest are unobservable."""


def sym_from_e(e: FloatArray) -> FloatArray:
    """Symmetric ``E`` from ``e = (xx, yy, zz, xy, xz, yz)``."""
    return np.array([[e[0], e[3], e[4]], [e[3], e[1], e[5]], [e[4], e[5], e[2]]])


@dataclass(frozen=True)
class State:
    """Estimate of one unit: ``R_link_su``, ``p_link_su`` (m), bias (m/s^2), ``e`` (scale and
    misalignment, dimensionless), ``tau`` (s)."""

    R: FloatArray
    p: FloatArray
    b: FloatArray
    e: FloatArray = field(default_factory=lambda: np.zeros(6))
    tau: float = 0.0

    @property
    def A(self) -> FloatArray:
        return np.eye(3) + sym_from_e(self.e)


@dataclass(frozen=True)
class Blocks:
    """Which parameter blocks are estimated."""

    scale: bool = True
    time_offset: bool = True

    @property
    def size(self) -> int:
        return 9 + 6 * self.scale + self.time_offset


@dataclass(frozen=True)
class Linearisation:
    """Signals at ``tau_k`` for the moving samples: ``u, du`` ``(M, 3)``, ``K, dK`` ``(M, 3, 3)``
    (``d`` = time derivative) and the stationary rows ``u_s`` ``(S, 3)``."""

    tau_k: float
    u: FloatArray
    K: FloatArray
    du: FloatArray
    dK: FloatArray


@dataclass(frozen=True)
class Fit:
    """Solver output: the state, the covariance of the estimated parameters (parameter-vector
    order), the robust residual std (m/s^2), the null-space directions (columns, parameter
    order), per-sample robust weights and the final weighted cost."""

    state: State
    covariance: FloatArray
    sigma: float
    null_space: FloatArray
    blocks: Blocks
    cost: float
    iterations: int
    residual_correlation: float


def _jacobian_and_residual(
    state: State,
    blocks: Blocks,
    lin: Linearisation | None,
    static_u: FloatArray,
    f_static: FloatArray,
    f_moving: FloatArray,
) -> tuple[FloatArray, FloatArray]:
    """Stacked residuals ``(S + M, 3)`` and Jacobian ``(S + M, 3, P)`` (static rows first)."""
    R, A = state.R, state.A
    if lin is not None:
        dtau = state.tau - lin.tau_k
        v_m = lin.u - dtau * lin.du + np.einsum("mij,j->mi", lin.K - dtau * lin.dK, state.p)
        v = np.concatenate([static_u, v_m])
    else:
        v = static_u
    f = v @ R  # rows: (R^T v)^T
    pred = f @ A.T + state.b
    meas = np.concatenate([f_static, f_moving]) if lin is not None else f_static
    r = pred - meas
    S = len(static_u)
    J = np.zeros((len(v), 3, blocks.size))
    J[:, :, 0:3] = A @ skew(f)  # d/d dtheta of A R^T v with R <- R Exp(dtheta): A [f]x
    if lin is not None:
        ART = A @ R.T
        J[S:, :, 3:6] = np.einsum("ij,mjk->mik", ART, lin.K - dtau * lin.dK)
    J[:, :, 6:9] = np.eye(3)
    col = 9
    if blocks.scale:
        fx, fy, fz = f[:, 0], f[:, 1], f[:, 2]
        J[:, 0, col + 0] = fx
        J[:, 1, col + 1] = fy
        J[:, 2, col + 2] = fz
        J[:, 0, col + 3], J[:, 1, col + 3] = fy, fx
        J[:, 0, col + 4], J[:, 2, col + 4] = fz, fx
        J[:, 1, col + 5], J[:, 2, col + 5] = fz, fy
        col += 6
    if blocks.time_offset and lin is not None:
        dv = lin.du + np.einsum("mij,j->mi", lin.dK, state.p)
        J[S:, :, col] = -(dv @ R) @ A.T
    return r, J


def _apply(state: State, blocks: Blocks, delta: FloatArray) -> State:
    R = state.R @ Rotation.from_rotvec(delta[0:3]).as_matrix()
    col = 9
    e = state.e
    if blocks.scale:
        e = e + delta[col : col + 6]
        col += 6
    tau = state.tau + (delta[col] if blocks.time_offset else 0.0)
    return replace(state, R=R, p=state.p + delta[3:6], b=state.b + delta[6:9], e=e, tau=float(tau))


def _robust_sigma(r_norm: FloatArray) -> float:
    """Robust std of one residual component from the norms of 3-vectors (MAD-based)."""
    if r_norm.size == 0:
        return 0.0
    # For 3-D Gaussian residuals the median norm is 1.5382 sigma.
    return float(np.median(r_norm) / 1.5382)


def solve(
    state: State,
    blocks: Blocks,
    static_u: FloatArray,
    static_f: FloatArray,
    static_weight: FloatArray,
    moving_f: FloatArray,
    linearise: Callable[[float], Linearisation] | None,
    *,
    max_outer: int = 6,
    max_inner: int = 8,
    tol: float = 1e-9,
) -> Fit:
    """Robust Gauss-Newton (see module docstring).

    Args:
        state: start.
        blocks: which optional blocks (scale/misalignment, time offset) are estimated.
        static_u, static_f, static_weight: averaged stationary rows ``(S, 3)``, ``(S, 3)``, ``(S,)``.
        moving_f: ``(M, 3)`` measured specific force of the moving samples.
        linearise: ``tau -> Linearisation`` for the moving samples (``None``: static data only).
    """
    if linearise is None:
        blocks = replace(blocks, time_offset=False)
    sw_static = np.sqrt(static_weight)
    lin = linearise(state.tau) if linearise is not None else None
    sigma = 1.0
    iterations = 0
    null = np.zeros((blocks.size, 0))
    H = np.zeros((blocks.size, blocks.size))
    r = np.zeros((0, 3))
    w = np.zeros(0)
    for _outer in range(max_outer):
        for _inner in range(max_inner):
            iterations += 1
            r, J = _jacobian_and_residual(state, blocks, lin, static_u, static_f, moving_f)
            # Row weights: static means count sqrt(n) times; Huber IRLS on the residual norm.
            base = np.concatenate([sw_static, np.ones(len(r) - len(sw_static))])
            norm = np.linalg.norm(r, axis=1) * base
            sigma = max(_robust_sigma(norm[len(sw_static) :] if len(r) > len(sw_static) else norm), 1e-12)
            scaled = norm / (HUBER_K * sigma)
            robust_w = np.where(scaled <= 1.0, 1.0, 1.0 / np.maximum(scaled, 1e-300))
            w = (base**2) * robust_w
            H, g = _normal_equations(J, r, w)
            delta, null = _pinv_step(H, g)
            state = _apply(state, blocks, delta)
            if np.max(np.abs(delta)) < tol:
                break
        max_inner = min(max_inner, 3)  # later outer loops only follow the small change of tau
        if lin is None or not blocks.time_offset or abs(state.tau - lin.tau_k) < 1e-7:
            break
        lin = linearise(state.tau)
    # Covariance from the last iteration's normal matrix (the final step changes it negligibly).
    rho = _residual_correlation(r[len(sw_static) :])
    cov = (sigma**2) * rho * _pinv(H)
    cost = float(np.sum(w * np.sum(r * r, axis=1)))
    return Fit(state, cov, sigma, null, blocks, cost, iterations, rho)


def _normal_equations(J: FloatArray, r: FloatArray, w: FloatArray) -> tuple[FloatArray, FloatArray]:
    """``H = J^T W J`` and ``g = J^T W r`` for row weights ``w`` (per sample, all 3 components)."""
    sw = np.sqrt(w)[:, None, None]
    Jw = (J * sw).reshape(-1, J.shape[2])
    return Jw.T @ Jw, Jw.T @ (r[:, :, None] * sw).reshape(-1)


def _scaled_eig(H: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
    d = np.sqrt(np.maximum(np.diag(H), 1e-300))
    Hs = H / np.outer(d, d)
    lam, V = np.linalg.eigh(Hs)
    return d, lam, V


def _pinv(H: FloatArray) -> FloatArray:
    d, lam, V = _scaled_eig(H)
    keep = lam > NULL_RATIO * lam.max()
    inv = (V[:, keep] / lam[keep]) @ V[:, keep].T
    return inv / np.outer(d, d)


def _pinv_step(H: FloatArray, g: FloatArray) -> tuple[FloatArray, FloatArray]:
    d, lam, V = _scaled_eig(H)
    keep = lam > NULL_RATIO * lam.max()
    step = -(V[:, keep] @ ((V[:, keep].T @ (g / d)) / lam[keep])) / d
    null = V[:, ~keep] / d[:, None]
    if null.size:
        null = null / np.linalg.norm(null, axis=0)
    return step, null


def _residual_correlation(r: FloatArray, max_lag: int = 20) -> float:
    """Integrated autocorrelation ``1 + 2 sum_k rho_k`` of the moving residuals (>= 1).

    Residuals of neighbouring samples are correlated when the error is not white (estimated
    joint accelerations, unmodelled dynamics); the covariance is inflated by this factor.
    """
    if len(r) < 10 * max_lag:
        return 1.0
    x = r - r.mean(axis=0)
    var = np.sum(x * x)
    if var <= 0:
        return 1.0
    total = 0.0
    for k in range(1, max_lag + 1):
        rho = float(np.sum(x[k:] * x[:-k]) / var)
        if rho <= 0.05:
            break
        total += rho
    return 1.0 + 2.0 * total
