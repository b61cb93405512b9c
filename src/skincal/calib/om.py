"""The paper's method, OM (Sec. III), and its unseparated variant, registered as ``om`` and ``om-joint``.

* ``om``: per unit on link ``n``, stage 1 fits the rotation ``(theta_v, theta_su, alpha_su)`` to the
  static error (paper Eq. 7), stage 2 the position ``(d_v, d_su, a_su)`` to the dynamic error over
  joints ``n-2..n`` (Eq. 8) with the paper's acceleration model (Eq. 2-6: gravity, centripetal,
  finite-difference tangential term). Optimiser, bounds and stopping rules: :mod:`skincal.calib.paper_opt`.
* ``om-joint``: the same model, all six parameters at once on ``E_s + E_d`` (the paper's "original
  problem", reported 4x slower).

Deliberate differences from the paper / the authors' code: every dynamic sample of the three joints
is used (strided to ``max_dynamic_samples``), not 4 per motion; joint accelerations come from the
shared preprocessing (Savitzky-Golay, joint states interpolated to the IMU instants), not noisy
differences; starts and MLSL are seeded; MLSL runs under an explicit evaluation budget instead of an
ad-hoc window of parameter changes. A unit on link 1 is returned but flagged unobservable (its yaw
about and offset along the joint-1 axis cannot be determined); the paper skips it.
"""

from __future__ import annotations

from skincal.calib.api import MethodSpec, UnitProblem, register
from skincal.calib.paper_opt import Fit, PaperOptions, fit_joint, fit_two_stage, unit_data
from skincal.data.result import UnitResult
from skincal.skin.pose import SkinUnitPose

POOR_STATIC_FIT = 0.05
"""Static error above which a unit gets a warning, (m/s^2)^2 (about 1.3 deg of tilt at 1 g)."""


def paper_unit_result(problem: UnitProblem, fit: Fit) -> UnitResult:
    """Wrap a fit as a :class:`UnitResult` with the paper's parameters and errors in ``extras``."""
    warnings: list[str] = []
    if problem.link_assignment is not None:
        warnings.extend(problem.link_assignment.warnings)
    observable = problem.link > 1
    if not observable:
        warnings.append("on link 1: yaw about and offset along the joint-1 axis are not observable")
    if fit.static_error > POOR_STATIC_FIT:
        warnings.append(f"poor static fit: E_s = {fit.static_error:.3g} (m/s^2)^2")
    extras = {
        "dh6": fit.params,
        "static_error": fit.static_error,
        "dynamic_error": fit.dynamic_error,
        "n_evals": sum(fit.n_evals.values()),
        "n_evals_per_stage": dict(fit.n_evals),
        "nlopt_status": dict(fit.status),
    }
    return UnitResult(
        pose=SkinUnitPose.from_dh6(problem.link, fit.params),
        observable=observable,
        warnings=tuple(warnings),
        extras=extras,
        link_confidence=None if problem.link_assignment is None else problem.link_assignment.confidence,
    )


def run_om(problem: UnitProblem) -> UnitResult:
    """OM, two stages (see module docstring)."""
    options: PaperOptions = problem.options
    static, dynamic = unit_data(problem, options)
    return paper_unit_result(problem, fit_two_stage(static, dynamic, problem.rng, options))


def run_om_joint(problem: UnitProblem) -> UnitResult:
    """OM's model with all six parameters optimised at once (see module docstring)."""
    options: PaperOptions = problem.options
    static, dynamic = unit_data(problem, options)
    return paper_unit_result(problem, fit_joint(static, dynamic, problem.rng, options, "om"))


register(
    "om",
    MethodSpec(run_om, "paper: static rotation then dynamic position, NLopt MLSL-LDS + NEWUOA", options=PaperOptions),
)
register(
    "om-joint",
    MethodSpec(run_om_joint, "paper's unseparated variant: all 6 parameters on E_s + E_d", options=PaperOptions),
)
