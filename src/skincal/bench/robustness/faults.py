"""The robustness benchmark's faults (:data:`FAULTS`, :class:`Fault`): each a change of the base session
(joint-velocity noise, IMU preset, unit clocks, saturation, stuck axis, bias drift, knock, gravity, the
faults of real recordings) with its target (the package docstring, "Faults")."""

from __future__ import annotations

from dataclasses import dataclass

from skincal.sim.faults import GRAVITY_DECLARED_MPS2
from skincal.skin.clock import ClockModel, get_clock_model
from skincal.skin.imu import STANDARD_GRAVITY

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
