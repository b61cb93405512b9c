"""Batched homogeneous transforms and rotation helpers.

All functions broadcast over leading axes: an angle array of shape ``(...,)`` gives transforms of
shape ``(..., 4, 4)``. Quaternions are ordered (w, x, y, z) at every boundary of skincal.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

FloatArray = NDArray[np.float64]


def rot_x(angle: ArrayLike) -> FloatArray:
    """Rotation matrices about x, shape ``(..., 3, 3)``; ``angle`` in rad."""
    a = np.asarray(angle, dtype=float)
    c, s = np.cos(a), np.sin(a)
    R = np.zeros(a.shape + (3, 3))
    R[..., 0, 0] = 1.0
    R[..., 1, 1] = c
    R[..., 1, 2] = -s
    R[..., 2, 1] = s
    R[..., 2, 2] = c
    return R


def rot_z(angle: ArrayLike) -> FloatArray:
    """Rotation matrices about z, shape ``(..., 3, 3)``; ``angle`` in rad."""
    a = np.asarray(angle, dtype=float)
    c, s = np.cos(a), np.sin(a)
    R = np.zeros(a.shape + (3, 3))
    R[..., 0, 0] = c
    R[..., 0, 1] = -s
    R[..., 1, 0] = s
    R[..., 1, 1] = c
    R[..., 2, 2] = 1.0
    return R


def homogeneous(R: ArrayLike, p: ArrayLike) -> FloatArray:
    """Stack rotations ``(..., 3, 3)`` and translations ``(..., 3)`` into ``(..., 4, 4)``."""
    R = np.asarray(R, dtype=float)
    p = np.asarray(p, dtype=float)
    shape = np.broadcast_shapes(R.shape[:-2], p.shape[:-1])
    T = np.zeros(shape + (4, 4))
    T[..., :3, :3] = R
    T[..., :3, 3] = p
    T[..., 3, 3] = 1.0
    return T


def modified_dh(theta: ArrayLike, d: ArrayLike, a: ArrayLike, alpha: ArrayLike) -> FloatArray:
    """Craig's modified DH step ``T_{i-1,i} = Rx(alpha) Tx(a) Rz(theta) Tz(d)``, ``(..., 4, 4)``."""
    theta, d, a, alpha = np.broadcast_arrays(*(np.asarray(x, dtype=float) for x in (theta, d, a, alpha)))
    ct, st = np.cos(theta), np.sin(theta)
    ca, sa = np.cos(alpha), np.sin(alpha)
    T = np.zeros(theta.shape + (4, 4))
    T[..., 0, 0] = ct
    T[..., 0, 1] = -st
    T[..., 0, 3] = a
    T[..., 1, 0] = st * ca
    T[..., 1, 1] = ct * ca
    T[..., 1, 2] = -sa
    T[..., 1, 3] = -sa * d
    T[..., 2, 0] = st * sa
    T[..., 2, 1] = ct * sa
    T[..., 2, 2] = ca
    T[..., 2, 3] = ca * d
    T[..., 3, 3] = 1.0
    return T


def standard_dh(theta: ArrayLike, d: ArrayLike, a: ArrayLike, alpha: ArrayLike) -> FloatArray:
    """Standard DH step ``T_{i-1,i} = Rz(theta) Tz(d) Tx(a) Rx(alpha)``, ``(..., 4, 4)``."""
    theta, d, a, alpha = np.broadcast_arrays(*(np.asarray(x, dtype=float) for x in (theta, d, a, alpha)))
    ct, st = np.cos(theta), np.sin(theta)
    ca, sa = np.cos(alpha), np.sin(alpha)
    T = np.zeros(theta.shape + (4, 4))
    T[..., 0, 0] = ct
    T[..., 0, 1] = -st * ca
    T[..., 0, 2] = st * sa
    T[..., 0, 3] = a * ct
    T[..., 1, 0] = st
    T[..., 1, 1] = ct * ca
    T[..., 1, 2] = -ct * sa
    T[..., 1, 3] = a * st
    T[..., 2, 1] = sa
    T[..., 2, 2] = ca
    T[..., 2, 3] = d
    T[..., 3, 3] = 1.0
    return T


def invert(T: ArrayLike) -> FloatArray:
    """Inverse of rigid transforms ``(..., 4, 4)``: ``[R^T, -R^T p]``."""
    T = np.asarray(T, dtype=float)
    Rt = np.swapaxes(T[..., :3, :3], -1, -2)
    return homogeneous(Rt, -np.einsum("...ij,...j->...i", Rt, T[..., :3, 3]))


def quat_wxyz_from_matrix(R: ArrayLike) -> FloatArray:
    """Unit quaternions (w, x, y, z), ``w >= 0``, from rotation matrices ``(..., 3, 3)``."""
    R = np.asarray(R, dtype=float)
    q = Rotation.from_matrix(R.reshape(-1, 3, 3)).as_quat(scalar_first=True)
    q = np.where(q[:, :1] < 0.0, -q, q)
    return q.reshape(R.shape[:-2] + (4,))


def matrix_from_quat_wxyz(q: ArrayLike) -> FloatArray:
    """Rotation matrices ``(..., 3, 3)`` from quaternions (w, x, y, z) (normalised here)."""
    q = np.asarray(q, dtype=float)
    R = Rotation.from_quat(q.reshape(-1, 4), scalar_first=True).as_matrix()
    return R.reshape(q.shape[:-1] + (3, 3))


def rotation_angle(R_a: ArrayLike, R_b: ArrayLike) -> FloatArray:
    """Angle of ``R_a^T R_b`` in rad, ``(...)``: the geodesic distance between two rotations."""
    R_rel = np.einsum("...ji,...jk->...ik", np.asarray(R_a, float), np.asarray(R_b, float))
    tr = np.trace(R_rel, axis1=-2, axis2=-1)
    # atan2 form: accurate near 0 and pi, unlike arccos((tr - 1) / 2).
    w = np.stack(
        [R_rel[..., 2, 1] - R_rel[..., 1, 2], R_rel[..., 0, 2] - R_rel[..., 2, 0], R_rel[..., 1, 0] - R_rel[..., 0, 1]],
        axis=-1,
    )
    return np.arctan2(0.5 * np.linalg.norm(w, axis=-1), 0.5 * (tr - 1.0))


def nearest_rotation(M: ArrayLike) -> FloatArray:
    """The rotation nearest to ``M`` ``(3, 3)`` in the Frobenius norm (SVD projection onto SO(3)).

    ``M = U S V^T``: ``R = U diag(1, 1, det(U) det(V)) V^T`` (the last sign keeps ``det R = +1``); the
    solution of Wahba's problem for ``M = B`` (:func:`skincal.calib.closed_form.wahba`).
    """
    U, _, Vt = np.linalg.svd(np.asarray(M, dtype=float))
    D = np.diag([1.0, 1.0, np.linalg.det(U) * np.linalg.det(Vt)])
    return U @ D @ Vt


def quaternion_distance(q_a: ArrayLike, q_b: ArrayLike) -> FloatArray:
    """The paper's quaternion distance ``min(|q_a - q_b|, |q_a + q_b|)`` on unit quaternions."""
    q_a = np.asarray(q_a, dtype=float)
    q_b = np.asarray(q_b, dtype=float)
    q_a = q_a / np.linalg.norm(q_a, axis=-1, keepdims=True)
    q_b = q_b / np.linalg.norm(q_b, axis=-1, keepdims=True)
    return np.minimum(np.linalg.norm(q_a - q_b, axis=-1), np.linalg.norm(q_a + q_b, axis=-1))


def exp_rotation(v: ArrayLike) -> FloatArray:
    """``Exp([v]x)`` ``(3, 3)`` of one rotation vector ``v`` ``(3,)`` (rad): through the unit quaternion
    ``(w, x, y, z) = (cos(|v|/2), sin(|v|/2) v / |v|)`` (a Taylor series of ``sin(|v|/2) / |v|`` below 1e-3 rad),
    the arithmetic of ``scipy.spatial.transform.Rotation.from_rotvec(v).as_matrix()`` without its object (a
    Gauss-Newton's step in a hot loop)."""
    v0, v1, v2 = (float(c) for c in np.asarray(v, dtype=float).reshape(3))
    angle = math.sqrt(v0 * v0 + v1 * v1 + v2 * v2)
    if angle <= 1e-3:
        a2 = angle * angle
        scale = 0.5 - a2 / 48 + a2 * a2 / 3840
    else:
        scale = math.sin(angle / 2) / angle
    x, y, z, w = scale * v0, scale * v1, scale * v2, math.cos(angle / 2)
    x2, y2, z2, w2 = x * x, y * y, z * z, w * w
    xy, zw, xz, yw, yz, xw = x * y, z * w, x * z, y * w, y * z, x * w
    return np.array([
        [x2 - y2 - z2 + w2, 2 * (xy - zw), 2 * (xz + yw)],
        [2 * (xy + zw), -x2 + y2 - z2 + w2, 2 * (yz - xw)],
        [2 * (xz - yw), 2 * (yz + xw), -x2 - y2 + z2 + w2],
    ])  # fmt: skip


def skew(v: ArrayLike) -> FloatArray:
    """Cross-product matrices ``[v]_x`` of shape ``(..., 3, 3)`` so that ``[v]_x w = v x w``."""
    v = np.asarray(v, dtype=float)
    S = np.zeros(v.shape[:-1] + (3, 3))
    S[..., 0, 1] = -v[..., 2]
    S[..., 0, 2] = v[..., 1]
    S[..., 1, 0] = v[..., 2]
    S[..., 1, 2] = -v[..., 0]
    S[..., 2, 0] = -v[..., 1]
    S[..., 2, 1] = v[..., 0]
    return S
