"""A gyroscope's scale and misalignment, checked against the robot's own rotation rate.

Consumer gyroscopes are off by a few percent in scale (``real-consumer`` IMUs: 4.5 % per axis) and the
calibrators' models read them as ``g = R^T w + b_g`` (``R = R_link_su``, ``w`` the link's angular velocity
in link frame from the joint stream). With a scale/misalignment matrix ``A_g`` the reading is
``g = A_g R^T w + b_g = M w + b_g``: linear in ``M`` (9) and ``b_g`` (3), so the moving samples give
``M`` by least squares. ``M M^T = A_g A_g^T`` does not depend on the unknown rotation, and for the
symmetric positive ``A_g`` of a scale and a symmetric misalignment, ``A_g = (M M^T)^(1/2)``: the
gyroscope is checked before the pose is fitted, with no new unknown in the pose fit. It is named, not
corrected: the antisymmetric part of a misalignment is a rotation, indistinguishable from the unit's pose
by the gyroscope alone, and correcting the scale alone would let the misaligned gyroscope decide the
rotation more firmly.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg import sqrtm

from skincal.kinematics.transforms import FloatArray

MIN_SAMPLES = 200
"""Moving samples needed before the scale is looked at."""
DETERMINED_STD = 0.002
"""Each diagonal element of ``A_g`` must be determined to this std (relative) to be used..."""
CORRECT_MIN = 0.005
"""...and differ from 1 by at least this (0.5 %) and by 4 of its std to be corrected."""
CORRECT_SIGMAS = 4.0


@dataclass(frozen=True)
class GyroScale:
    """The gyroscope's symmetric scale/misalignment ``A`` ``(3, 3)`` (readings ``A R^T w + b``), its
    diagonal's std ``(3,)``, the bias ``b`` ``(3,)`` rad/s, and whether it is determined and off."""

    A: FloatArray
    diag_std: FloatArray
    bias: FloatArray
    samples: int

    @property
    def determined(self) -> bool:
        return bool(self.samples >= MIN_SAMPLES and np.all(self.diag_std <= DETERMINED_STD))

    @property
    def off(self) -> bool:
        """Determined and off identity by more than :data:`CORRECT_MIN` and :data:`CORRECT_SIGMAS` std."""
        dev = np.abs(np.diag(self.A) - 1.0)
        return bool(self.determined and np.any((dev > CORRECT_MIN) & (dev > CORRECT_SIGMAS * self.diag_std)))

    def describe(self) -> str:
        pct = ", ".join(f"{100 * (s - 1):+.1f}" for s in np.diag(self.A))
        return (
            f"gyroscope scale off the robot's rotation rate by ({pct}) % per axis (not modelled: the rotation may "
            "be off by about as many percent of a radian)"
        )


def gyro_scale(w_link: FloatArray, gyro: FloatArray) -> GyroScale | None:
    """:class:`GyroScale` from the link's angular velocity ``w_link`` ``(M, 3)`` (link frame, rad/s) and
    the unit's readings ``gyro`` ``(M, 3)`` at the same instants (module docstring); None when the
    motion does not turn about three axes (``M`` undetermined)."""
    w = np.asarray(w_link, dtype=float)
    g = np.asarray(gyro, dtype=float)
    if w.shape[0] < 12:
        return None
    X = np.c_[w, np.ones(w.shape[0])]
    XtX = X.T @ X
    if np.linalg.cond(XtX) > 1e10:
        return None
    coef = np.linalg.solve(XtX, X.T @ g)  # (4, 3): rows M^T (3) and b
    M, b = coef[:3].T, coef[3]
    r = g - X @ coef
    dof = max(w.shape[0] - 4, 1)
    sigma2 = float(np.sum(r * r) / (3 * dof))
    cov_rows = sigma2 * np.linalg.inv(XtX)[:3, :3]  # covariance of each row of M
    A = np.real(sqrtm(M @ M.T))
    A = 0.5 * (A + A.T)
    # |row i of M| ~ A_ii to first order: its std along the row's direction
    diag_std = np.array([
        float(np.sqrt(max((M[i] / np.linalg.norm(M[i])) @ cov_rows @ (M[i] / np.linalg.norm(M[i])), 0.0)))
        for i in range(3)
    ])
    return GyroScale(A, diag_std, b, int(w.shape[0]))
