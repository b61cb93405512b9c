"""skincal: self-contained kinematic calibration of robot skin units.

Data flows one way: robot model (``kinematics``) -> sensors (``skin``) -> simulation or
hardware (``sim``, ``hw``) -> dataset (``data``) -> calibration (``calib``) -> perception ->
control. See ``docs/design.md`` for the layout and the conventions used everywhere:
SI units, radians inside, gravity ``[0, 0, -9.81]`` in the base frame, quaternions (w, x, y, z).
"""

from __future__ import annotations

__version__ = "0.1.0"

from skincal.errors import (
    CalibrationError,
    ConfigError,
    DatasetError,
    ProtocolError,
    SkincalError,
)

__all__ = [
    "CalibrationError",
    "ConfigError",
    "DatasetError",
    "ProtocolError",
    "SkincalError",
    "__version__",
]
