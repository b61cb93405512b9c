"""Design support of the streaming calibrator: the information a motion would add about a unit's pose at
its current estimate (:func:`design_normal`, :func:`pose_block`) and the joint whose short excitation
(:func:`excitation`) would add the most (:func:`best_joint`)."""

from __future__ import annotations

import numpy as np

from skincal.calib.online import stats
from skincal.calib.online.unit import UnitState
from skincal.calib.signals import frame_signals
from skincal.kinematics.chain import SerialChain
from skincal.kinematics.transforms import FloatArray


def normal(sol: stats.Solution, Za: FloatArray, Zg: FloatArray | None, sig: FloatArray) -> FloatArray:
    """Normal matrix ``(NP, NP)`` of the Grams ``Za``, ``Zg`` of moving samples at ``sol`` (no prior)."""
    return stats.normal_matrix(sol.R, sol.state, Za / sig[1] ** 2, None if Zg is None else Zg / sig[3] ** 2)


def design_normal(
    chain: SerialChain,
    gravity: FloatArray,
    sol: stats.Solution,
    sig: FloatArray,
    link: int,
    q,
    qd,
    qdd,
    dt: float,
    gyro: bool,
) -> FloatArray:
    """Normal matrix ``(NP, NP)`` that the motion ``q, qd, qdd`` (every ``dt`` s) of ``link`` adds at ``sol``."""
    u, K, w, dw, ug = frame_signals(chain.link_motion(q, qd, qdd, upto=link), gravity, link)
    du = np.gradient(u, dt, axis=0) if u.shape[0] > 1 else np.zeros_like(u)
    dK = np.gradient(K, dt, axis=0) if u.shape[0] > 1 else np.zeros_like(K)
    f = ug + (1.0 + sol.gravity_scale) * (u - ug + np.einsum("mij,j->mi", K, sol.p))
    a = (f @ sol.R) @ sol.A.T + sol.b
    Za = stats.gram(stats.accel_rows(a, u, K, du, dK, ug))
    Zg = None
    if gyro:
        g = w @ sol.R + sol.gyro_bias
        Zg = stats.gram(stats.gyro_rows(g, w, dw))
    return normal(sol, Za, Zg, sig)


def best_joint(
    chain: SerialChain, gravity: FloatArray, q_now: FloatArray | None, st: UnitState, link: int, sol: stats.Solution
) -> int | None:
    """The joint (0-based, up to ``link``) whose 2 s excitation at the current posture adds the
    most D-optimal information at ``q_now`` (log det of the pose's marginal information); cached for 2 s."""
    if q_now is None:
        return None
    if st.t_last - st.best_joint_t < 2.0 and st.best_joint is not None:
        return st.best_joint
    H0 = sol.information
    base = logdet(pose_block(H0))
    best, gain = None, 0.0
    for j in range(link):
        q, qd, qdd, dt = excitation(chain, q_now, j)
        dH = design_normal(chain, gravity, sol, st.sigmas[link], link, q, qd, qdd, dt, st.has_gyro is not False)
        g = logdet(pose_block(H0 + dH)) - base
        if g > gain:
            best, gain = j, g
    st.best_joint, st.best_joint_t = best, st.t_last
    return best


def pose_block(H: FloatArray) -> FloatArray:
    """Information about ``[dtheta, p]`` with the other unknowns as nuisance (Schur complement)."""
    idx = np.r_[0:3, 15:18]
    rest = np.setdiff1d(np.arange(H.shape[0]), idx)
    A, B, D = H[np.ix_(idx, idx)], H[np.ix_(idx, rest)], H[np.ix_(rest, rest)]
    return A - B @ np.linalg.pinv(D) @ B.T


def logdet(M: FloatArray) -> float:
    """``log det M`` (``-inf`` where ``M`` is not positive definite), ``M`` regularised by ``1e-12 I``."""
    sign, ld = np.linalg.slogdet(M + 1e-12 * np.eye(M.shape[0]))
    return float(ld) if sign > 0 else -np.inf


def excitation(
    chain: SerialChain, q0: FloatArray, joint: int, duration: float = 2.0, fraction: float = 0.3, rate_hz: float = 100.0
) -> tuple[FloatArray, FloatArray, FloatArray, float]:
    """A short excitation of ``joint`` from ``q0``: ``qd_j = A sin(2 pi t / duration)`` with
    ``A = fraction`` of its velocity limit (one period: starts and ends at rest), sampled at
    ``rate_hz``. Returns ``q, qd, qdd`` ``(M, n)`` and the period ``dt``."""
    dt = 1.0 / rate_hz
    t = dt * np.arange(int(duration * rate_hz))
    w = 2 * np.pi / duration
    vmax = chain.velocity_limit[joint] if chain.velocity_limit is not None else 1.0
    A = fraction * float(vmax)
    q = np.repeat(np.asarray(q0, dtype=float)[None], t.size, axis=0)
    qd, qdd = np.zeros_like(q), np.zeros_like(q)
    q[:, joint] += A / w * (1 - np.cos(w * t))
    qd[:, joint] = A * np.sin(w * t)
    qdd[:, joint] = A * w * np.cos(w * t)
    return q, qd, qdd, dt
