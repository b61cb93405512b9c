"""Serial revolute chains described by DH tables, with batched forward and point kinematics.

Frames
------
* Frame {0} is the robot base. Gravity is ``GRAVITY_BASE = [0, 0, -9.81]`` m/s^2 in it.
* Link frame ``i`` (1-based) is DH frame {i}: the product of the first ``i`` DH transforms of the
  chain's convention evaluated at the joint angles. It moves rigidly with joint ``i``.
* Joint ``i`` rotates about the z axis of DH frame {i} in modified (Craig) DH and about the z axis
  of DH frame {i-1} in standard DH.

Arrays: the first axis is samples ``N``; joints are 0-based in arrays (joint ``i`` in user output is
column ``i - 1``). Every function is vectorised over samples; only the joints are looped over.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike

from skincal.errors import ConfigError
from skincal.kinematics.transforms import FloatArray, modified_dh, standard_dh

GRAVITY_BASE = np.array([0.0, 0.0, -9.81])
"""Gravitational acceleration in the base frame {0}, m/s^2."""

CONVENTIONS = ("modified", "standard")


def _as_joint_vector(values: ArrayLike | None, n: int, name: str, chain: str) -> FloatArray | None:
    if values is None:
        return None
    arr = np.asarray(values, dtype=float)
    if arr.shape != (n,):
        raise ConfigError(f"robot '{chain}': {name} must have shape ({n},), got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ConfigError(f"robot '{chain}': {name} contains NaN or infinite values")
    arr.setflags(write=False)
    return arr


@dataclass(frozen=True)
class SerialChain:
    """A serial chain of revolute joints given by a DH table.

    Attributes:
        name: preset name or user label.
        convention: ``"modified"`` (Craig: ``Rx(alpha) Tx(a) Rz(theta + q) Tz(d)``) or
            ``"standard"`` (``Rz(theta + q) Tz(d) Tx(a) Rx(alpha)``).
        dh: ``(n, 4)`` rows ``[theta_offset, d, a, alpha]`` in rad and m.
        joint_lower, joint_upper: ``(n,)`` position limits [rad], optional.
        velocity_limit: ``(n,)`` symmetric joint velocity limits [rad/s], optional.
        T_link_flange: ``(4, 4)`` flange pose in the last link frame (identity when not given).
    """

    name: str
    convention: str
    dh: FloatArray
    joint_lower: FloatArray | None = None
    joint_upper: FloatArray | None = None
    velocity_limit: FloatArray | None = None
    T_link_flange: FloatArray = field(default_factory=lambda: np.eye(4))

    def __post_init__(self) -> None:
        if self.convention not in CONVENTIONS:
            raise ConfigError(
                f"robot '{self.name}': unknown DH convention '{self.convention}' (use 'modified' or 'standard')"
            )
        dh = np.array(self.dh, dtype=float)
        if dh.ndim != 2 or dh.shape[1] != 4:
            raise ConfigError(f"robot '{self.name}': DH table must have shape (n, 4), got {dh.shape}")
        if dh.shape[0] == 0:
            raise ConfigError(f"robot '{self.name}': DH table is empty (a chain needs at least one joint)")
        if not np.all(np.isfinite(dh)):
            raise ConfigError(f"robot '{self.name}': DH table contains NaN or infinite values")
        dh.setflags(write=False)
        object.__setattr__(self, "dh", dh)
        n = dh.shape[0]
        for attr in ("joint_lower", "joint_upper", "velocity_limit"):
            object.__setattr__(self, attr, _as_joint_vector(getattr(self, attr), n, attr, self.name))
        if (self.joint_lower is None) != (self.joint_upper is None):
            raise ConfigError(f"robot '{self.name}': give both joint_lower and joint_upper, or neither")
        if self.joint_lower is not None and np.any(self.joint_lower > self.joint_upper):
            bad = int(np.argmax(self.joint_lower > self.joint_upper)) + 1
            raise ConfigError(f"robot '{self.name}': joint {bad} has lower limit above upper limit")
        if self.velocity_limit is not None and np.any(self.velocity_limit <= 0):
            raise ConfigError(f"robot '{self.name}': velocity limits must be positive")
        T = np.array(self.T_link_flange, dtype=float)
        if T.shape != (4, 4) or not np.all(np.isfinite(T)):
            raise ConfigError(f"robot '{self.name}': T_link_flange must be a finite (4, 4) transform")
        T.setflags(write=False)
        object.__setattr__(self, "T_link_flange", T)

    # ------------------------------------------------------------------ basic facts
    @property
    def n_joints(self) -> int:
        """Number of revolute joints ``n``."""
        return int(self.dh.shape[0])

    def check_q(self, q: ArrayLike, name: str = "q") -> FloatArray:
        """Return ``q`` as a finite ``(N, n)`` array (a ``(n,)`` input becomes ``N = 1``)."""
        arr = np.asarray(q, dtype=float)
        if arr.ndim == 1:
            arr = arr[None, :]
        if arr.ndim != 2 or arr.shape[1] != self.n_joints:
            raise ConfigError(
                f"robot '{self.name}': {name} must have shape (N, {self.n_joints}), got {np.shape(q)}"
            )
        if not np.all(np.isfinite(arr)):
            raise ConfigError(f"robot '{self.name}': {name} contains NaN or infinite values")
        return arr

    # ------------------------------------------------------------------ forward kinematics
    def dh_transforms(self, q: ArrayLike) -> FloatArray:
        """Per-joint DH transforms ``T_{i-1,i}(q_i)``, shape ``(N, n, 4, 4)``."""
        q = self.check_q(q)
        theta = q + self.dh[:, 0]
        step = modified_dh if self.convention == "modified" else standard_dh
        return step(theta, self.dh[:, 1], self.dh[:, 2], self.dh[:, 3])

    def link_frames(self, q: ArrayLike, upto: int | None = None) -> FloatArray:
        """Poses ``T_base_link[i]`` of DH frames {0}..{n}, shape ``(N, n + 1, 4, 4)``.

        ``T_base_link[:, 0]`` is the identity (the base); ``T_base_link[:, i]`` is link frame ``i``.
        ``upto``: compute frames {0}..{upto} only (shape ``(N, upto + 1, 4, 4)``).
        (Stored joint-major so that each frame is a contiguous block; the result is a view.)
        """
        q = self.check_q(q)
        N = q.shape[0]
        n = self.n_joints if upto is None else self.check_link(upto)
        step = modified_dh if self.convention == "modified" else standard_dh
        T = np.empty((n + 1, N, 4, 4))
        T[0] = np.eye(4)
        for i in range(n):
            theta, d, a, alpha = self.dh[i]
            np.matmul(T[i], step(q[:, i] + theta, d, a, alpha), out=T[i + 1])
        return np.moveaxis(T, 0, 1)

    def flange_pose(self, q: ArrayLike) -> FloatArray:
        """``T_base_flange`` of shape ``(N, 4, 4)``."""
        return self.link_frames(q)[:, -1] @ self.T_link_flange

    def joint_axes(self, link_frames: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Points on and unit directions of the joint axes in the base frame.

        Args:
            link_frames: ``(N, n + 1, 4, 4)`` from :meth:`link_frames`.

        Returns:
            ``(c, z)``, each ``(N, n, 3)``: joint ``i`` (0-based) rotates about ``z[:, i]`` through
            ``c[:, i]``: DH frame {i+1}'s origin and z in modified DH, frame {i}'s in standard DH.
        """
        frames = link_frames[:, 1:] if self.convention == "modified" else link_frames[:, :-1]
        return frames[..., :3, 3], frames[..., :3, 2]

    def link_motion(self, q: ArrayLike, qd: ArrayLike, qdd: ArrayLike, upto: int | None = None) -> LinkMotion:
        """Frames, angular and linear velocity/acceleration of every link frame (base frame).

        ``upto``: stop at link ``upto`` (arrays then hold links 0..upto only).

        Recursion over joints ``k = 1..n`` with the joint axis ``z_k`` through ``c_k``::

            w_k     = w_{k-1} + qd_k z_k
            dw_k    = dw_{k-1} + qdd_k z_k + w_{k-1} x (qd_k z_k)
            v(c_k)  = v_{k-1} + w_{k-1} x (c_k - o_{k-1})          (c_k fixed on links k-1 and k)
            a(c_k)  = a_{k-1} + dw_{k-1} x r + w_{k-1} x (w_{k-1} x r),  r = c_k - o_{k-1}
            v_k     = v(c_k) + w_k x (o_k - c_k)
            a_k     = a(c_k) + dw_k x s + w_k x (w_k x s),              s = o_k - c_k

        where ``o_k`` is the origin of link frame k. The base is fixed (all zero).
        """
        q = self.check_q(q)
        qd = self.check_q(qd, "qd")
        qdd = self.check_q(qdd, "qdd")
        if not (q.shape == qd.shape == qdd.shape):
            raise ConfigError(f"robot '{self.name}': q, qd and qdd must have the same shape")
        T = self.link_frames(q, upto)
        N, n = q.shape[0], T.shape[1] - 1
        if self.convention == "modified":
            c, z = T[:, 1:, :3, 3], T[:, 1:, :3, 2]
        else:
            c, z = T[:, :-1, :3, 3], T[:, :-1, :3, 2]
        # Joint-major, contiguous per link; returned as (N, n + 1, 3) views.
        o = np.ascontiguousarray(np.moveaxis(T[..., :3, 3], 1, 0))
        c = np.ascontiguousarray(np.moveaxis(c, 1, 0))
        z = np.ascontiguousarray(np.moveaxis(z, 1, 0))
        w = np.zeros((n + 1, N, 3))
        dw = np.zeros((n + 1, N, 3))
        v = np.zeros((n + 1, N, 3))
        a = np.zeros((n + 1, N, 3))
        for k in range(1, n + 1):
            zk = z[k - 1]
            wz = qd[:, k - 1, None] * zk
            w[k] = w[k - 1] + wz
            dw[k] = dw[k - 1] + qdd[:, k - 1, None] * zk + cross(w[k - 1], wz)
            r = c[k - 1] - o[k - 1]
            s = o[k] - c[k - 1]
            v_c = v[k - 1] + cross(w[k - 1], r)
            a_c = a[k - 1] + cross(dw[k - 1], r) + cross(w[k - 1], cross(w[k - 1], r))
            v[k] = v_c + cross(w[k], s)
            a[k] = a_c + cross(dw[k], s) + cross(w[k], cross(w[k], s))
        w, dw, v, a = (np.moveaxis(x, 0, 1) for x in (w, dw, v, a))
        return LinkMotion(T_base_link=T, omega=w, omega_dot=dw, v_origin=v, a_origin=a)

    def point_jacobian(self, q: ArrayLike, link: int, p_link: ArrayLike) -> FloatArray:
        """Geometric Jacobian ``(N, 6, n)`` of a point fixed to ``link`` (1-based).

        Rows 0-2 map ``qd`` to the point's linear velocity in the base frame, rows 3-5 to the
        link's angular velocity: column ``j < link`` is ``[z_j x (x - c_j); z_j]``, later ones 0.
        ``p_link``: ``(3,)`` or ``(N, 3)`` point in link frame ``link``, m.
        """
        self.check_link(link)
        T = self.link_frames(q)
        c, z = self.joint_axes(T)
        x = transform_points(T[:, link], p_link)
        J = np.zeros((T.shape[0], 6, self.n_joints))
        J[:, :3, :link] = np.swapaxes(np.cross(z[:, :link], x[:, None, :] - c[:, :link]), 1, 2)
        J[:, 3:, :link] = np.swapaxes(z[:, :link], 1, 2)
        return J

    def check_link(self, link: int) -> int:
        """Return ``link`` if it names a moving link ``1..n``, else raise :class:`ConfigError`."""
        if not (isinstance(link, (int, np.integer)) and 1 <= int(link) <= self.n_joints):
            raise ConfigError(f"robot '{self.name}': link must be an integer in 1..{self.n_joints}, got {link!r}")
        return int(link)


@dataclass(frozen=True)
class LinkMotion:
    """Kinematic state of every link frame {0}..{n} in the base frame, arrays ``(N, n + 1, ...)``.

    Attributes:
        T_base_link: ``(N, n+1, 4, 4)`` link frame poses.
        omega: ``(N, n+1, 3)`` angular velocity of each link [rad/s].
        omega_dot: ``(N, n+1, 3)`` angular acceleration [rad/s^2].
        v_origin: ``(N, n+1, 3)`` linear velocity of each link frame origin [m/s].
        a_origin: ``(N, n+1, 3)`` linear acceleration of each link frame origin [m/s^2].
    """

    T_base_link: FloatArray
    omega: FloatArray
    omega_dot: FloatArray
    v_origin: FloatArray
    a_origin: FloatArray

    def point(self, link: int, p_link: ArrayLike) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Position, velocity and acceleration ``(N, 3)`` in the base frame of a point on ``link``.

        ``x = o + R p``, ``v = v_o + w x r``, ``a = a_o + dw x r + w x (w x r)`` with ``r = x - o``.
        ``p_link``: ``(3,)`` or ``(N, 3)`` in link frame ``link`` (1-based; 0 is the base).
        """
        T = self.T_base_link[:, link]
        x = transform_points(T, p_link)
        r = x - T[:, :3, 3]
        w = self.omega[:, link]
        v = self.v_origin[:, link] + cross(w, r)
        a = self.a_origin[:, link] + cross(self.omega_dot[:, link], r) + cross(w, cross(w, r))
        return x, v, a


def cross(a: FloatArray, b: FloatArray) -> FloatArray:
    """Row-wise cross product of ``(..., 3)`` arrays (a lean ``np.cross`` for the hot loops)."""
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    out = np.empty(np.broadcast_shapes(a.shape, b.shape))
    np.subtract(a1 * b2, a2 * b1, out=out[..., 0])
    np.subtract(a2 * b0, a0 * b2, out=out[..., 1])
    np.subtract(a0 * b1, a1 * b0, out=out[..., 2])
    return out


def transform_points(T: FloatArray, p: ArrayLike) -> FloatArray:
    """Apply transforms ``(N, 4, 4)`` to points ``(3,)`` or ``(N, 3)``; returns ``(N, 3)``."""
    p = np.asarray(p, dtype=float)
    return np.einsum("nij,n...j->n...i", T[:, :3, :3], np.broadcast_to(p, (T.shape[0],) + p.shape[-1:])) + T[:, :3, 3]
