"""The ``mle`` solver's Jacobians and priors (``skincal.calib.mle.solver``) against finite differences
and closed forms.

Jacobians: every column of ``accel_rows`` and ``gyro_rows`` (rotation ``R <- R Exp(dtheta)``,
position, biases, scale/misalignment in both parametrisations, time offset, clock drift, bias
drift, gravity scale) is compared with a central difference of the residual on random states and
random linearisation arrays. The time columns are linearised around ``(tau_k, d_k)``: they are
checked against a difference of the residual computed with that same linear formula (the
linearisation held fixed), and separately against a difference of the residual whose signals are
re-evaluated at the shifted instants (smooth closed-form signals), which checks the sign
convention ``s = t - tau - d (t - t_c)``.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy.optimize import minimize_scalar
from scipy.spatial.transform import Rotation

from skincal.calib.mle.solver import (
    PRIOR_STD,
    SCALE_FULL,
    SCALE_NONE,
    SCALE_SYM,
    Blocks,
    Linearisation,
    Rows,
    State,
    accel_rows,
    apply_step,
    gyro_rows,
    prior_terms,
    sandwich_inflation,
    solve,
)

ALL = dict(time_offset=True, clock_drift=True, gyro=True, bias_drift=True, gravity=True)


def _random_problem(seed: int, S: int = 5, M: int = 40):
    rng = np.random.default_rng(seed)
    u_s = rng.normal(size=(S, 3))
    u_s *= 9.81 / np.linalg.norm(u_s, axis=1, keepdims=True)
    rows = Rows(
        static_u=u_s,
        static_f=rng.normal(size=(S, 3)) * 5,
        static_g=rng.normal(size=(S, 3)) * 0.1,
        static_weight=rng.integers(20, 200, S).astype(float),
        static_t=rng.uniform(-200, 200, S),
        moving_t=np.sort(rng.uniform(-250, 250, M)),
        moving_f=rng.normal(size=(M, 3)) * 5,
        moving_g=rng.normal(size=(M, 3)),
    )
    lin = Linearisation(
        tau_k=0.011,
        d_k=-3e-4,
        u=rng.normal(size=(M, 3)) * 5,
        K=rng.normal(size=(M, 3, 3)) * 4,
        du=rng.normal(size=(M, 3)) * 20,
        dK=rng.normal(size=(M, 3, 3)) * 30,
        w=rng.normal(size=(M, 3)),
        dw=rng.normal(size=(M, 3)) * 6,
        ug=rng.normal(size=(M, 3)) * 9.81 / np.sqrt(3),
    )
    return rows, lin, rng


def _random_state(rng, scale: str) -> State:
    if scale == SCALE_FULL:
        E = rng.normal(size=(3, 3)) * 0.02
    else:
        E = rng.normal(size=(3, 3)) * 0.02
        E = 0.5 * (E + E.T)
    return State(
        R=Rotation.random(random_state=int(rng.integers(1 << 30))).as_matrix(),
        p=rng.normal(size=3) * 0.1,
        b=rng.normal(size=3) * 0.2,
        E=E,
        tau=0.0135,  # away from tau_k and d_k: the linearised dtau terms are exercised
        d=2.1e-4,
        bg=rng.normal(size=3) * 0.05,
        c=rng.normal(size=3) * 1e-3,
        k=0.004,
    )


def _perturb(state: State, blocks: Blocks, name: str, i: int, h: float) -> State:
    """``state`` with component ``i`` of block ``name`` moved by ``h`` (written out, not ``apply_step``)."""
    if name == "theta":
        return replace(state, R=state.R @ Rotation.from_rotvec(h * np.eye(3)[i]).as_matrix())
    if name in ("p", "b", "bg", "c"):
        v = getattr(state, name).copy()
        v[i] += h
        return replace(state, **{name: v})
    if name in ("tau", "d", "k"):
        return replace(state, **{name: getattr(state, name) + h})
    if name == "e":
        D = np.zeros((3, 3))
        if blocks.scale == SCALE_FULL:
            D[i // 3, i % 3] = h  # row-major
        else:  # (xx, yy, zz, xy, xz, yz), symmetric
            a, b = [(0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2)][i]
            D[a, b] = D[b, a] = h
        return replace(state, E=state.E + D)
    raise AssertionError(name)


STEP = {"theta": 1e-6, "p": 1e-6, "b": 1e-6, "e": 1e-6, "tau": 1e-7, "d": 1e-9, "bg": 1e-6, "c": 1e-8, "k": 1e-6}


def _check_jacobian(fn, state, blocks, lin, rows):
    r0, J = fn(state, blocks, lin, rows)
    assert J.shape == (len(r0), 3, blocks.size)
    checked = 0
    for name, sl in blocks.slices().items():
        for i in range(sl.stop - sl.start):
            h = STEP[name]
            rp = fn(_perturb(state, blocks, name, i, h), blocks, lin, rows)[0]
            rm = fn(_perturb(state, blocks, name, i, -h), blocks, lin, rows)[0]
            fd = (rp - rm) / (2 * h)
            col = J[:, :, sl.start + i]
            scale = max(np.max(np.abs(fd)), np.max(np.abs(col)), 1e-300)
            err = np.max(np.abs(fd - col)) / scale if scale > 1e-12 else np.max(np.abs(fd - col))
            assert err < 1e-6, (name, i, err)
            checked += 1
    assert checked == blocks.size


@pytest.mark.parametrize("scale", [SCALE_SYM, SCALE_FULL])
@pytest.mark.parametrize("seed", [0, 1])
def test_accelerometer_jacobian_by_finite_differences(scale, seed):
    rows, lin, rng = _random_problem(seed)
    blocks = Blocks(scale=scale, **ALL)
    state = _random_state(rng, scale)
    _check_jacobian(accel_rows, state, blocks, lin, rows)
    # static rows only (no linearisation): rotation, bias, scale, bias drift and gravity columns
    _check_jacobian(accel_rows, state, replace(blocks, time_offset=False, clock_drift=False), None, rows)


@pytest.mark.parametrize("scale", [SCALE_SYM, SCALE_FULL])
def test_gyroscope_jacobian_by_finite_differences(scale):
    rows, lin, rng = _random_problem(2)
    blocks = Blocks(scale=scale, **ALL)
    state = _random_state(rng, scale)
    _check_jacobian(gyro_rows, state, blocks, lin, rows)
    _, J = gyro_rows(state, blocks, lin, rows)
    sl = blocks.slices()
    for name in ("p", "b", "e", "c", "k"):  # the gyroscope model does not depend on these
        assert np.all(J[:, :, sl[name]] == 0.0), name
    # its residual is the model written out: R^T (w - dtau dw) + b_g - g
    S = len(rows.static_u)
    dtau = (state.tau - lin.tau_k) + (state.d - lin.d_k) * rows.moving_t
    w = lin.w - dtau[:, None] * lin.dw
    r, _ = gyro_rows(state, blocks, lin, rows)
    np.testing.assert_allclose(r[S:], w @ state.R + state.bg - rows.moving_g, atol=1e-12)
    np.testing.assert_allclose(r[:S], state.bg - rows.static_g, atol=1e-12)


def test_accelerometer_residual_is_the_model_written_out():
    """``a = A R^T v(s) + b + c t``, ``v = u - dtau du + (K - dtau dK) p + k u_g``; static rows ``(1 + k) u``."""
    rows, lin, rng = _random_problem(3)
    blocks = Blocks(scale=SCALE_FULL, **ALL)
    st = _random_state(rng, SCALE_FULL)
    S = len(rows.static_u)
    r, _ = accel_rows(st, blocks, lin, rows)
    A = np.eye(3) + st.E
    dtau = (st.tau - lin.tau_k) + (st.d - lin.d_k) * rows.moving_t
    for m in (0, 7, 39):
        v = lin.u[m] - dtau[m] * lin.du[m] + (lin.K[m] - dtau[m] * lin.dK[m]) @ st.p + st.k * lin.ug[m]
        pred = A @ st.R.T @ v + st.b + st.c * rows.moving_t[m]
        np.testing.assert_allclose(r[S + m], pred - rows.moving_f[m], atol=1e-10)
    for s in range(S):
        pred = A @ st.R.T @ ((1 + st.k) * rows.static_u[s]) + st.b + st.c * rows.static_t[s]
        np.testing.assert_allclose(r[s], pred - rows.static_f[s], atol=1e-10)


@pytest.mark.parametrize("scale", [SCALE_SYM, SCALE_FULL])
def test_apply_step_moves_each_block_as_the_jacobian_assumes(scale):
    """``apply_step`` with a unit step in one component equals the perturbation the Jacobian columns were
    differentiated along (so the solver steps where its Jacobian points)."""
    rows, lin, rng = _random_problem(4)
    blocks = Blocks(scale=scale, **ALL)
    st = _random_state(rng, scale)
    for name, sl in blocks.slices().items():
        for i in range(sl.stop - sl.start):
            delta = np.zeros(blocks.size)
            delta[sl.start + i] = 1e-3
            a, b = apply_step(st, blocks, delta), _perturb(st, blocks, name, i, 1e-3)
            for field in ("R", "p", "b", "E", "bg", "c"):
                np.testing.assert_allclose(getattr(a, field), getattr(b, field), atol=1e-15, err_msg=(name, i))
            for field in ("tau", "d", "k"):
                assert getattr(a, field) == pytest.approx(getattr(b, field), abs=1e-15)


# ---------------------------------------------------------------------------- time columns vs re-evaluated signals
def _smooth_signals(t_c: float):
    """Closed-form link signals (sinusoids) of time and their derivatives, and a linearise(tau, d)
    built exactly as the method does: ``s = t - tau - d (t - t_c)``."""
    freqs = np.array([0.7, 1.1, 1.9])

    def at(s):
        ph = np.outer(s, freqs) * 2 * np.pi
        u = 4 * np.sin(ph) + np.array([0.0, 0.0, 9.81])
        du = 4 * 2 * np.pi * freqs * np.cos(ph)
        K = np.stack([np.sin(ph + j) for j in range(3)], axis=1) * 3  # (M, 3, 3)
        dK = np.stack([2 * np.pi * freqs * np.cos(ph + j) for j in range(3)], axis=1) * 3
        w = 1.5 * np.cos(ph)
        dw = -1.5 * 2 * np.pi * freqs * np.sin(ph)
        ug = np.tile([0.0, 0.0, 9.81], (s.size, 1))
        return u, K, du, dK, w, dw, ug

    return at


def test_time_columns_match_the_signals_reevaluated_at_shifted_instants():
    rng = np.random.default_rng(5)
    t_c = 100.0
    M = 60
    rows = Rows(
        static_u=np.zeros((0, 3)), static_f=np.zeros((0, 3)), static_g=np.zeros((0, 3)),
        static_weight=np.zeros(0), static_t=np.zeros(0),
        moving_t=np.sort(rng.uniform(-80, 80, M)), moving_f=rng.normal(size=(M, 3)), moving_g=rng.normal(size=(M, 3)),
    )
    at = _smooth_signals(t_c)

    def linearise(tau, d):
        s = (rows.moving_t + t_c) - tau - d * rows.moving_t
        u, K, du, dK, w, dw, ug = at(s)
        return Linearisation(tau, d, u, K, du, dK, w, dw, ug)

    blocks = Blocks(scale=SCALE_FULL, **ALL)
    st = replace(_random_state(rng, SCALE_FULL), tau=0.02, d=5e-5)
    for fn in (accel_rows, gyro_rows):
        _, J = fn(st, blocks, linearise(st.tau, st.d), rows)
        sl = blocks.slices()
        for name, h in (("tau", 1e-6), ("d", 1e-8)):
            plus, minus = _perturb(st, blocks, name, 0, h), _perturb(st, blocks, name, 0, -h)
            rp = fn(plus, blocks, linearise(plus.tau, plus.d), rows)[0]
            rm = fn(minus, blocks, linearise(minus.tau, minus.d), rows)[0]
            fd = (rp - rm) / (2 * h)
            col = J[:, :, sl[name].start]
            assert np.max(np.abs(fd - col)) < 1e-5 * np.max(np.abs(col)), (fn.__name__, name)


# ---------------------------------------------------------------------------- priors
@pytest.mark.parametrize("scale", [SCALE_SYM, SCALE_FULL])
def test_prior_terms_information_and_gradient(scale):
    rng = np.random.default_rng(6)
    blocks = Blocks(scale=scale, **ALL)
    st = _random_state(rng, scale)
    H, g = prior_terms(st, blocks)
    sl = blocks.slices()
    expected_H = np.zeros(blocks.size)
    expected_g = np.zeros(blocks.size)
    e = st.E.reshape(-1) if scale == SCALE_FULL else st.E[[0, 1, 2, 0, 0, 1], [0, 1, 2, 1, 2, 2]]
    for name, value in (("e", e), ("d", [st.d]), ("c", st.c), ("k", [st.k])):
        expected_H[sl[name]] = 1 / PRIOR_STD[name] ** 2
        expected_g[sl[name]] = np.asarray(value) / PRIOR_STD[name] ** 2
    np.testing.assert_allclose(H, np.diag(expected_H))
    np.testing.assert_allclose(g, expected_g)
    # no prior on the pose, the biases or the time offset
    for name in ("theta", "p", "b", "tau", "bg"):
        assert np.all(H[sl[name], :] == 0) and np.all(g[sl[name]] == 0)


def _static_rows(R: np.ndarray, b: np.ndarray, scale: float = 1.0, n: int = 8, seed: int = 7) -> Rows:
    """Noise-free rest runs at ``n`` gravity directions, all at the reference instant (``t = 0``)."""
    rng = np.random.default_rng(seed)
    u = rng.normal(size=(n, 3))
    u *= 9.81 / np.linalg.norm(u, axis=1, keepdims=True)
    f = scale * (u @ R) + b
    return Rows(
        static_u=u, static_f=f, static_g=None, static_weight=np.full(n, 100.0), static_t=np.zeros(n),
        moving_t=np.zeros(0), moving_f=np.zeros((0, 3)), moving_g=None,
    )


def test_prior_terms_pull_an_undetermined_block_to_zero_with_the_prior_std():
    """All rest runs at one instant: the bias drift ``c`` has no data. It goes to zero from wherever
    it starts and its std is the prior's (1e-3 m/s^3), while rotation and bias are recovered and the
    position (static data only) is reported as a null-space direction."""
    R = Rotation.from_rotvec([0.3, -0.5, 1.1]).as_matrix()
    b = np.array([0.2, -0.1, 0.05])
    rows = _static_rows(R, b)
    blocks = Blocks(scale=SCALE_NONE, time_offset=False, clock_drift=False, gyro=False, bias_drift=True)
    start = State(R=R @ Rotation.from_rotvec([0.02, 0.01, -0.03]).as_matrix(), p=np.zeros(3), b=np.zeros(3),
                  c=np.array([0.01, -0.02, 0.005]))
    fit = solve(start, blocks, rows, None)
    sl = fit.blocks.slices()
    np.testing.assert_allclose(fit.state.c, 0.0, atol=1e-12)
    std = np.sqrt(np.diag(fit.covariance))
    np.testing.assert_allclose(std[sl["c"]], PRIOR_STD["c"], rtol=1e-6)
    np.testing.assert_allclose(fit.state.R, R, atol=1e-9)
    np.testing.assert_allclose(fit.state.b, b, atol=1e-9)
    # the position is unobservable from rest runs: exactly the three p directions, no prior there
    null = fit.null_space
    assert null.shape[1] == 3
    np.testing.assert_allclose(np.linalg.norm(null[sl["p"]], axis=0), 1.0, atol=1e-9)
    np.testing.assert_allclose(fit.state.p, 0.0, atol=1e-9)  # left at the start


def test_prior_terms_split_an_isotropic_scale_between_gravity_and_accelerometer_scale():
    """Rest runs read ``(1 + s)`` times the true gravity: from rest data alone a gravity error ``k``
    and an accelerometer scale ``E = e I`` are indistinguishable (``(1 + k)(1 + e) = 1 + s``). The MAP
    estimate then minimises the priors ``3 e^2 / 0.05^2 + k^2 / 0.01^2`` along that curve; its std
    along ``k`` is ``1 / sqrt(1 / 0.01^2 + 3 / 0.05^2)`` (the linearised constraint)."""
    s = 0.02
    R = Rotation.from_rotvec([-0.7, 0.2, 0.4]).as_matrix()
    b = np.array([0.05, 0.1, -0.2])
    rows = _static_rows(R, b, scale=1 + s, n=10)
    blocks = Blocks(scale=SCALE_SYM, time_offset=False, clock_drift=False, gyro=False, gravity=True)
    fit = solve(State(R=R, p=np.zeros(3), b=np.zeros(3)), blocks, rows, None, max_inner=30)

    def prior_cost(k):
        e = (1 + s) / (1 + k) - 1
        return 3 * e**2 / PRIOR_STD["e"] ** 2 + k**2 / PRIOR_STD["k"] ** 2

    k_map = minimize_scalar(prior_cost, bounds=(-0.1, 0.1), method="bounded", options={"xatol": 1e-12}).x
    print(f"k = {fit.state.k:.6g} (MAP {k_map:.6g}), E diag = {np.diag(fit.state.E)}")
    assert fit.state.k == pytest.approx(k_map, abs=2e-6)
    np.testing.assert_allclose(np.diag(fit.state.E), (1 + s) / (1 + k_map) - 1, atol=2e-6)
    np.testing.assert_allclose(fit.state.E - np.diag(np.diag(fit.state.E)), 0.0, atol=1e-8)
    sl = fit.blocks.slices()
    std_k = np.sqrt(fit.covariance[sl["k"], sl["k"]][0, 0])
    expected = 1 / np.sqrt(1 / PRIOR_STD["k"] ** 2 + 3 / PRIOR_STD["e"] ** 2)
    assert std_k == pytest.approx(expected, rel=0.03)


def _sandwich_case(rng, follow: float, blocks: int = 400, per_block: int = 50, corr_s: float = 1.0):
    """One-parameter regression ``y = x beta + e`` with unit white noise plus ``follow * eta_b x``: an
    error that follows the regressor and repeats within each ``corr_s`` block (eta_b ~ N(0, 1) per block).
    Returns the sandwich factor, the model std and the closed-form std of the estimate."""
    n = blocks * per_block
    t = np.arange(n) / per_block  # per_block samples per second
    x = np.sin(2.0 * np.pi * 0.37 * t) + 0.5 * np.sin(2.0 * np.pi * 1.9 * t)
    b = np.floor(t / corr_s).astype(int)
    eta = rng.standard_normal(int(b.max()) + 1)[b]
    r = rng.standard_normal(n) + follow * eta * x
    H = np.array([[np.sum(x * x)]])
    cov = np.linalg.inv(H)  # the model: white noise of unit variance
    scores = (x * r)[:, None]
    f = sandwich_inflation(cov, cov, scores, t, 0)[0]
    sxx = np.bincount(b, weights=x * x)
    true_var = (np.sum(x * x) + follow**2 * np.sum(sxx**2)) / np.sum(x * x) ** 2
    return f, float(np.sqrt(cov[0, 0])), float(np.sqrt(true_var))


def test_the_block_sandwich_leaves_white_noise_alone_and_follows_motion_correlated_errors():
    rng = np.random.default_rng(7)
    white = [_sandwich_case(rng, 0.0)[0] for _ in range(20)]
    assert sum(f > 1.0 for f in white) <= 1, white  # a false raise in ~1 % of cases
    for follow in (0.3, 1.0):
        f, s_model, s_true = _sandwich_case(rng, follow)
        assert f * s_model == pytest.approx(s_true, rel=0.12), (follow, f, s_true / s_model)
    # an error that stays correlated over 2.5 s (as on the real 14 Hz recordings) is counted too, less
    # what a block boundary splits off a stretch that straddles it (0.81-0.88 of the std on four seeds;
    # 1 s blocks see about 0.6)
    f, s_model, s_true = _sandwich_case(rng, 1.0, corr_s=2.5)
    assert 0.75 < f * s_model / s_true < 1.05, (f, s_true / s_model)
