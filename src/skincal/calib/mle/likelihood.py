"""Candidate links compared by their likelihood over every rest of the unit.

At rest the accelerometer reads gravity in the unit frame, so a rest run ``r`` (mean reading
``f_r`` over ``n_r`` samples, joint configuration ``q_r``) tells two candidate links apart through
the gravity each predicts with its own fitted pose and sensor state ``x_k`` (``R``, ``A``, ``b``;
:func:`~skincal.calib.model.predict_specific_force` with the link-frame gravity
``u_k(q_r)`` and no motion). With the residual ``e_kr = f_r - f_k(q_r, x_k)`` and the variance of a
rest mean ``v_r = sigma^2 / n_r + s^2`` per axis (``sigma`` the unit's rest noise, ``s^2`` what the
model leaves unexplained at the best candidate's rests: the smallest over candidates of
``max(median_r (|e_kr|^2 / 3 - sigma^2 / n_r), 0)``), the negative log-likelihood of candidate ``k`` is

    NLL_k = sum_r ( |e_kr|^2 / (2 v_r) + (3/2) log(2 pi v_r) ),

summed over the same rests for every candidate: the runs in which every candidate's joints rest.
Unlike a median residual, a sum cannot hide the one rest pose that tells two links apart.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from skincal.calib.mle.solver import State
from skincal.calib.model import predict_specific_force
from skincal.calib.signals import link_signals
from skincal.kinematics.chain import SerialChain
from skincal.kinematics.transforms import FloatArray


def rest_nll(
    chain: SerialChain,
    gravity: FloatArray,
    q_rest: FloatArray,
    f_rest: FloatArray,
    n_rest: FloatArray,
    noise: float,
    states: Mapping[int, State],
) -> dict[int, float]:
    """``NLL_k`` of each candidate link ``k`` (module docstring) over the rests ``q_rest`` ``(S, n)``
    (rad or m), mean readings ``f_rest`` ``(S, 3)`` (m/s^2) of ``n_rest`` ``(S,)`` samples each, rest
    noise ``noise`` (m/s^2 per sample), each candidate's fitted ``states``; empty without a rest."""
    S = len(f_rest)
    if S == 0 or not states:
        return {}
    zero = np.zeros_like(q_rest)
    residual = {}
    for k, st in states.items():
        u = link_signals(chain, k, q_rest, zero, zero, gravity).u
        pred = predict_specific_force(st.R, st.p, st.A, st.b, u, None, ug=u, gravity_scale=st.k)
        residual[k] = np.sum((f_rest - pred) ** 2, axis=1)
    mean_var = noise**2 / np.maximum(np.asarray(n_rest, dtype=float), 1.0)
    model = min(max(float(np.median(r / 3.0 - mean_var)), 0.0) for r in residual.values())
    v = mean_var + model
    v = np.maximum(v, 1e-300)
    return {k: float(np.sum(r / (2 * v) + 1.5 * np.log(2 * np.pi * v))) for k, r in residual.items()}
