"""Torque-level robot in MuJoCo: the controller's joint-velocity command tracked through joint torques.

The kinematic robot of :mod:`skincal.workflows.avoidance` integrates the command ideally
(``q <- q + qd dt``). :class:`TorqueRobot` instead drives the MuJoCo model of the chain with joint
torques (``motor`` actuators, :func:`torque_model`), so inertia, gravity, Coriolis forces, rotor
inertia (armature), joint damping and the torque limits all act:

1. **Reference.** Per physics step ``h`` (the model's timestep; ``step(qd_cmd, dt)`` takes
   ``dt / h`` of them) the reference velocity moves toward the command (scaled uniformly into the
   velocity limits), its change scaled uniformly so that no joint exceeds its acceleration limit
   (a stop keeps its path: stop category 2), and the reference position integrates it the way
   MuJoCo integrates the robot (semi-implicit Euler)::

       qd_ref+ = qd_ref + s (qd_cmd - qd_ref),   s = min(1, min_i a_i h / |qd_cmd,i - qd_ref,i|)
       qdd_ref = (qd_ref+ - qd_ref) / h,         q_ref+ = q_ref + h qd_ref+

2. **Torque.** With ``e = q_ref - q``, ``ed = qd_ref - qd`` and ``ID(q, qd, qdd)`` MuJoCo's inverse
   dynamics (``mj_inverse``: ``M(q) qdd + c(q, qd) + g(q)`` less the passive forces, armature included)::

       computed-torque:  tau = ID(q, qd, qdd_ref + Kp e + Kd ed)      Kp [1/s^2], Kd [1/s]
       impedance:        tau = Kp e + Kd ed + ID(q, qd, qdd_ref)      Kp [N m/rad], Kd [N m s/rad]

   clipped to the effort limits (:attr:`TorqueRobot.saturated` tells which joints were clipped).
   Anti-windup: the reference position stays within ``TorqueConfig.max_error`` of the robot's.

Limits: the chain's own (``effort_limit``, ``velocity_limit``, ``acceleration_limit``), else the maker's
published ones of the Panda, UR5e and iiwa14 (:data:`PUBLISHED_LIMITS`). A robot with no published
acceleration limits gets :func:`feasible_acceleration` (what its torques can do against gravity and
its worst-case inertia). Inertias: :func:`skincal.sim.mujoco_model.published_inertials`.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike

from skincal.errors import ConfigError
from skincal.kinematics.chain import SerialChain
from skincal.kinematics.presets import iiwa14, panda, ur5e
from skincal.kinematics.transforms import FloatArray
from skincal.sim.mujoco_model import (
    build_model,
    full_mass_matrix,
    joint_name,
    motor_name,
    published_inertials,
    require_mujoco,
)
from skincal.skin.pose import SkinUnitPose

if TYPE_CHECKING:  # pragma: no cover
    import mujoco

MODES = ("computed-torque", "impedance")

DEFAULT_ARMATURE = 0.1
"""Rotor inertia reflected at each joint, kg m^2 (MuJoCo Menagerie's Panda, UR5e and iiwa14 models use
0.1 for every joint: a harmonic drive's motor inertia times the gear ratio squared)."""

DEFAULT_DAMPING = 0.0
"""Viscous joint damping, N m s/rad. None by default: the torque loop supplies all damping."""

DEFAULT_KP = 900.0
"""Computed-torque stiffness, 1/s^2: natural frequency 30 rad/s (4.8 Hz) per joint, critically damped
(``Kd = 2 sqrt(Kp)``); at 1 kHz that is ``omega h = 0.03``, well inside the discrete loop's stability."""

ACCELERATION_SHARE = 0.5
"""Share of the torque left after gravity that :func:`feasible_acceleration` gives to accelerating (the
rest covers Coriolis terms and the tracking feedback)."""


@dataclass(frozen=True)
class PublishedLimits:
    """A maker's dynamic limits: ``effort`` N m, ``acceleration`` rad/s^2 (``None``: not published)."""

    effort: tuple[float, ...]
    acceleration: tuple[float, ...] | None = None


PUBLISHED_LIMITS: dict[str, PublishedLimits] = {
    # Franka's "Robot and interface specifications" (FCI docs): tau_max and qdd_max per joint.
    "panda": PublishedLimits((87.0, 87.0, 87.0, 87.0, 12.0, 12.0, 12.0), (15.0, 7.5, 10.0, 12.5, 15.0, 20.0, 20.0)),
    # Universal Robots, "max joint torques" (size 3 joints 150 N m, size 1 joints 28 N m); no per-joint
    # acceleration limits are published.
    "ur5e": PublishedLimits((150.0, 150.0, 150.0, 28.0, 28.0, 28.0)),
    # KUKA LBR iiwa 14 R820 specification: maximum torques per axis A1..A7.
    "iiwa14": PublishedLimits((320.0, 320.0, 176.0, 176.0, 110.0, 40.0, 40.0)),
}
_PRESETS = {"panda": panda, "ur5e": ur5e, "iiwa14": iiwa14}


def published_limits(chain: SerialChain) -> PublishedLimits | None:
    """The maker's limits of the Panda, UR5e or iiwa14 (matched by motion, whatever the chain's name)."""
    for name, preset in _PRESETS.items():
        if chain.same_motion(preset()):
            return PUBLISHED_LIMITS[name]
    return None


def effort_limits(chain: SerialChain) -> FloatArray:
    """Joint torque limits ``(n,)``, N m: the chain's ``effort_limit``, else the published ones; a
    :class:`ConfigError` when neither exists."""
    if chain.effort_limit is not None:
        return np.array(chain.effort_limit, dtype=float)
    pub = published_limits(chain)
    if pub is None:
        raise ConfigError(
            f"robot '{chain.name}' has no joint torque limits: torque mode needs them (a URDF's <limit effort=...>)"
        )
    return np.array(pub.effort)


def torque_model(
    chain: SerialChain,
    placements: Mapping[str, SkinUnitPose] | None = None,
    *,
    armature: float | ArrayLike = DEFAULT_ARMATURE,
    damping: float | ArrayLike = DEFAULT_DAMPING,
    **kwargs: Any,
) -> mujoco.MjModel:
    """The MuJoCo model for :class:`TorqueRobot`: :func:`skincal.sim.mujoco_model.build_model` with the
    published inertials (:func:`~skincal.sim.mujoco_model.published_inertials`; capsule inertias for a
    chain without any), one ``motor`` actuator per joint with ``ctrlrange`` = :func:`effort_limits`,
    joint ``armature`` and ``damping``. ``kwargs`` go to ``build_model`` (``scene``, ``range_directions``,
    ``link_radius``, ...)."""
    kwargs.setdefault("inertials", published_inertials(chain))
    return build_model(
        chain, placements, motor_limits=effort_limits(chain), armature=armature, damping=damping, **kwargs
    )


def _joint_configurations(chain: SerialChain, count: int, seed: int) -> FloatArray:
    """``count`` configurations uniform within the joint ranges (+-pi for a continuous joint)."""
    from skincal.protocol.limits import position_bounds

    lo, hi = position_bounds(chain)
    return np.random.default_rng(seed).uniform(lo, hi, size=(count, chain.n_joints))


def feasible_acceleration(
    chain: SerialChain, model: mujoco.MjModel, effort: ArrayLike, *, samples: int = 64, seed: int = 0
) -> FloatArray:
    """Acceleration limits ``(n,)`` rad/s^2 for a robot whose maker publishes none: over ``samples``
    configurations in its joint ranges, joint ``i`` gets
    ``min_q ACCELERATION_SHARE (tau_i - |g_i(q)|) / sum_j |M_ij(q)|`` (all joints accelerating at once
    then stay inside the torque left after gravity, with :data:`ACCELERATION_SHARE` of headroom)."""
    mujoco = require_mujoco()
    tau = np.asarray(effort, dtype=float)
    n = chain.n_joints
    data = mujoco.MjData(model)
    best = np.full(n, np.inf)
    for q in _joint_configurations(chain, samples, seed):
        data.qpos[:n] = q
        data.qvel[:] = 0.0
        mujoco.mj_forward(model, data)
        M = full_mass_matrix(model, data)
        spare = tau - np.abs(data.qfrc_bias[:n] - data.qfrc_passive[:n])
        if np.any(spare <= 0):
            bad = int(np.argmax(spare <= 0)) + 1
            raise ConfigError(f"robot '{chain.name}': joint {bad}'s torque limit cannot hold the arm against gravity")
        best = np.minimum(best, ACCELERATION_SHARE * spare / np.abs(M[:n, :n]).sum(axis=1))
    return best


def acceleration_limits(
    chain: SerialChain,
    model: mujoco.MjModel | None = None,
    effort: ArrayLike | None = None,
    override: ArrayLike | None = None,
) -> FloatArray:
    """The joint acceleration limits ``(n,)`` rad/s^2 :class:`TorqueRobot` brakes and accelerates its reference
    at: ``override``, else the chain's ``acceleration_limit``, else the published ones, else
    :func:`feasible_acceleration` on ``model`` (default :func:`torque_model`) with ``effort`` (default
    :func:`effort_limits`)."""
    acc = override if override is not None else chain.acceleration_limit
    if acc is None:
        pub = published_limits(chain)
        acc = pub.acceleration if pub is not None else None
    if acc is None:
        model = torque_model(chain) if model is None else model
        acc = feasible_acceleration(chain, model, effort_limits(chain) if effort is None else effort)
    return _vector(acc, chain.n_joints, "acceleration limit")


@dataclass(frozen=True)
class TorqueConfig:
    """How :class:`TorqueRobot` tracks the velocity command (module docstring).

    Attributes:
        mode: ``"computed-torque"`` or ``"impedance"``.
        kp, kd: gains, one or ``(n,)``. Computed torque: ``kp`` 1/s^2 (default :data:`DEFAULT_KP`),
            ``kd`` 1/s (default ``2 sqrt(kp)``). Impedance: ``kp`` N m/rad, ``kd`` N m s/rad (defaults:
            the computed-torque gains times the joint's inertia ``M_ii`` at the configuration of
            :meth:`TorqueRobot.reset`).
        effort_limit, velocity_limit, acceleration_limit: ``(n,)`` overrides of the chain's / published
            limits (N m, rad/s, rad/s^2).
        max_error: anti-windup, rad: the reference position is kept within this of the robot's (a
            saturated robot lagging behind does not leave a growing error that it would later race to
            close, faster than commanded).
        sensors: compute the model's sensors at every physics step (off: the caller reads the sensors
            it needs itself, e.g. the rangefinders at the ToF rate, as the avoidance loop does).
    """

    mode: str = "computed-torque"
    kp: float | tuple[float, ...] | None = None
    kd: float | tuple[float, ...] | None = None
    effort_limit: tuple[float, ...] | None = None
    velocity_limit: tuple[float, ...] | None = None
    acceleration_limit: tuple[float, ...] | None = None
    max_error: float = 0.02
    sensors: bool = False

    def __post_init__(self) -> None:
        if self.mode not in MODES:
            raise ConfigError(f"torque mode must be one of {', '.join(MODES)}, got {self.mode!r}")
        if not (isinstance(self.max_error, (int, float)) and np.isfinite(self.max_error) and self.max_error > 0):
            raise ConfigError(f"max_error must be a positive number of rad, got {self.max_error!r}")


def _vector(value: Any, n: int, what: str) -> FloatArray:
    try:
        arr = np.array(np.broadcast_to(np.asarray(value, dtype=float), (n,)))
    except (TypeError, ValueError):
        raise ConfigError(f"{what} must be one number or {n} numbers") from None
    if not np.all(np.isfinite(arr) & (arr > 0)):
        raise ConfigError(f"{what} must be finite positive numbers, got {arr.tolist()}")
    return arr


class TorqueRobot:
    """The chain's MuJoCo model driven by joint torques that track a joint-velocity command.

    Args:
        chain: the robot.
        model: a model with one ``motor`` actuator per joint (:func:`torque_model`, possibly with a
            scene and skin sensors); default ``torque_model(chain)``.
        config: :class:`TorqueConfig`.
        q0: start configuration (default: zeros, clipped into the joint ranges), at rest.
        control_model: the model the controller's inverse dynamics uses (same joints), e.g. one with
            wrong masses to see what model error costs; default ``model`` itself (an exact model).
    """

    def __init__(
        self,
        chain: SerialChain,
        model: mujoco.MjModel | None = None,
        config: TorqueConfig = TorqueConfig(),  # noqa: B008 - frozen, immutable default
        q0: ArrayLike | None = None,
        control_model: mujoco.MjModel | None = None,
    ) -> None:
        self._mj = require_mujoco()
        self.chain = chain
        self.config = config
        self.model = torque_model(chain) if model is None else model
        n = chain.n_joints
        self.n = n
        self._ctl = self.model if control_model is None else control_model
        for m in {id(self.model): self.model, id(self._ctl): self._ctl}.values():
            if m.nq != n or m.nv != n:
                raise ConfigError(
                    f"robot '{chain.name}': the MuJoCo model must have exactly the {n} joints of the chain"
                )
            try:
                dofs = np.array([m.joint(joint_name(i)).dofadr[0] for i in range(1, n + 1)])
            except KeyError as exc:
                raise ConfigError(f"robot '{chain.name}': the MuJoCo model has no joint {exc}") from None
            if not np.array_equal(dofs, np.arange(n)):
                raise ConfigError(f"robot '{chain.name}': the model's joints must be joint1..joint{n} in order")
        try:
            self._actuator = np.array([self.model.actuator(motor_name(i)).id for i in range(1, n + 1)])
        except KeyError as exc:
            raise ConfigError(
                f"robot '{chain.name}': the MuJoCo model has no torque actuator {exc} "
                "(build it with skincal.sim.dynamics.torque_model)"
            ) from None
        self._data = self._mj.MjData(self.model)
        self._scratch = self._mj.MjData(self._ctl)
        self.effort_limit = _vector(
            config.effort_limit if config.effort_limit is not None else effort_limits(chain), n, "effort limit"
        )
        vel = config.velocity_limit if config.velocity_limit is not None else chain.velocity_limit
        self.velocity_limit = np.full(n, np.inf) if vel is None else _vector(vel, n, "velocity limit")
        self.acceleration_limit = acceleration_limits(chain, self.model, self.effort_limit, config.acceleration_limit)
        self.h = float(self.model.opt.timestep)
        self.saturated = np.zeros(n, dtype=bool)
        self.saturation_steps = 0
        self.torque = np.zeros(n)
        self._kp = self._kd = np.zeros(n)
        self.reset(self._default_q() if q0 is None else q0)

    # ------------------------------------------------------------------------------------- state
    def _default_q(self) -> FloatArray:
        q = np.zeros(self.n)
        if self.chain.joint_lower is not None:
            q = np.clip(q, self.chain.joint_lower, self.chain.joint_upper)
        return q

    @property
    def data(self) -> mujoco.MjData:
        """The simulation's ``MjData`` (set ``mocap_pos`` here to move a scene's obstacles)."""
        return self._data

    @property
    def q(self) -> FloatArray:
        """Joint positions ``(n,)`` (a copy)."""
        return self._data.qpos[: self.n].copy()

    @property
    def qd(self) -> FloatArray:
        """Joint velocities ``(n,)`` (a copy)."""
        return self._data.qvel[: self.n].copy()

    @property
    def q_ref(self) -> FloatArray:
        """Reference joint positions ``(n,)`` being tracked (a copy)."""
        return self._q_ref.copy()

    @property
    def qd_ref(self) -> FloatArray:
        """Reference joint velocities ``(n,)`` (a copy)."""
        return self._qd_ref.copy()

    @property
    def time(self) -> float:
        """Simulated time, s."""
        return float(self._data.time)

    def reset(self, q: ArrayLike, qd: ArrayLike | None = None) -> None:
        """Put the robot at ``q`` moving at ``qd`` (default at rest), the reference on it, the clock at 0."""
        q = self._joint_vector(q, "q")
        qd = np.zeros(self.n) if qd is None else self._joint_vector(qd, "qd")
        self._mj.mj_resetData(self.model, self._data)
        self._data.qpos[: self.n] = q
        self._data.qvel[: self.n] = qd
        self._mj.mj_forward(self.model, self._data)
        self._q_ref, self._qd_ref, self._qdd_ref = q.copy(), qd.copy(), np.zeros(self.n)
        self.saturated[:] = False
        self.saturation_steps = 0
        self._set_gains(q)

    def _set_gains(self, q: FloatArray) -> None:
        n, cfg = self.n, self.config
        kp = _vector(DEFAULT_KP if cfg.kp is None else cfg.kp, n, "kp")
        kd = 2.0 * np.sqrt(kp) if cfg.kd is None else _vector(cfg.kd, n, "kd")
        if cfg.mode == "impedance" and (cfg.kp is None or cfg.kd is None):
            inertia = np.diag(self.mass_matrix(q))
            kp = kp * inertia if cfg.kp is None else kp
            kd = kd * inertia if cfg.kd is None else kd
        self._kp, self._kd = kp, kd

    def _joint_vector(self, value: ArrayLike, what: str) -> FloatArray:
        try:
            arr = np.array(value, dtype=float)
        except (TypeError, ValueError):
            raise ConfigError(f"{what} must be {self.n} numbers") from None
        if arr.shape != (self.n,) or not np.all(np.isfinite(arr)):
            raise ConfigError(f"{what} must be {self.n} finite numbers, got shape {arr.shape}")
        return arr

    # ------------------------------------------------------------------------------------- dynamics
    def mass_matrix(self, q: ArrayLike) -> FloatArray:
        """Joint-space inertia ``M(q)`` ``(n, n)`` (armature included)."""
        s = self._scratch
        s.qpos[:] = q
        s.qvel[:] = 0.0
        self._mj.mj_fwdPosition(self._ctl, s)
        return full_mass_matrix(self._ctl, s)

    def inverse_dynamics(self, q: ArrayLike, qd: ArrayLike, qdd: ArrayLike) -> FloatArray:
        """Joint torques ``(n,)`` that give acceleration ``qdd`` at ``(q, qd)``: MuJoCo's ``mj_inverse``
        on the controller's model (``M qdd + c + g`` less the passive forces: damping; armature is in
        ``M``), without constraint forces (the joint-limit stops are the plant's, not the controller's)."""
        s, opt = self._scratch, self._ctl.opt
        s.qpos[:], s.qvel[:], s.qacc[:] = q, qd, qdd
        flags = opt.disableflags
        opt.disableflags = flags | self._mj.mjtDisableBit.mjDSBL_CONSTRAINT  # a controller models no limit stops
        try:
            self._mj.mj_inverse(self._ctl, s)
        finally:
            opt.disableflags = flags
        return s.qfrc_inverse.copy()

    def control_torque(self) -> FloatArray:
        """The (unclipped) torque of the tracking law at the current state and reference."""
        q, qd = self._data.qpos[: self.n], self._data.qvel[: self.n]
        e, ed = self._q_ref - q, self._qd_ref - qd
        if self.config.mode == "computed-torque":
            return self.inverse_dynamics(q, qd, self._qdd_ref + self._kp * e + self._kd * ed)
        return self._kp * e + self._kd * ed + self.inverse_dynamics(q, qd, self._qdd_ref)

    def step(self, qd_cmd: ArrayLike, dt: float) -> None:
        """Track the velocity command ``qd_cmd`` ``(n,)`` rad/s for one control period ``dt`` s (a
        whole number of model timesteps), torques clipped at the effort limits."""
        cmd = self._joint_vector(qd_cmd, "qd_cmd")
        steps = int(round(float(dt) / self.h))
        if steps < 1 or abs(steps * self.h - dt) > 1e-9:
            raise ConfigError(f"control period {dt!r} s must be a whole number of model timesteps ({self.h} s)")
        over = np.max(np.abs(cmd) / self.velocity_limit)
        if over > 1.0:
            cmd = cmd / over  # uniformly into the velocity limits: same direction
        mj, model, data = self._mj, self.model, self._data
        flags, ctl_flags = model.opt.disableflags, self._ctl.opt.disableflags
        if not self.config.sensors:  # (the controller's model never needs its sensors)
            model.opt.disableflags = flags | mj.mjtDisableBit.mjDSBL_SENSOR
        self._ctl.opt.disableflags = ctl_flags | mj.mjtDisableBit.mjDSBL_SENSOR
        self.saturated[:] = False
        try:
            for _ in range(steps):
                delta = cmd - self._qd_ref
                need = np.max(np.abs(delta) / (self.acceleration_limit * self.h))
                self._qdd_ref = (delta / need if need > 1.0 else delta) / self.h
                # the law acts on the errors at the start of the step; the reference then moves as
                # MuJoCo's semi-implicit step moves a robot that follows it exactly
                tau = self.control_torque()
                self._qd_ref = self._qd_ref + self.h * self._qdd_ref
                q_next = data.qpos[: self.n] + self.h * data.qvel[: self.n]  # about where the robot goes
                lag = np.clip(
                    self._q_ref + self.h * self._qd_ref - q_next, -self.config.max_error, self.config.max_error
                )
                self._q_ref = q_next + lag
                clipped = np.clip(tau, -self.effort_limit, self.effort_limit)
                sat = clipped != tau
                if sat.any():
                    self.saturated |= sat
                    self.saturation_steps += 1
                self.torque = clipped
                data.ctrl[self._actuator] = clipped
                mj.mj_step(model, data)
        finally:
            model.opt.disableflags = flags
            self._ctl.opt.disableflags = ctl_flags
