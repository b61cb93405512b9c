"""A unit's accelerometer fitted to its rests, ``|C (a - b)| = |g|`` (:func:`fit_accel_ellipsoid`,
:class:`AccelFit`; :func:`fit_unit_accelerometer` from a stream): the absolute scale of the IMU-only
calibration (the package docstring, "The absolute scale from rests")."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from skincal.calib.imu_only.rests import NOISE_FLOOR, distinct_orientations, rest_means
from skincal.calib.model import sym_from_e
from skincal.calib.robust import pinv
from skincal.data.dataset import ImuStream
from skincal.data.imu_calibration import ImuCalibration
from skincal.kinematics.transforms import FloatArray

ORIENTATIONS_FULL = 9
"""Distinct orientations needed for the symmetric (scale and cross-axis) fit: 6 + 3 unknowns."""
ORIENTATIONS_DIAGONAL = 6
"""Distinct orientations needed for the diagonal scale and the bias: 3 + 3 unknowns."""
ORIENTATIONS_ADVISED = 12
"""Distinct orientations a user is asked for (the symmetric fit's 9 and a margin for its conditioning)."""
MAX_SCALE_STD = 0.01
"""A fit whose scale or cross-axis std exceeds this (orientations too alike) is not used."""


@dataclass(frozen=True)
class AccelFit:
    """One accelerometer fitted to its rests: the specific force is ``C (a - b)``.

    Attributes:
        C: ``(3, 3)`` symmetric correction (the inverse of the scale and cross-axis matrix, up to a
            rotation that an ellipsoid cannot see; identity-like), ``b``: ``(3,)`` bias, m/s^2.
        cov: ``(9, 9)`` covariance of ``p = [C11, C22, C33, C12, C13, C23, b1, b2, b3]`` (zero rows
            for the cross-axis terms of the diagonal model).
        model: ``"symmetric"`` or ``"diagonal"``.
        rests, orientations: rests used and how many distinct gravity directions they have.
        residual_std: RMS of ``|C (a - b)| - |g|`` over the rests, m/s^2.
    """

    C: FloatArray
    b: FloatArray
    cov: FloatArray
    model: str
    rests: int
    orientations: int
    residual_std: float

    def apply(self, accel: FloatArray) -> FloatArray:
        """Calibrated specific force ``(M, 3)`` of raw readings ``accel`` ``(M, 3)``."""
        return (accel - self.b) @ self.C.T

    def jacobian(self, accel: FloatArray) -> FloatArray:
        """``(M, 3, 9)`` derivative of :meth:`apply` with respect to ``p``."""
        y = accel - self.b
        J = np.zeros((len(y), 3, 9))
        for i in range(3):
            J[:, i, i] = y[:, i]
        for k, (i, j) in enumerate(_OFF_DIAGONAL):
            J[:, i, 3 + k] = y[:, j]
            J[:, j, 3 + k] = y[:, i]
        J[:, :, 6:] = -self.C
        return J

    @property
    def scale_std(self) -> float:
        """Largest std of the entries of ``C`` (dimensionless)."""
        return float(np.sqrt(np.max(np.diag(self.cov)[:6])))

    def imu_calibration(self) -> ImuCalibration:
        """As :class:`~skincal.data.imu_calibration.ImuCalibration`: ``A = C^-1`` and the bias."""
        bias_std = np.sqrt(np.maximum(np.diag(self.cov)[6:], 0.0))
        return ImuCalibration(accel_bias_mps2=self.b.copy(), accel_bias_std_mps2=bias_std,
                              accel_scale_misalignment=np.linalg.inv(self.C))  # fmt: skip


_OFF_DIAGONAL = ((0, 1), (0, 2), (1, 2))


def _ellipsoid_start(means: FloatArray, gravity: float, model: str) -> tuple[FloatArray, FloatArray] | None:
    """Algebraic fit of ``(a - b)^T Q (a - b) = g^2`` (linear in ``Q``, ``-2 Q b``, a constant; the
    smallest singular vector), ``C = Q^(1/2)``; None when the quadric is no ellipsoid."""
    a = means
    quad = [a[:, 0] ** 2, a[:, 1] ** 2, a[:, 2] ** 2]
    if model == "symmetric":
        quad += [2 * a[:, i] * a[:, j] for i, j in _OFF_DIAGONAL]
    D = np.column_stack([*quad, a, np.ones(len(a))])
    scale = np.linalg.norm(D, axis=0)
    z = np.linalg.svd(D / scale, full_matrices=False)[2][-1] / scale
    nq = len(quad)
    Q = sym_from_e(np.concatenate([z[:nq], np.zeros(6 - nq)]))
    L, k = z[nq : nq + 3], z[-1]
    eig = np.linalg.eigvalsh(Q)
    if eig[0] * eig[-1] <= 0:
        return None
    if eig[0] < 0:
        Q, L, k = -Q, -L, -k
    b = -0.5 * np.linalg.solve(Q, L)
    denom = float(b @ Q @ b - k)
    if denom <= 0:
        return None
    w, V = np.linalg.eigh(Q * gravity**2 / denom)
    return (V * np.sqrt(w)) @ V.T, b


def fit_accel_ellipsoid(
    means: FloatArray,
    counts: FloatArray,
    noise_var: FloatArray,
    gravity: float,
    model: str = "symmetric",
    iterations: int = 30,
) -> AccelFit | None:
    """Fit ``|C (m_k - b)| = gravity`` to rest means ``m_k`` ``(S, 3)`` (``counts`` ``(S,)`` samples,
    per-axis sample noise variance ``noise_var`` ``(3,)``): the algebraic start, then Gauss-Newton
    weighted by each mean's std along gravity; ``model`` ``"symmetric"`` (``C`` 3x3 symmetric) or
    ``"diagonal"``. The covariance is the weighted normal matrix's inverse, inflated by the reduced
    chi-square when it exceeds 1 and there are 3 or more redundant rests. None without an ellipsoid."""
    need = ORIENTATIONS_FULL if model == "symmetric" else ORIENTATIONS_DIAGONAL
    ok = np.all(np.isfinite(means), axis=1)
    means, counts = means[ok], counts[ok]
    if len(means) < need:
        return None
    start = _ellipsoid_start(means, gravity, model)
    if start is None:
        return None
    C, b = start
    free = np.ones(9, dtype=bool)
    if model == "diagonal":
        free[3:6] = False
        C = np.diag(np.diag(C))
    p = np.concatenate([np.diag(C), [C[i, j] for i, j in _OFF_DIAGONAL], b])
    H = np.eye(9)
    e = np.zeros(len(means))
    for _ in range(iterations):
        fit = AccelFit(sym_from_e(p[:6]), p[6:], np.zeros((9, 9)), model, len(means), 0, 0.0)
        f = fit.apply(means)
        norm = np.linalg.norm(f, axis=1)
        n = f / norm[:, None]
        e = norm - gravity
        sigma2 = np.einsum("si,ij,sj->s", n @ fit.C, np.diag(noise_var), n @ fit.C) / counts
        J = np.einsum("si,sip->sp", n, fit.jacobian(means))[:, free]
        Jw = J / np.sqrt(sigma2)[:, None]
        H = Jw.T @ Jw
        step = -np.linalg.lstsq(Jw, e / np.sqrt(sigma2), rcond=None)[0]
        p[free] += step
        if np.max(np.abs(step)) < 1e-12:
            break
    dof = len(means) - int(free.sum())
    chi2 = float(np.sum(e**2 / sigma2))
    inflate = max(1.0, chi2 / dof) if dof >= 3 else 1.0
    cov = np.zeros((9, 9))
    cov[np.ix_(free, free)] = pinv(H) * inflate
    return AccelFit(sym_from_e(p[:6]), p[6:], cov, model, len(means), distinct_orientations(means),
                    float(np.sqrt(np.mean(e**2))))  # fmt: skip


def fit_unit_accelerometer(stream: ImuStream, rests: FloatArray, gravity: float) -> tuple[AccelFit | None, int]:
    """The best identifiable accelerometer fit of one unit over ``rests`` (symmetric with
    ``ORIENTATIONS_FULL`` distinct orientations, diagonal with ``ORIENTATIONS_DIAGONAL``, none below; a
    fit whose scale std exceeds ``MAX_SCALE_STD`` is refused) and the number of distinct orientations."""
    means, counts, var = rest_means(stream, rests)
    ok = np.all(np.isfinite(means), axis=1)
    if not ok.any():
        return None, 0
    distinct = distinct_orientations(means[ok])
    noise_var = np.maximum(np.median(var[ok], axis=0), NOISE_FLOOR**2)
    for model, need in (("symmetric", ORIENTATIONS_FULL), ("diagonal", ORIENTATIONS_DIAGONAL)):
        if distinct < need:
            continue
        fit = fit_accel_ellipsoid(means, counts, noise_var, gravity, model)
        if fit is not None and fit.scale_std <= MAX_SCALE_STD:
            return fit, distinct
    return None, distinct
