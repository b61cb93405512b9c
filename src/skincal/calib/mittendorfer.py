"""The paper's baselines: ``mmm`` (modified Mittendorfer) and ``mm`` (Mittendorfer & Cheng 2012).

Both predict the dynamic accelerometer reading from the second derivative of the unit's position
as the excited joint moves (:func:`skincal.calib.paper_model.second_difference`):

* ``mmm``: gravity + centripetal + the full second difference, which already holds the centripetal
  part, so it is counted twice (the defect the paper fixes);
* ``mm``: the full second difference alone, no gravity.

As in the authors' implementation, all six parameters are optimised at once on the summed static
and dynamic errors ``E_s + E_d`` (their Mittendorfer optimiser combined both), with the paper's
optimiser, bounds and stopping rules (:mod:`skincal.calib.paper_opt`). Deliberate differences: the
same as for OM (all dynamic samples, smoothed joint accelerations, seeded, explicit budget).
"""

from __future__ import annotations

from skincal.calib.api import MethodSpec, UnitProblem, register
from skincal.calib.om import paper_unit_result
from skincal.calib.paper_opt import PaperOptions, fit_joint, unit_data
from skincal.data.result import UnitResult


def _run(problem: UnitProblem, model: str) -> UnitResult:
    options: PaperOptions = problem.options
    static, dynamic = unit_data(problem, options)
    return paper_unit_result(problem, fit_joint(static, dynamic, problem.rng, options, model))


def run_mmm(problem: UnitProblem) -> UnitResult:
    """Modified Mittendorfer (the paper's baseline, see module docstring)."""
    return _run(problem, "mmm")


def run_mm(problem: UnitProblem) -> UnitResult:
    """Original Mittendorfer: second derivative of the position, no gravity (see module docstring)."""
    return _run(problem, "mm")


register(
    "mmm",
    MethodSpec(run_mmm, "paper's baseline: gravity + centripetal + 2nd derivative of position", options=PaperOptions),
)
register("mm", MethodSpec(run_mm, "Mittendorfer 2012: 2nd derivative of position, no gravity", options=PaperOptions))
