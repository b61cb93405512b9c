"""Mittendorfer & Cheng 2012, registered as ``mm``.

It predicts the dynamic accelerometer reading from the full second difference of the unit's position
as the excited joint moves (:func:`skincal.calib.paper_model.second_difference`) alone, no gravity.
As for ``mmm`` (:mod:`skincal.calib.methods.mmm`), all six parameters are optimised at once on
``E_s + E_d`` with the paper's optimiser (:func:`skincal.calib.paper_opt.run_joint`).
"""

from __future__ import annotations

from skincal.calib.api import MethodSpec, UnitProblem, register
from skincal.calib.paper_opt import PaperOptions, run_joint
from skincal.data.result import UnitResult


def run_mm(problem: UnitProblem) -> UnitResult:
    """Original Mittendorfer: second derivative of the position, no gravity (see module docstring)."""
    return run_joint(problem, "mm")


register("mm", MethodSpec(run_mm, "Mittendorfer 2012: 2nd derivative of position, no gravity", options=PaperOptions))
