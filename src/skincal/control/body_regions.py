"""Body regions of ISO/TS 15066:2016 Annex A for power and force limiting (PFL): one table, cited.

Values per body region (SI units in code; the standard's N/mm for the spring constant):

* ``k``: effective spring constant of the body region, N/m (ISO/TS 15066:2016 Table A.3);
* ``mass``: effective mass of the body region ``m_H``, kg (Table A.3);
* ``quasi_static_force``: largest permissible quasi-static (clamping) contact force, N (Table A.2);
* ``transient_force``: largest permissible transient contact force, N: Table A.2's quasi-static value
  times its transient multiplier 2 (the regions where the standard allows transient contact), None for
  the head regions where transient contact is not permitted (the robot's allowed speed toward them is 0).

The figures are the ones the public summaries of the standard give (ISO/TS 15066:2016 Annex A as summarised:
spring constants, effective masses, the 2x transient forces of one public calculator) and the standard's
quasi-static forces they are twice of. The standard's permissible *pressures* (Table A.2, 29 body
points, N/cm^2) are not in this table: a pressure limit needs the contact area of the robot part, which
the capsule model does not have, and the pressure of each point is not reproduced here (the table is
copyrighted; cite it, check every value against your copy before relying on it).

Transient contact (Annex A, the energy model of a free collision of two masses and a spring)::

    E = F^2 / (2 k) = 1/2 mu v_rel^2,      mu = (1/m_H + 1/m_R)^-1
    v_rel,max = F_max / sqrt(mu k)

(:func:`pfl_speed_limit`, :func:`transfer_energy`, :func:`reduced_mass`), with ``m_R`` the robot's
effective mass at the contact point along the contact normal (:mod:`skincal.control.effective_mass`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from skincal.errors import ConfigError
from skincal.kinematics.transforms import FloatArray

N_PER_MM = 1e3
"""1 N/mm in N/m."""
TRANSIENT_FACTOR = 2.0
"""Table A.2's transient multiplier of the quasi-static force (body regions with transient contact permitted)."""


@dataclass(frozen=True)
class BodyRegion:
    """One body region of ISO/TS 15066:2016 Annex A (module docstring); SI units.

    Attributes:
        name: the key used in scenario files (``hand``, ``forearm``, ...).
        label: the standard's name of the region.
        k: effective spring constant, N/m (Table A.3).
        mass: effective body-part mass ``m_H``, kg (Table A.3).
        quasi_static_force: permissible quasi-static force, N (Table A.2).
        transient_force: permissible transient force, N (2x the quasi-static one), None: transient
            contact not permitted.
    """

    name: str
    label: str
    k: float
    mass: float
    quasi_static_force: float
    transient_force: float | None

    @property
    def transient_energy(self) -> float:
        """Largest permissible transferred energy ``E_max = F_T^2 / (2 k)``, J (0 when not permitted)."""
        return 0.0 if self.transient_force is None else self.transient_force**2 / (2.0 * self.k)


def _region(name: str, label: str, k_n_per_mm: float, mass: float, quasi_static: float, transient: bool):
    return BodyRegion(
        name, label, k_n_per_mm * N_PER_MM, mass, quasi_static, TRANSIENT_FACTOR * quasi_static if transient else None
    )


BODY_REGIONS: dict[str, BodyRegion] = {
    r.name: r
    for r in (
        _region("skull", "skull and forehead", 150, 4.4, 130, False),
        _region("face", "face", 75, 4.4, 65, False),
        _region("neck", "neck (sides)", 50, 1.2, 150, False),
        _region("back", "back and shoulders", 35, 40, 210, True),
        _region("chest", "chest", 25, 40, 140, True),
        _region("belly", "abdomen", 10, 40, 110, True),
        _region("pelvis", "pelvis", 25, 40, 180, True),
        _region("upper_arm", "upper arm and elbow joint", 30, 3.0, 150, True),
        _region("forearm", "lower arm and wrist joint", 40, 2.0, 160, True),
        _region("hand", "hand and fingers", 75, 0.6, 140, True),
        _region("thigh", "thigh and knee", 50, 75, 220, True),
        _region("lower_leg", "lower leg", 60, 75, 130, True),
    )
}
"""ISO/TS 15066:2016 Tables A.2 and A.3 by scenario-file key (module docstring). The neck's transient
contact is treated as not permitted, like the head's (a conservative choice: the public calculator gives
no transient value for it)."""

ALIASES = {"head": "skull", "forehead": "skull", "abdomen": "belly", "lower_arm": "forearm", "shoulder": "back",
           "elbow": "upper_arm", "wrist": "forearm", "fingers": "hand", "knee": "thigh"}  # fmt: skip
"""Other names accepted for a region."""


def body_region(name: str) -> BodyRegion:
    """The region called ``name`` (a key of :data:`BODY_REGIONS` or :data:`ALIASES`); a one-line
    :class:`ConfigError` otherwise."""
    key = ALIASES.get(name, name)
    if key not in BODY_REGIONS:
        known = ", ".join(list(BODY_REGIONS) + list(ALIASES))
        raise ConfigError(f"unknown body region '{name[:40]}' (use {known})")
    return BODY_REGIONS[key]


def reduced_mass(m_human: ArrayLike, m_robot: ArrayLike) -> FloatArray:
    """``mu = (1/m_H + 1/m_R)^-1``, kg (broadcast; an infinite robot mass gives ``m_H``)."""
    m_h = np.asarray(m_human, dtype=float)
    m_r = np.asarray(m_robot, dtype=float)
    return 1.0 / (1.0 / m_h + 1.0 / m_r)


def pfl_speed_limit(region: BodyRegion, m_robot: ArrayLike) -> FloatArray:
    """Largest permissible relative speed of a transient contact, m/s: ``v = F_T / sqrt(mu k)`` with
    ``mu`` :func:`reduced_mass` of the region's mass and the robot's effective mass ``m_robot`` (kg,
    broadcast); 0 where transient contact is not permitted."""
    mu = reduced_mass(region.mass, m_robot)
    if region.transient_force is None:
        return np.zeros_like(mu)
    return region.transient_force / np.sqrt(mu * region.k)


def transfer_energy(region: BodyRegion, m_robot: ArrayLike, speed: ArrayLike) -> FloatArray:
    """Energy transferred by a transient contact at relative ``speed`` (m/s, negative counted as 0), J:
    ``E = 1/2 mu v^2``."""
    v = np.maximum(np.asarray(speed, dtype=float), 0.0)
    return 0.5 * reduced_mass(region.mass, m_robot) * v * v


def contact_force(region: BodyRegion, m_robot: ArrayLike, speed: ArrayLike) -> FloatArray:
    """Peak force of a transient contact at relative ``speed`` (m/s), N: ``F = v sqrt(mu k)`` (from
    ``1/2 mu v^2 = F^2 / (2 k)``)."""
    v = np.maximum(np.asarray(speed, dtype=float), 0.0)
    return v * np.sqrt(reduced_mass(region.mass, m_robot) * region.k)


def simple_robot_mass(moving_mass: float, payload: float = 0.0) -> float:
    """The standard's conservative shortcut for the robot's effective mass, ``m_R = M / 2 + m_L``, kg
    (``M`` the total mass of the moving parts, ``m_L`` the payload)."""
    return 0.5 * float(moving_mass) + float(payload)
