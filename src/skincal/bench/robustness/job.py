"""One job of the robustness benchmark, ``(robot, backend, fault, seed)`` (:func:`run_job`, a pure function
of a picklable :class:`Job`): the faulty session simulated (:func:`build_dataset`), calibrated and each
unit judged against the truth (:func:`judge_unit`, the silent-error rule :data:`SILENT_RULE`)."""

from __future__ import annotations

import math
import time
from collections.abc import Mapping
from dataclasses import asdict, dataclass, replace
from typing import Any

import numpy as np

from skincal.bench.robustness.faults import (
    BRISK_FREQUENCY_FACTOR,
    FAULTS,
    KNOCK_AT,
    KNOCK_ROTATION_DEG,
    KNOCK_TRANSLATION_M,
    STUCK_AT,
)
from skincal.errors import ConfigError
from skincal.sim.faults import GRAVITY_DECLARED_MPS2

ROBOTS = ("panda", "sawyer", "ur5e")
BACKENDS = {
    "analytic": ("analytic", "kinematic"),
    "mujoco": ("mujoco", "kinematic"),
    "mujoco-dynamic": ("mujoco", "dynamic"),
}
"""Backend name -> (simulator, MuJoCo mode)."""
DEFAULT_BACKENDS = ("analytic", "mujoco")
N_UNITS = 6
SILENT_Z = 3.0
SILENT_RULE = (
    "a calibrated unit with no warning whose estimate is wrong beyond its reported uncertainty: link wrong, "
    "or (link right; e = p_est - p_true in the link frame, sigma the reported position std, z_i = e_i / sigma_i "
    "over the k axes with a finite sigma_i) any |z_i| > 3, or the normalised norm sum z_i^2 > chi2_k(0.9973) "
    "(the 3-sigma probability; 14.16 for k = 3); a unit that reports no std at all counts as sigma = 0"
)
"""What :func:`judge_unit` calls a silent error."""


@dataclass(frozen=True)
class RobustnessConfig:
    """What the benchmark runs: every ``(robot, backend, fault)`` cell with ``seeds`` placements.

    ``seed``: the placement sets are seeds ``seed .. seed + seeds - 1``.
    """

    robots: tuple[str, ...] = ROBOTS
    backends: tuple[str, ...] = DEFAULT_BACKENDS
    faults: tuple[str, ...] = tuple(FAULTS)
    seeds: int = 5
    protocol: str = "paper-sim"
    seed: int = 0
    n_units: int = N_UNITS

    def __post_init__(self) -> None:
        from skincal.kinematics.presets import PRESETS as ROBOT_PRESETS
        from skincal.protocol import PROTOCOLS

        for what, given, known in (
            ("robot", self.robots, ROBOT_PRESETS),
            ("backend", self.backends, BACKENDS),
            ("fault", self.faults, FAULTS),
        ):
            if not given:
                raise ConfigError(f"robustness: no {what} given")
            unknown = [x for x in given if x not in known]
            if unknown:
                raise ConfigError(f"robustness: unknown {what}(s) {', '.join(unknown)} (known: {', '.join(known)})")
        if self.seeds < 1:
            raise ConfigError(f"--placements must be at least 1, got {self.seeds}")
        if self.n_units < 2:
            raise ConfigError(f"robustness: units must be >= 2, got {self.n_units}")
        if self.protocol not in PROTOCOLS:
            raise ConfigError(f"robustness: unknown protocol '{self.protocol}' (presets: {', '.join(PROTOCOLS)})")

    @classmethod
    def quick(cls, **kw: Any) -> RobustnessConfig:
        """``--quick``: one seed, the ``fast`` protocol."""
        return cls(**{"seeds": 1, "protocol": "fast", **kw})


@dataclass(frozen=True)
class Job:
    """One ``(robot, backend, fault, seed)`` of a configuration."""

    robot: str
    backend: str
    fault: str
    seed: int
    protocol: str
    n_units: int = N_UNITS


def jobs(config: RobustnessConfig) -> list[Job]:
    """Every job, the slow ones (MuJoCo, two simulations) first so that the last ones finish together."""
    todo = [
        Job(r, b, f, config.seed + s, config.protocol, config.n_units)
        for r in config.robots
        for b in config.backends
        for f in config.faults
        for s in range(config.seeds)
    ]
    cost = {"analytic": 1.0, "mujoco": 2.0, "mujoco-dynamic": 6.0}
    return sorted(todo, key=lambda j: -cost[j.backend] * (2.0 if FAULTS[j.fault].knock else 1.0))


# --------------------------------------------------------------------------- sessions
def session_protocol(chain, name: str, brisk: bool = False):
    """The protocol preset for ``chain`` with amplitudes capped at 95 % of the velocity limits;
    ``brisk``: every frequency x :data:`BRISK_FREQUENCY_FACTOR`."""
    from skincal.workflows.session import fit_protocol

    config = fit_protocol(chain, name)
    if brisk:
        f = config.frequency_per_joint(chain.n_joints) * BRISK_FREQUENCY_FACTOR
        config = replace(config, frequency=tuple(float(x) for x in f))
    return config


@dataclass(frozen=True)
class Affected:
    """The units a fault picks, drawn from the seed: the stuck one, its axis, the knocked one."""

    stuck_unit: str
    stuck_axis: int
    knocked_unit: str


def build_dataset(job: Job):
    """The faulted dataset of ``job`` and the units the fault picked: ``(Dataset, Affected)``.

    Random streams: ``[seed, 0]`` draws the placements and the trajectory, ``[seed, 1]`` the
    simulation (sensor errors, noise, clocks, joint stream), ``[seed, 2]`` the fault choices (stuck
    unit and axis, knocked unit, bias-drift directions, knock direction), always in that order, so
    that every fault of a ``(robot, seed)`` shares placements, sensor draws and choices.
    """
    from skincal.kinematics import get_robot
    from skincal.protocol import build_trajectory
    from skincal.sim import faults as F
    from skincal.sim.joint_states import get_joint_model
    from skincal.skin.imu import get_imu_model
    from skincal.skin.placement import random_placement

    fault = FAULTS[job.fault]
    simulator, mode = BACKENDS[job.backend]
    chain = get_robot(job.robot)
    setup = np.random.default_rng([job.seed, 0])
    placements = random_placement(chain, job.n_units, setup)
    trajectory = build_trajectory(chain, session_protocol(chain, job.protocol, fault.brisk), setup)
    names = list(placements)
    pick = np.random.default_rng([job.seed, 2])
    order = pick.permutation(len(names))
    affected = Affected(names[order[0]], int(pick.integers(3)), names[order[1]])
    directions = dict(zip(names, F.random_directions(len(names), pick), strict=True))
    knocked = F.knocked_pose(placements[affected.knocked_unit], KNOCK_TRANSLATION_M, KNOCK_ROTATION_DEG, pick)

    imu_model = replace(get_imu_model(fault.imu), **dict(fault.imu_options))
    joint_model = get_joint_model(fault.joints)
    timing = {
        "joint_model": replace(joint_model, velocity_noise_std=fault.velocity_noise)
        if fault.joints == "controller"
        else joint_model,
        "clock_model": fault.clock_model(),
    }
    g_true = GRAVITY_DECLARED_MPS2 if fault.gravity_true_mps2 is None else fault.gravity_true_mps2
    gravity = np.array([0.0, 0.0, -g_true])
    text = f"robustness: robot={job.robot} backend={job.backend} fault={job.fault} seed={job.seed}"

    def simulate(pl: Mapping[str, Any]):
        from skincal.sim import Session, SimOptions, simulate

        rng = np.random.default_rng([job.seed, 1])
        session = Session(chain, pl, trajectory, imu_model, rng, gravity=gravity, description=text, **timing)
        return simulate(session, simulator, options=SimOptions(mode=mode) if simulator == "mujoco" else None)

    t0, t1 = float(trajectory.t[0]), float(trajectory.t[-1])
    if fault.knock:
        ds = F.simulate_knock(simulate, placements, affected.knocked_unit, t0 + KNOCK_AT * (t1 - t0), knocked)
    else:
        ds = simulate(placements)
    if fault.gravity_true_mps2 is not None:
        ds = F.declare_gravity(ds, [0.0, 0.0, -GRAVITY_DECLARED_MPS2])
    if fault.bias_drift_mps2:
        ds = F.drift_bias(ds, fault.bias_drift_mps2, directions=directions)
    if fault.saturation_mps2 is not None:
        ds = F.saturate_accel(ds, fault.saturation_mps2)
    if fault.stuck_axis:
        ds = F.stick_axis(ds, affected.stuck_unit, affected.stuck_axis, t0 + STUCK_AT * (t1 - t0))
    if fault.stamp_offset_s:
        ds = F.shift_imu_stamps(ds, fault.stamp_offset_s)
    if fault.unit_mistake:
        ds = F.misstate_units(ds, fault.unit_mistake)
    return ds, affected


# --------------------------------------------------------------------------- judging
def _floats(x: Any) -> list[float | None] | None:
    if x is None:
        return None
    return [float(v) if math.isfinite(v) else None for v in np.asarray(x, dtype=float).ravel()]


def silent_chi2(k: int) -> float:
    """``chi2_k(p)`` at the probability ``p = erf(3 / sqrt(2)) = 0.9973`` of a 3-sigma interval (14.16 for k = 3)."""
    from scipy.stats import chi2

    return float(chi2.ppf(math.erf(SILENT_Z / math.sqrt(2.0)), k))


def judge_unit(unit, truth, errors: Mapping[str, Any]) -> dict[str, Any]:
    """One calibrated unit against its truth: errors, z per axis, warnings, and whether it is a
    silent error (:data:`SILENT_RULE`). ``errors`` is the unit's entry of :func:`skincal.calib.evaluate`."""
    link_ok = unit.pose.link == truth.link
    e = np.asarray(unit.pose.p_link_su - truth.p_link_su, dtype=float) if link_ok else None
    std = None if unit.position_std_m is None else np.asarray(unit.position_std_m, dtype=float)
    z = None
    beyond = not link_ok
    if e is not None:
        sigma = np.zeros(3) if std is None else std
        finite = np.isfinite(sigma)
        with np.errstate(divide="ignore", invalid="ignore"):
            z = np.where(finite, e / sigma, np.nan)
        k = int(finite.sum())
        if k:
            zf = np.nan_to_num(z[finite], nan=0.0, posinf=np.inf, neginf=-np.inf)  # 0 / 0: no error, no claim
            beyond = bool(np.any(np.abs(zf) > SILENT_Z)) or bool(np.sum(zf**2) > silent_chi2(k))
    return {
        "calibrated": True,
        "link_true": int(truth.link),
        "link_estimated": int(unit.pose.link),
        "observable": bool(unit.observable),
        "position_error_mm": float(errors["position_error_mm"]),
        "rotation_error_deg": float(errors["rotation_error_deg"]),
        "error_m": _floats(e),
        "position_std_m": _floats(std),
        "rotation_std_deg": _floats(unit.rotation_std_deg),
        "z": _floats(z),
        "warnings": list(unit.warnings),
        "beyond_3sigma": bool(beyond),
        "silent": bool(beyond and not unit.warnings),
    }


def run_job(job: Job) -> dict[str, Any]:
    """Simulate ``job``'s faulted session, calibrate it with ``mle`` (one worker) and judge every unit.

    Returns ``{"robot", "backend", "fault", "seed", "simulate_s", "calibrate_s", "affected": {...},
    "units": {name: judge_unit(...) or {"calibrated": False, "failure": reason}}, "error"}``; an
    exception of the calibration is recorded in ``error`` (every unit then not calibrated).
    """
    from threadpoolctl import threadpool_limits

    from skincal.calib import calibrate, evaluate

    record: dict[str, Any] = {
        "robot": job.robot,
        "backend": job.backend,
        "fault": job.fault,
        "seed": job.seed,
        "error": None,
    }
    with threadpool_limits(1):
        start = time.perf_counter()
        ds, affected = build_dataset(job)
        record["simulate_s"] = time.perf_counter() - start
        record["affected"] = asdict(affected)
        start = time.perf_counter()
        try:
            result = calibrate(ds, "mle", workers=1)
            ev = evaluate(result, ds).to_dict()
        except Exception as exc:  # noqa: BLE001 - one broken cell must not end a long benchmark
            record["calibrate_s"] = time.perf_counter() - start
            record["error"] = f"{type(exc).__name__}: {exc}"
            record["units"] = {u: {"calibrated": False, "failure": record["error"]} for u in ds.units}
            return record
        record["calibrate_s"] = time.perf_counter() - start
    failed = dict(result.failed_units)
    units: dict[str, Any] = {}
    for name in ds.units:
        if name in result.units:
            units[name] = judge_unit(result.units[name], ds.truth[name], ev["units"][name])
        else:
            units[name] = {"calibrated": False, "failure": str(failed.get(name, "no result"))}
    record["units"] = units
    return record
