"""A result exported onto another description of its robot: the source chain of a result
(:func:`result_chain`) and the fixed offsets between the two chains' link frames (:func:`link_offsets`,
refused when the chains do not move alike)."""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial.transform import Rotation

from skincal.data.export.escape import shown
from skincal.data.result import CalibrationResult
from skincal.errors import ConfigError
from skincal.kinematics.chain import SerialChain
from skincal.kinematics.transforms import FloatArray

SAME_MOTION_ATOL_M = 1e-4
"""Largest change (m) of a link offset ``T_target_source`` over configurations that still counts as
the same motion (a URDF rounds its numbers: xarm_description writes pi/2 as 1.5708, 1e-5 m at the
tool; far below a calibration's millimetres)."""
SAME_MOTION_ATOL_RAD = 1e-4
"""The same for the offset's rotation (rad)."""


def _offset_spread(X: FloatArray) -> tuple[float, float]:
    """Largest change over configurations of offsets ``X`` ``(N, n + 1, 4, 4)`` from ``X[0]``:
    position (m) and rotation angle (rad)."""
    dp = float(np.max(np.linalg.norm(X[:, :, :3, 3] - X[:1, :, :3, 3], axis=-1)))
    dR = np.swapaxes(X[:1, :, :3, :3], -1, -2) @ X[:, :, :3, :3]
    return dp, float(np.max(Rotation.from_matrix(dR.reshape(-1, 3, 3)).magnitude()))


def _base_offset(source: SerialChain, target: SerialChain, F_s: FloatArray, F_t: FloatArray) -> FloatArray | None:
    """``T_targetbase_sourcebase`` ``B`` with ``U_k B = B D_k`` for the motions of the last link between
    configuration 0 and the single-joint steps ``1..n`` (``U_k = F_t[k] F_t[0]^-1``, the same ``D_k`` of
    ``source``; the hand-eye equation ``AX = XB``): the rotation by Kabsch from the motions' rotation
    vectors (a prismatic joint's translation), then ``(R_U - I) t_B = R_B t_D - t_U`` by least squares.
    None when the motions do not determine ``B`` (parallel axes only)."""
    n = source.n_joints
    U = F_t[1 : n + 1, -1] @ np.linalg.inv(F_t[0, -1])
    D = F_s[1 : n + 1, -1] @ np.linalg.inv(F_s[0, -1])
    a = np.where(source.revolute[:, None], Rotation.from_matrix(U[:, :3, :3]).as_rotvec(), U[:, :3, 3])
    b = np.where(source.revolute[:, None], Rotation.from_matrix(D[:, :3, :3]).as_rotvec(), D[:, :3, 3])
    u, sv, vt = np.linalg.svd(a.T @ b)
    if sv.size < 2 or sv[1] < 1e-6 * max(sv[0], 1e-300):
        return None
    R = u @ np.diag([1.0, 1.0, np.linalg.det(u @ vt)]) @ vt
    A = (U[:, :3, :3] - np.eye(3)).reshape(-1, 3)
    rhs = (D[:, :3, 3] @ R.T - U[:, :3, 3]).reshape(-1)
    t, _, rank, _ = np.linalg.lstsq(A, rhs, rcond=None)
    if rank < 3:
        return None
    B = np.eye(4)
    B[:3, :3], B[:3, 3] = R, t
    return B


def result_chain(result: CalibrationResult, target: SerialChain, source: SerialChain | None = None) -> SerialChain:
    """The chain whose link frames ``result``'s poses are in, for an export onto ``target``:
    ``source`` when known (the dataset's chain); else, from the link names the units record (extra
    ``link_name``, written by ``calibrate``): the preset the result names when they are the preset's
    (``link<i>``; ``target`` itself when it moves as that preset does), else ``target`` when it bears
    the result's robot name and those link names; a result that records no link names is of
    ``target`` when the names agree, else of the preset it names. Anything else is a result of
    another robot: a one-line :class:`ConfigError` (give its dataset)."""
    if source is not None:
        return source
    from skincal.kinematics.presets import PRESETS

    recorded = {u.pose.link: u.extras.get("link_name") for u in result.units.values()}
    named = any(isinstance(name, str) for name in recorded.values())

    def names_match(chain: SerialChain) -> bool:
        return all(not isinstance(name, str) or name == chain.link_name(link) for link, name in recorded.items())

    if result.robot == target.name and names_match(target) and not (named and result.robot in PRESETS):
        return target
    if result.robot in PRESETS:
        preset = PRESETS[result.robot]()
        if names_match(preset):
            return target if target.same_motion(preset) else preset
        if result.robot == target.name and names_match(target):
            return target
    on = ", ".join(sorted({shown(n) for n in recorded.values() if isinstance(n, str)})) or "unnamed links"
    raise ConfigError(
        f"the result is for robot '{shown(str(result.robot))}' (units on {on}), not for robot "
        f"'{shown(target.name)}': give the dataset it was computed from (--dataset) to export it onto another "
        "description of that robot"
    )


def link_offsets(source: SerialChain, target: SerialChain) -> FloatArray:
    """``T_targetlink_sourcelink`` ``(n + 1, 4, 4)``: the pose of each link frame of ``source`` (the
    chain a result was computed on) in the same link's frame of ``target`` (the robot it is exported
    onto), so that ``T_targetlink_su = T_targetlink_sourcelink @ T_sourcelink_su``.

    The two chains describe the same robot when ``F_t_i(q) X_i = B F_s_i(q)`` for every link ``i`` and
    configuration ``q`` with constant ``X_i`` and base offset ``B`` (forward kinematics ``F``, link
    poses in each chain's base). ``B = I`` is tried first, else solved from the motions
    (:func:`_base_offset`; the UR URDFs' ``base_link`` is the controller's base turned by pi about z);
    ``X_i = F_t_i(q)^-1 B F_s_i(q)`` at ``q = 0`` and checked constant to :data:`SAME_MOTION_ATOL_M`,
    :data:`SAME_MOTION_ATOL_RAD` over single-joint steps and random configurations (seeded).
    Raises a one-line :class:`ConfigError` when they differ (another robot, or other joint zeros or
    directions)."""
    n = source.n_joints
    shown_s, shown_t = shown(source.name), shown(target.name)
    if target.n_joints != n or target.joint_type != source.joint_type:
        raise ConfigError(
            f"the result is for robot '{shown_s}' ({n} joints {'/'.join(source.joint_type)}), which robot "
            f"'{shown_t}' ({target.n_joints} joints) is not: the result cannot be exported onto it"
        )
    steps = np.eye(n) * 0.4
    rng = np.random.default_rng(0)
    Q = np.vstack([np.zeros((1, n)), steps, rng.uniform(-1.5, 1.5, (6, n))])
    F_s, F_t = source.link_frames(Q), target.link_frames(Q)
    inv_t = np.linalg.inv(F_t)
    X = inv_t @ F_s
    spread = _offset_spread(X)
    if spread[0] > SAME_MOTION_ATOL_M or spread[1] > SAME_MOTION_ATOL_RAD:
        B = _base_offset(source, target, F_s, F_t)
        if B is not None:
            X_b = inv_t @ B @ F_s
            spread_b = _offset_spread(X_b)
            if spread_b[0] <= SAME_MOTION_ATOL_M and spread_b[1] <= SAME_MOTION_ATOL_RAD:
                X, spread = X_b, spread_b
    if spread[0] > SAME_MOTION_ATOL_M or spread[1] > SAME_MOTION_ATOL_RAD:
        raise ConfigError(
            f"robot '{shown_t}' does not move its links as the result's robot '{shown_s}' does (their link "
            f"frames drift apart by up to {spread[0] * 1e3:.3g} mm, {math.degrees(spread[1]):.3g} deg over "
            "configurations: another robot, or other joint zeros or directions): the result cannot be "
            "exported onto it"
        )
    out = X[0].copy()
    out[:, 3, :] = (0.0, 0.0, 0.0, 1.0)
    return out
