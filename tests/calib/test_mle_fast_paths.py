"""The fast paths of ``mle`` (issue 26) against slower reference paths computed in the same test: the
table interpolation, the normal equations, the kept linearisation, the consistency parts without
diagnostics and with the full run's clock alignment. Simulated data only."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from skincal.calib import calibrate
from skincal.calib.api import METHODS, calibrate_unit
from skincal.calib.hermite import hermite, hermite_rows
from skincal.calib.mle.problem import Problem, arrange, prepare
from skincal.calib.mle.solver import normal_equations
from skincal.calib.preprocess import JointInterpolator
from skincal.protocol.presets import get_protocol
from skincal.sim import simulate
from skincal.workflows.session import make_session


@pytest.fixture(scope="module")
def short():
    """Two random units on the Panda, ``realistic`` IMUs, controller joints, 3 poses of ``fast`` (simulated)."""
    protocol = dataclasses.replace(get_protocol("fast"), n_poses=3)
    return simulate(make_session("panda", "random", 2, "realistic", protocol, 4, joints="controller"))


def _naive_hermite(grid, y, dy, t):
    """Cubic Hermite, one instant at a time (the textbook form)."""
    out, d = np.empty((t.size, y.shape[1])), np.empty((t.size, y.shape[1]))
    for m, tm in enumerate(t):
        i = min(max(int(np.searchsorted(grid, tm)) - 1, 0), grid.size - 2)
        h = grid[i + 1] - grid[i]
        s = (tm - grid[i]) / h
        h00, h10, h01, h11 = 2 * s**3 - 3 * s**2 + 1, s**3 - 2 * s**2 + s, -2 * s**3 + 3 * s**2, s**3 - s**2
        out[m] = h00 * y[i] + h10 * h * dy[i] + h01 * y[i + 1] + h11 * h * dy[i + 1]
        d[m] = (1 - s) * dy[i] + s * dy[i + 1]
    return out, d


def test_table_rows_interpolate_as_hermite_and_the_textbook_form(rng):
    grid = np.cumsum(rng.uniform(0.5, 1.5, 40)) * 0.01
    table = rng.normal(size=(40, 10))
    t = np.sort(rng.uniform(grid[0] - 0.02, grid[-1] + 0.02, 200))  # a few beyond the ends: clipped
    y, dy = hermite_rows(grid, table, t, 5)
    ref_y, ref_dy, _ = hermite(grid, table[:, :5], table[:, 5:], t)
    assert np.array_equal(y, ref_y) and np.array_equal(dy, ref_dy)
    naive_y, naive_dy = _naive_hermite(grid, table[:, :5], table[:, 5:], t)
    np.testing.assert_allclose(y, naive_y, rtol=0, atol=1e-12)
    np.testing.assert_allclose(dy, naive_dy, rtol=0, atol=1e-12)


def test_normal_equations_from_the_residual_column(rng):
    J, r, w = rng.normal(size=(50, 3, 7)), rng.normal(size=(50, 3)), rng.uniform(0.1, 2.0, 50)
    H, g = normal_equations(np.concatenate([J, r[:, :, None]], axis=2).transpose(2, 0, 1).copy(), w)  # by columns
    W = np.repeat(w, 3)
    J2 = J.reshape(-1, 7)
    np.testing.assert_allclose(H, J2.T @ (W[:, None] * J2), rtol=1e-12)
    np.testing.assert_allclose(g, J2.T @ (W * r.reshape(-1)), rtol=1e-12)


def test_the_kept_linearisation_is_the_one_computed_afresh(short):
    spec = METHODS["mle"]
    interp = JointInterpolator(short.joints)
    shared = prepare(short, interp)
    unit = short.units[0]
    link = short.truth[unit].link
    captured = {}

    def run_unit(problem):
        captured["p"] = arrange(problem, link)
        return spec.run_unit(problem)

    calibrate_unit(short, unit, dataclasses.replace(spec, run_unit=run_unit), link=link,
                   rng=np.random.default_rng(0), interpolator=interp, shared=shared)  # fmt: skip
    p: Problem = captured["p"]
    first = p.linearise(0.01, 2e-6)
    assert p.linearise(0.01, 2e-6) is first  # kept
    fresh = Problem(p.table, p.data, p.sandwich).linearise(0.01, 2e-6)
    for name in ("u", "K", "du", "dK", "w", "dw", "ug"):
        assert np.array_equal(getattr(first, name), getattr(fresh, name))
    p.linearise(0.0, 0.0)  # another one replaces it
    assert p.linearise(0.01, 2e-6) is not first


def test_a_part_fit_without_diagnostics_keeps_the_pose_and_std(short):
    spec = METHODS["mle"]
    interp = JointInterpolator(short.joints)
    shared = spec.prepare(short, interp)
    for k, unit in enumerate(short.units):
        got = [
            calibrate_unit(short, unit, spec, link=short.truth[unit].link, rng=np.random.default_rng([0, k]),
                           interpolator=interp, shared=shared, diagnostics=flag)  # fmt: skip
            for flag in (True, False)
        ]
        full, lean = got
        assert "samples" in full.extras and "samples" not in lean.extras
        assert np.array_equal(full.pose.p_link_su, lean.pose.p_link_su)
        assert np.array_equal(full.pose.R_link_su, lean.pose.R_link_su)
        assert np.array_equal(full.position_std_m, lean.position_std_m)
        assert np.array_equal(full.rotation_std_deg, lean.rotation_std_deg)


def test_the_parts_reuse_the_full_runs_alignment_to_the_same_result(short):
    """The full run and the split check's six parts in forked workers (workers=2) give what one process gives."""
    serial = calibrate(short, "mle", workers=1)  # the parts take the full run's alignments
    forked = calibrate(short, "mle", workers=2)  # the full run in workers: the parts align again
    assert set(serial.units) == set(forked.units) == set(short.units)
    for unit in short.units:
        a, b = serial.units[unit], forked.units[unit]
        assert "consistency" in a.extras
        assert a.extras["consistency"] == b.extras["consistency"]
        assert np.array_equal(a.pose.p_link_su, b.pose.p_link_su)
        assert np.array_equal(a.position_std_m, b.position_std_m)


def test_a_column_range_of_the_table_rows_is_the_same_interpolation(rng):
    grid = np.arange(30) * 0.008
    table = rng.normal(size=(30, 12))
    t = rng.uniform(0.0, grid[-1], 50)
    y, dy = hermite_rows(grid, table, t, 6)
    y_c, dy_c = hermite_rows(grid, table, t, 6, slice(2, 5))
    assert np.array_equal(y_c, y[:, 2:5]) and np.array_equal(dy_c, dy[:, 2:5])


@pytest.mark.parametrize("n, noise", [(30, 1e-3), (400, 1e-4), (400, 0.0)])
def test_the_gcv_smoothing_parameter_is_scipys(n, noise):
    """gcv_lambda against SciPy's own choice (make_smoothing_spline with lam=None), bit for bit."""
    from scipy.interpolate import make_smoothing_spline

    from skincal.calib.preprocess.gcv import gcv_lambda

    rng = np.random.default_rng(n)
    t = np.cumsum(rng.uniform(0.5, 1.5, n)) / 14.0
    y = np.sin(2.1 * t) + 0.3 * np.cos(5.0 * t) + noise * rng.normal(size=n)
    lam = gcv_lambda(t, y)
    assert 0.0 <= lam <= n
    assert np.array_equal(make_smoothing_spline(t, y, lam=lam).c, make_smoothing_spline(t, y).c)


@pytest.mark.parametrize("n", [5, 6, 40, 400])
def test_the_smoothing_spline_from_shared_bands_is_scipys(n):
    """smoothing_spline (bands built once, their central columns on whole windows) against SciPy's
    make_smoothing_spline at the same lam, bit for bit, knots and coefficients."""
    from scipy.interpolate import make_smoothing_spline

    from skincal.calib.preprocess.gcv import smoothing_spline, spline_bands

    rng = np.random.default_rng(n)
    t = np.cumsum(rng.uniform(0.5, 1.5, n)) / 14.0
    y = np.sin(2.1 * t) + 1e-3 * rng.normal(size=n)
    bands = spline_bands(t)
    for lam in (0.0, 1e-5, 0.02, 3.0):
        ours, scipys = smoothing_spline(t, y, lam, bands), make_smoothing_spline(t, y, lam=lam)
        assert np.array_equal(ours.t, scipys.t) and np.array_equal(ours.c, scipys.c)


def test_a_stream_fitted_again_gets_the_same_spline_without_cross_validation(monkeypatch):
    """The conditioning's smoothing spline of a stream it has fitted before (the report-spacing check's
    thinned streams) skips the GCV search and is the same spline, bit for bit."""
    import skincal.calib.preprocess.conditioning as conditioning

    rng = np.random.default_rng(3)
    t = np.cumsum(rng.uniform(0.5, 1.5, 300)) / 14.0
    y = np.sin(2.1 * t) + 1e-4 * rng.normal(size=300)
    first = conditioning._smoothing_spline(t, y)
    searched: list[int] = []
    real = conditioning.gcv_lambda
    monkeypatch.setattr(conditioning, "gcv_lambda", lambda *a, **k: searched.append(1) or real(*a, **k))
    again = conditioning._smoothing_spline(t.copy(), y.copy())
    assert not searched and np.array_equal(again.c, first.c)
    conditioning._smoothing_spline(t, y + 1e-6)  # other data: searched
    assert searched == [1]


def _captured_fits(monkeypatch):
    """Record every ``fit_problem(p, blocks, ...)`` call of ``mle``'s ``run_unit`` with its outcome."""
    import skincal.calib.mle.method as method

    calls: list = []
    real = method.fit_problem

    def spy(p, blocks, **kw):
        fit = real(p, blocks, **kw)
        calls.append((p, blocks, kw, fit))
        return fit

    monkeypatch.setattr(method, "fit_problem", spy)
    return calls


def test_the_one_step_fit_linearises_once(short, monkeypatch):
    """The final one-step fit (``max_outer=1``) evaluates the link signals at its start only: a linearisation
    after its last step would have no outer loop left to use it."""
    calls = _captured_fits(monkeypatch)
    spec = METHODS["mle"]
    unit = short.units[0]
    calibrate_unit(short, unit, spec, link=short.truth[unit].link, rng=np.random.default_rng(0))
    p, blocks, kw, fit = calls[-1]
    assert kw.get("max_outer") == 1 and blocks.time_offset
    asked: list = []
    real = p.linearise

    def counted(tau, d):
        asked.append((tau, d))
        return real(tau, d)

    from skincal.calib.mle.solver import solve

    again = solve(kw["state"], blocks, p.data.rows, counted, max_outer=1, max_inner=1, sandwich=p.sandwich)
    assert asked == [(kw["state"].tau, kw["state"].d)]
    assert np.array_equal(again.state.p, fit.state.p) and np.array_equal(again.covariance, fit.covariance)


def test_a_part_skips_the_gyroscope_unit_check_and_keeps_its_fit(short, monkeypatch):
    """A consistency part (no diagnostics, link given) does not evaluate the gyroscope's rates for the unit check
    (the whole stream's run made it); its pose and std are the same as with the check."""
    import skincal.calib.mle.method as method

    spec = METHODS["mle"]
    unit = short.units[0]
    link = short.truth[unit].link
    asked: list = []
    real = method.gyro_rates
    monkeypatch.setattr(method, "gyro_rates", lambda problem: asked.append(problem.diagnostics) or real(problem))
    got = [calibrate_unit(short, unit, spec, link=link, rng=np.random.default_rng(0), diagnostics=flag)
           for flag in (True, False)]  # fmt: skip
    assert asked == [True]
    assert np.array_equal(got[0].pose.p_link_su, got[1].pose.p_link_su)
    assert np.array_equal(got[0].position_std_m, got[1].position_std_m)
