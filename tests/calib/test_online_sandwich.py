"""The streaming calibrator's block sandwich (skincal.calib.online.fit.sandwich, the rule of
skincal.calib.robust.sandwich_factors that ``mle`` applies too): window scores against finite differences
of the windows' cost, honest std on a low-rate joint stream, nothing changed on a controller's stream.
Simulated data only here (the real recordings are checked by ``skincal benchmark realdata``)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from skincal.calib.online import OnlineCalibrator, fit, replay, stats
from skincal.calib.online.unit import MOVING, REST
from skincal.calib.robust import sandwich_factors
from skincal.workflows.session import simulate_dataset


@pytest.fixture(scope="module")
def report14():
    """Six units on the Panda, ``fast`` protocol, a robot's ~14 Hz joint reports (seed 0: the session whose
    streaming std were over-confident without the sandwich)."""
    ds = simulate_dataset("panda", "paper", noise="realistic", protocol="fast", seed=0, joints="report14")
    cal = OnlineCalibrator(ds.robot, ds.units, ds.gravity)
    replay(ds, cal)
    return ds, cal, cal.result()


def _cost(st, link, sol, window, c, R, x):
    """Window ``window``'s class-``c`` part of ``C`` at ``R``, ``x`` (weighted as the fit weighs it)."""
    k = st.links.index(link)
    one_a, one_g = np.zeros((2, stats.NA, stats.NA)), np.zeros((2, stats.NG, stats.NG))
    one_a[c], one_g[c] = st.ledger.Za[window, k, c], st.ledger.Zg[window, k, c]
    Za, Zg = fit.weigh(one_a, one_g, st.sigmas[link], st.decided, bool(st.has_gyro))
    xa, _, xg, _ = stats.linearise(R, x)

    def form(Z, v):  # [v; -1]^T Z [v; -1], not clamped at 0 as residual_sum is (a window's noise-corrected Gram
        ve = np.append(v, -1.0)  # of a few samples need not be positive: the scores sum to the whole's gradient)
        return float(ve @ Z @ ve)

    return form(Za, xa) + (form(Zg, xg) if Zg is not None else 0.0)


def test_window_scores_are_half_the_gradient_of_each_windows_cost(report14):
    """A window's score is half the gradient of its part of the cost in the Gauss-Newton unknowns: checked
    against central differences of that cost, the rotation perturbed on the manifold (``R Exp(dtheta)``)."""
    _, cal, _ = report14
    st = cal.unit_state("su4")
    link = next(iter(st.solutions))
    sol = st.solutions[link]
    (rest, rest_w), (moving, moving_w) = fit.window_scores(st, link, sol)
    assert moving.shape == (moving_w.size, stats.NP) and moving_w.size >= 20 and rest_w.size >= 3
    for c, scores, windows in ((MOVING, moving, moving_w), (REST, rest, rest_w)):
        for i in (0, len(windows) // 2):
            w = int(windows[i])
            fd = np.zeros(stats.NP)
            for j in range(stats.NP):
                h = 1e-6 if j < 3 else 1e-6 * max(1.0, abs(float(sol.state[j])))
                costs = []
                for sign in (1.0, -1.0):
                    R, x = sol.R, sol.state.copy()
                    if j < 3:
                        R = sol.R @ Rotation.from_rotvec(sign * h * np.eye(3)[j]).as_matrix()
                    else:
                        x[j] += sign * h
                    costs.append(_cost(st, link, sol, w, c, R, x))
                fd[j] = (costs[0] - costs[1]) / (2 * h) / 2.0
            scale = np.abs(fd).max()
            assert np.allclose(scores[i], fd, rtol=1e-4, atol=1e-5 * scale), (c, w, scores[i], fd)


def test_sandwich_factors_rule():
    """The shared rule: scores that repeat what the model covariance says give no factor; scores four times
    larger than the model's (errors correlated within blocks) give 4 times the std on that parameter only;
    a parameter without a positive model variance is left alone."""
    rng = np.random.default_rng(3)
    B = 400
    cov = np.diag([1.0, 4.0, 0.0])
    H_inv = np.diag([1.0, 4.0, 1.0])
    H = np.array([1.0, 0.25, 1.0])  # the information (H_inv's inverse): honest scores sum to it, sum g g^T ~ H
    scores = rng.standard_normal((B, 3)) * np.sqrt(H / B)
    f = sandwich_factors(cov, H_inv, scores, B)
    assert f[0] == 1.0 and f[2] == 1.0  # honest; non-positive model variance
    scores[:, 0] *= 4.0
    f = sandwich_factors(cov, H_inv, scores, B)
    assert f[0] == pytest.approx(4.0, rel=0.1) and f[1] == 1.0


def test_the_sandwich_makes_a_low_rate_streams_std_honest(report14, monkeypatch):
    """SIMULATED, 14 Hz joint reports: without the sandwich a unit of this session is more than 2.5 of its
    std off along an axis; with it no unit is, each axis' RMS error / std lies in [0.5, 1.3], only the units
    whose residuals follow the motion are raised (the factors are in the result)."""
    ds, _, result = report14

    def ratios(res):
        z = np.array([(np.asarray(u.pose.p_link_su) - ds.truth[n].p_link_su) / u.position_std_m
                      for n, u in res.units.items()])  # fmt: skip
        return np.sqrt((z**2).mean(axis=0)), np.abs(z).max()

    with_it, worst_with = ratios(result)
    raised = [n for n, u in result.units.items() if max(u.extras["covariance_sandwich"]) > 1.0]
    monkeypatch.setattr(fit, "sandwich", lambda st, link, sol, kappa, windows=None: (sol, None))
    cal = OnlineCalibrator(ds.robot, ds.units, ds.gravity)
    replay(ds, cal)
    plain = cal.result()
    without, worst_without = ratios(plain)
    print(f"\nreport14 Panda seed 0: RMS error/std without the sandwich {without.round(2)} (worst "
          f"{worst_without:.1f}), with {with_it.round(2)} (worst {worst_with:.1f})")
    assert worst_without > 2.5 and worst_with < 2.5
    assert np.all((with_it >= 0.5) & (with_it <= 1.3)), with_it
    assert 1 <= len(raised) <= 3, raised  # the others keep their std (a live status's, which gates outliers
    # once settled, moves them by a few % through what it gates)


def test_a_controller_stream_gets_no_sandwich():
    """A 1 kHz controller stream is not spline-conditioned: no sandwich (as ``mle``), ``covariance_sandwich``
    null."""
    ds = simulate_dataset("panda", "random", units=2, noise="realistic", protocol="fast", seed=1)
    cal = OnlineCalibrator(ds.robot, ds.units, ds.gravity)
    replay(ds, cal)
    assert not cal.spline
    result = cal.result()
    assert result.units and all(u.extras["covariance_sandwich"] is None for u in result.units.values())


def test_a_cached_check_is_applied_to_the_current_solution(report14):
    """Between split checks (the live status reuses the last check while the data grow by < 10 % and the std move
    by < 20 %) what is reported is the current solution with the last check's factors (sandwich and split), not
    the last solution."""
    from dataclasses import replace

    _, cal, _ = report14
    st = cal.unit_state("su1")
    link = next(iter(st.solutions))
    sol = st.solutions[link]
    try:
        first = fit.reported(st, link, 0.0, True, True)  # made now, and cached
        assert first[1] is not None and max(first[1]) > 1.0  # this unit's std are raised by the sandwich
        st.solutions[link] = replace(sol, cov=sol.cov * 1.1)  # a new solution, std 5 % larger
        shown, factors, checked = fit.reported(st, link, fit.SPLIT_RECHECK, True, True)
        assert checked is first[2] and factors is first[1]  # the check reused...
        assert np.allclose(shown.cov, sol.cov * 1.1 * np.outer(factors, factors), rtol=1e-12)  # ...on the new one
        assert np.allclose(np.diag(shown.cov), 1.1 * np.diag(first[0].cov), rtol=1e-12)
    finally:
        st.solutions[link], st.split_cache = sol, None


def test_a_stream_too_short_for_the_sandwich_says_its_std_are_unchecked(report14):
    """A low-rate stream with fewer than three windows of motion has no sandwich: the unit's result says its std
    were not checked against the residuals (6 s of the session: the one unit calibrated by then); with enough
    windows (each its own block when the 3 s blocks are too few) the factors are there and nothing is said."""
    from skincal.workflows.monitoring import crop

    ds, _, _ = report14
    for length, expected in ((6.0, {"su1": False}), (12.0, dict.fromkeys(ds.units, True))):
        part = crop(ds, -np.inf, float(ds.joints.t[0]) + length)
        cal = OnlineCalibrator(part.robot, part.units, part.gravity)
        replay(part, cal)
        units = cal.result().units
        assert set(units) == set(expected), (length, list(units))
        for name, unit in units.items():
            said = any(w.startswith("std not checked against the residuals") for w in unit.warnings)
            assert said == (unit.extras["covariance_sandwich"] is None) == (not expected[name]), (length, name)
