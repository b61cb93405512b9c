"""The closed-loop avoidance experiment from one config: ``skincal avoid`` and the avoidance benchmark
(:mod:`skincal.bench.avoid`) both call :func:`run_experiment`.

One experiment: the simulated skin at its TRUE poses, the poses the controller BELIEVES (and their
covariance), a scenario on a robot, the controller's margin (``fixed``: the legacy critical distance;
``iso``: ISO/TS 15066's ``S_p`` with the scenario's ``v_h`` and the robot's measured stopping model, speed and
separation monitoring; ``iso-pfl``: the same with power and force limiting, issue 28), the
task clock that waits (``resume``) and the robot mode; run in MuJoCo by
:func:`skincal.workflows.avoidance.run_scenario` with the sensor noise seeded by ``seed``. With ``resume``
the same run without anybody is made too (or given), for the task time lost. The metrics are
:mod:`skincal.control.iso_metrics`' of the run's arrays, the clearance against the TRUE robot geometry.

Stopping models are measured on the torque robot (:func:`skincal.workflows.stopping.measure_stopping`,
a few seconds per robot); a :class:`StoppingModels` passed along measures each robot once for all the
runs that share it (a benchmark), and nothing is kept between calls otherwise.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, replace

import numpy as np

from skincal.control import iso_metrics
from skincal.control.body_regions import BodyRegion, body_region, pfl_speed_limit
from skincal.control.effective_mass import MassMatrix
from skincal.control.iso_metrics import AvoidMetrics
from skincal.control.qp import ControllerConfig
from skincal.control.separation import SeparationParams, StoppingModel
from skincal.errors import ConfigError
from skincal.kinematics.chain import SerialChain
from skincal.kinematics.transforms import FloatArray
from skincal.perception.body import RobotBody
from skincal.perception.uncertainty import SkinUncertainty
from skincal.sim.scenarios import Scenario
from skincal.skin.pose import SkinUnitPose
from skincal.workflows.avoidance import MODES, RunLog, robot_mass_matrix, run_scenario

MARGINS = ("fixed", "iso", "iso-pfl")
"""``fixed``: the legacy critical distance; ``iso``: ISO/TS 15066 ``S_p``, speed and separation monitoring
(inside ``S_p`` the robot never approaches); ``iso-pfl``: ``S_p`` with power and force limiting (inside it
the robot may approach at the Annex A speed of the body region, :mod:`skincal.control.body_regions`)."""
TORQUE_V_MAX = 0.5
"""The ramp's largest approach speed in torque mode with an ISO margin, m/s (kinematic: 1.0): half the slope
near ``S_p``, so that the drive's lag behind the command stays small (``hand`` on the Panda, torque, SSM:
the actual speed toward a point inside ``S_p`` reached 0.18 m/s with 1.0; simulated)."""
TORQUE_SP_BUFFER_M = 0.02
"""``ControllerConfig.sp_buffer`` in torque mode with an ISO margin, m: the lagging drive comes to rest before
``S_p`` (with :data:`TORQUE_V_MAX`: no step approaching inside ``S_p`` in ``hand``, Panda, torque; simulated,
chosen on that run)."""
TORQUE_ALL_DIRECTIONS = False
"""``ControllerConfig.all_directions`` in torque mode with an ISO margin. Off: measured on the Panda (torque,
``--margin iso``, true poses; simulated) it cut the time approaching inside ``S_p`` summed over the eight shipped
scenarios from 0.61 to 0.54 s and the largest speed there in ``lower`` from 0.84 to 0.05 m/s, but passed two of
them instead of four (``elbow`` and ``walk-at`` failed with it, ``pinch`` went from 0.19 to 0.44 s):
``docs/results-iso.md``."""
CRITERION = {"iso": "ssm", "iso-pfl": "pfl"}
"""The ISO criterion a margin's run is judged by (:func:`skincal.control.iso_metrics.iso_criteria`)."""


class StoppingModels:
    """Measured stopping models per robot, each measured once for the life of this object (a cache the
    caller owns and passes along; the separation module's placeholder when the measurement is unavailable)."""

    def __init__(self) -> None:
        self._models: dict[tuple, StoppingModel] = {}

    def __call__(self, chain: SerialChain) -> StoppingModel:
        """The stopping model of ``chain`` (:func:`skincal.workflows.stopping.measure_stopping`)."""
        key = (chain.name, chain.n_joints, chain.link_frames(np.zeros(chain.n_joints)).tobytes())
        if key not in self._models:
            try:
                from skincal.workflows.stopping import measure_stopping
            except ImportError:  # pragma: no cover - the dynamics need MuJoCo
                from skincal.control.separation import default_stopping

                self._models[key] = default_stopping()
            else:
                self._models[key] = measure_stopping(chain)
        return self._models[key]


def separation_for(
    chain: SerialChain, scenario: Scenario, human_speed: float | None = None, stopping: StoppingModels | None = None
) -> SeparationParams:
    """ISO/TS 15066 separation parameters for a run: ``v_h`` from the scenario (or ``human_speed``), the
    robot's measured stopping model (from ``stopping``, or measured now), the other terms the separation
    module's defaults."""
    v_h = scenario.human_speed if human_speed is None else float(human_speed)
    models = stopping if stopping is not None else StoppingModels()
    return SeparationParams(human_speed_mps=v_h, stopping=models(chain))


@dataclass(frozen=True)
class ExperimentConfig:
    """One closed-loop experiment (module docstring).

    Attributes:
        chain: the robot.
        scenario: start, task, people and duration (:mod:`skincal.sim.scenarios`).
        true_poses: the simulated skin (unit name -> pose).
        believed_poses: what perception believes (may lack units; ``{}``: blind).
        label: the beliefs' name in the metrics (``poses``).
        uncertainty: the believed poses' covariances (perception's default when None).
        margin: ``fixed``, ``iso`` or ``iso-pfl`` (:data:`MARGINS`).
        resume: the task clock that waits while a person is near.
        mode: ``kinematic`` or ``torque``.
        seed: seed of the sensor noise.
        reference: also run the scenario without anybody (default: with ``resume``).
    """

    chain: SerialChain
    scenario: Scenario
    true_poses: Mapping[str, SkinUnitPose]
    believed_poses: Mapping[str, SkinUnitPose]
    label: str = "truth"
    uncertainty: SkinUncertainty | None = None
    margin: str = "fixed"
    resume: bool = False
    mode: str = "kinematic"
    seed: int = 0
    reference: bool | None = None

    def __post_init__(self) -> None:
        if self.margin not in MARGINS:
            raise ConfigError(f"unknown margin '{self.margin}' (use {' or '.join(MARGINS)})")
        if self.mode not in MODES:
            raise ConfigError(f"unknown mode '{self.mode}' (use {' or '.join(MODES)})")


@dataclass(frozen=True)
class Experiment:
    """What :func:`run_experiment` made: the run, its reference without anybody (or None), its metrics,
    the controller configuration used and the true robot geometry the metrics are taken against."""

    config: ExperimentConfig
    controller: ControllerConfig
    log: RunLog
    reference: RunLog | None
    metrics: AvoidMetrics
    body: RobotBody


def run_experiment(
    config: ExperimentConfig, *, stopping: StoppingModels | None = None, reference: RunLog | None = None
) -> Experiment:
    """Run ``config`` (module docstring); ``stopping`` the cache of stopping models (``margin="iso"``),
    ``reference`` a run without anybody made before (then not run again)."""
    c = config
    controller = ControllerConfig()
    regions = scenario_regions(c.scenario)
    if c.margin in CRITERION:
        sep = separation_for(c.chain, c.scenario, stopping=stopping)
        controller = replace(controller, separation=sep, stop_never_approaches=True)
        if c.mode == "torque":  # speed scaling before S_p, and commands the drive reaches within a step
            from skincal.sim.dynamics import acceleration_limits

            accel = tuple(acceleration_limits(c.chain).tolist())
            controller = replace(
                controller,
                v_max=TORQUE_V_MAX,
                sp_buffer=TORQUE_SP_BUFFER_M,
                acceleration_limit=accel,
                all_directions=TORQUE_ALL_DIRECTIONS,
                feedback_speed=TORQUE_V_MAX,
            )
    if c.margin == "iso-pfl":
        controller = replace(controller, pfl=assumed_region(regions))
    mass = robot_mass_matrix(c.chain) if c.margin in CRITERION else None
    kw = dict(controller=controller, uncertainty=c.uncertainty, resume=c.resume, mode=c.mode, mass_matrix=mass)
    log = run_scenario(c.chain, c.scenario, c.true_poses, c.believed_poses, np.random.default_rng(c.seed), **kw)
    wanted = c.resume if c.reference is None else c.reference
    if reference is None and wanted:
        nobody = c.scenario.without_people()
        reference = run_scenario(
            c.chain, nobody, c.true_poses, c.believed_poses, np.random.default_rng(c.seed), **kw
        )  # fmt: skip
    body = RobotBody.of(c.chain)
    judged = (CRITERION[c.margin], regions, mass) if c.margin in CRITERION else None
    stop = controller.separation.stopping if controller.separation is not None else None
    metrics = summarize(log, body, c.label, reference, judged, stopping=stop)
    return Experiment(c, controller, log, reference, metrics, body)


def scenario_regions(scenario: Scenario) -> list[BodyRegion | None]:
    """The ISO/TS 15066 body region of every solid of the scenario's scene (its ``tof_primitives`` order):
    a person part's region, None for an object; a one-line :class:`ConfigError` naming the file and the
    person for an unknown region name."""
    out: list[BodyRegion | None] = []
    for obs in scenario.scene.obstacles:
        if not obs.body_regions:
            out += [None] * len(obs.primitives)
            continue
        for name in obs.body_regions:
            try:
                out.append(body_region(name))
            except ConfigError as e:
                raise ConfigError(f"{scenario.source or scenario.name}: person '{obs.name}': {e}") from None
    return out


def assumed_region(regions: list[BodyRegion | None]) -> BodyRegion:
    """The body region a PFL controller takes every perceived point to be: the skin does not tell who or what
    it sees, so the scenario's most restrictive person part (the lowest Annex A speed limit against an
    infinitely heavy robot); the hand without any person."""
    people = [r for r in regions if r is not None]
    if not people:
        return body_region("hand")
    return min(people, key=lambda r: float(pfl_speed_limit(r, np.inf)))


# ---------------------------------------------------------------------------------------------- a run's metrics
def clearance(log: RunLog, body: RobotBody) -> FloatArray:
    """``(S,)`` :func:`skincal.control.iso_metrics.clearance` of a run against the robot geometry ``body``, m."""
    scene = log.scenario.scene
    return iso_metrics.clearance(log.t, log.q, body, scene.tof_primitives if scene.obstacles else None)


def margin_of(log: RunLog) -> FloatArray:
    """``(S,)`` the protective separation ``S_p`` of each step, m (NaN without a logged margin)."""
    return log.margin if log.margin is not None else np.full(log.t.size, np.nan)


def task_time_lost(log: RunLog, reference: RunLog) -> float:
    """:func:`skincal.control.iso_metrics.task_time_lost` of ``log`` against ``reference``, s."""
    return iso_metrics.task_time_lost(
        log.t, log.tracking_error, log.task_time, reference.t, reference.tracking_error, reference.task_time
    )


def summarize(
    log: RunLog,
    body: RobotBody,
    poses: str = "",
    reference: RunLog | None = None,
    judged: tuple[str, list, MassMatrix | None] | None = None,
    stopping: StoppingModel | None = None,
) -> AvoidMetrics:
    """All metrics of a run; ``body`` is the TRUE robot geometry (as simulated); ``reference`` the same
    run without a person (for the task time lost; NaN without it); ``judged``: ``(criterion, regions,
    mass_matrix)`` to judge the run by ISO/TS 15066's criteria (:func:`skincal.control.iso_metrics.iso_criteria`);
    ``stopping`` the robot's stopping model there (the share of a violation that is a stop in progress)."""
    iso = None
    scene = log.scenario.scene
    if judged is not None:
        solids = scene.tof_primitives if scene.obstacles else None
        measured = None
        if log.sp_inside is not None and log.sp_approach is not None and log.sp_excess is not None:
            measured = (log.sp_inside, log.sp_approach, log.sp_excess)
        criterion, regions, mass = judged
        iso = iso_metrics.iso_criteria(
            log.t, log.q, body, solids, margin_of(log), regions, mass, criterion, measured=measured, stopping=stopping
        )
    return iso_metrics.summarize_run(
        scenario=log.scenario.name,
        poses=poses,
        t=log.t,
        clear=clearance(log, body),
        margin=margin_of(log),
        terms=log.terms,
        tracking_error=log.tracking_error,
        t_leave=log.scenario.t_leave,
        protective_stop=log.protective_stop if log.protective_stop is not None else ~log.feasible,
        feasible=log.feasible,
        n_obstacles=log.n_obstacles,
        solve_time_s=log.solve_time_s,
        step_time_s=log.step_time_s,
        loop_time_s=log.loop_time_s,
        task_time_lost_s=task_time_lost(log, reference) if reference is not None else float("nan"),
        mode=log.mode,
        iso=iso,
    )
