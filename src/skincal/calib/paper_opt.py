"""The paper's optimiser (Sec. IV): NLopt ``G_MLSL_LDS`` global search with ``LN_NEWUOA`` local searches.

Shared by the paper's method (two stages, :func:`fit_two_stage`) and by the joint problems
(all six parameters at once on ``E_s + E_d``, :func:`fit_joint`: the paper's "unseparated" variant
and the Mittendorfer baselines), and the one wrapping of a fit as a unit result
(:func:`paper_unit_result`) for the methods ``om``, ``om-joint``, ``mmm`` and ``mm``
(:mod:`skincal.calib.methods`). Parameters follow paper Eq. 1 in the authors' order
``[theta_v, d_v, theta_su, d_su, a_su, alpha_su]`` (rad, m).

Settings (:class:`PaperOptions`, all overridable through ``calibrate(..., **options)``):

* bounds (paper Sec. IV): ``theta in [-pi, pi]``, ``d in [-1, 1]`` m, ``a in [0, 1]`` m,
  ``alpha in [-pi, pi]``; the start point is drawn uniformly within them from the unit's ``rng``.
  ``LN_NEWUOA`` itself is unconstrained in NLopt (bounds only shape the global sampling), as the
  paper chose on purpose.
* stopping (paper Sec. IV): the search stops when the static error drops below ``stopval = 0.01``
  (m/s^2)^2 (for the joint problems: the summed error), and each local search when its parameter
  step is below ``xtol = 1e-3``. MLSL itself has no convergence test, so every stage also has an
  evaluation budget (``maxeval_*``) and optionally a time budget (``maxtime_s``); these replace the
  authors' ad-hoc window of parameter changes.
* data: all static segments; the dynamic samples of joints ``n-2..n``, evenly strided down to at
  most ``max_dynamic_samples`` (default 3000, i.e. about every 5th sample at 100 Hz with the paper-sim
  protocol) for speed. The authors used 4 samples per joint motion, a known defect we do not copy.
* seed: ``nlopt.srand`` gets an integer drawn from the unit's ``rng`` (NLopt's generator is
  process-global: concurrent runs in threads of one process are not reproducible; processes are).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import nlopt
import numpy as np

from skincal.calib.api import UnitProblem
from skincal.calib.paper_model import (
    DynamicData,
    StaticData,
    dynamic_data,
    dynamic_error,
    rotation_from_angles,
    static_data,
    static_error,
)
from skincal.data.result import UnitResult
from skincal.kinematics.transforms import FloatArray
from skincal.skin.pose import SkinUnitPose, dh6_to_transform

LOWER = np.array([-np.pi, -1.0, -np.pi, -1.0, 0.0, -np.pi])
"""Lower bounds of ``[theta_v, d_v, theta_su, d_su, a_su, alpha_su]`` (rad, m), paper Sec. IV."""
UPPER = np.array([np.pi, 1.0, np.pi, 1.0, 1.0, np.pi])
"""Upper bounds, paper Sec. IV."""
ROTATION_INDEX = np.array([0, 2, 5])
"""Indices of the rotational parameters ``theta_v, theta_su, alpha_su`` (stage 1)."""
POSITION_INDEX = np.array([1, 3, 4])
"""Indices of the positional parameters ``d_v, d_su, a_su`` (stage 2)."""


_NON_NEGATIVE = {"min": 0}


@dataclass(frozen=True)
class PaperOptions:
    """Optimiser settings of the paper's methods (see module docstring; units as named).

    Attributes:
        stopval: stop when the static error (joint problems: the summed error) is below, (m/s^2)^2.
        xtol: local searches stop when the parameter step is below this (rad or m).
        maxeval_static, maxeval_dynamic: evaluation budgets of OM's two stages.
        maxeval_joint: evaluation budget of the six-parameter problems.
        maxtime_s: optional wall-time budget per stage, s (0 = none).
        max_dynamic_samples: at most this many dynamic samples (0 = all).
        population: MLSL sample points per iteration (0 = NLopt's default).
    """

    stopval: float = field(default=0.01, metadata=_NON_NEGATIVE)
    xtol: float = field(default=1e-3, metadata=_NON_NEGATIVE)
    maxeval_static: int = field(default=2000, metadata=_NON_NEGATIVE)
    maxeval_dynamic: int = field(default=2000, metadata=_NON_NEGATIVE)
    maxeval_joint: int = field(default=6000, metadata=_NON_NEGATIVE)
    maxtime_s: float = field(default=0.0, metadata=_NON_NEGATIVE)
    max_dynamic_samples: int = field(default=3000, metadata=_NON_NEGATIVE)
    population: int = field(default=0, metadata=_NON_NEGATIVE)


@dataclass(frozen=True)
class Minimum:
    """Outcome of one MLSL search: best point, its value, evaluations used and NLopt's result code."""

    x: FloatArray
    value: float
    n_evals: int
    status: int


def minimize_mlsl(
    f: Callable[[FloatArray], float],
    lower: FloatArray,
    upper: FloatArray,
    x0: FloatArray,
    *,
    seed: int,
    options: PaperOptions,
    maxeval: int,
    stopval: float | None,
) -> Minimum:
    """Minimise ``f`` with ``G_MLSL_LDS`` + ``LN_NEWUOA`` (local ``xtol_abs = options.xtol``)."""
    n = len(x0)
    count = [0]
    best = [np.inf, np.array(x0, dtype=float)]

    def objective(x: FloatArray, grad: FloatArray) -> float:
        count[0] += 1
        value = float(f(x))
        if not np.isfinite(value):
            return 1e30
        if value < best[0]:
            best[0], best[1] = value, np.array(x)
        return value

    local = nlopt.opt(nlopt.LN_NEWUOA, n)
    local.set_xtol_abs(options.xtol)
    opt = nlopt.opt(nlopt.G_MLSL_LDS, n)
    opt.set_local_optimizer(local)
    opt.set_lower_bounds(lower)
    opt.set_upper_bounds(upper)
    opt.set_min_objective(objective)
    opt.set_maxeval(int(maxeval))
    if options.maxtime_s > 0:
        opt.set_maxtime(options.maxtime_s)
    if stopval is not None and stopval > 0:
        opt.set_stopval(stopval)
    if options.population > 0:
        opt.set_population(int(options.population))
    nlopt.srand(int(seed))
    try:
        opt.optimize(np.clip(x0, lower, upper))
        status = int(opt.last_optimize_result())
    except nlopt.RoundoffLimited:  # the best point so far stands (NLopt's documented meaning)
        status = int(nlopt.ROUNDOFF_LIMITED)
    except RuntimeError as exc:  # NLopt's generic failure; anything else (our objective) propagates
        if not str(exc).startswith("nlopt"):
            raise
        status = int(nlopt.FAILURE)
    return Minimum(x=best[1], value=float(best[0]), n_evals=count[0], status=status)


def position_from_params(params: FloatArray) -> FloatArray:
    """Unit position ``p_link_su`` ``(3,)`` m from the six parameters (paper Eq. 1)."""
    return dh6_to_transform(params)[:3, 3]


@dataclass(frozen=True)
class Fit:
    """Six fitted parameters with their errors and the evaluations spent per stage."""

    params: FloatArray
    static_error: float
    dynamic_error: float
    n_evals: dict[str, int]
    status: dict[str, int]


def _draw(rng: np.random.Generator) -> tuple[FloatArray, int]:
    x0 = rng.uniform(LOWER, UPPER)
    return x0, int(rng.integers(1, 2**31 - 1))


def fit_two_stage(static: StaticData, dynamic: DynamicData, rng: np.random.Generator, options: PaperOptions) -> Fit:
    """The paper's method (Sec. III-C): stage 1 fits ``theta_v, theta_su, alpha_su`` to ``E_s``
    (Eq. 7); stage 2 fits ``d_v, d_su, a_su`` to ``E_d`` (Eq. 8, model ``om``) with the rotation fixed."""
    x0, seed = _draw(rng)
    params = x0.copy()

    def f_static(xr: FloatArray) -> float:
        return static_error(rotation_from_angles(xr[0], xr[1], xr[2]), static)

    s1 = minimize_mlsl(
        f_static, LOWER[ROTATION_INDEX], UPPER[ROTATION_INDEX], x0[ROTATION_INDEX],
        seed=seed, options=options, maxeval=options.maxeval_static, stopval=options.stopval,
    )
    params[ROTATION_INDEX] = s1.x
    R = rotation_from_angles(s1.x[0], s1.x[1], s1.x[2])

    def f_dynamic(xp: FloatArray) -> float:
        p = params.copy()
        p[POSITION_INDEX] = xp
        return dynamic_error(R, position_from_params(p), dynamic, "om")

    s2 = minimize_mlsl(
        f_dynamic, LOWER[POSITION_INDEX], UPPER[POSITION_INDEX], x0[POSITION_INDEX],
        seed=seed + 1, options=options, maxeval=options.maxeval_dynamic, stopval=None,
    )
    params[POSITION_INDEX] = s2.x
    return Fit(
        params=params,
        static_error=s1.value,
        dynamic_error=s2.value,
        n_evals={"static": s1.n_evals, "dynamic": s2.n_evals},
        status={"static": s1.status, "dynamic": s2.status},
    )


def fit_joint(
    static: StaticData, dynamic: DynamicData, rng: np.random.Generator, options: PaperOptions, model: str
) -> Fit:
    """All six parameters at once on ``E_s + E_d`` with the dynamic ``model`` (``om``: the paper's
    unseparated variant; ``mmm``/``mm``: the baselines, as the authors optimised them)."""
    x0, seed = _draw(rng)

    def split(x: FloatArray) -> tuple[FloatArray, FloatArray]:
        return rotation_from_angles(x[0], x[2], x[5]), position_from_params(x)

    def f_joint(x: FloatArray) -> float:
        R, p = split(x)
        return static_error(R, static) + dynamic_error(R, p, dynamic, model)

    m = minimize_mlsl(
        f_joint, LOWER, UPPER, x0, seed=seed, options=options, maxeval=options.maxeval_joint, stopval=options.stopval
    )
    R, p = split(m.x)
    return Fit(
        params=m.x,
        static_error=static_error(R, static),
        dynamic_error=dynamic_error(R, p, dynamic, model),
        n_evals={"joint": m.n_evals},
        status={"joint": m.status},
    )


def unit_data(problem: Any, options: PaperOptions) -> tuple[StaticData, DynamicData]:
    """Static and dynamic data of a :class:`skincal.calib.api.UnitProblem`."""
    cap = options.max_dynamic_samples or None
    st = static_data(problem.chain, problem.samples, problem.link, problem.gravity)
    dy = dynamic_data(problem.chain, problem.samples, problem.link, problem.gravity, max_samples=cap)
    return st, dy


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


def run_joint(problem: UnitProblem, model: str) -> UnitResult:
    """A unit calibrated with all six parameters at once on ``E_s + E_d`` under the dynamic ``model``
    (:func:`fit_joint`; ``om`` for ``om-joint``, ``mmm``, ``mm``)."""
    options: PaperOptions = problem.options
    static, dynamic = unit_data(problem, options)
    return paper_unit_result(problem, fit_joint(static, dynamic, problem.rng, options, model))
