"""The robot's effective (reflected) mass at a point along a direction, from the joint-space inertia.

A force ``f n`` at a point of the robot with position Jacobian ``J`` (``3 x n``, base frame) accelerates
that point along ``n`` (unit, base frame) as if it had the mass (Khatib's operational-space inertia of
one direction)::

    M_eff = 1 / (n^T J M(q)^-1 J^T n)          kg

with ``M(q)`` the ``n x n`` joint-space inertia (kg m^2 for revolute joints; MuJoCo's ``mj_fullM`` of a
model with the robot's inertials, armature included, is what :mod:`skincal.workflows` passes). The row
``g = n^T J`` is the obstacle row of the avoidance QP (:func:`skincal.control.constraints.obstacle_geometry`),
so ``M_eff = 1 / (g M^-1 g^T)``. This module needs no simulator: the inertia comes in as an array or a
callable ``q -> M(q)`` (:data:`MassMatrix`).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import scipy.linalg
from numpy.typing import ArrayLike

from skincal.kinematics.transforms import FloatArray

MassMatrix = Callable[[FloatArray], FloatArray]
"""``mass_matrix(q)``: the joint-space inertia ``(n, n)`` at joint positions ``q`` ``(n,)``."""


def effective_mass(rows: ArrayLike, M: ArrayLike) -> FloatArray:
    """``(K,)`` effective masses (kg) of ``K`` rows ``g_i = n_i^T J_i`` ``(K, n)`` under the joint-space
    inertia ``M`` ``(n, n)`` (symmetric positive definite): ``1 / (g_i M^-1 g_i^T)``; ``inf`` for a row with
    no lever on the robot (a point on the base, or a direction no joint moves)."""
    G = np.asarray(rows, dtype=float)
    G = G.reshape(-1, G.shape[-1]) if G.size else np.zeros((0, np.asarray(M).shape[0]))
    if G.shape[0] == 0:
        return np.zeros(0)
    factor = scipy.linalg.cho_factor(np.asarray(M, dtype=float))
    X = scipy.linalg.cho_solve(factor, G.T)  # M^-1 g^T, (n, K)
    inv = np.einsum("kj,jk->k", G, X)
    return np.where(inv > 1e-12, 1.0 / np.maximum(inv, 1e-300), np.inf)


def point_effective_mass(J: ArrayLike, normal: ArrayLike, M: ArrayLike) -> FloatArray:
    """``(K,)`` effective masses (kg) of points with position Jacobians ``J`` ``(K, 3, n)`` along unit
    normals ``(K, 3)`` (base frame) under ``M`` ``(n, n)``: :func:`effective_mass` of ``n_i^T J_i``."""
    Jk = np.asarray(J, dtype=float)
    Jk = Jk.reshape(-1, 3, Jk.shape[-1])
    n = np.asarray(normal, dtype=float).reshape(-1, 3)
    return effective_mass(np.einsum("ki,kij->kj", n, Jk), M)
