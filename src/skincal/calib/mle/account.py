"""What ``mle`` tells about a unit besides its pose: where its motion went (:func:`sample_account`) and
which pose directions the data cannot determine, in words (:func:`describe_null`)."""

from __future__ import annotations

import numpy as np

from skincal.calib.api import UnitProblem
from skincal.calib.mle.problem import MAX_RESIDUAL_OFFSET_S, Problem, Shared
from skincal.kinematics.transforms import FloatArray


def sample_account(problem: UnitProblem, p: Problem) -> dict:
    """Where the unit's motion went: IMU samples at instants when some joint up to its link moves
    (the *motion*), those the fit kept as moving samples, and those dropped, by reason: at the joint
    stream's kinks (:meth:`JointInterpolator.reliable`), saturated (:class:`SampleAccount`, the
    moving ones), stuck, at the joint stream's ends (the residual clock margin) and otherwise (a
    rest run the IMU contradicted, the part before or after a move). Counts and shares of the motion."""
    s = problem.samples
    shared: Shared = problem.shared
    link = p.data.link
    ip = shared.interpolator
    moving = ~shared.rest.unit_rest(s.t, link)
    margin = MAX_RESIDUAL_OFFSET_S + 0.01
    inside = (s.t >= ip.t_start + margin) & (s.t <= ip.t_end - margin)
    kinks = int(np.count_nonzero(moving & inside & ~ip.reliable(s.t)))
    ends = int(np.count_nonzero(moving & ~inside))
    acc = s.account
    saturated = 0
    stuck = 0
    if acc is not None:
        sat_t = np.asarray(acc.saturated_t if acc.saturated_t is not None else np.zeros(0))
        sat_t = sat_t[(sat_t >= ip.t_start) & (sat_t <= ip.t_end)]
        saturated = int(np.count_nonzero(~shared.rest.unit_rest(sat_t, link))) if sat_t.size else 0
        stuck = int(acc.n_stuck)
    kept = int(len(p.data.rows.moving_t))
    motion = int(np.count_nonzero(moving)) + saturated + stuck
    other = max(motion - kept - kinks - ends - saturated - stuck, 0)
    counts = {"motion": motion, "kept": kept, "kinks": kinks, "saturated": saturated, "stuck": stuck,
              "ends": ends, "other": other}
    g = p.data.rows.moving_g
    # kept samples whose gyroscope reading was at its rail: the accelerometer's reading is used, the gyroscope's not
    gyro_rail = 0 if g is None else int(np.count_nonzero(~np.all(np.isfinite(g), axis=1)))
    shares = {k: (v / motion if motion else 0.0) for k, v in counts.items() if k != "motion"}
    return {**counts, "gyro_saturated": gyro_rail, "shares": shares}


ACCOUNT_WORDS = {
    "kinks": "at the joint stream's kinks",
    "saturated": "saturated",
    "stuck": "a stuck axis",
    "ends": "at the joint stream's ends",
    "other": "in rest runs the IMU contradicted or beyond a move",
}


def describe_account(account: dict) -> str:
    """One line for :func:`sample_account`: "kept 52 % of the motion (1065 samples): 31 % at the
    joint stream's kinks, 17 % saturated" (and, where a gyroscope clipped, in how many of the kept
    samples its reading was left out)."""
    sh = account["shares"]
    dropped = [f"{100 * sh[k]:.0f} % {w}" for k, w in ACCOUNT_WORDS.items() if account[k] > 0]
    head = f"kept {100 * sh['kept']:.0f} % of the motion ({account['kept']} of {account['motion']} samples)"
    rail = account.get("gyro_saturated", 0)
    tail = (
        f"; the gyroscope's reading left out at its rail in {rail} of the kept ({100 * rail / account['kept']:.0f} %)"
        if rail and account["kept"]
        else ""
    )
    return head + (": " + ", ".join(dropped) if dropped else "") + tail


NULL_POSITION_SCALE_M = 0.1
"""Positions are compared with rotations in null-space directions in units of this length (a unit
turned by one radian about an axis 0.1 m away moves by 0.1 m)."""


NULL_SHARE = 0.05
"""A pose component whose share in the null space (row norm of its orthonormal basis) exceeds this
is undetermined: its std is reported as null."""


def pose_null_basis(null: FloatArray) -> FloatArray:
    """Orthonormal basis ``(6, k)`` of the pose part of the null space (rows: rotation in the unit
    frame, rad; position in units of :data:`NULL_POSITION_SCALE_M`), whatever basis the solver
    returned: the row norms of it (the share of each parameter in the null space) do not depend on
    that basis. Directions of the sensor parameters alone are dropped."""
    pose = null[0:6].copy()
    pose[3:6] /= NULL_POSITION_SCALE_M
    if pose.size == 0 or not np.any(pose):
        return np.zeros((6, 0))
    U, s, _ = np.linalg.svd(pose, full_matrices=False)
    return U[:, s > 1e-12 * s.max()]


def describe_null(basis: FloatArray, R: FloatArray, axis_link: FloatArray, joint: int) -> str:
    """Words for a pose null space ``basis`` (:func:`pose_null_basis`): the rotation axes it turns
    about (link frame) and the directions it shifts along without turning."""
    parts = []
    rot = R @ basis[0:3]  # rotation part in link frame
    U, s, Vt = np.linalg.svd(rot, full_matrices=True)
    for k in range(min(3, s.size)):
        if s[k] > 0.3:
            a = U[:, k]
            what = f"joint-{joint} axis" if abs(a @ axis_link) > 0.99 else f"axis {np.round(a, 3).tolist()}"
            parts.append(f"rotation (yaw) about the {what}")
    # combinations of the basis that do not turn: the right singular vectors of the rotation part
    # with (near) zero singular value
    n_turn = int(np.sum(s > 1e-6))
    for v in Vt[n_turn:]:
        pos = basis[3:6] @ v
        if np.linalg.norm(pos) > 0.1:
            a = pos / np.linalg.norm(pos)
            what = f"joint-{joint} axis" if abs(a @ axis_link) > 0.99 else f"direction {np.round(a, 3).tolist()}"
            parts.append(f"offset along the {what}")
    if not parts:
        parts.append("a combination of sensor parameters")
    return "unobservable: " + " and ".join(dict.fromkeys(parts)) + " (left at the closed-form start)"
