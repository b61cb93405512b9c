"""The paper's acceleration model and error functions (paper Sec. III-C, Eqs. 2-8), vectorised.

A unit ``k`` on link ``n`` has the pose ``T_n_k(Phi)`` of paper Eq. 1 (:func:`skincal.skin.pose.dh6_to_transform`,
``Phi = [theta_v, d_v, theta_su, d_su, a_su, alpha_su]``). Everything that depends on the joint
states only (link frames, joint axes) is computed once per unit (:class:`StaticData`,
:class:`DynamicData`); the error functions then cost a few vector operations per evaluation.

Frames: ``base`` is DH frame {0}; ``link`` is link frame ``n`` (DH frame {n}); ``su`` the unit
frame. Accelerometers measure specific force ``f_su = R_su_base (a_base - g_base)``; the paper
writes the same with ``g_b = -g_base = [0, 0, 9.81]`` m/s^2 ("gravity" as the reading at rest).

Dynamic models (the only difference between the paper's method and its baselines):

* ``"om"`` (paper Eq. 2-6): ``a = a_cen + a_tan``, ``a_cen = w x (w x r)``, ``a_tan`` the second
  difference of the unit position as joint ``d`` advances, projected on the tangent ``e_tan``;
  plus gravity. Exact for a motion of joint ``d`` alone (up to the ``O(h^2)`` difference error).
* ``"mmm"`` (the paper's modified Mittendorfer baseline): gravity + ``a_cen`` + the *full* second
  difference, which already contains ``a_cen``: the centripetal term is counted twice.
* ``"mm"`` (Mittendorfer & Cheng 2012): the full second difference alone, no gravity (as in the
  authors' implementation of the original method).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from skincal.calib.preprocess import UnitSamples, static_means
from skincal.data.dataset import DYNAMIC
from skincal.errors import CalibrationError
from skincal.kinematics.chain import SerialChain, cross
from skincal.kinematics.transforms import FloatArray, rot_x, rot_z

FD_STEP_S = 1e-3
"""Time step ``h`` of the paper's finite-difference tangential acceleration (Eq. 5), s."""

DYNAMIC_MODELS = ("om", "mmm", "mm")
"""Dynamic acceleration models: the paper's (``om``) and its two baselines."""

JOINTS_BEFORE_LINK = 3
"""Excited joints used per unit: ``d in {n-2, n-1, n}`` with ``d >= 1`` (paper Eq. 8)."""


def rotation_from_angles(theta_v: float, theta_su: float, alpha_su: float) -> FloatArray:
    """Rotational part of paper Eq. 1: ``R_link_su = Rz(theta_v) Rx(alpha_su) Rz(theta_su)``, ``(3, 3)``."""
    return rot_z(theta_v) @ rot_x(alpha_su) @ rot_z(theta_su)


@dataclass(frozen=True)
class StaticData:
    """Static measurements of one unit (paper Eq. 7).

    Attributes:
        accel_su: ``(P, 3)`` mean specific force per static segment, unit frame, m/s^2.
        R_base_link: ``(P, 3, 3)`` orientation of link frame ``n`` at those poses.
        g_b: ``(3,)`` the paper's gravity vector ``-g_base`` (specific force at rest), m/s^2.
    """

    accel_su: FloatArray
    R_base_link: FloatArray
    g_b: FloatArray


def static_data(chain: SerialChain, samples: UnitSamples, link: int, gravity: FloatArray) -> StaticData:
    """Average each static segment and evaluate ``R_base_link`` there (see :class:`StaticData`)."""
    means = static_means(samples)
    if means.accel.shape[0] == 0:
        raise CalibrationError(f"unit '{samples.unit}': no static segment with samples")
    R = chain.link_frames(means.q, upto=link)[:, link, :3, :3]
    return StaticData(accel_su=means.accel, R_base_link=np.ascontiguousarray(R), g_b=-np.asarray(gravity, float))


def static_error(R_link_su: FloatArray, data: StaticData) -> float:
    """Paper Eq. 7: ``E_s = mean_p |R_base_link(q_p) R_link_su a_p - g_b|^2``, (m/s^2)^2."""
    f_base = np.einsum("pij,pj->pi", data.R_base_link, data.accel_su @ R_link_su.T)
    return float(np.mean(np.sum((f_base - data.g_b) ** 2, axis=1)))


@dataclass(frozen=True)
class DynamicData:
    """Dynamic samples of one unit with the joint-state-only quantities precomputed (Eq. 2-6, 8).

    Attributes:
        accel_su: ``(N, 3)`` measured specific force, unit frame, m/s^2.
        R_base_link: ``(N, 3, 3)``, ``o_base_link``: ``(N, 3)`` pose of link frame ``n``.
        c_base: ``(N, 3)`` a point on the excited joint's axis; ``z_base``: ``(N, 3)`` its unit direction.
        qd, qdd: ``(N,)`` velocity (rad/s) and acceleration (rad/s^2) of the excited joint.
        joint: ``(N,)`` 0-based excited joint.
        g_base: ``(3,)`` gravity in the base frame, m/s^2.
    """

    accel_su: FloatArray
    R_base_link: FloatArray
    o_base_link: FloatArray
    c_base: FloatArray
    z_base: FloatArray
    qd: FloatArray
    qdd: FloatArray
    joint: np.ndarray
    g_base: FloatArray

    def __len__(self) -> int:
        return int(self.qd.shape[0])


def dynamic_joints(link: int) -> tuple[int, ...]:
    """0-based joints whose excitation enters ``E_d`` for a unit on 1-based ``link`` (paper Eq. 8)."""
    return tuple(d - 1 for d in range(max(1, link - JOINTS_BEFORE_LINK + 1), link + 1))


def dynamic_data(
    chain: SerialChain,
    samples: UnitSamples,
    link: int,
    gravity: FloatArray,
    max_samples: int | None = None,
) -> DynamicData:
    """Gather the unit's samples of the dynamic segments of joints :func:`dynamic_joints` (``link``).

    ``max_samples``: keep at most this many, evenly strided in time (every ``ceil(N / max)``-th sample)
    so that every segment stays represented; ``None`` keeps all.
    """
    joints = dynamic_joints(link)
    mask = (samples.kind == DYNAMIC) & np.isin(samples.joint, joints)
    idx = np.flatnonzero(mask)
    if idx.size == 0:
        raise CalibrationError(
            f"unit '{samples.unit}': no dynamic samples for joints {[j + 1 for j in joints]} (needed for link {link})"
        )
    if max_samples is not None and idx.size > max_samples:
        idx = idx[:: int(np.ceil(idx.size / max_samples))]
    q, joint = samples.q[idx], samples.joint[idx]
    T = chain.link_frames(q, upto=link)
    c_all, z_all = chain.joint_axes(T)
    rows = np.arange(idx.size)
    return DynamicData(
        accel_su=samples.accel[idx],
        R_base_link=np.ascontiguousarray(T[:, link, :3, :3]),
        o_base_link=np.ascontiguousarray(T[:, link, :3, 3]),
        c_base=c_all[rows, joint],
        z_base=z_all[rows, joint],
        qd=samples.qd[idx, joint],
        qdd=samples.qdd[idx, joint],
        joint=joint,
        g_base=np.asarray(gravity, dtype=float),
    )


def rotate_about_axis(r: FloatArray, z: FloatArray, angle: FloatArray) -> FloatArray:
    """Rodrigues: rotate ``r`` ``(N, 3)`` about unit axes ``z`` ``(N, 3)`` by ``angle`` ``(N,)`` rad."""
    c, s = np.cos(angle)[:, None], np.sin(angle)[:, None]
    return r * c + cross(z, r) * s + z * np.sum(z * r, axis=1, keepdims=True) * (1.0 - c)


def second_difference(
    r: FloatArray, z: FloatArray, qd: FloatArray, qdd: FloatArray, h: float = FD_STEP_S
) -> FloatArray:
    """Paper Eq. 5 (numerator over ``h^2``): ``(r(h) + r(-h) - 2 r(0)) / h^2``, ``(N, 3)`` m/s^2.

    ``r(t)`` is the lever arm ``r`` ``(N, 3)`` (from the joint axis to the unit, base frame) carried
    along as joint ``d`` advances by ``q(t) - q(0) = qd t + qdd t^2 / 2`` about its axis ``z``.
    The result is the full acceleration of the point: tangential *and* centripetal.
    """
    r_plus = rotate_about_axis(r, z, qd * h + 0.5 * qdd * h * h)
    r_minus = rotate_about_axis(r, z, -qd * h + 0.5 * qdd * h * h)
    return (r_plus + r_minus - 2.0 * r) / (h * h)


def tangential_fd(r: FloatArray, z: FloatArray, qd: FloatArray, qdd: FloatArray, h: float = FD_STEP_S) -> FloatArray:
    """Paper Eq. 5: ``a_tan = e_tan (e_tan . D2 r)`` with ``e_tan = z x r / |z x r|``, ``(N, 3)`` m/s^2.

    Equals the analytic ``qdd z x r`` (paper Eq. 4) up to ``O(h^2)``. Points on the axis
    (``|z x r| = 0``) get zero.
    """
    t = cross(z, r)
    norm = np.linalg.norm(t, axis=1, keepdims=True)
    e_tan = np.divide(t, norm, out=np.zeros_like(t), where=norm > 0)
    d2 = second_difference(r, z, qd, qdd, h)
    return e_tan * np.sum(e_tan * d2, axis=1, keepdims=True)


def centripetal(r: FloatArray, z: FloatArray, qd: FloatArray) -> FloatArray:
    """Paper Eq. 3: ``a_cen = w x (w x r)`` with ``w = qd z``, ``(N, 3)`` m/s^2."""
    w = qd[:, None] * z
    return cross(w, cross(w, r))


def predicted_specific_force(
    R_link_su: FloatArray, p_link_su: FloatArray, data: DynamicData, model: str = "om", h: float = FD_STEP_S
) -> FloatArray:
    """Paper Eq. 2: predicted accelerometer reading ``(N, 3)`` in the unit frame, m/s^2.

    ``f_su = R_su_base (a_model - g_base)`` with the unit at ``x = o_link + R_base_link p_link_su``
    and the lever arm ``r = x - c`` from the excited joint's axis. ``a_model`` is ``a_cen + a_tan``
    (``om``), ``2 a_cen + a_tan`` in effect (``mmm``: ``a_cen`` + full second difference), or the full
    second difference with no gravity (``mm``); see the module docstring.
    """
    if model not in DYNAMIC_MODELS:
        raise CalibrationError(f"unknown dynamic model '{model}' (use {', '.join(DYNAMIC_MODELS)})")
    x = data.o_base_link + data.R_base_link @ p_link_su
    r = x - data.c_base
    if model == "om":
        a = centripetal(r, data.z_base, data.qd) + tangential_fd(r, data.z_base, data.qd, data.qdd, h)
        a = a - data.g_base
    elif model == "mmm":
        a = centripetal(r, data.z_base, data.qd) + second_difference(r, data.z_base, data.qd, data.qdd, h)
        a = a - data.g_base
    else:
        a = second_difference(r, data.z_base, data.qd, data.qdd, h)
    # f_su = R_link_su^T R_base_link^T a  (row-wise)
    return np.einsum("nji,nj->ni", data.R_base_link, a) @ R_link_su


def dynamic_error(R_link_su: FloatArray, p_link_su: FloatArray, data: DynamicData, model: str = "om") -> float:
    """Paper Eq. 8: ``E_d = mean |f_meas - f_pred|^2`` over the dynamic samples, (m/s^2)^2.

    The paper averages over poses and sums over the three excited joints; we average over all
    samples (a constant factor, which leaves the minimiser unchanged and keeps ``E_d`` in the units
    of ``E_s``).
    """
    f = predicted_specific_force(R_link_su, p_link_su, data, model)
    return float(np.mean(np.sum((data.accel_su - f) ** 2, axis=1)))
