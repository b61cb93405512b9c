"""Position covariance of obstacle points from the calibration's pose covariance, the ToF noise and the
joint noise (first-order propagation), for the protective separation's ``Z_d``
(:mod:`skincal.control.separation`).

A reading ``r`` of unit ``su`` on link ``l`` at joint angles ``q`` is the base-frame point::

    p = T_base_link(q) (p_link_su + R_link_su r e_z) = R_bl (p_ls + r a) + p_bl,   a = R_link_su e_z

**Pose perturbation** (the convention of the result file, ``docs/interfaces.md``, and of the exported
``covariance``): ``(x, y, z, rx, ry, rz)`` in the link frame's axes; the position error adds,
``p_ls = p_ls_est + dp``, and the rotation error is about the link's fixed axes (a left
perturbation), ``R_ls = Exp(dtheta) R_ls_est``. ``position_std_m`` / ``rotation_std_deg`` are the std of
``dp`` / ``dtheta``; a unit's ``pose_covariance`` (6x6, same order, m^2 and rad^2) is used when
present (:func:`skincal.data.export.pose_covariance`).

**Jacobians** at the estimate (``[u]_x`` the cross-product matrix)::

    dp/d(dp)     = R_bl                         (3 x 3)
    dp/d(dtheta) = -R_bl [r a]_x                (3 x 3: Exp(dtheta) r a ~ r a + dtheta x r a)
    dp/dr        = R_bl a                       (3 x 1: the ray)
    dp/dq        = the point's position Jacobian on link l  (3 x n, :meth:`SerialChain.point_jacobians`)

and, the three sources independent, ``Cov_p = J_pose Cov_pose J_pose^T + sigma_r^2 (R_bl a)(R_bl a)^T +
J_q Cov_q J_q^T``. The range variance is the ToF model's noise at the reading,
``(noise_std + noise_std_per_m r)^2``, plus its rounding, ``resolution^2 / 12``.

**No covariance is never zero**: a unit whose result gives no std (or leaves an axis undetermined,
``null``), or that has no result at all (poses given by hand), gets the std
``PerceptionConfig.assumed_position_std_m`` / ``assumed_rotation_std_deg`` on those axes.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike

from skincal.data.export import UNKNOWN_VARIANCE, pose_covariance
from skincal.data.result import CalibrationResult, UnitResult
from skincal.errors import ConfigError
from skincal.kinematics.chain import SerialChain
from skincal.kinematics.transforms import FloatArray
from skincal.names import printable
from skincal.perception.config import PerceptionConfig
from skincal.skin.tof import TofModel, get_tof_model

POSE_ORDER = ("x", "y", "z", "rx", "ry", "rz")
"""Order of the 6x6 pose covariance (link axes; m^2 and rad^2)."""


def assumed_pose_covariance(config: PerceptionConfig = PerceptionConfig()) -> FloatArray:
    """``(6, 6)`` diagonal pose covariance assumed for a unit without one (``PerceptionConfig.assumed_*``)."""
    std = np.array([config.assumed_position_std_m] * 3 + [np.radians(config.assumed_rotation_std_deg)] * 3)
    return np.diag(std**2)


def unit_pose_covariance(
    unit: UnitResult | None, config: PerceptionConfig = PerceptionConfig(), name: str = "unit"
) -> FloatArray:
    """``(6, 6)`` pose covariance of a calibrated unit in its link axes (module docstring), m^2 and rad^2.

    From the unit's ``pose_covariance`` or ``position_std_m`` / ``rotation_std_deg``; an axis the
    result leaves undetermined, or a unit without any (``unit`` None or no std), gets the assumed std
    of ``config`` (:func:`assumed_pose_covariance`) there.
    """
    assumed = assumed_pose_covariance(config)
    if unit is None:
        return assumed
    cov, source = pose_covariance(unit, np.eye(3), name)
    if source == "none":
        return assumed
    unknown = np.diag(cov) == UNKNOWN_VARIANCE
    cov = cov.copy()
    cov[unknown, unknown] = np.diag(assumed)[unknown]
    return cov


def _checked_cov(name: str, value: ArrayLike) -> FloatArray:
    where = f"pose covariance of unit '{printable(name)}'"
    try:
        cov = np.array(value, dtype=float)
    except (TypeError, ValueError):
        raise ConfigError(f"{where} must be a 6x6 matrix of numbers") from None
    if cov.shape != (6, 6) or not np.all(np.isfinite(cov)):
        raise ConfigError(f"{where} must be a 6x6 matrix of finite numbers (m^2, rad^2)")
    scale = max(float(np.abs(cov).max()), 1e-300)
    if not np.allclose(cov, cov.T, rtol=0, atol=1e-9 * scale) or np.linalg.eigvalsh(0.5 * (cov + cov.T)).min() < (
        -1e-9 * scale
    ):
        raise ConfigError(f"{where} must be symmetric positive semi-definite")
    return 0.5 * (cov + cov.T)


@dataclass(frozen=True)
class SkinUncertainty:
    """What perception knows about its own errors.

    Attributes:
        pose_cov: unit -> ``(6, 6)`` pose covariance in its link axes (:data:`POSE_ORDER`, m^2 and
            rad^2); units not in it get :func:`assumed_pose_covariance`.
        tof: the ToF sensor model whose noise the readings carry (None: the ``vl53l1x`` preset).
        joint_std_rad: joint-angle noise std, rad (or m for a prismatic joint): a number or ``(n,)``
            (0: the joint states are taken as exact).
    """

    pose_cov: Mapping[str, ArrayLike] = field(default_factory=dict)
    tof: TofModel | None = None
    joint_std_rad: float | ArrayLike = 0.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "pose_cov", {u: _checked_cov(u, c) for u, c in dict(self.pose_cov).items()})
        if self.tof is None:
            object.__setattr__(self, "tof", get_tof_model("vl53l1x"))
        std = np.array(self.joint_std_rad, dtype=float)
        if std.ndim > 1 or not np.all(np.isfinite(std)) or np.any(std < 0):
            raise ConfigError(f"joint_std_rad must be finite non-negative number(s), got {self.joint_std_rad!r}")
        object.__setattr__(self, "joint_std_rad", std)

    @classmethod
    def from_result(
        cls,
        result: CalibrationResult,
        config: PerceptionConfig = PerceptionConfig(),
        tof: TofModel | None = None,
        joint_std_rad: float | ArrayLike = 0.0,
        moved: Iterable[str] = (),
    ) -> SkinUncertainty:
        """The pose covariances of a calibration result's units (:func:`unit_pose_covariance`). Units in
        ``moved`` (flagged as moved since the calibration) get the assumed covariance added."""
        assumed = assumed_pose_covariance(config)
        moved = set(moved)
        cov = {}
        for name, unit in result.units.items():
            c = unit_pose_covariance(unit, config, name)
            cov[name] = c + assumed if name in moved else c
        return cls(cov, tof, joint_std_rad)

    def unit_covariances(self, units: Sequence[str], config: PerceptionConfig = PerceptionConfig()) -> FloatArray:
        """``(U, 6, 6)`` pose covariances of ``units`` in order (assumed where not given)."""
        assumed = assumed_pose_covariance(config)
        if not units:
            return np.zeros((0, 6, 6))
        return np.stack([self.pose_cov.get(u, assumed) for u in units])

    def range_variance(self, ranges: ArrayLike) -> FloatArray:
        """Variance of readings ``ranges`` (m), m^2: the ToF noise at the reading plus the rounding."""
        tof = self.tof
        assert tof is not None
        return tof.noise_std_at(ranges) ** 2 + tof.resolution_m**2 / 12.0

    def joint_covariance(self, n: int) -> FloatArray | None:
        """``(n, n)`` joint-angle covariance, or None when the joints are exact."""
        std = np.broadcast_to(np.asarray(self.joint_std_rad, dtype=float), (n,))
        return np.diag(std**2) if np.any(std > 0) else None


def pose_jacobian(R_base_link: ArrayLike, R_link_su: ArrayLike, ranges: ArrayLike) -> FloatArray:
    """``(K, 3, 7)`` Jacobian of the base-frame point w.r.t. ``(dp, dtheta, dr)`` (module docstring): the
    unit's position and rotation errors in link axes and the range error, for ``K`` readings with
    ``R_base_link``, ``R_link_su`` ``(K, 3, 3)`` and ``ranges`` ``(K,)`` m."""
    R_bl = np.asarray(R_base_link, dtype=float).reshape(-1, 3, 3)
    a = np.asarray(R_link_su, dtype=float).reshape(-1, 3, 3)[:, :, 2]  # the ray in link axes
    u = np.asarray(ranges, dtype=float).reshape(-1, 1) * a  # r a
    K = u.shape[0]
    S = np.zeros((K, 3, 3))  # [u]_x
    S[:, 0, 1], S[:, 0, 2], S[:, 1, 2] = -u[:, 2], u[:, 1], -u[:, 0]
    S[:, 1, 0], S[:, 2, 0], S[:, 2, 1] = u[:, 2], -u[:, 1], u[:, 0]
    J = np.empty((K, 3, 7))
    J[:, :, :3] = R_bl
    J[:, :, 3:6] = -R_bl @ S
    J[:, :, 6] = np.einsum("kij,kj->ki", R_bl, a)
    return J


def point_covariance(
    R_base_link: ArrayLike,
    R_link_su: ArrayLike,
    ranges: ArrayLike,
    pose_cov: ArrayLike,
    range_var: ArrayLike,
    J_q: ArrayLike | None = None,
    joint_cov: ArrayLike | None = None,
) -> FloatArray:
    """``(K, 3, 3)`` base-frame covariance (m^2) of ``K`` readings' points by first-order propagation.

    ``pose_cov`` ``(K, 6, 6)`` (link axes), ``range_var`` ``(K,)`` m^2; with ``J_q`` ``(K, 3, n)`` (the
    points' position Jacobians) and ``joint_cov`` ``(n, n)`` the joint noise is added too.
    """
    J = pose_jacobian(R_base_link, R_link_su, ranges)
    Jp = J[:, :, :6]
    cov = Jp @ np.asarray(pose_cov, dtype=float).reshape(-1, 6, 6) @ np.swapaxes(Jp, 1, 2)
    ray = J[:, :, 6]
    cov += np.asarray(range_var, dtype=float).reshape(-1, 1, 1) * ray[:, :, None] * ray[:, None, :]
    if J_q is not None and joint_cov is not None:
        Jq = np.asarray(J_q, dtype=float)
        cov += Jq @ np.asarray(joint_cov, dtype=float) @ np.swapaxes(Jq, 1, 2)
    return 0.5 * (cov + np.swapaxes(cov, 1, 2))


def reading_covariance(
    chain: SerialChain,
    T_base_link: FloatArray,
    links: ArrayLike,
    R_link_su: ArrayLike,
    ranges: ArrayLike,
    points: ArrayLike,
    pose_cov: ArrayLike,
    uncertainty: SkinUncertainty,
) -> FloatArray:
    """``(K, 3, 3)`` covariance of readings ``ranges`` ``(K,)`` m of units on ``links`` ``(K,)`` (orientations
    ``R_link_su`` ``(K, 3, 3)``, pose covariances ``(K, 6, 6)``) whose points are ``points`` ``(K, 3)``, with the
    robot at ``T_base_link``: ``(n + 1, 4, 4)`` (one configuration) or ``(K, n + 1, 4, 4)``."""
    T = np.asarray(T_base_link, dtype=float)
    links = np.asarray(links, dtype=int).reshape(-1)
    R_bl = T[links, :3, :3] if T.ndim == 3 else T[np.arange(links.size), links, :3, :3]
    r = np.asarray(ranges, dtype=float).reshape(-1)
    joint_cov = uncertainty.joint_covariance(chain.n_joints)
    J_q = None if joint_cov is None else chain.point_jacobians(T, links, points)
    return point_covariance(R_bl, R_link_su, r, pose_cov, uncertainty.range_variance(r), J_q, joint_cov)
