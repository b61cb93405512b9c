"""Closed-form starts for a unit's pose: Wahba's problem for the rotation, linear least squares
for the position. No bounds, no random restarts, no seed.

Measurement model (link frame ``n``, unit frame ``su``)::

    f_su = R^T (u + K p) + b           R = R_link_su, p = p_link_su, b accelerometer bias

where ``u`` is the specific force of the link frame's origin and ``K = [dw]x + [w]x^2`` maps the
unit's position to the rigid-body acceleration terms (both in link frame, see
:mod:`skincal.calib.signals`). At rest ``K = 0`` and ``u = R_base_link^T (-g)``.
"""

from __future__ import annotations

import numpy as np

from skincal.kinematics.transforms import FloatArray


def wahba(v_link: FloatArray, v_su: FloatArray, weights: FloatArray | None = None) -> FloatArray:
    """Rotation ``R_link_su`` minimising ``sum_i w_i |v_link_i - R v_su_i|^2`` (Wahba 1965).

    SVD solution (Markley 1988): ``B = sum w_i v_link_i v_su_i^T = U S V^T``,
    ``R = U diag(1, 1, det(U) det(V)) V^T``. Inputs ``(M, 3)``; needs two non-parallel pairs.
    """
    w = np.ones(len(v_link)) if weights is None else np.asarray(weights, dtype=float)
    B = np.einsum("i,ij,ik->jk", w, v_link, v_su)
    U, _, Vt = np.linalg.svd(B)
    D = np.diag([1.0, 1.0, np.linalg.det(U) * np.linalg.det(Vt)])
    return U @ D @ Vt


def static_rotation_and_bias(
    u_link: FloatArray, f_su: FloatArray, weights: FloatArray, iterations: int = 20
) -> tuple[FloatArray, FloatArray]:
    """Rotation and bias from static means: alternate Wahba on ``f - b`` and ``b = mean(f - R^T u)``.

    ``u_link``: ``(S, 3)`` specific force at rest in link frame (``R_base_link^T (-g)``);
    ``f_su``: ``(S, 3)`` measured static means; ``weights``: ``(S,)`` sample counts. The bias
    step is skipped when fewer than 4 static orientations are spread enough to separate it from
    the rotation (then ``b = 0``).
    """
    w = np.asarray(weights, dtype=float)
    b = np.zeros(3)
    dirs = u_link / np.linalg.norm(u_link, axis=1, keepdims=True)
    spread = np.linalg.svd(dirs - dirs.mean(axis=0), compute_uv=False)
    estimate_bias = len(u_link) >= 4 and spread.min() > 0.05 * np.sqrt(len(u_link))
    R = wahba(u_link, f_su, w)
    for _ in range(iterations if estimate_bias else 0):
        b_new = np.average(f_su - u_link @ R, axis=0, weights=w)  # rows: (R^T u)^T = u^T R
        R = wahba(u_link, f_su - b_new, w)
        if np.linalg.norm(b_new - b) < 1e-9:
            b = b_new
            break
        b = b_new
    return R, b


def position_and_bias(
    R_link_su: FloatArray, u_link: FloatArray, K_link: FloatArray, f_su: FloatArray, weights: FloatArray | None = None
) -> tuple[FloatArray, FloatArray]:
    """Linear least squares for ``p`` and ``b`` with the rotation known.

    ``R f = u + K p + R b`` gives, per sample, ``[K, I] [p; c] = R f - u`` with ``c = R b``.
    Inputs: ``u_link`` ``(M, 3)``, ``K_link`` ``(M, 3, 3)``, ``f_su`` ``(M, 3)``; returns ``(p, b)``.
    """
    M = len(u_link)
    w = np.ones(M) if weights is None else np.asarray(weights, dtype=float)
    A = np.zeros((M, 3, 6))
    A[:, :, :3] = K_link
    A[:, :, 3:] = np.eye(3)
    y = f_su @ R_link_su.T - u_link
    sw = np.sqrt(w)[:, None, None]
    sol, *_ = np.linalg.lstsq((A * sw).reshape(-1, 6), (y[:, :, None] * sw).reshape(-1), rcond=None)
    return sol[:3], R_link_su.T @ sol[3:]
