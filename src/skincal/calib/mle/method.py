"""The default calibrator ``mle``: global time alignment, closed-form start, robust joint maximum
likelihood, and residual tests that keep the reported uncertainty honest.

Per unit:

0. **Time** (before anything else, in :func:`align`): the IMU stream's offset to the joint stream
   is found globally by cross-correlation (:mod:`skincal.calib.timing`), up to +-0.5 s.
1. **Rest** (:mod:`skincal.calib.rest`): from ``/segments`` when the dataset has them, else from
   the joint positions over windows with noise-derived thresholds; every rest run cross-checked
   against the unit's own IMU (runs in which it moved are dropped and named).
2. **Link** (unless given): the activity matrix (accelerometer and gyroscope) proposes link
   ``n*``; unless that is decisive, the links ``1 .. n* + 1`` are each fitted quickly and the one
   whose model explains every sample best wins. Two links that explain the data about equally
   are reported as ambiguous, never silently chosen.
3. **Start** (no bounds, no seed): rotation and bias from the rest runs (Wahba's problem) or, with
   fewer than two, from the angular velocities; position and bias by linear least squares.
4. **Refinement** (:mod:`skincal.calib.mle.solver`): pose, accelerometer bias, scale/misalignment,
   gyroscope bias, time offset and clock drift, and a bias drift when the rest runs span the
   session, by robust Gauss-Newton over every sample of both sensors.
5. **Uncertainty**: covariance from the normal matrix with each sensor's robust residual variance
   and autocorrelation, inflated by the rest runs' disagreement with the model; directions the
   data cannot determine are reported (``observable: false``, ``null`` std) and left at the start.
   Warnings name what the model had to absorb ("bias drifts", "clock drifts", "time offset
   uncertain", "static segment moved", "rest poses disagree").
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from skincal.calib.api import UnitProblem
from skincal.calib.gyro import GyroScale, gyro_scale
from skincal.calib.mle.account import NULL_SHARE, describe_account, describe_null, pose_null_basis, sample_account
from skincal.calib.mle.discovery import choose_link, gyro_rates
from skincal.calib.mle.move import find_move
from skincal.calib.mle.problem import (
    Alignment,
    Problem,
    Shared,
    arrange,
    decimated,
    fit_problem,
    gyro_bias_start,
    use_gyro,
)
from skincal.calib.mle.solver import (
    SCALE_FULL,
    SCALE_NONE,
    SCALE_SYM,
    Blocks,
    Fit,
    Rows,
)
from skincal.calib.model import sym_from_e
from skincal.calib.preprocess import check_gyro_units
from skincal.calib.robust import CORRELATION_WARN
from skincal.calib.timing import (
    CLOCK_DRIFT_MIN_SPAN_S,
    OffsetSearch,
    widened_note,
)
from skincal.data.imu_calibration import ImuCalibration
from skincal.data.result import UnitResult
from skincal.kinematics.chain import SerialChain
from skincal.kinematics.transforms import FloatArray
from skincal.skin.pose import SkinUnitPose

SCALE_STD_LIMIT = 0.01
"""Scale/misalignment is kept only when each of its components is determined to this std."""


BIAS_DRIFT_MIN_RUNS = 6
"""The accelerometer bias drift is estimated with at least this many rest runs..."""


BIAS_DRIFT_MIN_SPAN_S = 60.0
"""...spanning at least this long, s."""


DRIFT_WARN_SIGMAS = 4.0
"""A drift (clock or bias) is reported when it exceeds this many of its standard deviations..."""


CLOCK_DRIFT_WARN_PPM = 20.0
"""...and this many ppm (clock)..."""


BIAS_DRIFT_WARN_MPS2 = 0.01
"""...or this change over the session, m/s^2 (bias)."""


STATIC_CHI2_WARN = 4.0
"""Rest runs whose residuals exceed the rest noise by this factor in variance are flagged."""


REST_NOISE_FLOOR = 1e-4
"""Smallest rest noise the rest-pose test assumes, m/s^2 (10 µg, below any real IMU's: noise-free
simulated data must not count as inconsistent)."""


OFFSET_SHARPNESS_MIN = 0.02
"""Coarse-alignment peaks less distinct than this (correlation units) leave the offset uncertain."""


OFFSET_JUMP_WARN_S = 0.05
"""A refined offset further than this from the coarse one is flagged as uncertain, s."""


SANDWICH_WARN = 2.0
"""A block-sandwich factor on the position std above this is reported (``solver.sandwich_inflation``)."""


@dataclass(frozen=True)
class MleOptions:
    """Options of ``mle`` (``calibrate(ds, "mle", scale=False)``, ``skincal calibrate --option
    scale=false``); each turns one block of the model off (all on by default).

    Attributes:
        scale: estimate the accelerometer's scale/misalignment matrix (symmetric without a
            gyroscope, full with one).
        time_offset: estimate the IMU's time offset to the joint stream (and, with ``clock_drift``,
            its drift); off: the stamps are taken as they are.
        clock_drift: estimate a clock drift when the moving data span long enough.
        bias_drift: estimate a linear accelerometer bias drift when rest runs span the session.
        gravity: estimate the gravity scale (needs ``scale``).
        gyro: use the gyroscope when the unit has one.
        detect_move: look for a unit that moved on its link during the session.
        consistency: calibrate independent parts of the recording too and inflate the std where they
            disagree beyond it (:mod:`skincal.calib.consistency`).
        joint_rate: on a low-rate joint stream, calibrate with every second and third report too and
            add the error the report spacing leaves in the pose to its std (:mod:`skincal.calib.joint_rate`).
    """

    scale: bool = True
    time_offset: bool = True
    clock_drift: bool = True
    bias_drift: bool = True
    gravity: bool = True
    gyro: bool = True
    detect_move: bool = True
    consistency: bool = True
    joint_rate: bool = True


GYRO_MOVING_RPS = 0.1
"""Samples whose link turns faster than this (rad/s) check the gyroscope's scale."""


def _gyro_scale(problem: UnitProblem, link: int) -> GyroScale | None:
    """:func:`~skincal.calib.gyro.gyro_scale` of the unit's moving samples on ``link`` (the link's rate from
    the signal table at the samples' aligned instants); None without enough motion about three axes."""
    s = problem.samples
    shared: Shared = problem.shared
    table = shared.table
    assert s.gyro is not None
    inside = (s.t >= table.t[0]) & (s.t <= table.t[-1]) & shared.interpolator.reliable(s.t)
    inside &= np.all(np.isfinite(s.gyro), axis=1)  # a reading at the gyroscope's rail is NaN
    if inside.sum() < 12:
        return None
    w = table.omega_at(link, s.t[inside])
    moving = np.linalg.norm(w, axis=1) > GYRO_MOVING_RPS
    if moving.sum() < 12:
        return None
    return gyro_scale(w[moving], s.gyro[inside][moving])


def _joint_axis_in_link(chain: SerialChain, link: int) -> FloatArray:
    """Unit direction of joint ``link``'s axis in link frame ``link`` (constant): the joint axis
    ``T_joint_link^-1`` maps into the link frame (it is fixed on both sides of the joint)."""
    return chain.T_joint_link[link - 1, :3, :3].T @ chain.axis[link - 1]


def _distinct_orientations(u_link: FloatArray, min_angle_deg: float = 5.0) -> int:
    """Number of static gravity directions (link frame) at least ``min_angle_deg`` apart."""
    if len(u_link) == 0:
        return 0
    dirs = u_link / np.linalg.norm(u_link, axis=1, keepdims=True)
    chosen: list[FloatArray] = []
    for d in dirs:
        if all(np.degrees(np.arccos(np.clip(d @ c, -1, 1))) >= min_angle_deg for c in chosen):
            chosen.append(d)
    return len(chosen)


def fit_blocks(problem: UnitProblem, p: Problem) -> Blocks:
    """The parameter blocks ``mle`` fits for this unit on its link: the scale/misalignment form (full with a
    gyroscope, symmetric without, none when off), gravity's scale with >= 10 moving rows, the clock offset,
    its drift over at least ``CLOCK_DRIFT_MIN_SPAN_S`` of motion, the gyroscope bias, and the bias drift over
    enough rest runs and span; the same choice the solver and the report's residuals use."""
    opts: MleOptions = problem.options
    rows = p.data.rows
    gyro = rows.static_g is not None
    scale = (SCALE_FULL if gyro else SCALE_SYM) if opts.scale else SCALE_NONE
    time_offset = opts.time_offset
    span = float(np.ptp(rows.moving_t)) if len(rows.moving_t) else 0.0
    static_span = float(np.ptp(rows.static_t)) if len(rows.static_t) else 0.0
    return Blocks(
        scale=scale,
        gravity=scale != SCALE_NONE and opts.gravity and len(rows.moving_t) >= 10,
        time_offset=time_offset,
        clock_drift=time_offset and opts.clock_drift and span >= CLOCK_DRIFT_MIN_SPAN_S,
        gyro=gyro,
        bias_drift=opts.bias_drift
        and len(rows.static_t) >= BIAS_DRIFT_MIN_RUNS
        and static_span >= BIAS_DRIFT_MIN_SPAN_S,
    )


def _static_chi2(fit: Fit, rows: Rows, rest_noise: float, angle_noise: float = 0.0) -> float:
    """Variance ratio of the rest rows' residuals to what the noise explains (1 when consistent).

    A rest run of ``n`` samples with white noise ``sigma_r`` has a mean residual of variance ``sigma_r^2
    / n`` per axis (``rest_noise`` carries the noise's autocorrelation factor when it is not white), plus
    ``(|u| sigma_q)^2`` from the joint angles' own error ``sigma_q`` (rad; an encoder's rounding tilts
    the predicted gravity); the ratio over all runs, ``sum |r|^2 / (3 var (S - k))``, exceeds 1 when the
    runs disagree with the model (bias drift, a moved unit, wrong gravity).
    """
    S = len(rows.static_u)
    if fit.residuals is None or S < 4:
        return 1.0
    rest_noise = max(rest_noise, REST_NOISE_FLOOR)
    r = fit.residuals[:S]
    var = rest_noise**2 / rows.static_weight + (np.linalg.norm(rows.static_u, axis=1) * angle_noise) ** 2
    dof = max(3 * S - 9, 1)
    return float(np.sum(np.sum(r * r, axis=1) / var) / dof)


def _honesty(
    fit: Fit, p: Problem, alignment: OffsetSearch | None, total_offset: float, angle_noise: float = 0.0
) -> tuple[FloatArray, list[str], list[str]]:
    """Residual tests: the covariance inflated where the model leaves something out, warnings (the
    estimate may be off: the reported std accounts for it) and notes (found and corrected, e.g. a
    drifting clock) (``angle_noise``: error of the rest poses' joint angles along the chain, rad)."""
    rows = p.data.rows
    sl = fit.blocks.slices()
    cov = fit.covariance
    std = np.sqrt(np.maximum(np.diag(cov), 0.0))
    st = fit.state
    warnings: list[str] = []
    notes: list[str] = []
    # The rest means vary as the IMU's noise at rest is correlated (measured inside the rest runs: the
    # moving residuals' correlation also carries model error, which the robot at rest does not have).
    chi2 = _static_chi2(fit, rows, p.data.rest.accel_noise * np.sqrt(p.data.rest.accel_correlation), angle_noise)
    if chi2 > STATIC_CHI2_WARN:
        cov = cov * chi2
        warnings.append(
            f"rest poses disagree with the model ({np.sqrt(chi2):.1f}x the rest noise; bias drift, gravity or "
            "a moved unit?): uncertainty inflated accordingly"
        )
    if "d" in sl:
        d, sd = st.d, std[sl["d"].start]
        if abs(d) > DRIFT_WARN_SIGMAS * sd and abs(d) * 1e6 > CLOCK_DRIFT_WARN_PPM:
            notes.append(f"clock drifts: {d * 1e6:+.0f} ppm relative to the robot's clock (estimated and corrected)")
    if "c" in sl:
        T = float(np.ptp(rows.static_t))
        change = np.linalg.norm(st.c) * T
        sc = np.linalg.norm(std[sl["c"]]) * T
        if change > DRIFT_WARN_SIGMAS * sc and change > BIAS_DRIFT_WARN_MPS2:
            warnings.append(
                f"bias drifts: the accelerometer bias changed by {change:.3g} m/s^2 over {T:.0f} s "
                "(estimated as a linear drift)"
            )
    if alignment is not None and alignment.widened:
        notes.append(widened_note(alignment.offset_s))
    if alignment is not None and (
        alignment.sharpness < OFFSET_SHARPNESS_MIN or abs(total_offset - alignment.offset_s) > OFFSET_JUMP_WARN_S
    ):
        warnings.append(
            f"time offset uncertain: coarse alignment {alignment.offset_s * 1e3:.0f} ms (peak sharpness "
            f"{alignment.sharpness:.2f}), refined {total_offset * 1e3:.0f} ms"
        )
    if fit.sandwich is not None and float(fit.sandwich[3:6].max()) > SANDWICH_WARN:
        warnings.append(
            f"residual errors follow the motion beyond the noise model (a low-rate joint stream's interpolation, "
            f"an unmodelled effect): position std raised up to x{float(fit.sandwich[3:6].max()):.1f} to what the "
            "residuals show"
        )
    if fit.residual_correlation > CORRELATION_WARN:
        warnings.append(
            f"residuals strongly correlated in time (factor {fit.residual_correlation:.1f}: unmodelled dynamics "
            "or joint-state errors); uncertainty inflated by it"
        )
    return cov, warnings, notes


def run_unit(problem: UnitProblem) -> UnitResult:
    """Calibrate one unit with the default method (module docstring)."""
    warnings: list[str] = []
    extras: dict = {}
    start, confidence = None, None
    early_notes: list[str] = []
    account = problem.samples.account
    if account is not None:  # the gyroscope's screening (the accelerometer's reaches the result elsewhere)
        warnings += [w for w in account.warnings if not w.startswith("accelerometer ")]
    # once: link discovery and the unit check below share them; a part of the consistency check (no
    # diagnostics, its link given) skips the unit check: the whole stream's run made it
    rates = gyro_rates(problem) if problem.link == 0 or problem.diagnostics else None
    if problem.link == 0:
        link, confidence, link_warnings, levels, start, by_gyro = choose_link(problem, rates)
        warnings += link_warnings
        extras["link_residual_mps2"] = {str(k): v for k, v in levels.items()}
        ruled_out = None if by_gyro is None else by_gyro.note()
        if ruled_out:
            early_notes.append(ruled_out)
    else:
        link = problem.link
    if rates is not None:
        warnings += check_gyro_units(problem.samples.unit, rates[0], rates[1][:, link - 1])
    if use_gyro(problem) and problem.diagnostics:  # the gyroscope's scale checked against the rotation (calib.gyro)
        # Checked, not corrected: a gyroscope's misalignment to the accelerometer has an antisymmetric part
        # that only a rotation of its own could absorb; correcting the scale alone made the gyroscope's
        # (misaligned) axes decide the rotation more firmly (simulated: 4.5 % scale, 1 % misalignment).
        scale = _gyro_scale(problem, link)
        if scale is not None and scale.off:
            warnings.append(scale.describe())
            extras["gyro_scale_misalignment"] = scale.A
    p = arrange(problem, link)
    warnings += list(p.data.rest.warnings)
    n_orient = _distinct_orientations(p.data.rows.static_u)
    if n_orient < 3:
        warnings.append(
            f"only {n_orient} distinct static orientation(s) (3 or more recommended): rotation, bias and scale "
            "rest on the moving data"
        )
    blocks = fit_blocks(problem, p)
    if start is not None:
        start = replace(start, E=np.zeros((3, 3)), bg=gyro_bias_start(p.data.rows))
    # Converge on every 8th moving sample, then one Gauss-Newton step on all of them, whose
    # normal matrix also gives the covariance.
    coarse = fit_problem(decimated(p, 8), blocks, state=start)
    move = None
    if problem.options.detect_move and coarse.residuals is not None:
        # a fitted bias drift can soak up part of a move: look with and without it
        S = len(p.data.rows.static_u)
        undrifted = coarse.residuals.copy()
        undrifted[:S] -= np.outer(p.data.rows.static_t, coarse.state.c)
        move = find_move(p.data.rows, coarse.residuals, p.data.t_c) or find_move(p.data.rows, undrifted, p.data.t_c)
    if move is not None:  # keep the longer part and fit again
        s = problem.samples
        before = np.count_nonzero(s.t <= move.t_before) >= np.count_nonzero(s.t >= move.t_after)
        p = arrange(problem, link, window=(-np.inf, move.t_before) if before else (move.t_after, np.inf))
        blocks = fit_blocks(problem, p)
        coarse = fit_problem(decimated(p, 8), blocks, state=coarse.state)
        extras["moved_between_s"] = [move.t_before, move.t_after]
        warnings.append(
            f"unit moved on its link between {move.t_before:.1f} s and {move.t_after:.1f} s (its rest poses before "
            f"and after differ by about {move.angle_deg:.1f} deg): calibrated from the part "
            f"{'before' if before else 'after'} it only"
        )
    fit = fit_problem(p, blocks, state=coarse.state, max_outer=1, max_inner=1)
    e = fit.blocks.slices().get("e")
    if e is not None:
        std_e = np.sqrt(np.maximum(np.diag(fit.covariance)[e], 0.0))
        if np.any(std_e > SCALE_STD_LIMIT):
            warnings.append(
                f"scale/misalignment weakly determined by the data (std up to {100 * std_e.max():.1f} %, "
                "held near zero by a 5 % prior; its uncertainty is in the reported std)"
            )
    st = fit.state
    sl = fit.blocks.slices()
    total_offset = problem.time_offset_s + st.tau
    steps = None if problem.alignment is None else problem.alignment.steps
    alignment: Alignment | None = problem.alignment
    sigma_q = problem.shared.interpolator.conditioning.position_noise
    angle_noise = 0.0 if sigma_q is None else float(np.sqrt(np.sum(np.square(sigma_q[:link]))))
    cov, honesty, notes = _honesty(fit, p, None if alignment is None else alignment.search, total_offset, angle_noise)

    warnings += honesty
    notes = early_notes + notes
    if problem.diagnostics:  # what became of every sample (extras and a note only)
        kept = sample_account(problem, p)
        extras["samples"] = kept
        notes.append(describe_account(kept))
    observable = fit.null_space.shape[1] == 0
    std = np.sqrt(np.maximum(np.diag(cov), 0.0))
    pos_std = std[3:6].copy()
    rot_cov = st.R @ cov[0:3, 0:3] @ st.R.T
    rot_std = np.degrees(np.sqrt(np.maximum(np.diag(rot_cov), 0.0)))
    if not observable:
        basis = pose_null_basis(fit.null_space)
        warnings.append(describe_null(basis, st.R, _joint_axis_in_link(problem.chain, link), link))
        affected_p = np.linalg.norm(basis[3:6], axis=1) > NULL_SHARE
        affected_r = np.linalg.norm(st.R @ basis[0:3], axis=1) > NULL_SHARE
        pos_std = np.where(affected_p, np.nan, pos_std)
        rot_std = np.where(affected_r, np.nan, rot_std)

    def get_std(name: str) -> FloatArray:
        """The std of a fitted block (callers check ``name in sl``)."""
        return std[sl[name]]

    # The offset at the start of the joint stream (where a simulation's truth and a user's sync
    # refer to), carried from the fit's reference t_c along the drift: tau + d (t_ref - t_c).
    t_ref = problem.shared.interpolator.t_start
    lever = t_ref - p.data.t_c
    offset_ref = total_offset + (st.d * lever if "d" in sl else 0.0)
    offset_ref_std = None
    if "tau" in sl:
        j = np.zeros(len(std))
        j[sl["tau"].start] = 1.0
        if "d" in sl:
            j[sl["d"].start] = lever
        offset_ref_std = float(np.sqrt(max(j @ cov @ j, 0.0)))
    imu: dict = {
        "accel_bias_mps2": st.b,
        "accel_scale_misalignment": st.A,
        "accel_bias_std_mps2": std[6:9],
        "time_offset_s": offset_ref,
        "time_offset_std_s": offset_ref_std,
        "time_reference_s": t_ref,
        "clock_drift_ppm": (st.d * 1e6 if "d" in sl else 0.0) + (steps.drift_ppm if steps is not None else 0.0)
        if "d" in sl or steps is not None
        else None,
        "clock_drift_std_ppm": float(get_std("d")[0]) * 1e6 if "d" in sl else None,
    }
    extras.update(
        {
            "time_offset_coarse_s": None if alignment is None else alignment.offset_s,
            "residual_std_mps2": fit.sigma,
            "residual_correlation": fit.residual_correlation,
            "covariance_sandwich": None if fit.sandwich is None else fit.sandwich[:6].copy(),
            "n_static_runs": int(p.data.n_static),
            "n_static_dropped": int(len(p.data.rest.dropped)),
            "n_moving_samples": int(len(p.data.rows.moving_t)),
            "iterations": fit.iterations,
            "scale_estimated": fit.blocks.scale != SCALE_NONE,
            "rest_source": problem.shared.rest.source,
        }
    )
    if steps is not None:
        imu["clock_resync_steps"] = steps.n_steps
        imu["clock_resync_period_s"] = steps.period_s
        imu["clock_resync_step_s"] = steps.mean_step_s
        notes.append(
            f"clock re-synced {steps.n_steps} times (every {steps.period_s:.2f} s, steps of "
            f"{steps.mean_step_s * 1e3:.2f} ms: the sensor clock drifts {steps.drift_ppm:+.0f} ppm between "
            "re-syncs); stamps corrected"
        )
    gaps = None if alignment is None else alignment.gaps
    if gaps is not None:  # a step found is named; one not corrected is a warning (the estimate had to cope)
        (notes if gaps.corrected.all() else warnings).append(gaps.describe())
        extras["clock_gap_steps"] = np.c_[gaps.gap_start_s, gaps.gap_end_s, gaps.step_s].tolist()
    if "bg" in sl:
        imu["gyro_bias_rps"] = st.bg
        imu["gyro_bias_std_rps"] = get_std("bg")
        extras["gyro_residual_std_rps"] = fit.sigma_gyro
    if "k" in sl:
        g0 = float(np.linalg.norm(problem.gravity))
        imu["gravity_mps2"] = g0 * (1.0 + st.k)
        imu["gravity_std_mps2"] = g0 * float(get_std("k")[0])
    if "c" in sl:
        imu["accel_bias_drift_mps3"] = st.c
        imu["accel_bias_drift_std_mps3"] = get_std("c")
        imu["accel_bias_reference_s"] = p.data.t_c
    if "e" in sl:
        std_e = get_std("e")
        imu["accel_scale_misalignment_std"] = (
            std_e.reshape(3, 3) if fit.blocks.scale == SCALE_FULL else sym_from_e(std_e)
        )
        extras["accel_scale"] = np.diag(st.A).copy()
        sym = 0.5 * (st.E + st.E.T)
        extras["accel_misalignment_sym"] = sym - np.diag(np.diag(sym))
    return UnitResult(
        pose=SkinUnitPose(link, st.R, st.p),
        observable=observable,
        position_std_m=pos_std,
        rotation_std_deg=rot_std,
        warnings=tuple(warnings),
        extras=extras,
        imu=ImuCalibration(**imu),
        link_confidence=confidence,
        notes=tuple(notes),
    )

