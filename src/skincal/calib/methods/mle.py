"""The default calibrator, registered as ``mle``.

Global time alignment, a closed-form start and a robust joint maximum likelihood of a unit's pose,
its IMU errors and its clock, with residual tests. The engine is the package
:mod:`skincal.calib.mle` (per-unit flow and honesty tests in :mod:`skincal.calib.mle.method`); this
module only registers it.
"""

from __future__ import annotations

from skincal.calib.api import MethodSpec, register
from skincal.calib.mle.method import MleOptions, run_unit
from skincal.calib.mle.problem import align, prepare

register(
    "mle",
    MethodSpec(
        run_unit=run_unit,
        description="global time alignment + closed-form start + robust joint maximum likelihood "
        "(pose, IMU errors, clock) with residual tests",
        discovers_links=True,
        use_gyro_for_links=True,
        prepare=prepare,
        exact_joint_states=False,
        align=align,
        needs_segments=False,
        options=MleOptions,
    ),
)
