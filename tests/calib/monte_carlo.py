"""Monte Carlo of the default calibrator's reported std (issue 27, item 3): helpers.

A session whose units are *replicas*: several units at exactly the same pose on the same link, each
with its own IMU errors (bias, scale, misalignment), noise, jitter and drops (``sim.analytic`` draws
every unit from its own child generator) and an exact joint stream. With the links given, ``mle``
calibrates every unit from its own samples only, so the replicas' estimates are independent draws of
one estimator at one geometry: their spread about the truth is what the reported std must describe.

For a component with reported std ``s_m`` and error ``e_m`` (replica ``m``), ``z_m = e_m / s_m`` is
standard normal when the std is right, so ``mean(z^2)`` over ``N`` replicas is ``chi2(N) / N``.
Components of one replica are correlated (e.g. position x and y), so a pool of ``K`` components over
``N`` replicas has fewer than ``N K`` degrees of freedom; for Gaussian ``z`` with correlation ``rho``,
``Var(sum z^2) = 2 N sum_ij rho_ij^2``, hence Satterthwaite's effective dof ``nu = N K^2 / sum_ij
rho_ij^2`` (``N K`` for independent components, ``N`` for identical ones). The test interval of
``mean(z^2)`` is ``[chi2.ppf(a/2, nu), chi2.ppf(1 - a/2, nu)] / nu``.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.signal import lfilter
from scipy.spatial.transform import Rotation
from scipy.stats import chi2

from skincal.calib import calibrate
from skincal.data.dataset import Dataset, ImuStream
from skincal.data.result import CalibrationResult
from skincal.kinematics import panda
from skincal.protocol import ProtocolConfig, build_trajectory
from skincal.sim.analytic import simulate
from skincal.skin.imu import ImuModel, get_imu_model
from skincal.skin.placement import random_placement

ALPHA = 2e-4
"""Two-sided false-alarm probability of each interval (the ~45 intervals of the Monte Carlo tests
together: about 1 % for a correct std)."""


@dataclass(frozen=True)
class Ratio:
    """``mean(z^2)`` of a pool of normalised errors and its interval if the std were right."""

    value: float
    low: float
    high: float
    dof: float

    @property
    def ok(self) -> bool:
        return self.low <= self.value <= self.high

    def __str__(self) -> str:
        return (
            f"spread/std {np.sqrt(self.value):.3f} (allowed {np.sqrt(self.low):.3f}..{np.sqrt(self.high):.3f}, "
            f"{self.dof:.0f} dof)"
        )


def variance_ratio(z: np.ndarray, alpha: float = ALPHA) -> Ratio:
    """``mean(z^2)`` of ``z`` ``(N, K)`` (replicas x components) and its ``1 - alpha`` interval (module doc)."""
    z = np.asarray(z, dtype=float).reshape(len(z), -1)
    n, k = z.shape
    if k == 1:
        nu = float(n)
    else:
        rho = np.corrcoef(z, rowvar=False)
        nu = n * k**2 / float(np.sum(rho**2))
    return Ratio(float(np.mean(z**2)), chi2.ppf(alpha / 2, nu) / nu, chi2.ppf(1 - alpha / 2, nu) / nu, nu)


QUANTITIES = ("position", "rotation", "accel_bias", "time_offset")
"""What is compared: position per axis (link frame), rotation per link axis, accelerometer bias per
axis (unit frame), time offset."""


def normalised_errors(result: CalibrationResult, truth: Dataset, units: list[str]) -> dict[str, np.ndarray]:
    """Per quantity, ``(len(units), k)`` errors divided by the reported std.

    Rotation: ``rotvec(R_est R_true^T)`` (the error as a rotation about the *link* axes, the frame
    ``rotation_std_deg`` is stated in), deg."""
    out: dict[str, list] = {q: [] for q in QUANTITIES}
    for name in units:
        unit, pose, sensor = result.units[name], truth.truth[name], truth.truth_sensor[name]
        assert unit.imu is not None and unit.position_std_m is not None and unit.rotation_std_deg is not None
        out["position"].append((unit.pose.p_link_su - pose.p_link_su) / unit.position_std_m)
        d_rot = np.degrees(Rotation.from_matrix(unit.pose.R_link_su @ pose.R_link_su.T).as_rotvec())
        out["rotation"].append(d_rot / unit.rotation_std_deg)
        out["accel_bias"].append((unit.imu.accel_bias_mps2 - sensor["accel_bias"]) / unit.imu.accel_bias_std_mps2)
        assert unit.imu.time_offset_std_s is not None
        out["time_offset"].append([(unit.imu.time_offset_s - sensor["time_offset_s"]) / unit.imu.time_offset_std_s])
    return {q: np.array(v, dtype=float) for q, v in out.items()}


# ---------------------------------------------------------------------------------------- sessions
MC_REPLICAS = 100
"""Replicas per pose of the white-noise session (3 poses: 300 units)."""
MC_COLOURED_REPLICAS = 40
"""Replicas per pose of the coloured-noise session (2 poses: 80 units)."""
AR1_PHI = 0.6
"""Lag-1 correlation of the coloured accelerometer noise ``e_k = phi e_(k-1) + sqrt(1 - phi^2) sigma w_k``
(integrated autocorrelation ``(1 + phi) / (1 - phi) = 4``)."""
AR1_SIGMA = 0.05
"""Its stationary std per axis, m/s^2 (``realistic``'s white accelerometer noise is 0.031)."""
Q_MC = np.array([0.0, -0.3, 0.0, -2.2, 0.0, 2.0, np.pi / 4])
"""The Panda configuration the static poses are drawn about, rad."""
MC_OPTIONS = {"gravity": False, "consistency": False}
"""``mle`` options of the Monte Carlo: the simulated gravity is exact (so its 0.2 % prior, a statement
about the site, is not in the spread: ``gravity=False``); the split check (``consistency``) inflates
only where parts disagree, which replicas of an honest session do in 1 % of units, and costs four fits
more per unit."""


@dataclass(frozen=True)
class McSession:
    """A replica session (``monte_carlo`` module doc) and its calibration.

    ``groups``: per base pose (link 2, 3, 4) the names of its replicas."""

    dataset: Dataset
    result: CalibrationResult
    groups: tuple[tuple[str, ...], ...]

    @property
    def units(self) -> list[str]:
        return [u for g in self.groups for u in g]


def replica_session(replicas: int, links: tuple[int, ...], seed: int, imu: ImuModel, colour=None) -> McSession:
    """Units on ``links`` (one random pose each), ``replicas`` copies of each, on a short protocol whose
    static poses stay near :data:`Q_MC` (+-0.3 rad on joints 2-4, joint 1 anywhere: the gravity
    directions in the link frames span a narrow cone, so the rotation std differ per link axis) and
    only joints 1-4 excited (58 s). ``colour(rng, stream)``: replaces each unit's accelerometer noise."""
    chain = panda()
    rng = np.random.default_rng(seed)
    poses = np.tile(Q_MC, (5, 1))
    poses[:, 0] = rng.uniform(-2.0, 2.0, 5)
    poses[:, 1:4] += rng.uniform(-0.3, 0.3, (5, 3))
    config = ProtocolConfig(
        poses=poses, amplitude=1.2, excite_duration=1.0, rest_duration=0.5, static_duration=0.5,
        excited_joints=(0, 1, 2, 3),
    )
    base = random_placement(chain, len(links), rng, links=list(links))
    groups = tuple(tuple(f"{b}_{m:03d}" for m in range(replicas)) for b in base)
    placements = {name: pose for (b, pose), g in zip(base.items(), groups, strict=True) for name in g}
    ds = simulate(chain, placements, build_trajectory(chain, config, rng), imu, rng)
    if colour is not None:
        ds = replace(ds, imu={u: colour(rng, s) for u, s in ds.imu.items()})
    result = calibrate(ds, "mle", links={u: p.link for u, p in placements.items()}, **MC_OPTIONS)
    return McSession(ds, result, groups)


def ar1_noise(rng: np.random.Generator, stream: ImuStream) -> ImuStream:
    """``stream`` with AR(1) accelerometer noise (:data:`AR1_PHI`, :data:`AR1_SIGMA`) added per axis."""
    w = rng.normal(0.0, AR1_SIGMA * np.sqrt(1.0 - AR1_PHI**2), stream.accel.shape)
    e0 = rng.normal(0.0, AR1_SIGMA, (1, 3))  # the state before the first sample: stationary from the start
    e = lfilter([1.0], [1.0, -AR1_PHI], w, axis=0, zi=AR1_PHI * e0)[0]
    return ImuStream(stream.t, stream.accel + e, stream.gyro)


def white_session() -> McSession:
    """300 units (100 replicas on each of links 2, 3, 4), ``realistic`` IMUs, white noise."""
    return replica_session(MC_REPLICAS, (2, 3, 4), 1, get_imu_model("realistic"))


def coloured_session() -> McSession:
    """80 units (40 replicas on links 3 and 4), ``realistic`` IMUs whose white accelerometer noise is
    replaced by AR(1) noise (:data:`AR1_PHI`, :data:`AR1_SIGMA`)."""
    imu = replace(get_imu_model("realistic"), accel_noise_density=0.0)
    return replica_session(MC_COLOURED_REPLICAS, (3, 4), 2, imu, colour=ar1_noise)
