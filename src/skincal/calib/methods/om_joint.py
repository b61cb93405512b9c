"""The paper's unseparated variant of OM, registered as ``om-joint``.

OM's model (:mod:`skincal.calib.methods.om`) with all six parameters optimised at once on
``E_s + E_d`` (the paper's "original problem", reported 4x slower): :func:`skincal.calib.paper_opt.run_joint`
with the dynamic model ``om``. Deliberate differences from the paper: as for ``om``.
"""

from __future__ import annotations

from skincal.calib.api import MethodSpec, UnitProblem, register
from skincal.calib.paper_opt import PaperOptions, run_joint
from skincal.data.result import UnitResult


def run_om_joint(problem: UnitProblem) -> UnitResult:
    """OM's model with all six parameters optimised at once (see module docstring)."""
    return run_joint(problem, "om")


register(
    "om-joint",
    MethodSpec(run_om_joint, "paper's unseparated variant: all 6 parameters on E_s + E_d", options=PaperOptions),
)
