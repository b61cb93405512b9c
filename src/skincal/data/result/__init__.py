"""Calibration result files: JSON ``format = "skincal-result"``, ``version = 1`` (``docs/interfaces.md``).

Example::

    {"format": "skincal-result", "version": 1, "method": "mle", "robot": "panda",
     "dataset_sha256": "...", "runtime_s": 0.41,
     "units": {"su1": {"link": 3, "position_m": [0.05, 0.0, 0.12], "quaternion_wxyz": [1, 0, 0, 0],
                       "observable": true, "position_std_m": [1e-5, 1e-5, 2e-5],
                       "rotation_std_deg": [0.01, 0.01, 0.02], "warnings": []}}}

Poses are in link frame ``link`` (a URDF robot's link frame, or DH frame {link}; ``docs/interfaces.md``),
named by ``link_name`` too; quaternions are (w, x, y, z). The IMU calibration of a unit
(``accel_bias_mps2``, ``accel_scale_misalignment``, ``time_offset_s``, ``clock_drift_ppm``,
``gyro_bias_rps``, their std, ...: :data:`~skincal.data.imu_calibration.IMU_KEYS`) is written next to
the contract fields from ``UnitResult.imu`` and read back into it (a unit with none of those fields
gets ``imu = None``; a malformed one is refused).

The facts every method gives have typed fields, under the file's keys (checked on write and read):
``CalibrationResult.failed_units`` (``failed_units``), ``.notes`` (``notes``), ``.events`` (``events``,
:class:`~skincal.data.events.MoveEvent`), ``.reference`` (``reference``); ``UnitResult.link_confidence``,
``.pose_covariance`` (6x6, ``null`` -> NaN), ``.notes``, ``.moved_at_s``. Other fields beyond the
contract (per unit, e.g. ``dh6``; at the top level, e.g. ``seed``) are the method's own: written next to
the contract fields and read back into ``extras`` (which may not hold a typed fact). In extras,
NumPy arrays become JSON lists (non-finite numbers become ``null``) and numeric lists come back as
float64 arrays (``null`` -> NaN). Floats are written with full (round-trip) precision.

Undetermined std components: a NaN component of ``position_std_m`` / ``rotation_std_deg`` is written
as ``null`` and read back as NaN (the other components must be finite and >= 0).

Units without a pose ("never lose a result"): each unit of ``failed_units`` (name -> reason) that is
not in ``units`` is also written under ``units`` as ``{"link": null, "position_m": null,
"quaternion_wxyz": null, "observable": false, "position_std_m": null, "rotation_std_deg": null,
"warnings": [reason]}``; the top-level ``failed_units`` is written as before. On read, a unit entry
with a ``null`` ``position_m`` or ``quaternion_wxyz`` must have ``observable: false``; it is returned
in ``failed_units`` (name -> its warnings joined with ``"; "``), not in ``CalibrationResult.units``,
so every unit in ``units`` has a pose.

Moved units (``docs/interfaces.md``): a top-level ``events`` list and a per-unit ``moved_at_s`` list are
optional; they are checked on write and read (:func:`~skincal.data.events.check_events`).

Relative results (``skincal.calib.imu_only``): a top-level ``reference`` names a unit of ``units``; every
pose is then ``T_ref_su`` in that unit's frame and ``link`` may be 0 (:data:`REFERENCE_LINK`), which
means exactly that; without ``reference``, link 0 is refused as before.

The types and what is asked of them are :mod:`~skincal.data.result.types`, the document and the file
:mod:`~skincal.data.result.codec`; their names are re-exported here.
"""

from __future__ import annotations

from skincal.data.result.codec import read_result, result_from_dict, result_to_dict, sha256_file, write_result
from skincal.data.result.types import (
    EVENTS,
    FAILED_UNITS,
    FORMAT,
    LINK_CONFIDENCE,
    MOVED_AT,
    NOTES,
    POSE_COVARIANCE,
    POSITION_DETERMINED,
    REFERENCE,
    REFERENCE_LINK,
    VERSION,
    CalibrationResult,
    UnitResult,
    check_links,
    check_pose_covariance,
    has_position,
    with_events,
)

__all__ = [
    "CalibrationResult",
    "EVENTS",
    "FAILED_UNITS",
    "FORMAT",
    "LINK_CONFIDENCE",
    "MOVED_AT",
    "NOTES",
    "POSE_COVARIANCE",
    "POSITION_DETERMINED",
    "REFERENCE",
    "REFERENCE_LINK",
    "UnitResult",
    "VERSION",
    "check_links",
    "check_pose_covariance",
    "has_position",
    "read_result",
    "result_from_dict",
    "result_to_dict",
    "sha256_file",
    "with_events",
    "write_result",
]
