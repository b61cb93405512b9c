"""Sufficient statistics of the streaming calibrator and the pose solve from them.

The accelerometer model of :mod:`skincal.calib.model` (``a = A R^T v(s) + b`` with
``v = u + K p`` in link frame, ``R = R_link_su``) is rearranged to be *linear* in its unknowns::

    G a - h - K p - du T - dK (T p) - k (u - u_g) - K (k p) = u,    G = R A^-1 ~ R (I + E),  h = G b   (1)
    T = tau + d (s - t_ref)

(``du``, ``dK`` = d/ds: the samples measured the motion at ``s + T``, a small residual clock error
after the unit's clock mapping (:mod:`skincal.calib.timing`: coarse offset, drift, re-sync steps), to
first order: a residual offset ``tau`` at the unit's reference instant ``t_ref`` and a residual drift
``d`` (dimensionless, 1e-6 per ppm; ``s - t_ref`` is given per sample); the unit's time offset is then
the mapping's MINUS ``tau``;
``u_g = -R_base_link^T g`` the part of ``u`` due to gravity and ``k`` the relative error of the
motion's accelerations against gravity (``v = u_g + (1 + k) (u - u_g + K p)``: the IMU's own
filtering of the motion or a gravity that is not the dataset's, which the accelerometer's scale
cannot absorb because it scales both; ``mle``'s gravity scale is ``-k`` to first order; ``k p`` is
kept as 3 unknowns of its own like ``tau p``), and the gyroscope's ``g = R^T w + b_g`` likewise::

    R g - c - dw T = w,            c = R b_g                                                    (2)

``u``, ``K``, ``w`` are :func:`skincal.calib.signals.link_signals` of the unit's link at its
sample instants (link frame), ``a`` and ``g`` its readings (unit frame). Each sample adds one
3-row block ``Phi x - y`` to a linear least-squares problem, so everything the data say about the
unknowns is the Gram matrix ``Z = sum [Phi y]^T [Phi y]`` of each equation (28 x 28 for (1) with
``x_a = [vec(G) (9, row-major), h, p, tau, tau p, k, k p, d, d p]`` (the products ``tau p``, ``k p``,
``d p`` kept as 3 unknowns each, so the rows stay linear), 15 x 15 for (2) with ``x_g = [vec(R), c, tau, d]``):
no re-linearisation is ever needed, because (1) and (2) are exact in ``G``, ``R`` and the offsets
(only ``tau`` is first order). The pose then follows from minimising, over ``R`` in SO(3), ``E``,
``h``, ``p``, ``c``, ``tau``::

    C = J_a(vec(R (I + E)), h, p, tau) / sigma_a^2 + J_g(vec(R), c, tau) / sigma_g^2 + |E|^2 / sigma_E^2

with ``J(x) = [x; -1]^T Z [x; -1]`` the residual sum of squares: a Gauss-Newton over
``delta = [dtheta (3, R <- R Exp(dtheta)), dE (9), dh, dp, dc, dtau, dk, dd]`` (:func:`solve`), started from
the unconstrained linear solution of (2) (or of (1) without a gyroscope). The covariance is the
inverse of its normal matrix; ``sigma_a``, ``sigma_g`` are the residual std of the fit.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from skincal.kinematics.transforms import FloatArray, exp_rotation, nearest_rotation, rotation_angle, skew

NA = 28
"""Columns of the accelerometer Gram: ``[vec(G) 9, h 3, p 3, tau 1, tau p 3, k 1, k p 3, d 1, d p 3]`` and the
right-hand side."""
NG = 15
"""Columns of the gyroscope Gram: ``[vec(R) 9, c 3, tau 1, d 1]`` and the right-hand side."""
NP = 24
"""Gauss-Newton unknowns: ``[dtheta 3, dE 9, h 3, p 3, c 3, tau 1, k 1, d 1]``."""
SCALE_PRIOR = 0.02
"""Prior std of each element of ``E`` (the accelerometer's scale/misalignment relative to 1)."""
SCALE_FIXED = 1e-6
"""``scale_prior`` that holds ``E`` at zero (scale/misalignment not estimated)."""


def _antisymmetric_projector() -> FloatArray:
    """``(9, 9)`` projector onto the antisymmetric part of a row-major ``vec(E)``: ``E``'s rotation part,
    which no accelerometer reading tells from the unit's rotation ``R`` (``R (I + [e]x) ~ R Exp(e)``)."""
    V = np.zeros((9, 3))
    for k, (i, j) in enumerate(((0, 1), (0, 2), (1, 2))):
        V[3 * i + j, k], V[3 * j + i, k] = 2**-0.5, -(2**-0.5)
    return V @ V.T


_ANTISYMMETRIC = _antisymmetric_projector()
RESTART_ANGLE_RAD = np.radians(30.0)
"""A start rotation this far from the linear solution's (rad) is replaced by it."""
MAX_TURN_RAD = 0.5
"""Largest rotation step of one Gauss-Newton iteration (rad): a direction the data leave open (rests in
one orientation only) must not throw the estimate around the sphere."""
TAU_PRIOR_S = 0.01
"""Prior std of the residual time offset after the coarse alignment, s."""
_TH, _E, _H, _P, _C, _T, _K, _D = slice(0, 3), slice(3, 12), slice(12, 15), slice(15, 18), slice(18, 21), 21, 22, 23
TAU, DRIFT = _T, _D
"""Indices of the residual time offset and clock drift among the Gauss-Newton unknowns (``Solution.cov``)."""
DRIFT_PRIOR = 1e-3
"""Prior std of the residual clock drift ``d`` (1000 ppm: ``mle``'s, far wider than any real clock's)."""
DRIFT_SHORT_PRIOR = 1e-4
"""Prior std of the mapping's drift while the stream is shorter than
:data:`~skincal.calib.timing.CLOCK_DRIFT_MIN_SPAN_S` (100 ppm: a crystal's tolerance), where ``mle`` fits
none: a free drift took up a 14 Hz stream's model errors as -2000 to -9000 ppm on real recordings of one
host's clock; held at 0, a WiFi clock drifting at 300 ppm left the stream 1.4x ``mle``'s error
(simulated)."""
GRAVITY_PRIOR = 0.001
"""Prior std of ``k``, the motion's accelerations' relative error against gravity (``mle``: 0.2 %, the
spread of the local gravity). 0.1 % here, measured (`benchmarks/bench_online.py --accuracy`): 0.2 %
made the std of units whose link origin barely accelerates (where ``k`` and the lever arm's length
trade off) two to five times their error on the ``fast`` protocol; 0.05 % left pick-and-place
errors at 3-4 std."""


def accel_rows(
    a: FloatArray,
    u: FloatArray,
    K: FloatArray,
    du: FloatArray,
    dK: FloatArray | None = None,
    ug: FloatArray | None = None,
    elapsed: FloatArray | None = None,
) -> FloatArray:
    """``(..., M, 3, NA)`` rows ``[Phi y]`` of equation (1) for readings ``a`` ``(..., M, 3)`` and link
    signals ``u`` ``(..., M, 3)``, ``K`` ``(..., M, 3, 3)``, their derivatives ``du`` ``(..., M, 3)`` and
    ``dK`` ``(..., M, 3, 3)``, the gravity part ``ug`` ``(..., M, 3)`` of ``u`` (None: zero) and
    ``elapsed = s - t_ref`` ``(M,)`` s (None: no drift column) (module docstring)."""
    Z = np.zeros((*u.shape[:-1], 3, NA))
    for i in range(3):  # vec(G) row-major: (G a)_i = sum_j G_ij a_j
        Z[..., i, 3 * i : 3 * i + 3] = a
    Z[..., 9:12] = -np.eye(3)
    Z[..., 12:15] = -K
    Z[..., 15] = -du
    if dK is not None:
        Z[..., 16:19] = -dK
    if ug is not None:
        Z[..., 19] = ug - u
        Z[..., 20:23] = -K
    if elapsed is not None:
        e = np.asarray(elapsed, dtype=float)[:, None]
        Z[..., 23] = -du * e
        if dK is not None:
            Z[..., 24:27] = -dK * e[..., None]
    Z[..., 27] = u
    return Z


def gyro_rows(g: FloatArray, w: FloatArray, dw: FloatArray, elapsed: FloatArray | None = None) -> FloatArray:
    """``(..., M, 3, NG)`` rows of equation (2) for rates ``g`` ``(..., M, 3)`` (unit frame), the link's
    ``w``, ``dw`` ``(..., M, 3)`` (link frame) and ``elapsed = s - t_ref`` ``(M,)`` s (None: no drift).
    A reading with a NaN (at the gyroscope's rail) gives zero rows: it adds nothing to a Gram."""
    Z = np.zeros((*w.shape[:-1], 3, NG))
    for i in range(3):
        Z[..., i, 3 * i : 3 * i + 3] = g
    Z[..., 9:12] = -np.eye(3)
    Z[..., 12] = -dw
    if elapsed is not None:
        Z[..., 13] = -dw * np.asarray(elapsed, dtype=float)[:, None]
    Z[..., 14] = w
    missing = ~np.all(np.isfinite(np.broadcast_to(g, w.shape)), axis=-1)
    if missing.any():
        Z[missing] = 0.0
    return Z


def gram(rows: FloatArray) -> FloatArray:
    """``sum_m rows_m^T rows_m`` of ``(..., M, 3, k)`` rows: ``(..., k, k)``."""
    flat = rows.reshape(*rows.shape[:-3], -1, rows.shape[-1])
    return np.swapaxes(flat, -1, -2) @ flat


def shift_clock(Za: FloatArray, Zg: FloatArray, tau_r: float, d_r: float) -> tuple[FloatArray, FloatArray]:
    """Grams ``(..., NA, NA)``, ``(..., NG, NG)`` of samples absorbed under a clock mapping, re-expressed in the
    unknowns of the mapping composed with the residual ``(tau_r, d_r)``
    (:func:`~skincal.calib.timing.compose_clock`), exactly.

    A sample absorbed at ``s`` (old mapping) is at ``s' = s + tau_r + d_r (s - t_ref)`` under the new one, so
    its residual clock error ``T = tau + d (s - t_ref)`` in the old unknowns is, in the new ones ``(tau', d')``
    (``T' = tau' + d' (s' - t_ref)``, the same instant measured)::

        tau = tau_r + tau' + tau_r d',    d = d_r + (1 + d_r) d'
        tau p = tau_r p + (tau p)' + tau_r (d p)',    d p = d_r p + (1 + d_r) (d p)'

    i.e. ``x = M x' + m``, affine; with ``T = [[M, -m], [0, 1]]`` the Gram of ``[x'; -1]`` is ``T^T Z T``.
    The rows stay linearised at the old instants (first order in the old residual, which the re-alignment
    kept within a few ms): what the kept statistics of samples no longer in the history become when the
    unit's clock mapping is re-aligned, instead of being lost."""
    Ta = np.eye(NA)
    Ta[15, 23], Ta[15, NA - 1] = tau_r, -tau_r
    i3 = np.arange(3)
    Ta[16 + i3, 24 + i3] = tau_r
    Ta[16 + i3, 12 + i3] = tau_r
    Ta[23, 23], Ta[23, NA - 1] = 1.0 + d_r, -d_r
    Ta[24 + i3, 24 + i3] = 1.0 + d_r
    Ta[24 + i3, 12 + i3] = d_r
    Tg = np.eye(NG)
    Tg[12, 13], Tg[12, NG - 1] = tau_r, -tau_r
    Tg[13, 13], Tg[13, NG - 1] = 1.0 + d_r, -d_r
    return Ta.T @ Za @ Ta, Tg.T @ Zg @ Tg


def residual_sum(Z: FloatArray, x: FloatArray) -> float:
    """``J(x) = [x; -1]^T Z [x; -1]``, the residual sum of squares of the equations whose Gram is ``Z``."""
    xe = np.append(x, -1.0)
    return float(max(xe @ Z @ xe, 0.0))


@dataclass(frozen=True)
class Solution:
    """Minimiser of ``C`` (module docstring) for one unit on one link.

    Attributes:
        R: ``(3, 3)`` ``R_link_su``; ``p``: ``(3,)`` ``p_link_su``, m.
        A: ``(3, 3)`` accelerometer scale/misalignment (``a = A f + b``); ``b``: ``(3,)`` its bias, m/s^2.
        gyro_bias: ``(3,)`` rad/s (zeros without a gyroscope); ``tau``: residual time offset at the
            unit's ``t_ref``, s; ``drift``: residual clock drift (dimensionless).
        cov: ``(NP, NP)`` covariance of the Gauss-Newton unknowns at the solution (rotation about the
            UNIT axes, ``R <- R Exp(dtheta)``), not yet inflated for correlated residuals.
        sigma_a, sigma_g: residual std of equations (1) (m/s^2) and (2) (rad/s; nan: no gyroscope).
        cost: ``J_a / sigma_a^2 + J_g / sigma_g^2`` at the solution with the noise levels given to
            :func:`solve` (comparable between candidate links).
        rss_a: ``J_a`` at the solution, (m/s^2)^2.
        information: ``(NP, NP)`` the normal matrix (inverse of ``cov``).
        x_a, x_g: the linear unknowns of (1) ``(NA - 1,)`` and (2) ``(NG - 1,)`` at the solution (for
            :func:`residual_sum` of other Grams, e.g. per class of samples).
        state: ``x`` of :func:`linearise` at the solution (with ``R``: for :func:`normal_matrix`).
    """

    R: FloatArray
    p: FloatArray
    A: FloatArray
    b: FloatArray
    gyro_bias: FloatArray
    tau: float
    gravity_scale: float
    drift: float
    cov: FloatArray
    sigma_a: float
    sigma_g: float
    cost: float
    rss_a: float
    information: FloatArray
    x_a: FloatArray
    x_g: FloatArray
    state: FloatArray

    def pose_covariance(self) -> FloatArray:
        """``(6, 6)`` covariance of ``(x, y, z, rx, ry, rz)`` in the LINK frame's axes (m^2, rad^2): the
        position block and the rotation block turned from unit axes to link axes (``phi = R dtheta``),
        symmetric to the last bit (a normal matrix's inverse is only to its round-off, which a result file
        refuses beyond 1e-9 of the std product)."""
        idx = np.r_[np.arange(15, 18), np.arange(0, 3)]
        C = self.cov[np.ix_(idx, idx)]
        T = np.eye(6)
        T[3:, 3:] = self.R
        out = T @ C @ T.T
        return 0.5 * (out + out.T)


_GENERATORS = skew(np.eye(3))
"""``(3, 3, 3)``: ``[e_k]x``, the generators of so(3)."""


def _vec_jacobians(R: FloatArray, F: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
    """d vec(R Exp(dth) F)/d dth ``(9, 3)``, d vec(R (F + dE))/d vec(dE) ``(9, 9)`` (``R kron I``: row ``3 i + a``,
    column ``3 j + b`` is ``R_ij delta_ab``), d vec(R Exp(dth))/d dth."""
    RG = R @ _GENERATORS  # (3, 3, 3): R [e_k]x
    JG = (RG @ F).reshape(3, 9).T
    JR = RG.reshape(3, 9).T
    JE = (R[:, None, :, None] * _EYE3[None, :, None, :]).reshape(9, 9)
    return JG, JE, JR


_EYE3 = np.eye(3)
_JA_CONSTANT = np.zeros((NA - 1, NP))
_JA_CONSTANT[9:12, _H], _JA_CONSTANT[12:15, _P], _JA_CONSTANT[15, _T] = _EYE3, _EYE3, 1.0
_JA_CONSTANT[19, _K], _JA_CONSTANT[23, _D] = 1.0, 1.0
_JG_CONSTANT = np.zeros((NG - 1, NP))
_JG_CONSTANT[9:12, _C], _JG_CONSTANT[12, _T], _JG_CONSTANT[13, _D] = _EYE3, 1.0, 1.0


def _rotation_start(Za: FloatArray, Zg: FloatArray | None, held: bool) -> FloatArray | None:
    """The rotation of the linear solution: from the gyroscope's Gram when it holds all of ``vec(R)``,
    else from the accelerometer's (``vec(G)``, ``G = R (I + E)``); with ``held`` only from a Gram that
    holds all of it (None otherwise)."""
    for Z, n in ((Zg, NG - 1), (Za, NA - 1)):
        if Z is None:
            continue
        full = np.linalg.matrix_rank(Z[:9, :9], tol=1e-9 * max(Z[:9, :9].trace(), 1e-300)) >= 9
        if not full and (held or Z is Zg):
            continue
        start = _linear_start(Z, n)
        if start is not None:
            return nearest_rotation(start[:9].reshape(3, 3))
    return None


def _linear_start(Z: FloatArray, n: int) -> FloatArray | None:
    """Unconstrained least-squares solution of the first ``n`` unknowns of a Gram ``Z`` (None: singular)."""
    Q, b = Z[:n, :n], Z[:n, n]
    try:
        x = np.linalg.solve(Q + 1e-12 * np.trace(Q) / n * np.eye(n), b)
    except np.linalg.LinAlgError:
        return None
    return x if np.all(np.isfinite(x)) else None


def linearise(R: FloatArray, x: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """The unknowns of (1) and (2) at ``R`` and ``x = [0 (3), E, h, p, c, tau, k, d]`` ``(NP,)`` and their
    Jacobians with respect to ``delta`` (module docstring): ``x_a`` ``(NA - 1,)``, ``J_a``
    ``(NA - 1, NP)``, ``x_g`` ``(NG - 1,)``, ``J_g`` ``(NG - 1, NP)``."""
    F = _EYE3 + x[_E].reshape(3, 3)
    JG, JE, JR = _vec_jacobians(R, F)
    Ja = _JA_CONSTANT.copy()  # d h, d p, d tau, d k, d d: identities
    Ja[:9, _TH], Ja[:9, _E] = JG, JE
    Ja[16:19, _T], Ja[16:19, _P] = x[_P], x[_T] * _EYE3  # d(tau p)
    Ja[20:23, _K], Ja[20:23, _P] = x[_P], x[_K] * _EYE3  # d(k p)
    Ja[24:27, _D], Ja[24:27, _P] = x[_P], x[_D] * _EYE3  # d(d p)
    xa = np.concatenate([
        (R @ F).reshape(9), x[_H], x[_P], [x[_T]], x[_T] * x[_P], [x[_K]], x[_K] * x[_P], [x[_D]], x[_D] * x[_P]
    ])  # fmt: skip
    Jg = _JG_CONSTANT.copy()
    Jg[:9, _TH] = JR
    xg = np.concatenate([R.reshape(9), x[_C], [x[_T]], [x[_D]]])
    return xa, Ja, xg, Jg


def normal_matrix(R: FloatArray, x: FloatArray, Za: FloatArray, Zg: FloatArray | None) -> FloatArray:
    """``(NP, NP)`` Gauss-Newton normal matrix of the (already weighted) Grams ``Za``, ``Zg`` at ``R``,
    ``x`` (:func:`linearise`; no prior)."""
    _, Ja, _, Jg = linearise(R, x)
    H = Ja.T @ Za[: NA - 1, : NA - 1] @ Ja
    if Zg is not None:
        H = H + Jg.T @ Zg[: NG - 1, : NG - 1] @ Jg
    return H


def solve(
    Za: FloatArray,
    Zg: FloatArray | None,
    sigma_a: float,
    sigma_g: float,
    *,
    R0: FloatArray | None = None,
    iterations: int = 12,
    scale_prior: float = SCALE_PRIOR,
    drift_prior: float = DRIFT_PRIOR,
    drift_total: float = 0.0,
    x0: FloatArray | None = None,
    hold: bool = False,
) -> Solution | None:
    """Gauss-Newton minimiser of ``C`` (module docstring) from the Grams ``Za`` ``(NA, NA)`` and ``Zg``
    ``(NG, NG)`` (None: no gyroscope) with noise levels ``sigma_a`` (m/s^2), ``sigma_g`` (rad/s); ``R0``
    a start rotation (default: the linear solution); ``scale_prior`` the prior std of each element of ``E``
    (tiny: the accelerometer's scale/misalignment held at the identity), ``drift_prior`` that of the
    residual clock drift about ``drift_total``, the drift of the mapping it adds to: the prior holds the
    mapping's whole drift (``drift_total - d`` to first order), not each re-alignment's residual, which
    would otherwise walk away by a prior's width at every re-alignment. None when the data determine
    nothing yet. ``x0``: a start of the other unknowns (a :attr:`Solution.state`, at ``R0``); ``hold``: ``R0`` is
    kept even far from the linear solution (a part of the data whose linear solution is another basin)."""
    have_g = Zg is not None and Zg[0, 0] > 0
    linear = _rotation_start(Za, Zg if have_g else None, held=R0 is not None)
    if R0 is None:
        R0 = np.eye(3) if linear is None else linear
    elif not hold and linear is not None and float(rotation_angle(R0, linear)) > RESTART_ANGLE_RAD:
        R0 = linear  # the last solution is another basin (it was fitted before the data held the rotation)
    R, x = np.array(R0, dtype=float), np.zeros(NP)  # x holds E, h, p, c, tau, k, d (dtheta always 0 at the current R)
    if x0 is not None:  # a start for E, h, p, c, tau, k, d (a part of the data started from the whole's solution)
        x[3:] = np.asarray(x0, dtype=float)[3:]
    wa, wg = 1.0 / sigma_a**2, (1.0 / sigma_g**2 if have_g else 0.0)
    prior = np.zeros(NP)
    prior[_E] = 1.0 / scale_prior**2
    prior[_T] = 1.0 / TAU_PRIOR_S**2
    prior[_K] = 1.0 / GRAVITY_PRIOR**2
    prior[_D] = 1.0 / drift_prior**2
    P = np.diag(prior)
    if not have_g:  # E symmetric (as mle's): its rotation part, which only a gyroscope tells from R, is R's
        P[_E, _E] += _ANTISYMMETRIC / SCALE_FIXED**2
    H = np.eye(NP)
    for it in range(iterations):
        xa, Ja, xg, Jg = linearise(R, x)
        ga = Za[: NA - 1, : NA - 1] @ xa - Za[: NA - 1, NA - 1]
        H = wa * Ja.T @ Za[: NA - 1, : NA - 1] @ Ja + P
        centred = x.copy()  # x[:3] (dtheta) is 0
        centred[_D] -= drift_total
        grad = wa * Ja.T @ ga + P @ centred
        if have_g:
            assert Zg is not None
            gg = Zg[: NG - 1, : NG - 1] @ xg - Zg[: NG - 1, NG - 1]
            H = H + wg * Jg.T @ Zg[: NG - 1, : NG - 1] @ Jg
            grad = grad + wg * Jg.T @ gg
        if not have_g:
            H[_C, _C] += np.eye(3)  # c does not enter: keep H invertible
        try:
            step = -np.linalg.solve(H + 1e-9 * np.diag(np.diag(H) + 1e-12), grad)
        except np.linalg.LinAlgError:
            return None
        if not np.all(np.isfinite(step)):
            return None
        turn = float(np.linalg.norm(step[_TH]))
        if turn > MAX_TURN_RAD:  # a rotation the data do not hold yet (one gravity direction): no wild jump
            step *= MAX_TURN_RAD / turn
        R = R @ exp_rotation(step[_TH])
        x[3:] += step[3:]
        if np.linalg.norm(step[_TH]) < 1e-10 and it > 1:
            break
    F = np.eye(3) + x[_E].reshape(3, 3)
    G = R @ F
    xa, _, xg, _ = linearise(R, x)
    rss_a = residual_sum(Za, xa)
    rss_g = residual_sum(Zg, xg) if have_g and Zg is not None else 0.0
    try:
        cov = np.linalg.inv(H)
    except np.linalg.LinAlgError:
        return None
    A = np.linalg.inv(F)  # G = R A^-1
    b = np.linalg.solve(G, x[_H])  # h = G b
    gyro_bias = R.T @ x[_C] if have_g else np.zeros(3)
    # Z[9, 9] counts the samples (the -I column): 3 rows each, less the unknowns
    sa = float(np.sqrt(rss_a / max(3.0 * Za[9, 9] - 16.0, 1.0)))
    sg = float(np.sqrt(rss_g / max(3.0 * Zg[9, 9] - 13.0, 1.0))) if have_g and Zg is not None else float("nan")
    return Solution(
        R=R, p=x[_P].copy(), A=A, b=b, gyro_bias=gyro_bias, tau=float(x[_T]),
        gravity_scale=float(x[_K]), drift=float(x[_D]),
        cov=cov, sigma_a=sa, sigma_g=sg,
        cost=rss_a * wa + rss_g * wg, rss_a=rss_a, information=H, x_a=xa, x_g=xg, state=x.copy(),
    )  # fmt: skip
