"""The default calibrator ``mle``: closed-form start, then robust joint maximum likelihood.

Per unit:

1. **Link** (unless given): the activity matrix (accelerometer and gyroscope) proposes link
   ``n*``; unless that is decisive, the links ``1 .. n* + 1`` are each fitted quickly and the one
   whose model explains every sample best wins. Its confidence compares the residual levels; two links that
   explain the data about equally are reported as ambiguous, never silently chosen.
2. **Start** (no bounds, no seed): rotation and bias from the stationary runs (Wahba's problem,
   :mod:`skincal.calib.closed_form`), position and bias by linear least squares on the moving
   samples.
3. **Refinement** (:mod:`skincal.calib.mle.solver`): pose, bias, symmetric scale/misalignment
   and the IMU time offset by robust Gauss-Newton over every sample; scale/misalignment is
   dropped (with a warning) when the data cannot determine it.
4. **Uncertainty**: covariance from the Jacobian at the solution, scaled by the robust residual
   variance and the residuals' autocorrelation; directions the data cannot determine are
   reported (``observable: false``) and left at the start values.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from skincal.calib.api import MethodSpec, UnitProblem, register
from skincal.calib.closed_form import position_and_bias, static_rotation_and_bias
from skincal.calib.links import discover_link
from skincal.calib.mle.signals import SignalTable, UnitData, arrange_unit_data
from skincal.calib.mle.solver import Blocks, Fit, Linearisation, State, solve, sym_from_e
from skincal.calib.preprocess import JointInterpolator
from skincal.data.dataset import Dataset
from skincal.data.result import UnitResult
from skincal.errors import CalibrationError
from skincal.kinematics.chain import SerialChain
from skincal.kinematics.transforms import FloatArray
from skincal.skin.pose import SkinUnitPose

MAX_TIME_OFFSET_S = 0.25
"""Largest IMU time offset the data are trimmed for, s."""
SCALE_STD_LIMIT = 0.01
"""Scale/misalignment is kept only when each of its components is determined to this std."""
DECISIVE_ACTIVITY = 0.9
"""Activity confidence above which neighbouring links are not fitted for comparison."""
AMBIGUITY_RATIO = 1.5
"""A second link whose residual level is within this factor of the best makes the link ambiguous."""


@dataclass(frozen=True)
class _Problem:
    table: SignalTable
    data: UnitData

    def linearise(self, tau: float) -> Linearisation:
        u, K, du, dK = self.table.at(self.data.link, self.data.moving_t - tau)
        return Linearisation(tau_k=tau, u=u, K=K, du=du, dK=dK)


def prepare(dataset: Dataset, interpolator: JointInterpolator) -> SignalTable:
    """Once per dataset: the link signals of every link on a uniform grid."""
    return SignalTable(dataset.robot, interpolator, np.asarray(dataset.gravity, dtype=float))


def _decimated(p: _Problem, step: int) -> _Problem:
    """The same problem keeping every ``step``-th moving sample (stationary rows all kept)."""
    d = p.data
    data = UnitData(
        d.link, d.static_u, d.static_f, d.static_weight, d.static_q,
        d.moving_t[::step], d.moving_f[::step], None if d.moving_gyro is None else d.moving_gyro[::step],
    )
    return _Problem(p.table, data)


def _arrange(problem: UnitProblem, link: int, decimate: int = 1) -> _Problem:
    s = problem.samples
    interp = problem.interpolator
    # Keep samples whose instants stay inside the joint stream for any time offset tried.
    margin = MAX_TIME_OFFSET_S + 0.01
    keep = (s.t >= interp.t_start + margin) & (s.t <= interp.t_end - margin)
    data = arrange_unit_data(
        problem.chain, link, s.t[keep], s.accel[keep], None if s.gyro is None else s.gyro[keep],
        (s.q[keep], s.qd[keep], s.qdd[keep]), problem.gravity,
    )
    p = _Problem(problem.shared, data)
    return _decimated(p, decimate) if decimate > 1 else p


def _start(p: _Problem) -> State:
    d = p.data
    if len(d.static_u) < 2:
        raise CalibrationError(
            f"only {len(d.static_u)} stationary period(s) for link {d.link}; "
            "at least 2 distinct static poses are needed"
        )
    R, b = static_rotation_and_bias(d.static_u, d.static_f, d.static_weight)
    if len(d.moving_t) >= 10:
        lin = p.linearise(0.0)
        pos, b_dyn = position_and_bias(R, lin.u, lin.K, d.moving_f)
        return State(R=R, p=pos, b=b_dyn if np.linalg.norm(b) == 0 else b)
    return State(R=R, p=np.zeros(3), b=b)


def _fit(p: _Problem, blocks: Blocks, state: State | None = None, **kw) -> Fit:
    d = p.data
    state = _start(p) if state is None else state
    has_moving = len(d.moving_t) >= 10
    return solve(
        state, blocks, d.static_u, d.static_f, d.static_weight, d.moving_f if has_moving else np.zeros((0, 3)),
        p.linearise if has_moving else None, **kw,
    )


def _residual_level(problem: UnitProblem, link: int, state: State) -> float:
    """Median residual norm of the fitted model over every sample of the unit (m/s^2)."""
    s = problem.samples.select(slice(None, None, 4))
    table: SignalTable = problem.shared
    t = s.t - state.tau
    keep = (t >= table.t[0]) & (t <= table.t[-1])
    u, K, _, _ = table.at(link, t[keep])
    v = u + np.einsum("mij,j->mi", K, state.p)
    pred = (v @ state.R) @ state.A.T + state.b
    return float(np.median(np.linalg.norm(pred - s.accel[keep], axis=1)))


def choose_link(problem: UnitProblem) -> tuple[int, float, list[str], dict[int, float], State | None]:
    """Link discovery by activity, then model comparison among neighbouring links.

    Returns the link, its confidence, warnings, the residual level of each candidate fitted and
    the winner's quick-fit state (a start for the full fit; ``None`` when the activity alone was
    decisive and no candidate had to be fitted).
    """
    n = problem.chain.n_joints
    activity = discover_link(problem.samples, n, use_gyro=True)
    if activity.link == 0:
        raise CalibrationError("; ".join(activity.warnings) or "no joint motion excites this unit")
    # The model comparison below settles ambiguity; keep only the activity's other notes.
    warnings = [w for w in activity.warnings if "ambiguous" not in w]
    levels: dict[int, float] = {}
    states: dict[int, State] = {}
    if activity.confidence >= DECISIVE_ACTIVITY:
        return activity.link, activity.confidence, warnings, levels, None  # no doubt: nothing to compare
    # Not decisive: a joint's motion can shake earlier links through the servos' finite stiffness
    # (the activity then points too far out), so every link up to one past the suggestion competes.
    for link in range(1, min(n, activity.link + 1) + 1):
        try:
            fit = _fit(_arrange(problem, link, decimate=10), Blocks(scale=False, time_offset=True), max_outer=2)
        except CalibrationError:
            continue
        levels[link] = _residual_level(problem, link, fit.state)
        states[link] = fit.state
    if not levels:
        raise CalibrationError("no candidate link could be fitted")
    ranked = sorted(levels, key=levels.get)
    best = ranked[0]
    confidence = 1.0
    if len(ranked) > 1:
        ratio = levels[ranked[1]] / max(levels[best], 1e-12)
        confidence = float(np.clip(1.0 - 1.0 / ratio, 0.0, 1.0))
        if ratio < AMBIGUITY_RATIO:
            warnings.append(
                f"link is ambiguous: links {best} and {ranked[1]} explain the data almost equally "
                f"(residual {levels[best]:.3g} vs {levels[ranked[1]]:.3g} m/s^2); chose {best}"
            )
    return best, confidence, warnings, levels, states[best]


def _describe_null(null: FloatArray, R: FloatArray, axis_link: FloatArray, joint: int) -> str:
    parts = []
    for k in range(null.shape[1]):
        v = null[:, k]
        rot = R @ v[0:3]
        pos = v[3:6]
        if np.linalg.norm(rot) > 0.1 * np.linalg.norm(v):
            a = rot / np.linalg.norm(rot)
            what = f"joint-{joint} axis" if abs(a @ axis_link) > 0.99 else f"axis {np.round(a, 3).tolist()}"
            parts.append(f"rotation (yaw) about the {what}")
        elif np.linalg.norm(pos) > 0.1 * np.linalg.norm(v):
            a = pos / np.linalg.norm(pos)
            what = f"joint-{joint} axis" if abs(a @ axis_link) > 0.99 else f"direction {np.round(a, 3).tolist()}"
            parts.append(f"offset along the {what}")
        else:
            parts.append("a combination of sensor parameters")
    return "unobservable: " + " and ".join(parts) + " (left at the closed-form start)"


def _joint_axis_in_link(chain: SerialChain, link: int) -> FloatArray:
    """Unit direction of joint ``link``'s axis in link frame ``link`` (constant)."""
    T = chain.link_frames(np.zeros(chain.n_joints), upto=link)[0]
    z = T[link - 1, :3, 2] if chain.convention == "standard" else T[link, :3, 2]
    return T[link, :3, :3].T @ z


def _distinct_orientations(u_link: FloatArray, min_angle_deg: float = 5.0) -> int:
    """Number of static gravity directions (link frame) at least ``min_angle_deg`` apart."""
    dirs = u_link / np.linalg.norm(u_link, axis=1, keepdims=True)
    chosen: list[FloatArray] = []
    for d in dirs:
        if all(np.degrees(np.arccos(np.clip(d @ c, -1, 1))) >= min_angle_deg for c in chosen):
            chosen.append(d)
    return len(chosen)


def run_unit(problem: UnitProblem) -> UnitResult:
    """Calibrate one unit with the default method (module docstring)."""
    warnings: list[str] = []
    extras: dict = {}
    start = None
    if problem.link == 0:
        link, confidence, link_warnings, levels, start = choose_link(problem)
        warnings += link_warnings
        extras["link_confidence"] = confidence
        extras["link_residual_mps2"] = {str(k): v for k, v in levels.items()}
    else:
        link = problem.link
    p = _arrange(problem, link)
    n_orient = _distinct_orientations(p.data.static_u)
    if n_orient < 3:
        warnings.append(
            f"only {n_orient} distinct static orientation(s) (3 or more recommended): rotation, bias and scale "
            "rest on the moving data"
        )
    opts = problem.options
    want_scale = bool(opts.get("scale", True))
    blocks = Blocks(scale=want_scale, time_offset=bool(opts.get("time_offset", True)))
    # Converge on every 8th moving sample (time offset included), then one Gauss-Newton step on
    # all of them, whose normal matrix also gives the covariance.
    coarse = _fit(_decimated(p, 8), blocks, state=start)
    fit = _fit(p, blocks, state=coarse.state, max_outer=1, max_inner=1)
    if want_scale:
        std_e = np.sqrt(np.maximum(np.diag(fit.covariance)[9:15], 0.0))
        if fit.null_space.size and np.any(np.abs(fit.null_space[9:15]) > 0.1) or np.any(std_e > SCALE_STD_LIMIT):
            warnings.append("scale/misalignment not estimated: the static poses do not determine it")
            fit = _fit(p, Blocks(scale=False, time_offset=blocks.time_offset), state=fit.state)
    st = fit.state
    observable = fit.null_space.shape[1] == 0
    cov = fit.covariance
    pos_std = np.sqrt(np.maximum(np.diag(cov)[3:6], 0.0))
    rot_cov = st.R @ cov[0:3, 0:3] @ st.R.T
    rot_std = np.degrees(np.sqrt(np.maximum(np.diag(rot_cov), 0.0)))
    if not observable:
        warnings.append(_describe_null(fit.null_space, st.R, _joint_axis_in_link(problem.chain, link), link))
        affected_p = np.abs(fit.null_space[3:6]).max(axis=1) > 1e-3
        affected_r = np.abs(st.R @ fit.null_space[0:3]).max(axis=1) > 1e-3
        pos_std = np.where(affected_p, np.nan, pos_std)
        rot_std = np.where(affected_r, np.nan, rot_std)
    col = 15 if fit.blocks.scale else 9
    extras.update(
        {
            "accel_bias_mps2": st.b,
            "accel_scale_misalignment": st.A,
            "accel_bias_std_mps2": np.sqrt(np.maximum(np.diag(cov)[6:9], 0.0)),
            "time_offset_s": st.tau,
            "time_offset_std_s": float(np.sqrt(cov[col, col])) if fit.blocks.time_offset else None,
            "residual_std_mps2": fit.sigma,
            "residual_correlation": fit.residual_correlation,
            "n_static_runs": int(len(p.data.static_u)),
            "n_moving_samples": int(len(p.data.moving_t)),
            "iterations": fit.iterations,
            "scale_estimated": fit.blocks.scale,
        }
    )
    if fit.blocks.scale:
        std_e = np.sqrt(np.maximum(np.diag(cov)[9:15], 0.0))
        extras["accel_scale_misalignment_std"] = sym_from_e(std_e)
        extras["accel_scale"] = np.diag(st.A).copy()
        extras["accel_misalignment_sym"] = sym_from_e(st.e) - np.diag(np.diag(sym_from_e(st.e)))
    return UnitResult(
        pose=SkinUnitPose(link, st.R, st.p),
        observable=observable,
        position_std_m=pos_std,
        rotation_std_deg=rot_std,
        warnings=tuple(warnings),
        extras=extras,
    )


register(
    "mle",
    MethodSpec(
        run_unit=run_unit,
        description="closed-form start + robust joint maximum likelihood (pose, bias, scale, time offset)",
        discovers_links=True,
        use_gyro_for_links=True,
        prepare=prepare,
        exact_joint_states=False,
    ),
)
