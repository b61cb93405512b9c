"""The streaming calibrator's fit of one unit from its Grams: the residuals (:func:`residuals`), their
correlation inflation (:func:`window_means`, :func:`inflation`), each candidate link's pose solved with
per-class noise levels (:func:`solve_unit`), what a status and a result report of it (:func:`reported`: the
block sandwich of a low-rate joint stream, :func:`sandwich`, and the split check of its parts, :func:`solve_part`)
and the link decision (:func:`decide`, :func:`cost`)."""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from dataclasses import replace

import numpy as np
from scipy.stats import chi2

from skincal.calib import consistency
from skincal.calib.online import split, stats
from skincal.calib.online.clock import ALIGN_SHARPNESS
from skincal.calib.online.options import OnlineOptions
from skincal.calib.online.screen import accel_at_rail
from skincal.calib.online.unit import MOVING, REST, Grid, UnitState, Windows, signals_at, windowed_link
from skincal.calib.rest import link_moving
from skincal.calib.robust import CORRELATION_WARN, SANDWICH_BLOCK_S, huber_weights, robust_sigma, sandwich_factors
from skincal.calib.timing import CLOCK_DRIFT_MIN_SPAN_S, compose_clock
from skincal.data.imu_calibration import ImuCalibration
from skincal.kinematics.transforms import FloatArray

SCALE_STD_LIMIT = 0.01
"""The accelerometer's scale/misalignment counts as estimated when each of its 9 elements is determined to
this std; else the prior (:data:`~skincal.calib.online.stats.SCALE_PRIOR`) holds it near zero, its
uncertainty in the std, and a warning says so (as ``mle``)."""
JOINT_ACTIVE_RPS = 0.1
JOINT_ACTIVE_MIN_S = 1.0
"""A joint counts as moved once it has turned faster than ``JOINT_ACTIVE_RPS`` (rad/s) for
``JOINT_ACTIVE_MIN_S`` (s) in all; two candidate links are told apart only after a joint between them moved."""
LINK_CHI2_MARGIN = 25.0
"""Two links are told apart when their costs (chi-square, correlation-inflated) differ by this much...
"""
LINK_RELATIVE_MARGIN = 0.05
"""...and by this fraction of the best one's (the joint-derived model errors are not white noise: a
few % of cost between two links is not evidence). A decision is final: the other links' statistics are
then dropped, so it waits for clear evidence."""
SPLIT_RECHECK = 1.1
"""The live status's split check is made again once the unit's absorbed samples grew by this factor..."""
SPLIT_STD_CHANGE = 0.2
"""...or a component of its unchecked std changed by this fraction (the factors are relative to it)."""
MIN_SANDWICH_BLOCKS = 3
"""Blocks of moving samples the block sandwich needs (fewer: not applied)."""
CORRELATION_MAX = 100.0
"""Largest variance inflation applied for autocorrelated residuals."""
WINDOW_SAMPLES = 100
"""Samples per window of the correlation inflation (1 s at 100 Hz)."""
MIN_WINDOWS = 5
"""Windows before the inflation is applied whatever its value."""
EARLY_FALSE_ALARM = 1e-3
"""With fewer windows, the inflation is applied once white residuals would exceed it with at most this
probability (a chi-square with 3 degrees of freedom per window): clear evidence is not held back."""


DRIFT_UNDETERMINED_PPM = 100.0
"""A residual clock drift whose std exceeds this (ppm) is not determined yet: the result says so."""
DRIFT_NOTE_SIGMAS, DRIFT_NOTE_PPM = 4.0, 20.0
"""A drift beyond this many std and ppm is named in the result (``mle``'s rule)."""


def residuals(
    sol: stats.Solution,
    a: FloatArray,
    u: FloatArray,
    K: FloatArray,
    du: FloatArray,
    dK: FloatArray,
    ug: FloatArray,
    elapsed: FloatArray,
) -> FloatArray:
    """``(M, 3)`` residuals of equation (1) of :mod:`~skincal.calib.online.stats` at ``sol``, m/s^2
    (``elapsed`` ``(M,)`` = ``s - t_ref``, s)."""
    G = sol.R @ np.linalg.inv(sol.A)
    h = G @ sol.b
    T = (sol.tau + sol.drift * elapsed)[:, None]  # residual clock error per sample, s
    Kp = np.einsum("mij,j->mi", (1.0 + sol.gravity_scale) * K, sol.p) + T * np.einsum("mij,j->mi", dK, sol.p)
    return a @ G.T - h - Kp - du * T - sol.gravity_scale * (u - ug) - u


def window_means(w: Windows, rn: FloatArray) -> None:
    """Add normalised residuals ``rn`` ``(M, 3)`` to a link's windows ``w`` of :data:`WINDOW_SAMPLES`."""
    i = 0
    while i < rn.shape[0]:
        take = min(WINDOW_SAMPLES - w.n, rn.shape[0] - i)
        w.sum += rn[i : i + take].sum(axis=0)
        w.n += take
        i += take
        if w.n >= WINDOW_SAMPLES:
            w.stat += float(w.sum @ w.sum) / w.n
            w.count += 1
            w.sum, w.n = np.zeros(3), 0


def needs_rewindow(st: UnitState) -> bool:
    """Whether no link of the unit holds :data:`MIN_WINDOWS` residual windows yet (:func:`rewindow` may form them)."""
    return bool(st.raw) and all(w.count < MIN_WINDOWS for w in st.windows.values())


def rewindow(st: UnitState, grid: Grid, instants: Callable[[FloatArray], FloatArray]) -> bool:
    """At the data's end: the windows of a unit whose leading link has fewer than :data:`MIN_WINDOWS` of them
    (its clock aligned at the data's end only, as on a 12 s real recording, so nothing was windowed as it came;
    or its link never decided) formed again from its kept samples (``st.raw``, stamps mapped to the robot's
    clock by ``instants``) at the final solution, when they fill that many. Whether it did."""
    lead = windowed_link(st)
    if lead is None or not needs_rewindow(st) or sum(len(r[0]) for r in st.raw) < MIN_WINDOWS * WINDOW_SAMPLES:
        return False
    sol, sig, fresh = st.solutions[lead], st.sigmas[lead], Windows()
    for t, a, _, _ in st.raw:
        s = instants(t)
        keep = (s >= grid.t[0]) & (s <= grid.t[-1]) & ~accel_at_rail(st, a)
        if not keep.any():
            continue
        u, K, om, dom, du, dK, ug, ok = signals_at(grid, s[keep], [lead])
        moving = link_moving(om, dom)[0]
        r = residuals(sol, a[keep], u[0], K[0], du[0], dK[0], ug[0], s[keep] - st.t_ref)
        rn = r / np.maximum(np.where(moving, sig[1], sig[0]), 1e-9)[:, None]
        window_means(fresh, rn[ok])
    st.windows[lead] = fresh
    return True


def inflation(w: Windows | None) -> float:
    """Variance inflation for correlated residuals: the variance of the residuals' means over a link's windows
    ``w`` of :data:`WINDOW_SAMPLES` consecutive samples against white noise's (``n |mean|^2`` averages 3
    for white residuals of unit variance; None: no windows yet, 1). It covers every correlation shorter than a
    window, incl. the slow errors of joint-derived accelerations, which a lag-1 autocorrelation misses. From
    :data:`MIN_WINDOWS` windows on it is applied as it is; before, only when it is beyond what white
    residuals reach (:data:`EARLY_FALSE_ALARM`): a real recording whose residuals are strongly correlated
    shows an honest std from its first window, not an uninflated one that jumps at the data's end."""
    if w is None or w.count == 0:
        return 1.0
    dof = 3 * w.count
    ratio = w.stat / dof
    if w.count < MIN_WINDOWS and ratio < chi2.isf(EARLY_FALSE_ALARM, dof) / dof:
        return 1.0
    return float(np.clip(ratio, 1.0, CORRELATION_MAX))


def weighted(st: UnitState, k: int, sig: FloatArray) -> tuple[FloatArray, FloatArray | None]:
    """Candidate ``k``'s Grams with each class weighted by its noise level (so ``solve`` runs with 1, 1),
    corrected for the readings' own noise.

    The readings are regressors of ``G`` (``R``): their white noise adds ``n sigma^2`` to each
    diagonal element of the ``vec(G)`` block of a class's Gram (``sum a a^T = sum f f^T + n
    sigma^2 I``), which biases ``G`` toward zero along axes with little signal (errors in
    variables: a unit axis that never sees gravity at rest would read a scale several % too
    large). The rest class's residual std is the sensor noise (nothing else is left at rest), so
    ``n sigma_rest^2`` is removed from that block of both classes (bias-corrected least squares),
    once the unit's link is decided (a wrong candidate's rest residual is not the sensor's noise).
    """
    return weigh(st.Za[k], st.Zg[k], sig, st.decided, bool(st.has_gyro))


def weigh(Za2: FloatArray, Zg2: FloatArray, sig: FloatArray, decided: bool, gyro: bool
          ) -> tuple[FloatArray, FloatArray | None]:  # fmt: skip
    """:func:`weighted` of one link's Grams ``(..., 2, NA, NA)`` and ``(..., 2, NG, NG)`` (rest, moving classes;
    leading axes: e.g. windows)."""

    def corrected(Z: FloatArray, noise: float) -> FloatArray:
        Z = Z.copy()
        d = np.arange(9)  # Z[9, 9]: the class's samples
        Z[..., d, d] -= np.minimum(Z[..., 9, 9] * noise**2, 0.5 * np.min(Z[..., d, d], axis=-1))[..., None]
        return Z

    a_rest, a_moving, g_rest, g_moving = Za2[..., REST, :, :], Za2[..., MOVING, :, :], Zg2[..., REST, :, :], Zg2[
        ..., MOVING, :, :]  # fmt: skip
    if not decided:  # a wrong candidate's rest residual is not the sensor noise: no correction yet
        Za = a_rest / sig[0] ** 2 + a_moving / sig[1] ** 2
        Zg = g_rest / sig[2] ** 2 + g_moving / sig[3] ** 2 if gyro else None
        return Za, Zg
    Za = corrected(a_rest, sig[0]) / sig[0] ** 2 + corrected(a_moving, sig[0]) / sig[1] ** 2
    Zg = None
    if gyro:
        Zg = corrected(g_rest, sig[2]) / sig[2] ** 2 + corrected(g_moving, sig[2]) / sig[3] ** 2
    return Za, Zg


GATE_SIGMAS = 6.0
"""Once a unit is settled, samples whose residual norm exceeds this many class std per axis (times sqrt 3) are
not absorbed."""
HUBER = True
"""Once a unit is settled, each absorbed sample's accelerometer rows are weighted by ``mle``'s Huber weight of its
residual."""
ROBUST_SCALE_MIN = 200
"""Recent residual norms of a settled unit needed before their robust scale weights the samples."""
ROBUST_SCALE_FLOOR = 0.1
"""Smallest robust scale, in class std (a run of exact fits must not give NaN weights)."""


def robust_weights(rn: FloatArray, settled: bool, recent: deque) -> tuple[np.ndarray, FloatArray | None]:
    """Which of the samples with residuals ``rn`` ``(M, 3)`` (in class std, at the lead link's estimate) are
    absorbed, and the Huber weights ``w`` of those (None: all 1) that scale their accelerometer rows by
    ``sqrt(w)`` (the gyroscope's rows are not weighted).

    A settled unit's samples beyond :data:`GATE_SIGMAS` are dropped and the kept weighted by
    :func:`~skincal.calib.robust.huber_weights` ``w = min(1, k c / |rn|)`` (``k`` = 3), ``c`` the robust scale
    of the settled unit's recent residual norms ``recent`` (:func:`~skincal.calib.robust.robust_sigma`, at
    least :data:`ROBUST_SCALE_FLOOR`; the norms of ``rn`` join it): the robust loss ``mle``'s Gauss-Newton
    iterates with, on a scale heavy tails do not inflate as they inflate the class std. An accelerometer Gram's
    ``Z[9, 9]`` then sums the weights, the weighted sample count its noise terms need. Before a unit settles
    every sample counts in full, and samples absorbed again before the unit has a new estimate (a clock
    re-alignment's) count in full too: applied from the link decision on, the weights moved the REAL
    recordings' tool-axis spread from 48 to 53 mm (MPU6050). SIMULATED, UR5e ``fast``, ``wifi`` clocks, seeds
    0-9: the stream's mean position error went from 1.15 to 0.94 times ``mle``'s
    (``benchmarks/bench_streaming_clock.py --robots ur5e --protocols fast``)."""
    if not settled:
        return np.ones(len(rn), bool), None
    norm = np.linalg.norm(rn, axis=1)
    recent.extend(norm.tolist())
    keep = norm <= GATE_SIGMAS * np.sqrt(3.0)
    if not HUBER or len(recent) < ROBUST_SCALE_MIN:
        return keep, None
    scale = max(robust_sigma(np.fromiter(recent, float, len(recent))), ROBUST_SCALE_FLOOR)
    return keep, huber_weights(norm[keep], scale)


def class_sigmas(st: UnitState, k: int, sol: stats.Solution, prior: FloatArray) -> FloatArray:
    """Residual std per class ``[accel rest, accel moving, gyro rest, gyro moving]`` at ``sol``
    (a class with too few samples keeps ``prior``'s value)."""
    out = prior.copy()
    for c in (REST, MOVING):
        n = st.Za[k, c, 9, 9]
        if n >= 20:
            out[c] = max(
                np.sqrt(
                    stats.residual_sum(st.Za[k, c], sol.x_a)
                    / max(3 * n - 16.0 * n / max(st.Za[k, :, 9, 9].sum(), 1), 1.0)
                ),
                1e-5,
            )
        ng = st.Zg[k, c, 9, 9]
        if st.has_gyro and ng >= 20:
            out[2 + c] = max(
                np.sqrt(
                    stats.residual_sum(st.Zg[k, c], sol.x_g)
                    / max(3 * ng - 13.0 * ng / max(st.Zg[k, :, 9, 9].sum(), 1), 1.0)
                ),
                1e-6,
            )
    return out


def solve_unit(st: UnitState, o: OnlineOptions) -> None:
    """Solve every candidate link. Undecided, all candidates are weighted with the same noise
    levels (those the best candidate fitted last time): a wrong link must not set its own weights,
    or it could shrink one class's noise level until it fits that class alone. Decided, the one
    link's fit sets its own levels."""
    if not st.dirty:
        return
    default = np.array([o.accel_sigma, o.accel_sigma, o.gyro_sigma, o.gyro_sigma])
    common = st.sigmas.get(0, default)
    # like mle: a drift only from a stream long enough to tell it from the offset and the model's errors
    drift = stats.DRIFT_PRIOR if st.t_last - st.t_first >= CLOCK_DRIFT_MIN_SPAN_S else stats.DRIFT_SHORT_PRIOR
    clock = {"drift_prior": drift, "drift_total": st.drift}
    sols: dict[int, stats.Solution] = {}
    for k, link in enumerate(st.links):
        if st.Za[k, :, 9, 9].sum() < 10:
            continue
        prev = st.solutions.get(link)
        sig = st.sigmas.get(link, common) if st.decided else common
        Za, Zg = weighted(st, k, sig)
        sol = stats.solve(Za, Zg, 1.0, 1.0, R0=None if prev is None else prev.R, **clock)
        if sol is None:
            continue
        if st.decided:
            for _ in range(1 if prev is not None else 2):  # re-weight with the fit's own noise levels
                sig = class_sigmas(st, k, sol, sig)
                Za, Zg = weighted(st, k, sig)
                sol = stats.solve(Za, Zg, 1.0, 1.0, R0=sol.R, **clock) or sol
            # as mle: the scale/misalignment always fitted under its prior; where the data leave it weakly
            # determined (scale_std), the prior holds it near zero and its uncertainty stays in the std (fixing
            # it dropped that: a real 150 mm/s linear move's rotation came out 0.2 deg std, 2.3 deg off)
        st.sigmas[link] = sig if st.decided else class_sigmas(st, k, sol, common)
        sols[link] = sol
    st.solutions = sols
    if sols and not st.decided:
        best = min(sols, key=lambda link: cost(st, link, common))
        st.sigmas[0] = st.sigmas[best]  # the weights of the next solve of every candidate
    st.dirty = False


def solve_part(st: UnitState, link: int, Za2: FloatArray, Zg2: FloatArray, span_s: float) -> stats.Solution | None:
    """A part of decided ``link``'s data (Grams ``(2, NA, NA)``, ``(2, NG, NG)`` spanning ``span_s`` s) solved
    as :func:`solve_unit` solves the whole: the stream's noise levels, its scale/misalignment choice, the
    drift prior of the part's span (:mod:`skincal.calib.online.split`)."""
    if Za2[:, 9, 9].sum() < 10:
        return None
    Za, Zg = weigh(Za2, Zg2, st.sigmas[link], st.decided, bool(st.has_gyro))
    drift = stats.DRIFT_PRIOR if span_s >= CLOCK_DRIFT_MIN_SPAN_S else stats.DRIFT_SHORT_PRIOR
    whole = st.solutions[link]  # the start: a part's solution is a few std from the whole's
    return stats.solve(Za, Zg, 1.0, 1.0, R0=whole.R, x0=whole.state, hold=True,
                       drift_prior=drift, drift_total=st.drift)  # fmt: skip


def sandwich(st: UnitState, link: int, sol: stats.Solution, kappa: float, windows: np.ndarray | None = None
             ) -> tuple[stats.Solution, FloatArray | None]:  # fmt: skip
    """``sol`` (``link``'s fit of the ledger's ``windows``, all by default) with its covariance raised to the
    block sandwich's where the residuals follow the motion, as ``mle`` raises its own for a low-rate joint
    stream (:func:`skincal.calib.robust.sandwich_factors`), and the ``(NP,)`` factors (None: too few blocks).

    A window's score is ``g = J_a^T (Z_a x_a - z_a) + J_g^T (Z_g x_g - z_g)`` of its weighted Grams (the
    Gauss-Newton Jacobians :func:`~skincal.calib.online.stats.linearise` at ``sol``): the sum of its
    samples' ``J_i^T W_i r_i``, so a block's score is the sum of its windows'. Moving samples are summed
    over blocks of windows at least :data:`~skincal.calib.robust.SANDWICH_BLOCK_S` long, each window's rest
    samples are a block of their own (``mle``: each rest row its own), each window a block when that makes fewer
    than :data:`MIN_SANDWICH_BLOCKS`; the model covariance compared is ``cov kappa`` (the correlation
    inflation)."""
    if st.ledger.Za is None:
        return sol, None
    (rest, _), (moving_scores, moving_w) = window_scores(st, link, sol, windows)
    group = max(int(np.ceil(SANDWICH_BLOCK_S / st.ledger.width - 1e-9)), 1)
    blocks, at = np.unique(moving_w // group, return_inverse=True)  # each moving window's block
    if blocks.size < MIN_SANDWICH_BLOCKS:  # a short stream: its windows as blocks (shorter, but some check)
        blocks, at = np.unique(moving_w, return_inverse=True)
    if blocks.size < MIN_SANDWICH_BLOCKS:
        return sol, None
    moving = np.zeros((blocks.size, stats.NP))
    np.add.at(moving, at, moving_scores)
    factors = sandwich_factors(sol.cov * kappa, sol.cov, np.concatenate([rest, moving]), blocks.size)
    return with_factors(sol, factors), factors


def scale_std(sol: stats.Solution) -> float:
    """The largest std of the accelerometer's scale/misalignment elements at ``sol`` (estimated where it is at
    most :data:`SCALE_STD_LIMIT`)."""
    return float(np.sqrt(np.clip(np.diag(sol.cov)[3:12], 0.0, None)).max())


def unit_warnings(st: UnitState, unchecked: bool, sol: stats.Solution | None = None, kappa: float = 1.0) -> list[str]:
    """The warnings of a unit's result at ``sol``: a time offset without motion to align on; a weakly determined
    scale/misalignment; an accelerometer axis stuck or at its rail (those samples left out) and a gyroscope at
    its rail (those readings left out), as ``mle``'s screening warns; ``unchecked``: a
    low-rate joint stream whose block sandwich could not be formed (fewer than :data:`MIN_SANDWICH_BLOCKS`
    windows of motion), so its std were never held against what the residuals show; ``kappa``, the correlation
    inflation applied, beyond :data:`~skincal.calib.robust.CORRELATION_WARN` (as ``mle`` warns; at its cap
    :data:`CORRELATION_MAX` the std may still be too small)."""
    out = []
    if np.isfinite(st.offset_sharpness) and st.offset_sharpness < ALIGN_SHARPNESS:
        out.append("time offset uncertain (no motion to align the unit's clock on)")
    worst = 0.0 if sol is None else scale_std(sol)
    if worst > SCALE_STD_LIMIT:  # as mle warns
        prior = 100 * stats.SCALE_PRIOR
        out.append(f"scale/misalignment weakly determined by the data (std up to {100 * worst:.1f} %, held near "
                   f"zero by a {prior:.0f} % prior; its uncertainty is in the reported std)")  # fmt: skip
    out += st.stuck.warnings()  # as mle's screening warns
    if st.saturated:
        out.append(f"accelerometer at its rail in {st.saturated} samples; those samples are ignored")
    if st.gyro_saturated:  # as mle's screening warns
        out.append(f"gyroscope at its rail in {st.gyro_saturated} samples; those gyroscope readings are ignored "
                   "(the accelerometer's are kept)")  # fmt: skip
    if kappa > CORRELATION_WARN:
        capped = kappa >= CORRELATION_MAX
        cap = f", at its cap of {CORRELATION_MAX:.0f}: the std may still be too small" if capped else ""
        out.append(f"residuals strongly correlated in time (factor {kappa:.1f}{cap}: unmodelled dynamics or "
                   "joint-state errors); uncertainty inflated by it")  # fmt: skip
    if unchecked:
        out.append(f"std not checked against the residuals (a low-rate joint stream with fewer than "
                   f"{MIN_SANDWICH_BLOCKS} windows of motion): they may be too small")  # fmt: skip
    return out


def unit_notes(st: UnitState, drift: float, drift_std_ppm: float) -> list[str]:
    """The notes of a unit's result: its clock drift, undetermined or estimated (``drift`` s/s, its std in
    ppm)."""
    out = []
    if drift_std_ppm > DRIFT_UNDETERMINED_PPM:
        out.append(f"clock drift not determined yet (std {drift_std_ppm:.0f} ppm over {st.t_last - st.t_first:.0f} s"
                   " of data): the time offset holds near the data's start")  # fmt: skip
    elif abs(drift) * 1e6 > max(DRIFT_NOTE_SIGMAS * drift_std_ppm, DRIFT_NOTE_PPM):
        out.append(f"clock drifts: {drift * 1e6:+.0f} ppm relative to the robot's clock (estimated and corrected)")
    return out


def with_factors(sol: stats.Solution, factors: FloatArray | None) -> stats.Solution:
    """``sol`` with each unknown's std multiplied by ``factors`` ``(NP,)`` (None or all 1: ``sol`` itself)."""
    if factors is None or np.all(factors == 1.0):
        return sol
    return replace(sol, cov=sol.cov * np.outer(factors, factors))


def window_scores(st: UnitState, link: int, sol: stats.Solution, windows: np.ndarray | None = None
                  ) -> tuple[tuple[FloatArray, np.ndarray], tuple[FloatArray, np.ndarray]]:  # fmt: skip
    """Per class (rest, then moving) the scores ``(B, NP)`` of the ledger's ``windows`` (all by default) that
    hold samples of that class, at ``sol`` of ``link``, and those windows' indices ``(B,)``: a window's score is
    ``J_a^T (Z_a x_a - z_a) + J_g^T (Z_g x_g - z_g)`` of its class's weighted Grams (:func:`weigh`), half the
    gradient of its part of ``C`` (:mod:`~skincal.calib.online.stats`) in the Gauss-Newton unknowns."""
    ledger = st.ledger
    assert ledger.Za is not None and ledger.Zg is not None and ledger.n is not None
    k = st.links.index(link)
    use = np.flatnonzero((ledger.n > 0) if windows is None else (ledger.n > 0) & windows)
    _, Ja, _, Jg = stats.linearise(sol.R, sol.state)
    na, ng = stats.NA - 1, stats.NG - 1
    out = []
    for c in (REST, MOVING):  # each class weighted alone: (W, NA, NA), (W, NG, NG)
        one_a, one_g = np.zeros((use.size, 2, stats.NA, stats.NA)), np.zeros((use.size, 2, stats.NG, stats.NG))
        one_a[:, c], one_g[:, c] = ledger.Za[use, k, c], ledger.Zg[use, k, c]
        Za, Zg = weigh(one_a, one_g, st.sigmas[link], st.decided, bool(st.has_gyro))
        g = (Za[:, :na, :na] @ sol.x_a - Za[:, :na, na]) @ Ja
        if Zg is not None:
            g = g + (Zg[:, :ng, :ng] @ sol.x_g - Zg[:, :ng, ng]) @ Jg
        held = ledger.Za[use, k, c, 9, 9] > 0
        out.append((g[held], use[held]))
    return out[0], out[1]


def reported(st: UnitState, link: int, grow: float = 0.0, spline: bool = False, consistency_check: bool = True
             ) -> tuple[stats.Solution, FloatArray | None, consistency.Consistency | None]:  # fmt: skip
    """What a status and a result report of ``link``'s estimate: its solution with the covariance the std are
    read from (:func:`sandwich`'d for a joint stream conditioned by ``spline`` s, as ``mle``), the sandwich's
    factors (None: not applied) and the split check of that solution (:func:`skincal.calib.online.split.check`;
    None: no data or ``consistency_check`` off). ``grow``: the last answer is reused for the same link while
    the unit's absorbed samples grew by less than this factor and its unchecked std moved by less than
    :data:`SPLIT_STD_CHANGE` since, its factors applied to the current solution (the live status asks every
    second, with :data:`SPLIT_RECHECK`: six part solves per unit each time would cost a hundred units a second
    of CPU); 1: only for the same samples and solution (a result right after a status); 0: never. A restart of
    the unit's statistics (clock re-alignment, link decision, moved unit) clears it."""
    n = float(st.ledger.n.sum()) if st.ledger.n is not None else 0.0
    sol = st.solutions[link]
    kappa = inflation(st.windows.get(link))
    full = np.sqrt(np.clip(np.r_[np.diag(sol.pose_covariance()), sol.cov[stats.TAU, stats.TAU]] * kappa, 0.0, None))
    key = (link, spline, consistency_check)
    if grow and st.split_cache is not None:
        key0, n0, sol0, full0, answer = st.split_cache
        same = key0 == key and (n == n0 and sol is sol0)
        with np.errstate(divide="ignore", invalid="ignore"):
            steady = bool(np.all(np.abs(full / full0 - 1.0) < SPLIT_STD_CHANGE))  # NaN (a zero std): not steady
        close = key0 == key and n0 <= n < grow * n0 and steady
        if same:
            return answer
        if grow > 1.0 and close:  # the factors of the last answer, applied to the current solution
            factors, checked = answer[1], answer[2]
            return (with_factors(sol, factors), factors, checked)
    shown, factors = sandwich(st, link, sol, kappa) if spline else (sol, None)
    checked = None
    if consistency_check:
        shown_std = np.sqrt(np.clip(np.r_[np.diag(shown.pose_covariance()), shown.cov[stats.TAU, stats.TAU]] * kappa,
                                    0.0, None))  # fmt: skip

        def solve(Za2: FloatArray, Zg2: FloatArray, span: float, windows: np.ndarray) -> stats.Solution | None:
            part = solve_part(st, link, Za2, Zg2, span)
            return part if part is None or not spline else sandwich(st, link, part, kappa, windows)[0]

        checked = split.check(st.ledger, st.links.index(link), shown_std, sol.R, solve, kappa)
    answer = (shown, factors, checked)
    st.split_cache = (key, n, sol, full, answer)
    return answer


def decide(st: UnitState, joint_active_s: FloatArray) -> tuple[int | None, float, list[int]]:
    """Best link, its margin and the links still ambiguous with it (``joint_active_s`` ``(n,)``: how long each
    joint has moved, s)."""
    if not st.solutions:
        return None, float("nan"), []
    if len(st.solutions) == 1:
        (link,) = st.solutions
        return link, float("inf"), [link]
    # every candidate on one chi-square scale: the noise levels they were all weighted with
    ref = st.sigmas.get(0, np.min(np.stack([st.sigmas[k] for k in st.solutions]), axis=0))
    costs = {k: cost(st, k, ref) for k in st.solutions}
    best_link = min(costs, key=costs.__getitem__)
    c0 = costs[best_link]
    kappa = inflation(st.windows.get(best_link)) if st.decided else 1.0  # undecided: chi-square margins as fitted
    others = sorted(v for k, v in costs.items() if k != best_link)
    margin = others[0] / c0 if c0 > 0 else float("inf")
    ambiguous = [k for k, v in costs.items() if v - c0 < max(LINK_CHI2_MARGIN * kappa, LINK_RELATIVE_MARGIN * c0)]
    # links joined by joints that have not moved yet are one rigid body: their costs differ only by the
    # noise of those joints' derived accelerations, which is no evidence
    active = joint_active_s >= JOINT_ACTIVE_MIN_S
    for k in costs:
        lo, hi = min(k, best_link), max(k, best_link)
        if k not in ambiguous and not active[lo:hi].any():  # joints lo+1..hi (0-based lo..hi-1)
            ambiguous.append(k)
    ambiguous.sort()
    return best_link, float(margin), sorted(ambiguous)


def cost(st: UnitState, link: int, sig: FloatArray) -> float:
    """Chi-square of ``link``'s fit with the noise levels ``sig`` (:func:`class_sigmas` order)."""
    sol = st.solutions[link]
    k = st.links.index(link)
    cost = sum(stats.residual_sum(st.Za[k, c], sol.x_a) / sig[c] ** 2 for c in (REST, MOVING))
    if st.has_gyro:
        cost += sum(stats.residual_sum(st.Zg[k, c], sol.x_g) / sig[2 + c] ** 2 for c in (REST, MOVING))
    return float(cost)


def imu_calibration(st: UnitState, sol: stats.Solution, kappa: float, gravity: FloatArray
                    ) -> tuple[ImuCalibration, float, float]:  # fmt: skip
    """The unit's IMU errors and clock at ``sol`` (std inflated by ``kappa``; ``gravity`` the dataset's, base
    frame, m/s^2), with the composed mapping's drift (dimensionless) and the drift's std, ppm."""
    idx_b = slice(12, 15)
    G = sol.R @ np.linalg.inv(sol.A)
    Ginv = np.linalg.inv(G)
    cov_b = Ginv @ sol.cov[idx_b, idx_b] @ Ginv.T * kappa
    # the clock: the mapping composed with the residual (stats: the samples saw s + tau + d (s - t_ref))
    offset, drift = compose_clock(st.offset or 0.0, st.drift, sol.tau, sol.drift)
    drift_std_ppm = 1e6 * float(np.sqrt(max(sol.cov[stats.DRIFT, stats.DRIFT] * kappa, 0.0)))
    imu = ImuCalibration(
        accel_bias_mps2=sol.b,
        accel_bias_std_mps2=np.sqrt(np.clip(np.diag(cov_b), 0, None)),
        accel_scale_misalignment=sol.A,
        time_offset_s=offset,
        time_offset_std_s=float(np.sqrt(max(sol.cov[stats.TAU, stats.TAU] * kappa, 0.0))),
        time_reference_s=st.t_ref,
        clock_drift_ppm=1e6 * drift + (st.steps.drift_ppm if st.steps is not None else 0.0),
        clock_drift_std_ppm=drift_std_ppm,
        clock_resync_steps=None if st.steps is None else st.steps.n_steps,
        clock_resync_period_s=None if st.steps is None else st.steps.period_s,
        clock_resync_step_s=None if st.steps is None else st.steps.mean_step_s,
        gyro_bias_rps=sol.gyro_bias if st.has_gyro else None,
        gravity_mps2=float(np.linalg.norm(gravity) / (1.0 + sol.gravity_scale)),
        gravity_std_mps2=float(np.linalg.norm(gravity) * np.sqrt(max(sol.cov[22, 22] * kappa, 0.0))),
    )
    return imu, drift, drift_std_ppm
