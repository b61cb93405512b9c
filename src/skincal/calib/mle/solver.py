"""Robust Gauss-Newton for one unit: pose, IMU errors and the unit's clock.

Measurement model (unit frame ``su``, link frame ``n``; ``R = R_link_su``, ``p = p_link_su``)::

    accelerometer:  a_i = A R^T v(s_i) + b + c (t_i - t_c) + noise,   v(s) = u(s) + K(s) p
    gyroscope:      g_i = R^T w(s_i) + b_g + noise
    physical instant of the sample stamped t_i:  s_i = t_i - tau - d (t_i - t_c)

``u``, ``K``, ``w`` (link-frame specific force of the origin, rigid-body matrix, angular velocity)
come from :mod:`skincal.calib.signals`; at rest ``K = 0``, ``w = 0``. Parameters:

* ``b`` accelerometer bias; ``c`` its drift rate (m/s^2 per s, optional); ``b_g`` gyroscope bias;
* ``A = I + E``: ``E`` symmetric (6) when only the accelerometer is used (an antisymmetric part
  would be a rotation: the unit frame is then the accelerometer's polar frame), or full (9) when
  the gyroscope is fitted too (the unit frame is then the gyroscope's frame and the accelerometer's
  misalignment to it is estimated);
* ``tau`` the IMU's time offset at ``t_c`` (the middle of the unit's samples) and ``d`` the clock
  drift (dimensionless, 1e-6 = 1 ppm; optional).

The solver works on the manifold (``R <- R Exp(dtheta)``, ``dtheta`` in the unit frame),
linearises the time dependence around the current ``tau_k, d_k``
(``v(s) ~ v(s_k) - (s_k - s) dv/dt``) and re-evaluates the signals in an outer loop. Each sensor's
rows are weighted by its own robust residual variance (times the residuals' autocorrelation
factor); outliers get Huber weights; directions the data cannot determine (a unit on link 1) are
left at their start values (pseudo-inverse on the scaled normal equations) and reported. The
covariance is the normal equations' (divided by the autocorrelation factor); for data whose errors
the noise model does not describe (a low-rate joint stream) it is raised per parameter to the block
sandwich's where the residuals show errors that follow the motion (:func:`sandwich_inflation`).

Parameter vector order: ``dtheta (3), p (3), b (3)``, then the optional blocks in this order:
``e (6: xx, yy, zz, xy, xz, yz, or 9: row-major E)``, ``tau (1)``, ``d (1)``, ``b_g (3)``, ``c (3)``,
``k (1)``.

Gravity: the link-frame specific force splits as ``u = u_a + u_g`` (``u_g = -R_base_link^T g``) and
the dataset's gravity may be wrong by a factor: ``u = u_a + (1 + k) u_g`` (``k`` optional; the
accelerometer scale cannot absorb it because it scales the motion's acceleration too).
The sensor blocks have wide zero-mean priors (:data:`PRIOR_STD`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np
from scipy.spatial.transform import Rotation

from skincal.calib.model import accelerometer, link_specific_force, sym_from_e
from skincal.calib.robust import (
    SANDWICH_BLOCK_S,
    huber_weights,
    pinv,
    pinv_step,
    residual_correlation,
    robust_sigma,
    sandwich_factors,
)
from skincal.kinematics.transforms import FloatArray, skew

PRIOR_STD = {"e": 0.05, "d": 1e-3, "c": 1e-3, "k": 0.002}
"""Zero-mean Gaussian priors of the sensor blocks (a MAP estimate): scale/misalignment 5 % (real
IMUs: 1-3 %), clock drift 1000 ppm, bias drift 1e-3 m/s^3 (0.6 m/s^2 over ten minutes): far wider
than any real value, so data that determine a block are not biased; where the data do not, the
block stays near zero and its prior std enters the covariance instead of an arbitrary null-space
value. Gravity 0.2 %: the spread of the local gravity magnitude over the Earth's surface
(9.780-9.832 m/s^2) about the 9.81 a dataset usually states; a unit whose data cannot separate it
from its position then carries that uncertainty honestly in its position std."""
MAX_STEP = {"theta": 0.5, "p": 0.5}
"""Largest Gauss-Newton step of the rotation (rad) and position (m); a larger one is scaled down."""
SIGMA_FLOOR = 1e-3
"""Smallest residual std the weights assume, m/s^2 (0.1 mg, below any real accelerometer's noise;
a tenth of it for the gyroscope, rad/s): noise-free data must not make the data's information so
large that the priors vanish below round-off."""

SCALE_NONE, SCALE_SYM, SCALE_FULL = "none", "sym", "full"


@dataclass(frozen=True)
class State:
    """Estimate of one unit: ``R_link_su``, ``p_link_su`` (m), accelerometer bias ``b`` (m/s^2),
    ``E`` (scale and misalignment, ``A = I + E``), ``tau`` (s at ``t_c``), clock drift ``d``,
    gyroscope bias ``bg`` (rad/s) and bias drift ``c`` (m/s^3)."""

    R: FloatArray
    p: FloatArray
    b: FloatArray
    E: FloatArray = field(default_factory=lambda: np.zeros((3, 3)))
    tau: float = 0.0
    d: float = 0.0
    bg: FloatArray = field(default_factory=lambda: np.zeros(3))
    c: FloatArray = field(default_factory=lambda: np.zeros(3))
    k: float = 0.0

    @property
    def A(self) -> FloatArray:
        return np.eye(3) + self.E


@dataclass(frozen=True)
class Blocks:
    """Which parameter blocks are estimated (see the module docstring)."""

    scale: str = SCALE_SYM
    time_offset: bool = True
    clock_drift: bool = False
    gyro: bool = False
    bias_drift: bool = False
    gravity: bool = False

    @property
    def n_scale(self) -> int:
        return {SCALE_NONE: 0, SCALE_SYM: 6, SCALE_FULL: 9}[self.scale]

    def slices(self) -> dict[str, slice]:
        """Column ranges of every estimated block in the parameter vector."""
        out = {"theta": slice(0, 3), "p": slice(3, 6), "b": slice(6, 9)}
        col = 9
        for name, size in (
            ("e", self.n_scale), ("tau", int(self.time_offset)), ("d", int(self.clock_drift)),
            ("bg", 3 * self.gyro), ("c", 3 * self.bias_drift), ("k", int(self.gravity)),
        ):
            if size:
                out[name] = slice(col, col + size)
                col += size
        return out

    @property
    def size(self) -> int:
        return max(s.stop for s in self.slices().values())


@dataclass(frozen=True)
class Linearisation:
    """Signals of the moving samples at their physical instants ``s_k`` under ``(tau_k, d_k)``:
    ``u, du, w, dw`` ``(M, 3)``, ``K, dK`` ``(M, 3, 3)`` (``d`` = time derivative)."""

    tau_k: float
    d_k: float
    u: FloatArray
    K: FloatArray
    du: FloatArray
    dK: FloatArray
    w: FloatArray | None = None
    dw: FloatArray | None = None
    ug: FloatArray | None = None


@dataclass(frozen=True)
class Rows:
    """The measurements of one unit.

    Attributes:
        static_u: ``(S, 3)`` link-frame specific force of each rest run; ``static_f`` ``(S, 3)`` its
            mean accelerometer reading; ``static_g`` ``(S, 3)`` mean gyroscope reading or ``None``;
            ``static_weight`` ``(S,)`` samples per run; ``static_t`` ``(S,)`` mid instant, s.
        moving_t: ``(M,)`` stamps of the moving samples relative to ``t_c``, s; ``moving_f`` ``(M, 3)``;
            ``moving_g`` ``(M, 3)`` or ``None``.
    """

    static_u: FloatArray
    static_f: FloatArray
    static_g: FloatArray | None
    static_weight: FloatArray
    static_t: FloatArray
    moving_t: FloatArray
    moving_f: FloatArray
    moving_g: FloatArray | None


@dataclass(frozen=True)
class Fit:
    """Solver output: the state, the covariance of the estimated parameters (parameter-vector
    order), robust residual std per sensor (m/s^2, rad/s), the null-space directions (unit columns,
    parameter order),
    the blocks, the final weighted cost, iterations and the autocorrelation factors applied."""

    state: State
    covariance: FloatArray
    sigma: float
    null_space: FloatArray
    blocks: Blocks
    cost: float
    iterations: int
    residual_correlation: float
    sigma_gyro: float = 0.0
    residuals: FloatArray | None = None
    """``(S + M, 3)`` accelerometer residuals (static rows first) at the solution."""
    sandwich: FloatArray | None = None
    """``(P,)`` the factors :func:`sandwich_inflation` raised each parameter's std by (1: none)."""


def _scale_columns(J: FloatArray, f: FloatArray, scale: str, sl: slice) -> None:
    """d(E f)/de into the columns ``J[sl]`` of a column-major Jacobian ``(P, N, 3)`` for ``f`` ``(N, 3)``."""
    c = sl.start
    if scale == SCALE_FULL:  # d(E f)_a / dE_am = f_m
        for a in range(3):
            J[c + 3 * a : c + 3 * a + 3, :, a] = f.T
        return
    fx, fy, fz = f[:, 0], f[:, 1], f[:, 2]
    J[c + 0, :, 0] = fx
    J[c + 1, :, 1] = fy
    J[c + 2, :, 2] = fz
    J[c + 3, :, 0], J[c + 3, :, 1] = fy, fx
    J[c + 4, :, 0], J[c + 4, :, 2] = fz, fx
    J[c + 5, :, 1], J[c + 5, :, 2] = fz, fy


def _times_columns(J: FloatArray, cols: slice, M: FloatArray, X: FloatArray, rows: slice = slice(None)) -> None:
    """``J[cols.start + j, rows] = (M X_n)[:, j]`` for every ``X_n`` of ``X`` ``(N, 3, 3)``: column ``j`` of the
    products ``M X_n`` as one matrix product ``X[:, :, j] M^T`` ``(N, 3)``, written into a column-major
    Jacobian ``(P, N, 3)`` (contiguous rows)."""
    for j in range(3):
        np.matmul(X[:, :, j], M.T, out=J[cols.start + j, rows])


def _diagonal_columns(J: FloatArray, cols: slice, values: FloatArray | float) -> None:
    """``J[cols]`` ``(3, N, 3)`` = ``I * values`` (one 3 x 3 identity per row times ``values`` ``(N,)`` or a scalar);
    the entries off the diagonal are left as they are (zero)."""
    for a in range(3):
        J[cols.start + a, :, a] = values


def accel_rows(
    state: State, blocks: Blocks, lin: Linearisation | None, rows: Rows
) -> tuple[FloatArray, FloatArray]:
    """Accelerometer residuals ``(S + M, 3)`` and Jacobian ``(S + M, 3, P)`` (static rows first)."""
    r, Jr = _accel_rows_with_residual(state, blocks, lin, rows)
    return r, Jr[:-1].transpose(1, 2, 0)


def _accel_rows_with_residual(
    state: State, blocks: Blocks, lin: Linearisation | None, rows: Rows
) -> tuple[FloatArray, FloatArray]:
    """:func:`accel_rows` with the residuals as a last column of the Jacobian, stored by columns:
    ``Jr`` ``(P + 1, S + M, 3)``, ``Jr[c]`` the column ``c`` of every row (one product
    :func:`normal_equations` then gives ``J^T W J`` and ``J^T W r``; each column contiguous, so it is
    written in one pass)."""
    sl = blocks.slices()
    R, A = state.R, state.A
    S = len(rows.static_u)
    # static rows are pure gravity: u_s = u_g, K = 0 (the model: skincal.calib.model)
    v = link_specific_force(rows.static_u, None, state.p, gravity_scale=state.k)
    if lin is not None:
        dtau = (state.tau - lin.tau_k) + (state.d - lin.d_k) * rows.moving_t  # s_k - s per sample
        Kd = lin.K - dtau[:, None, None] * lin.dK
        v_m = link_specific_force(lin.u - dtau[:, None] * lin.du, Kd, state.p, lin.ug, state.k)
        ug = np.concatenate([rows.static_u, lin.ug]) if lin.ug is not None else None
        v = np.concatenate([v, v_m])
        t_rel = np.concatenate([rows.static_t, rows.moving_t])
        meas = np.concatenate([rows.static_f, rows.moving_f])
    else:
        ug = rows.static_u
        t_rel, meas = rows.static_t, rows.static_f
    f = v @ R  # rows: (R^T v)^T
    pred = accelerometer(f, A, state.b, state.c, t_rel)
    r = pred - meas
    J = np.zeros((blocks.size + 1, len(v), 3))
    J[-1] = r
    _times_columns(J, sl["theta"], A, skew(f))  # d/d dtheta of A R^T v with R <- R Exp(dtheta): A [f]x
    if lin is not None:
        _times_columns(J, sl["p"], A @ R.T, Kd, slice(S, None))
    _diagonal_columns(J, sl["b"], 1.0)
    if "e" in sl:
        _scale_columns(J, f, blocks.scale, sl["e"])
    if lin is not None and ("tau" in sl or "d" in sl):
        dv = lin.du + _times_vector(lin.dK, state.p)
        col = -(dv @ R) @ A.T
        if "tau" in sl:
            J[sl["tau"].start, S:] = col
        if "d" in sl:
            J[sl["d"].start, S:] = col * rows.moving_t[:, None]
    if "c" in sl:
        _diagonal_columns(J, sl["c"], t_rel)
    if "k" in sl and ug is not None:
        J[sl["k"].start] = (ug @ R) @ A.T
    return r, J


def gyro_rows(
    state: State, blocks: Blocks, lin: Linearisation | None, rows: Rows
) -> tuple[FloatArray, FloatArray]:
    """Gyroscope residuals ``(S + M, 3)`` and Jacobian ``(S + M, 3, P)`` (static rows: ``w = 0``)."""
    r, J_c, cols = _gyro_rows_compact(state, blocks, lin, rows)
    J = np.zeros((len(r), 3, blocks.size))
    J[:, :, cols] = J_c[:-1].transpose(1, 2, 0)
    return r, J


def _gyro_rows_compact(
    state: State, blocks: Blocks, lin: Linearisation | None, rows: Rows
) -> tuple[FloatArray, FloatArray, np.ndarray]:
    """:func:`gyro_rows` with only the columns the gyroscope depends on (rotation, time offset,
    clock drift, gyroscope bias): residuals, Jacobian by columns ``(C + 1, S + M, 3)`` (the residuals its
    last column, as in :func:`_accel_rows_with_residual`) and the ``C`` column indices."""
    sl = blocks.slices()
    names = [n for n in ("theta", "tau", "d", "bg") if n in sl and (lin is not None or n in ("theta", "bg"))]
    cols = np.concatenate([np.arange(sl[n].start, sl[n].stop) for n in names])
    at = {n: np.arange(sl[n].start, sl[n].stop) for n in names}
    local = {n: np.searchsorted(cols, at[n]) for n in names}
    R = state.R
    parts_w = [np.zeros_like(rows.static_u)]
    meas = [rows.static_g]
    if lin is not None:
        dtau = (state.tau - lin.tau_k) + (state.d - lin.d_k) * rows.moving_t
        parts_w.append(lin.w - dtau[:, None] * lin.dw)
        meas.append(rows.moving_g)
    w = np.concatenate(parts_w)
    g = w @ R
    r = g + state.bg - np.concatenate(meas)
    J = np.zeros((cols.size + 1, len(w), 3))
    J[-1] = r
    gx = skew(g)
    for j, c in enumerate(local["theta"]):
        J[c] = gx[:, :, j]
    for a, c in enumerate(local["bg"]):
        J[c, :, a] = 1.0
    if lin is not None and ("tau" in sl or "d" in sl):
        S = len(rows.static_u)
        col = -(lin.dw @ R)
        if "tau" in local:
            J[local["tau"][0], S:] = col
        if "d" in local:
            J[local["d"][0], S:] = col * rows.moving_t[:, None]
    return r, J, cols


def _finite_gyro_rows(r: FloatArray, J: FloatArray) -> np.ndarray:
    """``(S + M,)`` the gyroscope rows with a reading; the others (NaN: the reading was at the gyroscope's
    rail, :func:`~skincal.calib.preprocess.unit_samples`) are zeroed in ``r`` and ``J`` in place, so they
    add nothing to the normal equations, the scores or the residual statistics."""
    ok = np.all(np.isfinite(r), axis=1)
    if not ok.all():
        r[~ok] = 0.0
        J[:, ~ok] = 0.0
    return ok


def apply_step(state: State, blocks: Blocks, delta: FloatArray) -> State:
    """``state`` moved by the parameter step ``delta`` ``(P,)`` (rotation on the manifold, ``R <- R Exp(dtheta)``;
    the other blocks added)."""
    sl = blocks.slices()
    R = state.R @ Rotation.from_rotvec(delta[sl["theta"]]).as_matrix()
    E = state.E
    if "e" in sl:
        de = delta[sl["e"]]
        E = E + (de.reshape(3, 3) if blocks.scale == SCALE_FULL else sym_from_e(de))
    get = lambda name, old: old + delta[sl[name]] if name in sl else old  # noqa: E731
    return replace(
        state, R=R, p=state.p + delta[sl["p"]], b=state.b + delta[sl["b"]], E=E,
        tau=float(get("tau", np.array([state.tau]))[0]), d=float(get("d", np.array([state.d]))[0]),
        bg=get("bg", state.bg), c=get("c", state.c), k=float(get("k", np.array([state.k]))[0]),
    )


def prior_terms(state: State, blocks: Blocks) -> tuple[FloatArray, FloatArray]:
    """Information ``(P, P)`` and gradient ``(P,)`` of the zero-mean priors (:data:`PRIOR_STD`)."""
    sl = blocks.slices()
    H = np.zeros((blocks.size, blocks.size))
    g = np.zeros(blocks.size)
    values = {
        "e": state.E.reshape(-1) if blocks.scale == SCALE_FULL
        else np.array([state.E[0, 0], state.E[1, 1], state.E[2, 2], state.E[0, 1], state.E[0, 2], state.E[1, 2]]),
        "d": np.array([state.d]), "c": state.c, "k": np.array([state.k]),
    }
    for name, std in PRIOR_STD.items():
        if name in sl:
            idx = np.arange(sl[name].start, sl[name].stop)
            H[idx, idx] = 1.0 / std**2
            g[idx] = values[name] / std**2
    return H, g


def _limit_step(delta: FloatArray, blocks: Blocks) -> FloatArray:
    """Scale a step down so that no rotation or position change exceeds :data:`MAX_STEP`."""
    sl = blocks.slices()
    ratio = max(np.linalg.norm(delta[sl[name]]) / limit for name, limit in MAX_STEP.items())
    return delta / ratio if ratio > 1.0 else delta


def solve(
    state: State,
    blocks: Blocks,
    rows: Rows,
    linearise: Callable[[float, float], Linearisation] | None,
    *,
    max_outer: int = 6,
    max_inner: int = 8,
    tol: float = 1e-6,
    sigma_floor: float = SIGMA_FLOOR,
    sandwich: bool = False,
) -> Fit:
    """Robust Gauss-Newton (see module docstring).

    Args:
        state: start.
        blocks: which optional blocks are estimated.
        rows: the unit's measurements.
        linearise: ``(tau, d) -> Linearisation`` of the moving samples (``None``: static data only).
        sandwich: raise the covariance to the block sandwich's where it is larger
            (:func:`sandwich_inflation`; for data whose errors the noise model does not describe, such
            as a low-rate joint stream's interpolated accelerations).
    """
    if linearise is None:
        blocks = replace(blocks, time_offset=False, clock_drift=False)
    use_gyro = blocks.gyro and rows.static_g is not None
    blocks = replace(blocks, gyro=use_gyro)
    sw_static = np.sqrt(rows.static_weight)
    S = len(rows.static_u)
    lin = linearise(state.tau, state.d) if linearise is not None else None
    sigma = sigma_g = 1.0
    iterations = 0
    null = np.zeros((blocks.size, 0))
    H = np.zeros((blocks.size, blocks.size))
    r = r_g = np.zeros((0, 3))
    rho = rho_g = 1.0
    cost = 0.0
    H_gyro = np.zeros((blocks.size, blocks.size))
    for _outer in range(max_outer):
        for _inner in range(max_inner):
            iterations += 1
            r, J = _accel_rows_with_residual(state, blocks, lin, rows)
            base = np.concatenate([sw_static, np.ones(len(r) - S)])
            norm = np.linalg.norm(r, axis=1) * base
            sigma = max(robust_sigma(norm[S:] if len(r) > S else norm), sigma_floor)
            w = (base**2) * huber_weights(norm, sigma) / sigma**2
            H, g = normal_equations(J, w, overwrite=True)  # J is W^1/2 [J | r] from here
            cost = float(np.sum(w * np.sum(r * r, axis=1)))
            if use_gyro:
                r_g, J_g, cols_g = _gyro_rows_compact(state, blocks, lin, rows)
                ok_g = _finite_gyro_rows(r_g, J_g)
                norm_g = np.linalg.norm(r_g, axis=1) * base
                moving_ok = norm_g[S:][ok_g[S:]]
                sigma_g = max(robust_sigma(moving_ok if moving_ok.size else norm_g[ok_g]), 0.1 * sigma_floor)
                w_g = ok_g * (base**2) * huber_weights(norm_g, sigma_g) / sigma_g**2
                H_g_c, g_g = normal_equations(J_g, w_g, overwrite=True)
                H_gyro = np.zeros_like(H)
                H_gyro[np.ix_(cols_g, cols_g)] = H_g_c
                H = H + H_gyro
                g[cols_g] += g_g
                cost += float(np.sum(w_g * np.sum(r_g * r_g, axis=1)))
            H_p, g_p = prior_terms(state, blocks)
            H, g = H + H_p, g + g_p
            delta, null = pinv_step(H, g)
            state = apply_step(state, blocks, _limit_step(delta, blocks))
            if float(delta @ H @ delta) < tol:  # the step moves less than 1e-3 std in every direction
                break
        max_inner = min(max_inner, 3)  # later outer loops only follow the small change of tau
        if lin is None or not (blocks.time_offset or blocks.clock_drift):
            break
        if abs(state.tau - lin.tau_k) < 1e-7 and abs(state.d - lin.d_k) * (np.ptp(rows.moving_t) + 1e-9) < 1e-7:
            break
        if _outer == max_outer - 1:  # no outer loop left to use a new linearisation (the final one-step fit)
            break
        lin = linearise(state.tau, state.d)
    # Covariance from the last iteration's normal matrix (the final step changes it negligibly),
    # each sensor's information divided by its residuals' autocorrelation factor.
    rho = residual_correlation(r[S:])
    H_p, _ = prior_terms(state, blocks)
    if use_gyro:
        rho_g = residual_correlation(r_g[S:][ok_g[S:]])
        info = (H - H_gyro - H_p) / rho + H_gyro / rho_g + H_p
    else:
        info = (H - H_p) / rho + H_p
    cov = pinv(info)
    factors = np.ones(blocks.size)
    if sandwich and len(r) > S + 20:
        # a row's score J^T W r from the weighted rows W^1/2 [J | r] of the last iteration
        scores = _row_scores(J)
        if use_gyro:
            scores[:, cols_g] += _row_scores(J_g)
        factors = sandwich_inflation(cov, pinv(H), scores, rows.moving_t, S)
        cov = cov * np.outer(factors, factors)
    return Fit(
        state, cov, sigma, null, blocks, cost, iterations, max(rho, rho_g), sigma_g if use_gyro else 0.0, r, factors
    )


def sandwich_inflation(
    cov: FloatArray, H_inv: FloatArray, scores: FloatArray, moving_t: FloatArray, n_static: int,
    block_s: float = SANDWICH_BLOCK_S,
) -> FloatArray:
    """``(P,)`` factors by which each parameter's std is raised to what the residuals themselves say.

    The block sandwich (:func:`skincal.calib.robust.sandwich_factors`, the rule the streaming calibrator
    shares) sums each sample's score ``J_i^T W_i r_i`` over blocks of ``block_s`` seconds of the moving
    samples (each rest row its own block), so errors correlated in time *and with the regressors* (a
    low-rate joint stream's interpolation error that follows the motion, a path-dependent model error)
    count as often as they repeat.

    Args:
        cov: the model covariance (``P, P``); ``H_inv``: the (pseudo-)inverse of the normal matrix
            with the priors; ``scores``: ``(S + M, P)`` per-row scores, rest rows first;
        moving_t: ``(M,)`` stamps of the moving rows, s.
    """
    t = np.asarray(moving_t, dtype=float)
    block = np.concatenate([np.arange(n_static), n_static + np.floor((t - t.min()) / block_s).astype(np.intp)])
    nb = int(block.max()) + 1
    summed = np.zeros((nb, scores.shape[1]))
    np.add.at(summed, block, scores)
    return sandwich_factors(cov, H_inv, summed, nb - n_static)


def _row_scores(Jr: FloatArray) -> FloatArray:
    """``(N, P)`` each row's score ``sum_k J_nk r_nk`` from weighted rows ``W^1/2 [J | r]`` stored by columns
    ``(P + 1, N, 3)``, the three components summed in order."""
    J, r = Jr[:-1], Jr[-1]
    return (J[:, :, 0] * r[:, 0] + J[:, :, 1] * r[:, 1] + J[:, :, 2] * r[:, 2]).T


def _times_vector(K: FloatArray, p: FloatArray) -> FloatArray:
    """``(M, 3)`` ``K_m p`` of ``K`` ``(M, 3, 3)`` and ``p`` ``(3,)`` (one matrix-vector product over the rows)."""
    return (K.reshape(-1, 3) @ p).reshape(-1, 3)


def normal_equations(Jr: FloatArray, w: FloatArray, overwrite: bool = False) -> tuple[FloatArray, FloatArray]:
    """``H = J^T W J`` and ``g = J^T W r`` for row weights ``w`` (per sample, all 3 components), from
    ``Jr = [J | r]`` stored by columns, ``(P + 1, N, 3)`` (:func:`_accel_rows_with_residual`): one product
    ``(W^1/2 Jr)^T (W^1/2 Jr)``, whose last column is ``g``. ``overwrite``: scale ``Jr`` itself to
    ``W^1/2 Jr`` (no copy)."""
    sw = np.repeat(np.sqrt(w), 3)
    Jw = Jr.reshape(Jr.shape[0], -1)
    if overwrite:
        Jw *= sw
    else:
        Jw = Jw * sw
    rows = Jw.T  # (3 N, P + 1), column-major: the product below is BLAS's J^T J of the stacked rows
    G = rows.T @ rows
    return G[:-1, :-1].copy(), G[:-1, -1].copy()
