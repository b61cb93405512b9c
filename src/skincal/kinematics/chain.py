"""Serial chains of revolute and prismatic joints, with batched forward and point kinematics.

A chain is general: joint ``i`` (1-based) moves link frame ``i`` against link frame ``i - 1`` by

    T_{i-1,i}(q_i) = T_parent_joint[i] @ M(axis[i], q_i) @ T_joint_link[i]

where ``M`` is a rotation by ``q_i`` about the unit ``axis[i]`` (revolute, rad) or a translation by
``q_i`` along it (prismatic, m), ``axis[i]`` given in the joint frame ``T_parent_joint[i]``. A DH
table (:meth:`SerialChain.from_dh`) and a URDF (:mod:`skincal.kinematics.urdf`) are constructors of
it; the DH ``convention`` is kept only to say where the chain came from.

Frames
------
* Frame {0} is the robot base. Gravity is ``GRAVITY_BASE = [0, 0, -9.81]`` m/s^2 in it.
* Link frame ``i`` is the product of the first ``i`` joint transforms above: for a DH chain DH frame
  {i}; for a URDF chain the frame of the child link of the ``i``-th movable joint.
* Modified (Craig) DH ``Rx(alpha) Tx(a) Rz(theta + q) Tz(d)``: ``T_parent_joint = Rx(alpha) Tx(a)
  Rz(theta)``, axis ``z``, ``T_joint_link = Tz(d)``. Standard DH ``Rz(theta + q) Tz(d) Tx(a)
  Rx(alpha)``: ``T_parent_joint = Rz(theta)``, axis ``z``, ``T_joint_link = Tz(d) Tx(a) Rx(alpha)``.

Arrays: the first axis is samples ``N``; joints are 0-based in arrays (joint ``i`` in user output is
column ``i - 1``). Every function is vectorised over samples; only the joints are looped over.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from skincal.errors import ConfigError
from skincal.kinematics.inertia import LinkInertial
from skincal.kinematics.transforms import FloatArray, modified_dh, skew, standard_dh

GRAVITY_BASE = np.array([0.0, 0.0, -9.81])
"""Gravitational acceleration in the base frame {0}, m/s^2."""

CONVENTIONS = ("modified", "standard")
"""DH conventions :meth:`SerialChain.from_dh` accepts."""
REVOLUTE, PRISMATIC = "revolute", "prismatic"
JOINT_TYPES = (REVOLUTE, PRISMATIC)


def _as_joint_vector(
    values: ArrayLike | None, n: int, name: str, chain: str, allow_inf: bool = False
) -> FloatArray | None:
    if values is None:
        return None
    arr = np.array(values, dtype=float)
    if arr.shape != (n,):
        raise ConfigError(f"robot '{chain}': {name} must have shape ({n},), got {arr.shape}")
    if np.any(np.isnan(arr)) or (not allow_inf and not np.all(np.isfinite(arr))):
        raise ConfigError(f"robot '{chain}': {name} contains NaN or infinite values")
    arr.setflags(write=False)
    return arr


MAX_JOINTS = 64
"""Most movable joints of a chain: a 7-joint arm on a 3-joint base has 10, a long snake robot a few tens; a
chain of thousands is a wrong base/tip choice or a hostile file, and every design and fit grows with it."""
MAX_OFFSET_M = 1000.0
"""Largest translation of a joint or flange transform, m: an origin beyond 1 km is a typo (``1e300`` overflowed
in every product of the chain), not an arm."""


def _check_offsets(p: FloatArray, name: str, chain: str, per_joint: bool = True) -> None:
    """Refuse a translation ``p`` ``(n, 3)`` beyond :data:`MAX_OFFSET_M` (``per_joint``: joint ``i`` named, 1-based)."""
    far = np.abs(p).max(axis=1) > MAX_OFFSET_M
    if np.any(far):
        i = int(np.argmax(far))
        which = f"{name} of joint {i + 1}" if per_joint else name
        raise ConfigError(
            f"robot '{chain}': {which} is {np.abs(p[i]).max():.3g} m from its parent "
            f"(more than {MAX_OFFSET_M:g} m: a typo in an origin or a DH length?)"
        )


def _as_transforms(values: ArrayLike, n: int, name: str, chain: str) -> FloatArray:
    T = np.array(values, dtype=float)
    if T.shape != (n, 4, 4) or not np.all(np.isfinite(T)):
        raise ConfigError(f"robot '{chain}': {name} must be finite transforms of shape ({n}, 4, 4), got {T.shape}")
    _check_offsets(T[:, :3, 3], name, chain)
    if not np.allclose(T[:, 3], [0.0, 0.0, 0.0, 1.0], atol=1e-9) or not np.allclose(
        T[:, :3, :3] @ np.swapaxes(T[:, :3, :3], 1, 2), np.eye(3), atol=1e-6
    ):
        raise ConfigError(f"robot '{chain}': {name} must hold rigid transforms (a rotation, last row 0 0 0 1)")
    T.setflags(write=False)
    return T


def _names(values: object, count: int, what: str, chain: str) -> tuple[str, ...] | None:
    if values is None:
        return None
    names = tuple(str(v) for v in values)  # type: ignore[attr-defined]
    if len(names) != count:
        raise ConfigError(f"robot '{chain}': {count} {what} names expected, got {len(names)}")
    if len(set(names)) != len(names):
        raise ConfigError(f"robot '{chain}': {what} names must be distinct")
    return names


@dataclass(frozen=True)
class SerialChain:
    """A serial chain of ``n`` revolute or prismatic joints (see the module docstring).

    Build one with :meth:`from_dh` or :func:`skincal.kinematics.urdf.chain_from_urdf`.

    Attributes:
        name: preset name or user label.
        T_parent_joint: ``(n, 4, 4)`` fixed pose of joint ``i``'s frame in link frame ``i - 1``.
        axis: ``(n, 3)`` unit joint axes, each in its joint frame.
        T_joint_link: ``(n, 4, 4)`` fixed pose of link frame ``i`` in the moved joint frame.
        joint_type: ``n`` of ``"revolute"`` (q in rad) and ``"prismatic"`` (q in m).
        joint_lower, joint_upper: ``(n,)`` position limits [rad or m], optional; ``-inf``/``inf``
            for a continuous joint.
        velocity_limit: ``(n,)`` symmetric joint velocity limits [rad/s or m/s], optional.
        acceleration_limit: ``(n,)`` symmetric joint acceleration limits [rad/s^2 or m/s^2], optional.
        effort_limit: ``(n,)`` joint torque or force limits [N m or N], optional.
        T_link_flange: ``(4, 4)`` flange pose in the last link frame (identity when not given).
        joint_names: ``n`` joint names (default ``joint1`` .. ``jointn``).
        link_names: ``n + 1`` link frame names, the base first (default ``link0`` .. ``linkn``).
        convention: where the chain came from: ``"modified"``/``"standard"`` DH, ``"urdf"``.
        dh: ``(n, 4)`` rows ``[theta_offset, d, a, alpha]`` (rad, m) of a DH chain, else ``None``.
        source: the URDF text of a URDF chain (kept so exports can extend the user's own file).
        inertials: ``n + 1`` link inertials (:class:`~skincal.kinematics.inertia.LinkInertial`, the
            base first) in the link frames, ``None`` for a link without one, or ``None`` when the
            chain has none (a DH chain; a URDF without ``<inertial>``). A URDF chain's come from its
            ``<inertial>`` elements (:mod:`skincal.kinematics.urdf`). Used to build the simulator's
            model in memory (:mod:`skincal.sim.mujoco_model`). The dataset file does not store them
            (a chain read from a dataset has none; a URDF chain's can be rebuilt from its ``source``
            with ``chain_from_urdf(text=...)``), and calibration does not use them.
    """

    name: str
    T_parent_joint: FloatArray
    axis: FloatArray
    T_joint_link: FloatArray
    joint_type: tuple[str, ...] = ()
    joint_lower: FloatArray | None = None
    joint_upper: FloatArray | None = None
    velocity_limit: FloatArray | None = None
    acceleration_limit: FloatArray | None = None
    effort_limit: FloatArray | None = None
    T_link_flange: FloatArray = field(default_factory=lambda: np.eye(4))
    joint_names: tuple[str, ...] | None = None
    link_names: tuple[str, ...] | None = None
    convention: str = "urdf"
    dh: FloatArray | None = None
    source: str | None = field(default=None, repr=False)
    inertials: tuple[LinkInertial | None, ...] | None = field(default=None, repr=False, compare=False)
    _terms: FloatArray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        axis = np.array(self.axis, dtype=float)
        if axis.ndim != 2 or axis.shape[1] != 3:
            raise ConfigError(f"robot '{self.name}': joint axes must have shape (n, 3), got {axis.shape}")
        n = axis.shape[0]
        if n == 0:
            raise ConfigError(f"robot '{self.name}': a chain needs at least one joint")
        if n > MAX_JOINTS:
            raise ConfigError(f"robot '{self.name}': {n} joints in one chain (at most {MAX_JOINTS})")
        norm = np.linalg.norm(axis, axis=1)
        if not np.all(np.isfinite(norm)) or np.any(norm < 1e-9):
            raise ConfigError(f"robot '{self.name}': joint axes must be finite and non-zero")
        if np.any(np.abs(norm - 1.0) > 1e-12):  # (already unit axes are kept bit for bit)
            axis = axis / norm[:, None]
        axis.setflags(write=False)
        object.__setattr__(self, "axis", axis)
        for attr in ("T_parent_joint", "T_joint_link"):
            object.__setattr__(self, attr, _as_transforms(getattr(self, attr), n, attr, self.name))
        types = tuple(self.joint_type) or (REVOLUTE,) * n
        if len(types) != n or any(t not in JOINT_TYPES for t in types):
            raise ConfigError(f"robot '{self.name}': joint_type must be {n} of {JOINT_TYPES}, got {types}")
        object.__setattr__(self, "joint_type", types)
        object.__setattr__(self, "joint_lower", _as_joint_vector(self.joint_lower, n, "joint_lower", self.name, True))
        object.__setattr__(self, "joint_upper", _as_joint_vector(self.joint_upper, n, "joint_upper", self.name, True))
        for attr in ("velocity_limit", "acceleration_limit", "effort_limit"):
            object.__setattr__(self, attr, _as_joint_vector(getattr(self, attr), n, attr, self.name))
        if (self.joint_lower is None) != (self.joint_upper is None):
            raise ConfigError(f"robot '{self.name}': give both joint_lower and joint_upper, or neither")
        if self.joint_lower is not None and np.any(self.joint_lower > self.joint_upper):
            bad = int(np.argmax(self.joint_lower > self.joint_upper)) + 1
            raise ConfigError(f"robot '{self.name}': joint {bad} has lower limit above upper limit")
        for attr in ("velocity_limit", "acceleration_limit", "effort_limit"):
            value = getattr(self, attr)
            if value is not None and np.any(value <= 0):
                raise ConfigError(f"robot '{self.name}': {attr.replace('_', ' ')}s must be positive")
        T = np.array(self.T_link_flange, dtype=float)
        if T.shape != (4, 4) or not np.all(np.isfinite(T)):
            raise ConfigError(f"robot '{self.name}': T_link_flange must be a finite (4, 4) transform")
        _check_offsets(T[None, :3, 3], "T_link_flange", self.name, per_joint=False)
        T.setflags(write=False)
        object.__setattr__(self, "T_link_flange", T)
        object.__setattr__(self, "joint_names", _names(self.joint_names, n, "joint", self.name))
        object.__setattr__(self, "link_names", _names(self.link_names, n + 1, "link", self.name))
        if self.dh is not None:
            dh = np.array(self.dh, dtype=float)
            dh.setflags(write=False)
            object.__setattr__(self, "dh", dh)
        if self.inertials is not None:
            inertials = tuple(self.inertials)
            if len(inertials) != n + 1 or not all(li is None or isinstance(li, LinkInertial) for li in inertials):
                raise ConfigError(f"robot '{self.name}': inertials must be {n + 1} LinkInertial or None (base first)")
            object.__setattr__(self, "inertials", inertials)
        object.__setattr__(self, "_terms", self._joint_terms())

    @classmethod
    def from_dh(
        cls,
        name: str,
        convention: str,
        dh: ArrayLike,
        *,
        joint_lower: ArrayLike | None = None,
        joint_upper: ArrayLike | None = None,
        velocity_limit: ArrayLike | None = None,
        acceleration_limit: ArrayLike | None = None,
        effort_limit: ArrayLike | None = None,
        T_link_flange: ArrayLike | None = None,
        joint_names: tuple[str, ...] | None = None,
        link_names: tuple[str, ...] | None = None,
    ) -> SerialChain:
        """A revolute chain from a DH table ``(n, 4)`` of rows ``[theta_offset, d, a, alpha]`` (rad,
        m) in the ``"modified"`` (Craig) or ``"standard"`` convention (see the module docstring)."""
        if convention not in CONVENTIONS:
            raise ConfigError(f"robot '{name}': unknown DH convention '{convention}' (use 'modified' or 'standard')")
        table = np.array(dh, dtype=float)
        if table.ndim != 2 or table.shape[1] != 4:
            raise ConfigError(f"robot '{name}': DH table must have shape (n, 4), got {table.shape}")
        if table.shape[0] == 0:
            raise ConfigError(f"robot '{name}': DH table is empty (a chain needs at least one joint)")
        if not np.all(np.isfinite(table)):
            raise ConfigError(f"robot '{name}': DH table contains NaN or infinite values")
        theta, d, a, alpha = table.T
        zero = np.zeros_like(theta)
        if convention == "modified":
            before, after = modified_dh(theta, zero, a, alpha), modified_dh(zero, d, zero, zero)
        else:
            before, after = standard_dh(theta, zero, zero, zero), standard_dh(zero, d, a, alpha)
        return cls(
            name=name,
            T_parent_joint=before,
            axis=np.tile([0.0, 0.0, 1.0], (table.shape[0], 1)),
            T_joint_link=after,
            joint_lower=joint_lower,
            joint_upper=joint_upper,
            velocity_limit=velocity_limit,
            acceleration_limit=acceleration_limit,
            effort_limit=effort_limit,
            T_link_flange=np.eye(4) if T_link_flange is None else T_link_flange,
            joint_names=joint_names,
            link_names=link_names,
            convention=convention,
            dh=table,
        )

    def _joint_terms(self) -> FloatArray:
        """``(n, 3, 4, 4)`` fixed matrices ``C`` with ``T_{i-1,i}(q) = C0 + s C1 + (1 - c) C2`` for a
        revolute joint (``s, c = sin q, cos q``; Rodrigues: ``M = I + s K + (1 - c) K^2``, ``K`` the
        axis' cross-product matrix) and ``T_{i-1,i}(q) = C0 + q C1`` for a prismatic one."""
        n = self.n_joints
        C = np.zeros((n, 3, 4, 4))
        for i in range(n):
            A, B, u = self.T_parent_joint[i], self.T_joint_link[i], self.axis[i]
            C[i, 0] = A @ B
            if self.joint_type[i] == REVOLUTE:
                K = np.zeros((4, 4))
                K[:3, :3] = skew(u)
                C[i, 1] = A @ K @ B
                C[i, 2] = A @ K @ K @ B
            else:
                E = np.zeros((4, 4))
                E[:3, 3] = u
                C[i, 1] = A @ E @ B
        C.setflags(write=False)
        return C

    # ------------------------------------------------------------------ basic facts
    @property
    def n_joints(self) -> int:
        """Number of joints ``n``."""
        return int(self.axis.shape[0])

    @property
    def revolute(self) -> NDArray[np.bool_]:
        """``(n,)`` True where the joint is revolute."""
        return np.array([t == REVOLUTE for t in self.joint_type])

    @property
    def described_by(self) -> str:
        """Where the chain came from, for people: ``"URDF"``, ``"modified DH"`` or ``"standard DH"``."""
        return "URDF" if self.dh is None else f"{self.convention} DH"

    def same_motion(self, other: SerialChain, atol: float = 1e-9) -> bool:
        """True when ``other`` moves every link frame as this chain does (same joint count and types,
        link frames equal to ``atol`` at a spread of configurations), whatever its name or origin."""
        if other.n_joints != self.n_joints or other.joint_type != self.joint_type:
            return False
        q = np.linspace(-1.0, 1.0, 3 * self.n_joints).reshape(3, self.n_joints)
        return bool(np.allclose(self.link_frames(q), other.link_frames(q), atol=atol))

    def link_name(self, link: int) -> str:
        """Name of link frame ``link`` (0 = base): the URDF link name, else ``link<i>``."""
        return self.link_names[link] if self.link_names is not None else f"link{link}"

    def joint_name(self, joint: int) -> str:
        """Name of joint ``joint`` (1-based): the URDF joint name, else ``joint<i>``."""
        return self.joint_names[joint - 1] if self.joint_names is not None else f"joint{joint}"

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
    def _step(self, i: int, qi: FloatArray) -> FloatArray:
        """``T_{i,i+1}(q)`` of 0-based joint ``i`` for ``(N,)`` values, ``(N, 4, 4)``."""
        C = self._terms[i]
        if self.joint_type[i] == REVOLUTE:
            return C[0] + np.sin(qi)[:, None, None] * C[1] + (1.0 - np.cos(qi))[:, None, None] * C[2]
        return C[0] + qi[:, None, None] * C[1]

    def joint_transforms(self, q: ArrayLike) -> FloatArray:
        """Per-joint transforms ``T_{i-1,i}(q_i)``, shape ``(N, n, 4, 4)`` (all joints at once)."""
        q = self.check_q(q)
        rev = self.revolute
        first = np.where(rev, np.sin(q), q)[..., None, None]
        second = np.where(rev, 1.0 - np.cos(q), 0.0)[..., None, None]
        C = self._terms
        return C[:, 0] + first * C[:, 1] + second * C[:, 2]

    def link_frames(self, q: ArrayLike, upto: int | None = None) -> FloatArray:
        """Poses ``T_base_link[i]`` of link frames {0}..{n}, shape ``(N, n + 1, 4, 4)``.

        ``T_base_link[:, 0]`` is the identity (the base); ``T_base_link[:, i]`` is link frame ``i``.
        ``upto``: compute frames {0}..{upto} only (shape ``(N, upto + 1, 4, 4)``).
        (Stored joint-major so that each frame is a contiguous block; the result is a view.)
        """
        q = self.check_q(q)
        N = q.shape[0]
        n = self.n_joints if upto is None else self.check_link(upto)
        T = np.empty((n + 1, N, 4, 4))
        T[0] = np.eye(4)
        for i in range(n):
            np.matmul(T[i], self._step(i, q[:, i]), out=T[i + 1])
        return np.moveaxis(T, 0, 1)

    def flange_pose(self, q: ArrayLike) -> FloatArray:
        """``T_base_flange`` of shape ``(N, 4, 4)``."""
        return self.link_frames(q)[:, -1] @ self.T_link_flange

    def joint_axes(self, link_frames: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Points on and unit directions of the joint axes in the base frame.

        Args:
            link_frames: ``(N, m + 1, 4, 4)`` from :meth:`link_frames` (``m <= n``).

        Returns:
            ``(c, z)``, each ``(N, m, 3)``: joint ``i`` (0-based) moves along or about ``z[:, i]``
            through ``c[:, i]``, the origin of its joint frame ``T_base_link[i] T_parent_joint[i]``.
        """
        m = link_frames.shape[1] - 1
        P = self.T_parent_joint[:m]
        R_prev = link_frames[:, :-1, :3, :3]
        c = np.einsum("nkij,kj->nki", R_prev, P[:, :3, 3]) + link_frames[:, :-1, :3, 3]
        z = np.einsum("nkij,kj->nki", R_prev, np.einsum("kij,kj->ki", P[:, :3, :3], self.axis[:m]))
        return c, z

    def link_motion(self, q: ArrayLike, qd: ArrayLike, qdd: ArrayLike, upto: int | None = None) -> LinkMotion:
        """Frames, angular and linear velocity/acceleration of every link frame (base frame).

        ``upto``: stop at link ``upto`` (arrays then hold links 0..upto only).

        Recursion over joints ``k = 1..n`` with the joint axis ``z_k`` through ``c_k``; for a
        revolute joint::

            w_k     = w_{k-1} + qd_k z_k
            dw_k    = dw_{k-1} + qdd_k z_k + w_{k-1} x (qd_k z_k)
            v(c_k)  = v_{k-1} + w_{k-1} x (c_k - o_{k-1})          (c_k fixed on links k-1 and k)
            a(c_k)  = a_{k-1} + dw_{k-1} x r + w_{k-1} x (w_{k-1} x r),  r = c_k - o_{k-1}
            v_k     = v(c_k) + w_k x (o_k - c_k)
            a_k     = a(c_k) + dw_k x s + w_k x (w_k x s),              s = o_k - c_k

        and for a prismatic one (link k slides along ``z_k`` relative to link k-1)::

            w_k = w_{k-1},  dw_k = dw_{k-1},  r = o_k - o_{k-1}
            v_k = v_{k-1} + w_{k-1} x r + qd_k z_k
            a_k = a_{k-1} + dw_{k-1} x r + w_{k-1} x (w_{k-1} x r) + qdd_k z_k + 2 w_{k-1} x (qd_k z_k)

        where ``o_k`` is the origin of link frame k. The base is fixed (all zero).
        """
        q = self.check_q(q)
        qd = self.check_q(qd, "qd")
        qdd = self.check_q(qdd, "qdd")
        if not (q.shape == qd.shape == qdd.shape):
            raise ConfigError(f"robot '{self.name}': q, qd and qdd must have the same shape")
        T = self.link_frames(q, upto)
        N, n = q.shape[0], T.shape[1] - 1
        c, z = self.joint_axes(T)
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
            if self.joint_type[k - 1] == PRISMATIC:
                r = o[k] - o[k - 1]
                slide = qd[:, k - 1, None] * zk
                w[k], dw[k] = w[k - 1], dw[k - 1]
                v[k] = v[k - 1] + cross(w[k - 1], r) + slide
                a[k] = (
                    a[k - 1] + cross(dw[k - 1], r) + cross(w[k - 1], cross(w[k - 1], r))
                    + qdd[:, k - 1, None] * zk + 2.0 * cross(w[k - 1], slide)
                )
                continue
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
        link's angular velocity: column ``j < link`` is ``[z_j x (x - c_j); z_j]`` for a revolute
        joint and ``[z_j; 0]`` for a prismatic one, later columns 0.
        ``p_link``: ``(3,)`` or ``(N, 3)`` point in link frame ``link``, m.
        """
        self.check_link(link)
        T = self.link_frames(q)
        c, z = self.joint_axes(T)
        x = transform_points(T[:, link], p_link)
        J = np.zeros((T.shape[0], 6, self.n_joints))
        rev = self.revolute[:link]
        J[:, :3, :link] = np.swapaxes(self._linear_columns(c[:, :link], z[:, :link], x[:, None, :]), 1, 2)
        J[:, 3:, :link] = np.swapaxes(np.where(rev[None, :, None], z[:, :link], 0.0), 1, 2)
        return J

    def point_jacobians(self, T_base_link: FloatArray, links: ArrayLike, p_base: ArrayLike) -> FloatArray:
        """Position Jacobians ``(K, 3, n)`` of points ``p_base`` ``(K, 3)`` (base frame, m) fixed to ``links`` ``(K,)``.

        The linear rows of :meth:`point_jacobian` for many points on any links at known frames: column
        ``j`` (0-based) of a point ``x`` on link ``l`` is ``z_j x (x - c_j)`` for a revolute joint and
        ``z_j`` for a prismatic one when ``j < l``, 0 otherwise, with joint axis ``z_j`` through ``c_j``
        (:meth:`joint_axes`); a point on the base (link 0) has a zero Jacobian. ``T_base_link``:
        ``(n + 1, 4, 4)`` at one configuration, or ``(K, n + 1, 4, 4)``: each point at its own configuration.
        """
        T = np.asarray(T_base_link)
        p = np.asarray(p_base, dtype=float).reshape(-1, 3)
        links = np.asarray(links, dtype=int).reshape(-1)
        if T.ndim == 4:
            c, z = self.joint_axes(T)  # (K, n, 3)
        else:
            c, z = self.joint_axes(T[None])
            c, z = c[0][None], z[0][None]  # (1, n, 3)
        cols = self._linear_columns(c, z, p[:, None, :])  # (K, n, 3)
        mask = np.arange(self.n_joints)[None, :] < links[:, None]
        return np.swapaxes(cols * mask[..., None], 1, 2)

    def _linear_columns(self, c: FloatArray, z: FloatArray, x: FloatArray) -> FloatArray:
        """``(..., m, 3)`` linear Jacobian columns of points ``x`` ``(..., 1, 3)`` for joints ``0..m-1``
        (axes ``z`` through ``c``, ``(..., m, 3)``): ``z_j x (x - c_j)`` if revolute, ``z_j`` if prismatic."""
        m = c.shape[-2]
        lin = cross(z, x - c)
        if self.revolute[:m].all():
            return lin
        return np.where(self.revolute[:m, None], lin, np.broadcast_to(z, lin.shape))

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
