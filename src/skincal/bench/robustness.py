"""The robustness benchmark (``skincal benchmark robustness``): the default calibrator under faults of
real robots and real IMUs, one at a time and all together.

**Session.** Per robot (``panda``, ``sawyer``, ``ur5e``) and seed: 6 units at random places on links
2..n (:func:`skincal.skin.placement.random_placement`), the protocol (``paper-sim``; ``--quick``:
``fast``) with amplitudes capped at 95 % of the velocity limits, simulated by a backend
(``analytic``, ``mujoco`` = MuJoCo kinematic mode, ``mujoco-dynamic`` = MuJoCo with velocity servos).
The base session of every fault has ``realistic`` IMUs, ``controller`` joint states (500 Hz,
encoder steps, no qdd) with 3e-3 rad/s velocity noise, ideal unit clocks and ``|g| = 9.81``.

**Faults** (:data:`FAULTS`; the stream faults are :mod:`skincal.sim.faults`): joint-velocity noise
1e-3 / 3e-3 (the base session itself) / 1e-2 rad/s; the ``real`` IMU preset; unit clocks ``wifi``
(offsets up to 0.5 s, 100 ppm std free-running drift, 1 ms jitter), a fixed 0.4 s offset, a
100 ppm free-running drift, ``driver`` (440 ppm slow clock re-synced every 2.51 s: stamp steps);
saturation (a +-2 g accelerometer with brisk motion: the protocol's frequencies x 1.5);
an accelerometer axis stuck from mid-session; a 0.05 m/s^2 bias drift over the session; a unit
knocked 3 cm / 10 deg at 2/3 of the session; gravity 9.796 m/s^2 simulated while the dataset says
9.81; and ``all`` of them at once (velocity noise 1e-2, ``real`` IMUs, ``wifi-resync`` clocks,
brisk +-2 g, stuck axis, bias drift, knock, gravity). Placements, trajectories and sensor draws are
the same for every fault of a ``(robot, seed)`` (paired comparison); the unit with the stuck axis
and the knocked unit are two different units drawn from the seed.

The faults of real recordings (issue 24): ``report14`` joint states, ``host`` and ``host-gaps``
unit clocks (the clock cells' 1 mm target), gyroscope scale and misalignment, the three unit
mistakes of :func:`skincal.sim.faults.misstate_units` and ``real-recording`` (``real-consumer`` IMUs
with ``report14`` joints and ``host-gaps`` clocks); those but the clock cells have no mean target yet.

**Truth.** Each unit's simulated pose; for the knocked unit the pose before the knock, held for
2/3 of the session (:func:`skincal.sim.faults.splice_knock`).

**Per cell** ``(robot, backend, fault)``, over its seeds' units (:func:`summarise_cell`): mean and
max position error (mm) and rotation error (deg) of the calibrated units (as
:func:`skincal.calib.evaluate`), links right, RMS of ``z = e_i / sigma_i`` (position error per
link axis over the reported std), units calibrated, units with any warning, and silent errors
(:data:`SILENT_RULE`). Targets (:func:`targets`): mean <= 0.3 mm for the joint-noise cells
(``controller`` joints, ``realistic`` IMUs), <= 1 mm for the ``real`` IMU and clock cells; in
every cell all links right and no silent error.

One job is one ``(robot, backend, fault, seed)`` (:func:`run_job`): a pure function of a picklable
:class:`Job`, run in local processes or on Dask by :mod:`skincal.workflows.sweep`.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, dataclass, replace
from typing import Any

import numpy as np

from skincal.bench.harness import RunInfo
from skincal.bench.options import ROBUSTNESS
from skincal.errors import ConfigError
from skincal.sim.faults import GRAVITY_DECLARED_MPS2
from skincal.skin.clock import ClockModel, get_clock_model
from skincal.skin.imu import STANDARD_GRAVITY

ROBOTS = ("panda", "sawyer", "ur5e")
BACKENDS = {
    "analytic": ("analytic", "kinematic"),
    "mujoco": ("mujoco", "kinematic"),
    "mujoco-dynamic": ("mujoco", "dynamic"),
}
"""Backend name -> (simulator, MuJoCo mode)."""
DEFAULT_BACKENDS = ("analytic", "mujoco")

N_UNITS = 6
BASE_VELOCITY_NOISE = 3e-3
"""Joint-velocity noise of the base session, rad/s (the ``controller`` preset's)."""
SATURATION_RANGE_MPS2 = 2.0 * STANDARD_GRAVITY
"""Accelerometer full scale of the saturation fault, m/s^2 (+-2 g)."""
BRISK_FREQUENCY_FACTOR = 1.5
"""Brisk motion: every excitation frequency of the protocol times this (accelerations x 1.5)."""
CLOCK_OFFSET_S = 0.4
CLOCK_DRIFT_PPM = 100.0
STUCK_AT = 0.5
"""The stuck axis sticks at this fraction of the session."""
BIAS_DRIFT_MPS2 = 0.05
KNOCK_AT = 2.0 / 3.0
"""The knock happens at this fraction of the session (the pose before it is the truth)."""
KNOCK_TRANSLATION_M = 0.03
KNOCK_ROTATION_DEG = 10.0
GRAVITY_TRUE_MPS2 = 9.796
SILENT_Z = 3.0

SILENT_RULE = (
    "a calibrated unit with no warning whose estimate is wrong beyond its reported uncertainty: link wrong, "
    "or (link right; e = p_est - p_true in the link frame, sigma the reported position std, z_i = e_i / sigma_i "
    "over the k axes with a finite sigma_i) any |z_i| > 3, or the normalised norm sum z_i^2 > chi2_k(0.9973) "
    "(the 3-sigma probability; 14.16 for k = 3); a unit that reports no std at all counts as sigma = 0"
)
"""What :func:`judge_unit` calls a silent error."""


@dataclass(frozen=True)
class Fault:
    """A cell's sensor and timing conditions (the base session with some faults switched on).

    Attributes:
        name, description: as printed.
        imu: IMU preset (:data:`skincal.skin.imu.IMU_PRESETS`).
        velocity_noise: ``controller`` joint states with this velocity noise, rad/s.
        clock: unit clock preset (:data:`skincal.skin.clock.CLOCK_PRESETS`) or ``"drift"``
            (free-running, :data:`CLOCK_DRIFT_PPM` on every unit).
        stamp_offset_s: fixed clock offset added to every IMU stamp (:func:`~skincal.sim.faults.shift_imu_stamps`), s.
        brisk: protocol frequencies x :data:`BRISK_FREQUENCY_FACTOR`.
        saturation_mps2: accelerometer range (:func:`~skincal.sim.faults.saturate_accel`), m/s^2, or ``None``.
        stuck_axis: one unit's axis stuck from :data:`STUCK_AT` (:func:`~skincal.sim.faults.stick_axis`).
        bias_drift_mps2: linear accelerometer bias drift over the session, m/s^2 (0 = none).
        knock: one unit knocked at :data:`KNOCK_AT` (:func:`~skincal.sim.faults.simulate_knock`).
        gravity_true_mps2: simulated ``|g|`` while the dataset states 9.81, or ``None``.
        target_mean_mm: the cell's target on the mean position error, mm, or ``None``.
        joints: joint-state preset (:data:`skincal.sim.joint_states.JOINT_PRESETS`; ``controller``
            gets ``velocity_noise``).
        imu_options: ``(field, value)`` pairs replaced in the IMU preset (e.g. gyroscope scale).
        unit_mistake: a stream in the wrong unit (:data:`skincal.sim.faults.UNIT_MISTAKES`), or ``None``.
    """

    name: str
    description: str
    imu: str = "realistic"
    velocity_noise: float = BASE_VELOCITY_NOISE
    clock: str = "ideal"
    stamp_offset_s: float = 0.0
    brisk: bool = False
    saturation_mps2: float | None = None
    stuck_axis: bool = False
    bias_drift_mps2: float = 0.0
    knock: bool = False
    gravity_true_mps2: float | None = None
    target_mean_mm: float | None = None
    joints: str = "controller"
    imu_options: tuple[tuple[str, float], ...] = ()
    unit_mistake: str | None = None

    def clock_model(self) -> ClockModel:
        if self.clock == "drift":
            return ClockModel(drift_ppm_mean=CLOCK_DRIFT_PPM)
        return get_clock_model(self.clock)


def _faults() -> dict[str, Fault]:
    f = [
        Fault("qd-1e-3", "controller joints, velocity noise 1e-3 rad/s", velocity_noise=1e-3, target_mean_mm=0.3),
        Fault("qd-3e-3", "controller joints, velocity noise 3e-3 rad/s (the base session)", target_mean_mm=0.3),
        Fault("qd-1e-2", "controller joints, velocity noise 1e-2 rad/s", velocity_noise=1e-2, target_mean_mm=0.3),
        Fault("imu-real", "IMU preset real (measured IMUs)", imu="real", target_mean_mm=1.0),
        Fault(
            "clock-wifi",
            "clock wifi: offsets up to 0.5 s, 100 ppm std free-running, 1 ms jitter",
            clock="wifi",
            target_mean_mm=1.0,
        ),
        Fault(
            "clock-offset",
            f"every IMU stamp {CLOCK_OFFSET_S} s late",
            stamp_offset_s=CLOCK_OFFSET_S,
            target_mean_mm=1.0,
        ),
        Fault("clock-drift", f"free-running clocks, {CLOCK_DRIFT_PPM:.0f} ppm fast", clock="drift", target_mean_mm=1.0),
        Fault(
            "clock-driver",
            "clock driver: 440 ppm slow, re-synced every 2.51 s (stamp steps)",
            clock="driver",
            target_mean_mm=1.0,
        ),
        Fault(
            "saturation",
            "accelerometer +-2 g with brisk motion (frequencies x 1.5)",
            brisk=True,
            saturation_mps2=SATURATION_RANGE_MPS2,
        ),
        Fault("stuck-axis", f"one unit's accelerometer axis stuck from {STUCK_AT:.0%} of the session", stuck_axis=True),
        Fault(
            "bias-drift",
            f"accelerometer bias drift {BIAS_DRIFT_MPS2} m/s^2 over the session",
            bias_drift_mps2=BIAS_DRIFT_MPS2,
        ),
        Fault(
            "knock",
            f"one unit knocked {KNOCK_TRANSLATION_M * 100:.0f} cm / {KNOCK_ROTATION_DEG:.0f} deg at "
            f"{KNOCK_AT:.0%} of the session",
            knock=True,
        ),
        Fault(
            "gravity",
            f"simulated |g| = {GRAVITY_TRUE_MPS2}, dataset says {GRAVITY_DECLARED_MPS2}",
            gravity_true_mps2=GRAVITY_TRUE_MPS2,
        ),
        Fault(
            "all",
            "all at once: qd noise 1e-2, real IMUs, wifi-resync clocks, brisk +-2 g, stuck axis, "
            "bias drift, knock, gravity",
            imu="real",
            velocity_noise=1e-2,
            clock="wifi-resync",
            brisk=True,
            saturation_mps2=SATURATION_RANGE_MPS2,
            stuck_axis=True,
            bias_drift_mps2=BIAS_DRIFT_MPS2,
            knock=True,
            gravity_true_mps2=GRAVITY_TRUE_MPS2,
        ),
        Fault("joints-report14", "joints report14: 13.6 Hz host-stamped reports, 8 % lost, central-difference qd",
              joints="report14"),
        Fault("clock-host", "clock host: host-stamped, 80-100 ms lag, spacing 2.5-17.5 ms", clock="host",
              target_mean_mm=1.0),
        Fault("clock-gaps", "clock host-gaps: host with 0.3-0.7 s gaps, a clock step after each", clock="host-gaps",
              target_mean_mm=1.0),
        Fault("gyro-scale", "gyroscope scale 4.5 % std and 1 % misalignment per axis",
              imu_options=(("gyro_scale_std", 0.045), ("gyro_misalignment_std", 0.01))),
        Fault("units-gyro-deg", "gyroscope in deg/s stored as rad/s (x 57.3)", unit_mistake="gyro-deg"),
        Fault("units-accel-g", "accelerometer in g stored as m/s^2 (/ 9.81)", unit_mistake="accel-g"),
        Fault("units-raw", "raw 16-bit counts (+-4 g, +-2000 deg/s) stored as SI", unit_mistake="raw-counts"),
        Fault("real-recording", "like a real recording: real-consumer IMUs, report14 joints, host-gaps clocks",
              imu="real-consumer", joints="report14", clock="host-gaps"),
    ]  # fmt: skip
    return {x.name: x for x in f}


FAULTS: dict[str, Fault] = _faults()
"""The fault cells by name, in table order."""


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
        if self.seeds < 1 or self.n_units < 2:
            raise ConfigError(f"robustness: seeds must be >= 1 and units >= 2, got {self.seeds} and {self.n_units}")
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


# --------------------------------------------------------------------------- summary
def targets(fault: str) -> dict[str, Any]:
    """The cell's targets: ``mean_position_error_mm`` (or ``None``), all links right, no silent error."""
    return {"mean_position_error_mm": FAULTS[fault].target_mean_mm, "links": "all", "silent_errors": 0}


def summarise_cell(records: Sequence[Mapping[str, Any]]) -> dict[str, Any]:
    """Statistics of one cell over its records (all seeds' units); see the module docstring.

    Means and maxima are over calibrated observable units; ``z_rms`` over every finite ``z`` of
    those with the right link; ``warned`` counts calibrated units with any warning, ``silent``
    the silent errors (:data:`SILENT_RULE`), ``beyond_3sigma`` the units wrong beyond their
    uncertainty by the same rule, warned or not. ``pass`` checks :func:`targets`.
    """
    first = records[0]
    units = [u for r in records for u in r["units"].values()]
    done = [u for u in units if u["calibrated"]]
    seen = [u for u in done if u["observable"]]
    pos = [u["position_error_mm"] for u in seen]
    rot = [u["rotation_error_deg"] for u in seen]
    z = [v for u in seen if u["z"] is not None for v in u["z"] if v is not None]
    links = sum(u["link_estimated"] == u["link_true"] for u in done)
    silent = [f"seed {r['seed']} {n}" for r in records for n, u in r["units"].items() if u.get("silent")]
    beyond = int(sum(bool(u.get("beyond_3sigma")) for u in done))
    cell: dict[str, Any] = {
        "robot": first["robot"],
        "backend": first["backend"],
        "fault": first["fault"],
        "seeds": sorted(r["seed"] for r in records),
        "mean_position_error_mm": float(np.mean(pos)) if pos else None,
        "max_position_error_mm": float(np.max(pos)) if pos else None,
        "mean_rotation_error_deg": float(np.mean(rot)) if rot else None,
        "max_rotation_error_deg": float(np.max(rot)) if rot else None,
        "links_correct": int(links),
        "units_total": len(units),
        "units_calibrated": len(done),
        "z_rms": float(np.sqrt(np.mean(np.square(z)))) if z else None,
        "warned": int(sum(bool(u["warnings"]) for u in done)),
        "beyond_3sigma": beyond,
        "silent": len(silent),
        "silent_units": silent,
        "errors": [r["error"] for r in records if r["error"]],
        "simulate_s": float(sum(r["simulate_s"] for r in records)),
        "calibrate_s": float(sum(r["calibrate_s"] for r in records)),
        "targets": targets(first["fault"]),
    }
    cell["failed_targets"] = failed_targets(cell)
    cell["pass"] = not cell["failed_targets"]
    return cell


def failed_targets(cell: Mapping[str, Any]) -> list[str]:
    """Which of the cell's targets it misses (short phrases; empty when it meets them all)."""
    out = []
    goal = cell["targets"]["mean_position_error_mm"]
    mean = cell["mean_position_error_mm"]
    if goal is not None and (mean is None or mean > goal):
        out.append(f"mean > {goal:g} mm")
    if cell["links_correct"] < cell["units_total"]:
        out.append("links")
    if cell["silent"]:
        out.append("silent")
    if cell["errors"]:
        out.append("crashed")
    return out


def summarise(config: RobustnessConfig, records: Sequence[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """One :func:`summarise_cell` per cell, in the configuration's order (robot, backend, fault)."""
    by_cell: dict[tuple[str, str, str], list[Mapping[str, Any]]] = {}
    for r in records:
        by_cell.setdefault((r["robot"], r["backend"], r["fault"]), []).append(r)
    return [
        summarise_cell(by_cell[(r, b, f)])
        for r in config.robots
        for b in config.backends
        for f in config.faults
        if (r, b, f) in by_cell
    ]


def run(
    config: RobustnessConfig,
    workers: int = 1,
    dask: Any = None,
    progress: Callable[[dict[str, Any]], None] | None = None,
) -> list[dict[str, Any]]:
    """Every job's record (in :func:`jobs` order), in local processes or on a Dask cluster."""
    from skincal.workflows.sweep import map_jobs

    return map_jobs(run_job, jobs(config), workers=workers, dask=dask, progress=progress)


def config_dict(config: RobustnessConfig) -> dict[str, Any]:
    """JSON-ready description of the configuration, the faults and the definitions."""
    return {
        **asdict(config),
        "faults_run": {name: asdict(FAULTS[name]) for name in config.faults},
        "base_session": "realistic IMUs, controller joint states (500 Hz, encoder steps, no qdd) with "
        f"{BASE_VELOCITY_NOISE} rad/s velocity noise, ideal unit clocks, |g| = 9.81",
        "truth": "each unit's simulated pose; for the knocked unit the pose before the knock "
        f"(held for {KNOCK_AT:.0%} of the session)",
        "silent_error": SILENT_RULE,
        "z": "e_i / sigma_i: position error on link axis i over the reported std (link right, finite std)",
        "warned": "calibrated units with at least one warning",
        "beyond_3sigma": "calibrated units wrong beyond their reported uncertainty by the silent-error rule, "
        "warned or not",
    }


# --------------------------------------------------------------------------- the benchmark as run and shown
def names(text: str | None) -> tuple[str, ...] | None:
    """``"a, b"`` -> ``("a", "b")``; ``None`` stays ``None`` (the default)."""
    if text is None:
        return None
    return tuple(x.strip() for x in text.split(",") if x.strip())


def config_from_options(
    robots: str | None = None,
    backends: str | None = None,
    faults: str | None = None,
    seeds: int | None = None,
    quick: bool = False,
    protocol: str | None = None,
    seed: int = 0,
) -> RobustnessConfig:
    """The configuration of the command's options (comma-separated lists; ``None``: the default)."""
    overrides: dict[str, Any] = {"seed": seed}
    for key, value in (("robots", names(robots)), ("backends", names(backends)), ("faults", names(faults))):
        if value is not None:
            overrides[key] = value
    if seeds is not None:
        overrides["seeds"] = seeds
    if protocol is not None:
        overrides["protocol"] = protocol
    return RobustnessConfig.quick(**overrides) if quick else RobustnessConfig(**overrides)


def fault_lines() -> list[str]:
    """One line per fault: name, description and target (``--list``)."""
    out = []
    for f in FAULTS.values():
        target = f"mean <= {f.target_mean_mm:g} mm" if f.target_mean_mm is not None else "no mean target"
        out.append(f"{f.name:14s} {f.description} ({target})")
    return out


def run_benchmark(
    config: RobustnessConfig,
    workers: int = 1,
    dask: Any = None,
    progress: Callable[[dict[str, Any]], None] | None = None,
) -> dict[str, Any]:
    """Run every job and summarise (:func:`~skincal.bench.harness.run_harness`).

    Returns ``{"config", "cells", "records", "wall_time_s", "workers", "dask"}`` (the ``--out`` document).
    """
    from skincal.bench.harness import run_harness

    return run_harness(HARNESS, config, workers=workers, dask=dask, progress=progress)[0]


def _num(x: float | None, digits: int) -> str:
    return "-" if x is None else f"{x:.{digits}f}"


def robustness_table(config: RobustnessConfig, cells: list[dict[str, Any]]):
    """A rich table with one row per cell (robot, backend, fault)."""
    from rich.table import Table

    table = Table(
        title=f"robustness: mle, {config.protocol} protocol, {config.seeds} placement(s) of "
        f"{config.n_units} units per cell"
    )
    for col, justify in (
        ("robot", "left"), ("backend", "left"), ("fault", "left"), ("pos mean/max mm", "right"),
        ("rot mean/max deg", "right"), ("links", "right"), ("z rms", "right"), ("calibrated", "right"),
        ("warned", "right"), ("beyond", "right"), ("silent", "right"), ("targets", "left"),
    ):  # fmt: skip
        table.add_column(col, justify=justify, no_wrap=col in ("backend", "fault"))
    previous = None
    for c in cells:
        if previous is not None and (c["robot"], c["backend"]) != previous:
            table.add_section()
        previous = (c["robot"], c["backend"])
        n = c["units_total"]
        verdict = "ok" if c["pass"] else "[red]" + ", ".join(c["failed_targets"]) + "[/red]"
        table.add_row(
            c["robot"], c["backend"], c["fault"],
            f"{_num(c['mean_position_error_mm'], 3)} / {_num(c['max_position_error_mm'], 2)}",
            f"{_num(c['mean_rotation_error_deg'], 3)} / {_num(c['max_rotation_error_deg'], 2)}",
            f"{c['links_correct']}/{n}", _num(c["z_rms"], 2), f"{c['units_calibrated']}/{n}",
            str(c["warned"]), str(c["beyond_3sigma"]),
            ("[red]" + str(c["silent"]) + "[/red]") if c["silent"] else "0", verdict,
        )  # fmt: skip
    return table


LEGEND = (
    "errors of calibrated units (means over observable ones); z = position error / reported std per link axis; "
    "warned: units with any warning; beyond: units on a wrong link or beyond 3 sigma (any axis, or sum z^2 > "
    "chi2_3(0.9973)); silent: beyond and not warned. Targets: mean <= 0.3 mm (qd-*), <= 1 mm (imu-real, "
    "clock-*); all links right and no silent error in every cell."
)
"""What the table's columns mean, printed under it."""


def where(workers: int, dask: Any) -> str:
    """Where the jobs ran, for the summary line."""
    return f"dask {dask}" if dask else f"{workers} local process(es)"


def report(config: RobustnessConfig, doc: Mapping[str, Any]) -> list[Any]:
    """What the command prints after a run: the table, the legend and the summary line."""
    cells = doc["cells"]
    passed = sum(c["pass"] for c in cells)
    line = (
        f"{passed}/{len(cells)} cells meet their targets; {len(doc['records'])} jobs in {doc['wall_time_s']:.1f} s "
        f"wall ({where(doc['workers'] or 1, doc['dask'])})"
    )
    return [robustness_table(config, cells), LEGEND, line]




class RobustnessHarness:
    """The robustness benchmark as a :class:`~skincal.bench.harness.Harness`."""

    options = ROBUSTNESS
    jobs = staticmethod(jobs)
    run_job = staticmethod(run_job)

    def config(self, values: Mapping[str, Any]) -> RobustnessConfig:
        """:func:`config_from_options` of the parsed options."""
        v = values
        return config_from_options(v["robots"], v["backends"], v["faults"], v["seeds"], v["quick"], v["protocol"],
                                   v["seed"])  # fmt: skip

    def summary(self, config: RobustnessConfig, records: list[dict[str, Any]], run: RunInfo) -> dict[str, Any]:
        """The ``--out`` document: ``{"config", "cells", "records", "wall_time_s", "workers", "dask"}``."""
        return {
            "config": config_dict(config),
            "cells": summarise(config, records),
            "records": records,
            "wall_time_s": run.wall_time_s,
            "workers": None if run.dask else run.workers,
            "dask": run.dask,
        }

    def report(self, config: RobustnessConfig, doc: Mapping[str, Any], run: RunInfo) -> list[Any]:
        """:func:`report`."""
        return report(config, doc)


HARNESS = RobustnessHarness()
