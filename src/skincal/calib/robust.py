"""Robust least-squares pieces shared by the calibrators (``mle``, the IMU-only fit, the streaming
calibrator): Huber weights, a MAD-based residual scale, a scaled pseudo-inverse of normal matrices that
names its null space, the integrated autocorrelation of residuals that inflates a covariance, and the
block sandwich that raises it where the residuals follow the motion."""

from __future__ import annotations

import numpy as np

from skincal.kinematics.transforms import FloatArray

HUBER_K = 3.0
"""Huber threshold in robust standard deviations of the residual norm."""
NULL_RATIO = 1e-12
"""Eigenvalues of the scaled normal matrix below this fraction of the largest are unobservable
(exactly unobservable directions sit at ~1e-16, round-off; a direction that only a prior
determines sits far above, ~1e-10 for noise-free data, and is kept with the prior's uncertainty)."""
SANDWICH_BLOCK_S = 3.0
"""Length of the blocks of moving samples whose scores the block sandwich sums (:func:`sandwich_factors`), s:
longer than a 14 Hz joint stream's interpolation error stays correlated with the motion (on the real ABB
recordings, 1 s blocks left ``mle``'s tool-axis lever arm 1.7-2.2x over-confident across recordings, 3 s
blocks 1.3-1.6x; measured, real data), and still about twenty blocks in a recording of a minute."""


def robust_sigma(r_norm: FloatArray) -> float:
    """Robust std of one residual component from the norms of 3-vectors (MAD-based)."""
    if r_norm.size == 0:
        return 0.0
    # For 3-D Gaussian residuals the median norm is 1.5382 sigma.
    return float(np.median(r_norm) / 1.5382)


def huber_weights(norm: FloatArray, sigma: float) -> FloatArray:
    """Huber weights ``min(1, k sigma / |r|)`` of residual norms ``norm`` (``k`` = :data:`HUBER_K`)."""
    scaled = norm / (HUBER_K * sigma)
    return np.where(scaled <= 1.0, 1.0, 1.0 / np.maximum(scaled, 1e-300))


def scaled_eig(H: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Eigen-decomposition of ``D^-1 H D^-1`` with ``D = sqrt(diag H)`` floored at ``1e-7`` of its
    largest entry (a parameter without information must not be divided by ~0)."""
    diag = np.maximum(np.diag(H), 0.0)
    d = np.sqrt(np.maximum(diag, 1e-14 * max(diag.max(), 1e-300)))
    Hs = H / np.outer(d, d)
    lam, V = np.linalg.eigh(Hs)
    return d, lam, V


def pinv(H: FloatArray) -> FloatArray:
    """Pseudo-inverse of a normal matrix in its scaled eigenbasis (:func:`scaled_eig`), the directions below
    :data:`NULL_RATIO` dropped."""
    d, lam, V = scaled_eig(H)
    keep = lam > NULL_RATIO * lam.max()
    inv = (V[:, keep] / lam[keep]) @ V[:, keep].T
    return inv / np.outer(d, d)


def pinv_step(H: FloatArray, g: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Gauss-Newton step ``-H^+ g`` (:func:`pinv`) and the unit null-space directions it leaves out."""
    d, lam, V = scaled_eig(H)
    keep = lam > NULL_RATIO * lam.max()
    step = -(V[:, keep] @ ((V[:, keep].T @ (g / d)) / lam[keep])) / d
    null = V[:, ~keep] / d[:, None]
    if null.size:
        null = null / np.linalg.norm(null, axis=0)
    return step, null


RHO_CUTOFF = 0.05
"""The lags of an integrated autocorrelation are summed until the first at or below this correlation."""


def _integrated(rho: FloatArray) -> float:
    """``1 + 2 sum_k rho_k`` over the lags ``k >= 1`` of ``rho`` ``(K + 1,)`` before the first at or below
    :data:`RHO_CUTOFF` (the noisy tail of a sample autocorrelation is left out)."""
    low = np.flatnonzero(rho[1:] <= RHO_CUTOFF)
    end = int(low[0]) + 1 if low.size else len(rho)
    return 1.0 + 2.0 * float(np.sum(rho[1:end]))


CORRELATION_WARN = 4.0
"""Residual autocorrelation factors above this are reported (model error, covariance inflated), by ``mle`` and
the streaming calibrator alike."""


def residual_correlation(r: FloatArray, max_lag: int = 20) -> float:
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
    for k in range(1, max_lag + 1):  # lag by lag: white residuals stop after the first
        rho = float(np.sum(x[k:] * x[:-k]) / var)
        if rho <= RHO_CUTOFF:
            break
        total += rho
    return 1.0 + 2.0 * total


MIN_RUN_LAGS = 5
"""Fewest lags :func:`run_correlation` sums (``10`` samples per lag: 50 samples at least)."""


def run_correlation(runs: list[FloatArray], max_lag: int = 20, iterations: int = 3) -> float:
    """Integrated autocorrelation ``tau = 1 + 2 sum_k rho_k`` (>= 1) of a noise seen in short runs
    ``(n_r, 3)``, each known only about its own mean (the rest runs of a unit).

    Deviations from a run's mean ``x_t = e_t - mean(e)`` are correlated less than the noise: with
    ``Var(mean) ~ sigma^2 tau / n`` (``n`` samples), ``E[sum_t x_t x_(t+k)] ~ (n - k)(gamma_k - sigma^2
    tau / n)``, so the lag sums ``C_k`` pooled over the runs (and axes) give ``rho_k = (C_k / sigma^2 +
    3 tau sum_r (n_r - k) / n_r) / (3 sum_r (n_r - k))`` with ``sigma^2 = C_0 / (3 (N - R tau))`` (``N``
    samples in ``R`` runs). ``tau`` takes ``iterations`` such steps from ``tau = 1``:
    their fixed point is unstable when runs are a few correlation times short, so a few steps remove
    most of the bias without it (AR(1) noise of lag-1 correlation 0.6, truncated sum 3.77, 300 draws:
    5 runs of 28 samples give a median 2.90 after one step, 3.61 after three, 3.72 at the fixed point
    but with 5 % of the draws at the cap; 10 runs of 55 samples 3.32, 3.80, 3.82; measured, simulated
    noise). ``tau`` stays below ``N / (4 R)`` (a run's mean taking a quarter of its variance). 1 with
    fewer than 50 samples (:data:`MIN_RUN_LAGS` lags of 10 samples each).
    """
    runs = [r - r.mean(axis=0) for r in runs if len(r) > 1]
    n = np.array([len(r) for r in runs], dtype=float)
    N, R = float(n.sum()), len(runs)
    max_lag = min(max_lag, int(N) // 10)
    if max_lag < MIN_RUN_LAGS:
        return 1.0
    lags = np.arange(max_lag + 1)
    x = np.concatenate(runs)  # the runs end to end: a lag's products across a run's end are taken out
    x = x.reshape(len(x), -1)
    starts = np.cumsum(n.astype(int))[:-1]  # where runs 2..R begin
    C = np.zeros(max_lag + 1)
    C[0] = float(np.sum(x * x))
    for k in lags[1:]:
        across = np.unique((starts[:, None] - np.arange(1, k + 1)[None, :]).ravel())  # i < start <= i + k
        across = across[(across >= 0) & (across + k < len(x))]
        C[k] = float(np.sum(x[k:] * x[:-k])) - float(np.sum(x[across] * x[across + k]))
    if C[0] <= 0:
        return 1.0
    axes = runs[0].shape[1] if runs[0].ndim > 1 else 1
    pairs = np.maximum(n[None, :] - lags[:, None], 0.0)  # (K + 1, R) products per lag and run
    S, B = axes * pairs.sum(axis=1), axes * (pairs / n[None, :]).sum(axis=1)
    tau, cap = 1.0, 0.25 * N / R
    for _ in range(iterations):
        var = C[0] / (S[0] - B[0] * tau)
        rho = np.where(S > 0, (C / var + B * tau) / np.maximum(S, 1.0), 0.0)
        new = min(_integrated(rho), cap)
        if abs(new - tau) < 1e-6:
            break
        tau = new
    return tau


def sandwich_factors(cov: FloatArray, H_inv: FloatArray, block_scores: FloatArray, moving_blocks: int) -> FloatArray:
    """``(P,)`` factors by which each parameter's std is raised to what the residuals themselves say.

    The model covariance ``cov`` ``(P, P)`` trusts the noise model (white after the autocorrelation factor).
    The block sandwich ``H^-1 (sum_b g_b g_b^T) H^-1`` does not: ``g_b`` ``(B, P)`` (``block_scores``) is the
    score ``sum_{i in b} J_i^T W_i r_i`` of block ``b`` of samples at the estimate (``H_inv`` the
    (pseudo-)inverse of the normal matrix with the priors), so errors correlated in time *and with the
    regressors* count as often as they repeat. With ``B`` blocks the sandwich std is itself uncertain by
    about ``sqrt(1 / (2 B))``; a factor ``std_sandwich / std_model`` is applied only beyond the 99 % point of
    that noise, so honest data keep their std (in 1 % of the parameters by a few percent). The sandwich is
    scaled by ``B_m / (B_m - 1)`` (``moving_blocks`` ``B_m`` blocks of moving samples), the usual correction
    of a cluster sandwich for its few clusters. A parameter whose model variance is not positive (a normal
    matrix not positive definite there) keeps its std (factor 1)."""
    nb = block_scores.shape[0]
    cov_sw = H_inv @ (block_scores.T @ block_scores) @ H_inv
    if moving_blocks > 1:  # the small-sample correction of a cluster sandwich, B / (B - 1)
        cov_sw = cov_sw * (moving_blocks / (moving_blocks - 1.0))
    model, sw = np.diag(cov), np.diag(cov_sw)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):  # a non-positive variance: not raised
        ratio = np.sqrt(np.maximum(sw, 0.0) / np.maximum(model, 1e-300))
    ratio = np.where((model > 0) & np.isfinite(ratio), ratio, 1.0)
    return np.where(ratio > 1.0 + 2.33 * np.sqrt(0.5 / nb), ratio, 1.0)
