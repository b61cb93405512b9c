"""Skin unit poses on the kinematic chain and the paper's 6-parameter virtual-joint DH form.

A skin unit (SU) on link ``n`` moves rigidly with joint ``n``. Its pose ``T_link_su = (R, p)`` is
given in link frame ``n`` = DH frame {n} of the robot's convention (``docs/interfaces.md``). The
SU's z axis points out of the link surface; the time-of-flight sensor looks along it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from skincal.errors import ConfigError
from skincal.kinematics.transforms import (
    FloatArray,
    homogeneous,
    matrix_from_quat_wxyz,
    modified_dh,
    quat_wxyz_from_matrix,
    rot_x,
    rot_z,
)

DH6_NAMES = ("theta_v", "d_v", "theta_su", "d_su", "a_su", "alpha_su")
"""Order of the paper's SU parameters (the authors' code order)."""

_SINGULAR_SIN = 1e-12
_NEAR_SINGULAR_SIN = 1e-6


@dataclass(frozen=True)
class SkinUnitPose:
    """Pose of one skin unit in its link frame.

    Attributes:
        link: 1-based link the unit is fixed to (it moves with joint ``link``); 0 is the base frame, or
            the reference unit's frame of an IMU-only relative result (``calib.imu_only``).
        R_link_su: ``(3, 3)`` rotation: columns are the SU axes in link frame ``link``.
        p_link_su: ``(3,)`` SU origin in link frame ``link``, m.
    """

    link: int
    R_link_su: FloatArray
    p_link_su: FloatArray

    def __post_init__(self) -> None:
        if not isinstance(self.link, (int, np.integer)) or int(self.link) < 0:
            raise ConfigError(f"skin unit link must be a non-negative integer, got {self.link!r}")
        object.__setattr__(self, "link", int(self.link))
        R = np.array(self.R_link_su, dtype=float)
        p = np.array(self.p_link_su, dtype=float)
        if R.shape != (3, 3) or p.shape != (3,):
            raise ConfigError(f"skin unit pose needs R (3, 3) and p (3,), got {R.shape} and {p.shape}")
        if not (np.all(np.isfinite(R)) and np.all(np.isfinite(p))):
            raise ConfigError("skin unit pose contains NaN or infinite values")
        if np.abs(R.T @ R - np.eye(3)).max() > 1e-6 or np.linalg.det(R) < 0:
            raise ConfigError("skin unit rotation is not a proper rotation matrix")
        R.setflags(write=False)
        p.setflags(write=False)
        object.__setattr__(self, "R_link_su", R)
        object.__setattr__(self, "p_link_su", p)

    @classmethod
    def from_quaternion(cls, link: int, position: ArrayLike, quaternion_wxyz: ArrayLike) -> SkinUnitPose:
        """Build from a position (m) and a quaternion ordered (w, x, y, z)."""
        q = np.asarray(quaternion_wxyz, dtype=float)
        if q.shape != (4,) or not np.all(np.isfinite(q)) or np.linalg.norm(q) < 1e-9:
            raise ConfigError(f"quaternion_wxyz must be 4 finite numbers, not all zero, got {q.tolist()}")
        return cls(link, matrix_from_quat_wxyz(q), position)

    @classmethod
    def from_dh6(cls, link: int, params: ArrayLike) -> SkinUnitPose:
        """Build from the paper's parameters ``[theta_v, d_v, theta_su, d_su, a_su, alpha_su]``."""
        T = dh6_to_transform(params)
        return cls(link, T[:3, :3], T[:3, 3])

    @property
    def quaternion_wxyz(self) -> FloatArray:
        """Orientation as a unit quaternion (w, x, y, z) with ``w >= 0``."""
        return quat_wxyz_from_matrix(self.R_link_su)

    @property
    def T_link_su(self) -> FloatArray:
        """Homogeneous ``(4, 4)`` pose in the link frame."""
        return homogeneous(self.R_link_su, self.p_link_su)

    def dh6(self) -> FloatArray:
        """The paper's six parameters of this pose (one of the equivalent sets; see :func:`dh6_from_transform`)."""
        return dh6_from_transform(self.T_link_su)


def dh6_to_transform(params: ArrayLike) -> FloatArray:
    """Paper Eq. 1: ``T_n_k = [Rz(theta_v) Tz(d_v)] . modDH(theta_su, d_su, a_su, alpha_su)``.

    ``modDH(theta, d, a, alpha) = Rx(alpha) Tx(a) Rz(theta) Tz(d)`` (Craig). ``params``: ``(..., 6)``
    in the order of :data:`DH6_NAMES`; returns ``(..., 4, 4)`` poses of the SU in joint/link frame n.
    """
    x = np.asarray(params, dtype=float)
    if x.shape[-1] != 6:
        raise ConfigError(f"DH6 parameters must have 6 entries, got shape {x.shape}")
    theta_v, d_v, theta_su, d_su, a_su, alpha_su = np.moveaxis(x, -1, 0)
    T_v = homogeneous(rot_z(theta_v), np.stack([np.zeros_like(d_v), np.zeros_like(d_v), d_v], axis=-1))
    return T_v @ modified_dh(theta_su, d_su, a_su, alpha_su)


def dh6_from_transform(T: ArrayLike) -> FloatArray:
    """Inverse of :func:`dh6_to_transform`: one parameter set reproducing the pose exactly.

    The rotation is a z-x-z Euler product ``R = Rz(theta_v) Rx(alpha_su) Rz(theta_su)``; the
    position satisfies ``p = d_su z_su + a_su [cos theta_v, sin theta_v, 0] + d_v e_z``, a 3x3
    linear system whose determinant is ``sin(alpha_su)``. The branch with ``a_su >= 0`` is chosen
    (the paper's bound). When the SU's z axis is parallel to the joint axis (``sin(alpha) = 0``)
    the representation is singular: then ``theta_v`` points the virtual joint's x axis at the SU,
    ``d_su = 0`` and ``d_v`` carries the height, which still reproduces the pose exactly. Within
    ``sin(alpha) < 1e-6`` of the singularity no parameter set is both bounded and exact; the better
    of the two readings is returned (round-trip error below 1e-8 everywhere).
    """
    T = np.asarray(T, dtype=float)
    if T.shape[-2:] != (4, 4):
        raise ConfigError(f"expected (..., 4, 4) transforms, got {T.shape}")
    flat = T.reshape(-1, 4, 4)
    out = np.array([_dh6_single(Ti) for Ti in flat])
    return out.reshape(T.shape[:-2] + (6,))


def _dh6_single(T: FloatArray) -> FloatArray:
    R, p = T[:3, :3], T[:3, 3]
    sin_alpha = float(np.hypot(R[0, 2], R[1, 2]))
    if sin_alpha < _SINGULAR_SIN:
        return _dh6_singular(R, p)
    general = _dh6_general(R, p, sin_alpha)
    if sin_alpha < _NEAR_SINGULAR_SIN:
        # Near the singularity the position solve amplifies rounding by 1/sin(alpha) while snapping
        # alpha to {0, pi} costs sin(alpha) in rotation: keep whichever reproduces the pose better.
        snapped = _dh6_singular(R, p)
        err = [np.abs(dh6_to_transform(x) - T).max() for x in (general, snapped)]
        return general if err[0] <= err[1] else snapped
    return general


def _wrap(angle: float) -> float:
    return float((angle + np.pi) % (2 * np.pi) - np.pi)


def _dh6_general(R: FloatArray, p: FloatArray, sin_alpha: float) -> FloatArray:
    # Branch with alpha in (0, pi): theta_v from the SU's z axis; theta_su from the residual
    # rotation (Rz(theta_v) Rx(alpha))^T R = Rz(theta_su), accurate also for small alpha.
    alpha = float(np.arctan2(sin_alpha, R[2, 2]))
    theta_v = float(np.arctan2(R[0, 2], -R[1, 2]))
    M = (rot_z(theta_v) @ rot_x(alpha)).T @ R
    theta_su = float(np.arctan2(M[1, 0], M[0, 0]))
    x_v = np.array([np.cos(theta_v), np.sin(theta_v), 0.0])
    A = np.column_stack([R[:, 2], x_v, [0.0, 0.0, 1.0]])
    d_su, a_su, d_v = np.linalg.solve(A, p)
    if a_su < 0.0:  # the equivalent branch (theta_v + pi, -alpha, theta_su + pi) flips a_su
        theta_v, alpha, theta_su, a_su = theta_v + np.pi, -alpha, theta_su + np.pi, -a_su
    return np.array([_wrap(theta_v), d_v, _wrap(theta_su), d_su, a_su, _wrap(alpha)])


def _dh6_singular(R: FloatArray, p: FloatArray) -> FloatArray:
    # z_su is +-z_link: R = Rz(theta_v) Rx(alpha) Rz(theta_su) with alpha in {0, pi}.
    alpha = 0.0 if R[2, 2] > 0 else np.pi
    radial = float(np.hypot(p[0], p[1]))
    theta_v = float(np.arctan2(p[1], p[0])) if radial > 0 else 0.0
    M = (rot_z(theta_v) @ _rot_x_exact(alpha)).T @ R
    theta_su = float(np.arctan2(M[1, 0], M[0, 0]))
    return np.array([_wrap(theta_v), float(p[2]), _wrap(theta_su), 0.0, radial, _wrap(alpha)])


def _rot_x_exact(alpha: float) -> FloatArray:
    """``Rx(alpha)`` for ``alpha`` in {0, pi} without the ``sin(pi) = 1.2e-16`` residue."""
    return np.diag([1.0, 1.0, 1.0]) if alpha == 0.0 else np.diag([1.0, -1.0, -1.0])
