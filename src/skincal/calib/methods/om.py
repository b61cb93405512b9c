"""The paper's method, OM (Sec. III), registered as ``om``.

Per unit on link ``n``, stage 1 fits the rotation ``(theta_v, theta_su, alpha_su)`` to the static
error (paper Eq. 7), stage 2 the position ``(d_v, d_su, a_su)`` to the dynamic error over joints
``n-2..n`` (Eq. 8) with the paper's acceleration model (Eq. 2-6: gravity, centripetal,
finite-difference tangential term). Optimiser, bounds and stopping rules: :mod:`skincal.calib.paper_opt`.
Its unseparated variant is ``om-joint`` (:mod:`skincal.calib.methods.om_joint`).

Deliberate differences from the paper / the authors' code (shared by ``om-joint``, ``mmm``, ``mm``):
every dynamic sample of the three joints is used (strided to ``max_dynamic_samples``), not 4 per
motion; joint accelerations come from the shared preprocessing (Savitzky-Golay, joint states
interpolated to the IMU instants), not noisy differences; starts and MLSL are seeded; MLSL runs
under an explicit evaluation budget instead of an ad-hoc window of parameter changes. A unit on
link 1 is returned but flagged unobservable (its yaw about and offset along the joint-1 axis cannot
be determined); the paper skips it.
"""

from __future__ import annotations

from skincal.calib.api import MethodSpec, UnitProblem, register
from skincal.calib.paper_opt import PaperOptions, fit_two_stage, paper_unit_result, unit_data
from skincal.data.result import UnitResult


def run_om(problem: UnitProblem) -> UnitResult:
    """OM, two stages (see module docstring)."""
    options: PaperOptions = problem.options
    static, dynamic = unit_data(problem, options)
    return paper_unit_result(problem, fit_two_stage(static, dynamic, problem.rng, options))


register(
    "om",
    MethodSpec(run_om, "paper: static rotation then dynamic position, NLopt MLSL-LDS + NEWUOA", options=PaperOptions),
)
