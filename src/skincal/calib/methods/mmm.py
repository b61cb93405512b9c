"""The paper's baseline, modified Mittendorfer, registered as ``mmm``.

It predicts the dynamic accelerometer reading as gravity + centripetal + the full second difference
of the unit's position as the excited joint moves (:func:`skincal.calib.paper_model.second_difference`);
the second difference already holds the centripetal part, so it is counted twice (the defect the
paper fixes). As in the authors' implementation, all six parameters are optimised at once on the
summed static and dynamic errors ``E_s + E_d`` (their Mittendorfer optimiser combined both), with
the paper's optimiser, bounds and stopping rules (:func:`skincal.calib.paper_opt.run_joint`).
Deliberate differences: the same as for OM (all dynamic samples, smoothed joint accelerations,
seeded, explicit budget).
"""

from __future__ import annotations

from skincal.calib.api import MethodSpec, UnitProblem, register
from skincal.calib.paper_opt import PaperOptions, run_joint
from skincal.data.result import UnitResult


def run_mmm(problem: UnitProblem) -> UnitResult:
    """Modified Mittendorfer (the paper's baseline, see module docstring)."""
    return run_joint(problem, "mmm")


register(
    "mmm",
    MethodSpec(run_mmm, "paper's baseline: gravity + centripetal + 2nd derivative of position", options=PaperOptions),
)
