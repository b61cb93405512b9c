"""Rigid-body inertia of a link in its link frame, and the sum of rigidly joined bodies.

A :class:`LinkInertial` is the mass, the centre of mass ``c`` and the inertia tensor ``I_c`` about
the centre of mass, all in one frame (a chain's link frame). Bodies fixed to one another are one
body (:func:`combine`): with ``m = sum m_k`` and ``c = sum m_k c_k / m``,

    I_c = sum_k [ R_k I_k R_k^T + m_k (|d_k|^2 E - d_k d_k^T) ],   d_k = c_k - c

(each body's tensor rotated into the common frame, then moved to the common centre of mass by the
parallel-axis theorem). :meth:`LinkInertial.transformed` expresses a body in another frame.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from skincal.errors import ConfigError
from skincal.kinematics.transforms import FloatArray

MAX_MASS_KG = 1e6
"""A link heavier than this (1000 t) is not a robot's: refused like a negative mass (a URDF mass of 1e308
overflowed the sum of a link's parts)."""
MAX_INERTIA_KGM2 = 1e9
"""Likewise for an inertia tensor entry, kg m^2..."""
MAX_COM_M = 1000.0
"""...and a centre of mass beyond 1 km of its link frame (the bound of joint origins)."""
INERTIA_TOLERANCE = 1e-9
"""Relative slack (of the trace) allowed on the eigenvalue and triangle checks: rounding only."""


def tensor_from_six(inertia: ArrayLike) -> FloatArray:
    """The symmetric ``(3, 3)`` tensor of ``[Ixx, Iyy, Izz, Ixy, Ixz, Iyz]``."""
    xx, yy, zz, xy, xz, yz = np.asarray(inertia, dtype=float)
    return np.array([[xx, xy, xz], [xy, yy, yz], [xz, yz, zz]])


def six_from_tensor(tensor: ArrayLike) -> FloatArray:
    """``[Ixx, Iyy, Izz, Ixy, Ixz, Iyz]`` of a ``(3, 3)`` tensor (symmetrised)."""
    t = np.asarray(tensor, dtype=float)
    t = (t + t.T) / 2
    return np.array([t[0, 0], t[1, 1], t[2, 2], t[0, 1], t[0, 2], t[1, 2]])


def inertia_problem(tensor: ArrayLike) -> str | None:
    """Why a ``(3, 3)`` inertia tensor about a centre of mass is not physical, or ``None``:
    finite, symmetric, positive semi-definite, and its principal moments satisfy the triangle
    inequality ``A + B >= C`` (MuJoCo's rule), each to :data:`INERTIA_TOLERANCE` of the trace."""
    t = np.asarray(tensor, dtype=float)
    if t.shape != (3, 3) or not np.all(np.isfinite(t)):
        return "inertia must be 6 finite numbers [Ixx, Iyy, Izz, Ixy, Ixz, Iyz]"
    if np.any(np.abs(t) > MAX_INERTIA_KGM2):
        return f"inertia entries must be within {MAX_INERTIA_KGM2:g} kg m^2"
    slack = INERTIA_TOLERANCE * max(float(np.abs(np.trace(t))), 1e-300)
    if np.any(np.abs(t - t.T) > slack):
        return "inertia tensor must be symmetric"
    moments = np.linalg.eigvalsh((t + t.T) / 2)  # ascending
    if moments[0] < -slack:
        return f"inertia tensor must be positive semi-definite (principal moments {moments.tolist()})"
    if moments[0] + moments[1] < moments[2] - slack:
        return f"principal moments {moments.tolist()} break the triangle inequality A + B >= C"
    return None


@dataclass(frozen=True)
class LinkInertial:
    """Rigid-body inertia of one link, in its link frame (read-only arrays, validated).

    Attributes:
        mass: kg, finite and > 0.
        com: ``(3,)`` centre of mass in the link frame, m.
        inertia: ``(6,)`` ``[Ixx, Iyy, Izz, Ixy, Ixz, Iyz]`` about the CoM, link-frame axes, kg m^2
            (MuJoCo's ``fullinertia`` order); positive semi-definite, triangle inequality
            (:func:`inertia_problem`).
    """

    mass: float
    com: FloatArray
    inertia: FloatArray

    def __post_init__(self) -> None:
        try:
            mass = float(self.mass)
            com = np.array(self.com, dtype=float)
            inertia = np.array(self.inertia, dtype=float)
        except (TypeError, ValueError):
            raise ConfigError("inertial: mass, com and inertia must be numbers") from None
        if not (np.isfinite(mass) and 0 < mass <= MAX_MASS_KG):
            raise ConfigError(f"inertial: mass must be a positive number of kg up to {MAX_MASS_KG:g}, got {mass!r}")
        if com.shape != (3,) or not np.all(np.isfinite(com)) or np.any(np.abs(com) > MAX_COM_M):
            raise ConfigError(f"inertial: com must be 3 finite numbers in m within {MAX_COM_M:g} m (shape {com.shape})")
        if inertia.shape != (6,):
            raise ConfigError(f"inertial: inertia must be [Ixx, Iyy, Izz, Ixy, Ixz, Iyz], got shape {inertia.shape}")
        problem = inertia_problem(tensor_from_six(inertia))
        if problem:
            raise ConfigError(f"inertial: {problem}")
        com.setflags(write=False)
        inertia.setflags(write=False)
        object.__setattr__(self, "mass", mass)
        object.__setattr__(self, "com", com)
        object.__setattr__(self, "inertia", inertia)

    @classmethod
    def from_tensor(cls, mass: float, com: ArrayLike, tensor: ArrayLike) -> LinkInertial:
        """A body of ``mass`` at ``com`` with the ``(3, 3)`` inertia ``tensor`` about its CoM."""
        t = np.asarray(tensor, dtype=float)
        if t.shape != (3, 3):
            raise ConfigError(f"inertial: inertia tensor must be (3, 3), got {t.shape}")
        problem = inertia_problem(t)  # before symmetrising, so an asymmetric tensor is refused
        if problem:
            raise ConfigError(f"inertial: {problem}")
        return cls(mass, np.asarray(com, dtype=float), six_from_tensor(t))

    @property
    def tensor(self) -> FloatArray:
        """``(3, 3)`` inertia tensor about the CoM, link-frame axes."""
        return tensor_from_six(self.inertia)

    def transformed(self, T_new_old: ArrayLike) -> LinkInertial:
        """The same body in another frame: ``T_new_old`` (4, 4) is the pose of this body's frame in
        the new one (``c' = R c + p``, ``I' = R I R^T``)."""
        T = np.asarray(T_new_old, dtype=float)
        R, p = T[:3, :3], T[:3, 3]
        return LinkInertial.from_tensor(self.mass, R @ self.com + p, R @ self.tensor @ R.T)


def combine(parts: Iterable[LinkInertial], poses: Sequence[ArrayLike] | None = None) -> LinkInertial | None:
    """One body of rigidly joined ``parts`` (each in its own frame, placed by ``poses``: (4, 4)
    transforms into the common frame; default all identity), see the module docstring; ``None``
    when there are no parts."""
    parts = list(parts)
    if poses is not None:
        if len(poses) != len(parts):
            raise ConfigError(f"inertial: {len(parts)} parts need {len(parts)} poses, got {len(poses)}")
        parts = [part.transformed(T) for part, T in zip(parts, poses, strict=True)]
    if not parts:
        return None
    if len(parts) == 1:
        return parts[0]
    masses = np.array([p.mass for p in parts])
    coms = np.array([p.com for p in parts])
    mass = float(masses.sum())
    com = masses @ coms / mass
    tensor = np.zeros((3, 3))
    for m, c, part in zip(masses, coms, parts, strict=True):
        d = c - com
        tensor += part.tensor + m * (float(d @ d) * np.eye(3) - np.outer(d, d))
    return LinkInertial.from_tensor(mass, com, tensor)
