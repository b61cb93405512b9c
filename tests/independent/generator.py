"""An independent generator of skincal datasets: its own robots, its own DH -> MJCF, MuJoCo physics,
its own protocol and its own sensor/recording model. It imports nothing from ``skincal``.

What it models (see README.md next to this file):

* **Robots**: two invented arms (``arm6``, ``arm7``) given as modified (Craig) DH tables; link
  frame ``i`` = prod_{j <= i} RotX(alpha_{j-1}) TransX(a_{j-1}) RotZ(q_j + offset_j) TransZ(d_j),
  table rows ``[offset_j, d_j, a_{j-1}, alpha_{j-1}]`` (the dataset contract's ``/robot/dh``).
* **Physics**: MuJoCo. One body per link (capsules with mass), a hinge about each DH frame's z,
  a site per skin unit with an ``accelerometer`` and a ``gyro``. Readings come from
  ``mj_inverse`` with the analytic ``q, qd, qdd`` of the commanded trajectory imposed at each
  true IMU instant (the arm follows the trajectory exactly: rigid links, no servo error).
* **Protocol**: ``P`` random static poses (within 60 % of the joint limits); at each: rest 2 s,
  then per joint a windowed sinusoid ``q_j = q0_j + B sin(2 pi f t) w(t)`` (2-3 s, peak speed
  1-1.5 rad/s capped below the velocity limit, ``w`` a C2 ramp so it starts and stops at rest),
  rest 1-2 s after each; minimum-jerk moves between poses.
* **Recording**: joint states as a controller streams them (500 Hz, 18-bit encoder quantisation,
  velocity noise, stamp jitter, no qdd); IMUs at 100 Hz with their own phase, per-axis bias,
  scale, a non-symmetric misalignment, gyro bias, white noise, 16-bit quantisation and
  saturation, dropped samples, stamp jitter, a constant latency, and optionally clock drift,
  bias drift and a true gravity different from the one written in the file.

Unit frame: a real accelerometer's axes are not the board's (site's) axes. Its reading is
``a = P f_site + b`` with ``P = M diag(s)`` (``M`` non-symmetric). Writing ``P = A Rm`` (polar
decomposition, ``A`` symmetric, ``Rm`` a rotation) gives ``a = A f_U + b`` in the frame ``U`` with
``R_link_U = R_link_site Rm^T``: the accelerometer's polar frame, the only frame an
accelerometer-only calibration can recover. ``/truth`` and :attr:`UnitTruth.R` hold that frame;
:attr:`UnitTruth.R_site` is the board's. The gyroscope is modelled in frame ``U`` as well.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

import h5py
import mujoco
import numpy as np

G_FILE = 9.81
"""Gravity written to the file (``/robot`` attr ``gravity = [0, 0, -G_FILE]``)."""

_PI = np.pi


# ---------------------------------------------------------------------------------------- robots
@dataclass(frozen=True)
class RobotSpec:
    """An invented arm: modified DH rows ``[theta_offset, d, a, alpha]`` (a, alpha of the previous
    link, Craig), limits in rad and rad/s."""

    name: str
    dh: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    velocity_limit: np.ndarray

    @property
    def n(self) -> int:
        return int(self.dh.shape[0])


def _arm6() -> RobotSpec:
    dh = np.array(
        [
            [0.0, 0.30, 0.00, 0.0],
            [-_PI / 2, 0.00, 0.12, -_PI / 2],
            [0.0, 0.00, 0.35, 0.0],
            [0.0, 0.28, 0.08, -_PI / 2],
            [0.0, 0.00, 0.00, _PI / 2],
            [0.0, 0.11, 0.00, -_PI / 2],
        ]
    )
    return RobotSpec(
        "arm6-indep",
        dh,
        lower=np.array([-2.8, -1.6, -2.6, -2.9, -1.9, -3.1]),
        upper=np.array([2.8, 1.8, 2.2, 2.9, 2.1, 3.1]),
        velocity_limit=np.array([1.9, 1.9, 2.2, 2.6, 2.6, 3.0]),
    )


def _arm7() -> RobotSpec:
    dh = np.array(
        [
            [0.0, 0.25, 0.00, 0.0],
            [0.0, 0.00, 0.05, -_PI / 2],
            [0.0, 0.30, 0.00, _PI / 2],
            [0.0, 0.00, 0.10, _PI / 2],
            [0.0, 0.27, 0.10, -_PI / 2],
            [0.0, 0.00, 0.00, _PI / 2],
            [0.3, 0.12, 0.06, -_PI / 2],
        ]
    )
    return RobotSpec(
        "arm7-indep",
        dh,
        lower=np.array([-2.7, -1.8, -2.7, -2.6, -2.8, -1.7, -2.9]),
        upper=np.array([2.7, 1.8, 2.7, 0.4, 2.8, 2.9, 2.9]),
        velocity_limit=np.array([1.6, 1.6, 1.8, 1.2, 2.4, 2.4, 2.8]),
    )


ROBOTS = {"arm6": _arm6, "arm7": _arm7}


def robot_spec(name: str) -> RobotSpec:
    if name not in ROBOTS:
        raise ValueError(f"unknown robot {name!r} (have {sorted(ROBOTS)})")
    return ROBOTS[name]()


# ---------------------------------------------------------------------------------------- geometry
def rot_x(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rot_z(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def homogeneous(R: np.ndarray, p: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = p
    return T


def dh_step(offset: float, d: float, a: float, alpha: float, q: float) -> np.ndarray:
    """Modified DH: RotX(alpha) TransX(a) RotZ(q + offset) TransZ(d) as a 4x4 matrix."""
    A = homogeneous(rot_x(alpha), np.zeros(3))
    B = homogeneous(np.eye(3), np.array([a, 0.0, 0.0]))
    C = homogeneous(rot_z(q + offset), np.zeros(3))
    D = homogeneous(np.eye(3), np.array([0.0, 0.0, d]))
    return A @ B @ C @ D


def forward_kinematics(dh: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Frames {0}..{n} in the base, ``(n + 1, 4, 4)``, by plain products of :func:`dh_step`."""
    frames = [np.eye(4)]
    for (offset, d, a, alpha), qj in zip(dh, q, strict=True):
        frames.append(frames[-1] @ dh_step(offset, d, a, alpha, qj))
    return np.array(frames)


def quat_wxyz(R: np.ndarray) -> np.ndarray:
    """Unit quaternion (w, x, y, z), w >= 0, of a rotation matrix (Shepperd's method)."""
    m = np.asarray(R, dtype=float)
    tr = np.trace(m)
    cands = [tr, m[0, 0], m[1, 1], m[2, 2]]
    k = int(np.argmax(cands))
    if k == 0:
        w = 0.5 * np.sqrt(1.0 + tr)
        q = np.array([w, (m[2, 1] - m[1, 2]) / (4 * w), (m[0, 2] - m[2, 0]) / (4 * w), (m[1, 0] - m[0, 1]) / (4 * w)])
    else:
        i = k - 1
        j, l = (i + 1) % 3, (i + 2) % 3
        s = 2.0 * np.sqrt(1.0 + m[i, i] - m[j, j] - m[l, l])
        v = np.zeros(3)
        v[i] = 0.25 * s
        v[j] = (m[j, i] + m[i, j]) / s
        v[l] = (m[l, i] + m[i, l]) / s
        w = (m[l, j] - m[j, l]) / s
        q = np.array([w, *v])
    q /= np.linalg.norm(q)
    return q if q[0] >= 0 else -q


def random_rotation(rng: np.random.Generator) -> np.ndarray:
    """Uniformly random rotation (normalised Gaussian quaternion)."""
    w, x, y, z = rng.normal(size=4)
    n = np.sqrt(w * w + x * x + y * y + z * z)
    w, x, y, z = w / n, x / n, y / n, z / n
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def rotation_log(R: np.ndarray) -> np.ndarray:
    """Rotation vector (axis * angle, rad) of a rotation matrix."""
    q = quat_wxyz(R)
    v = q[1:]
    s = np.linalg.norm(v)
    if s < 1e-15:
        return 2.0 * v
    return v / s * 2.0 * np.arctan2(s, q[0])


# ---------------------------------------------------------------------------------------- MJCF
@dataclass(frozen=True)
class Placement:
    """A skin unit's site: link (1-based), position and board orientation in that link frame."""

    name: str
    link: int
    position: np.ndarray
    R_site: np.ndarray


def _fmt(v) -> str:
    return " ".join(f"{float(x):.17g}" for x in np.ravel(v))


def mjcf_xml(spec: RobotSpec, placements: list[Placement], gravity: float = G_FILE) -> str:
    """MJCF of ``spec`` with one body per link (body frame = DH frame {i}) and a site + accelerometer
    + gyro per placement. Body ``i`` sits in body ``i-1`` at RotX(alpha) TransX(a) RotZ(offset)
    TransZ(d); its hinge turns about its own z through its origin, so the body frame is
    RotX(alpha) TransX(a) RotZ(offset + q) TransZ(d) (RotZ and TransZ commute)."""
    n = spec.n
    # fixed parent -> child transforms
    fixed = [dh_step(*row, 0.0) for row in spec.dh]
    by_link: dict[int, list[Placement]] = {}
    for p in placements:
        by_link.setdefault(p.link, []).append(p)
    lines = [
        f'<mujoco model="{spec.name}">',
        '  <compiler angle="radian"/>',
        f'  <option gravity="0 0 {-gravity:.17g}" timestep="0.002">',
        '    <flag contact="disable"/>',
        "  </option>",
        '  <default><geom density="1500" rgba="0.6 0.6 0.7 1"/></default>',
        "  <worldbody>",
        '    <geom name="base" type="cylinder" size="0.08 0.02" pos="0 0 0.02"/>',
    ]
    indent = "    "
    for i in range(1, n + 1):
        T = fixed[i - 1]
        lines.append(f'{indent}<body name="link{i}" pos="{_fmt(T[:3, 3])}" quat="{_fmt(quat_wxyz(T[:3, :3]))}">')
        inner = indent + "  "
        lines.append(f'{inner}<joint name="j{i}" type="hinge" axis="0 0 1" pos="0 0 0"/>')
        # a capsule towards the next joint's origin (or a short one along z on the last link)
        child = fixed[i][:3, 3] if i < n else np.array([0.0, 0.0, 0.08])
        if np.linalg.norm(child) > 1e-3:
            lines.append(f'{inner}<geom type="capsule" fromto="0 0 0 {_fmt(child)}" size="0.035"/>')
        else:
            lines.append(f'{inner}<geom type="sphere" size="0.045"/>')
        for p in by_link.get(i, []):
            lines.append(
                f'{inner}<site name="{p.name}" pos="{_fmt(p.position)}" quat="{_fmt(quat_wxyz(p.R_site))}" '
                'size="0.01"/>'
            )
        indent = inner
    for _ in range(n, 0, -1):
        indent = indent[:-2]
        lines.append(f"{indent}</body>")
    lines.append("  </worldbody>")
    lines.append("  <sensor>")
    for p in placements:
        lines.append(f'    <accelerometer name="{p.name}_acc" site="{p.name}"/>')
        lines.append(f'    <gyro name="{p.name}_gyro" site="{p.name}"/>')
    lines.append("  </sensor>")
    lines.append("</mujoco>")
    return "\n".join(lines) + "\n"


def build_model(spec: RobotSpec, placements: list[Placement], gravity: float = G_FILE) -> mujoco.MjModel:
    return mujoco.MjModel.from_xml_string(mjcf_xml(spec, placements, gravity))


def sensor_slices(model: mujoco.MjModel, name: str) -> tuple[slice, slice]:
    """Slices of ``sensordata`` holding unit ``name``'s accelerometer and gyro."""
    acc = model.sensor(f"{name}_acc")
    gyr = model.sensor(f"{name}_gyro")
    return slice(acc.adr[0], acc.adr[0] + 3), slice(gyr.adr[0], gyr.adr[0] + 3)


def mujoco_readings(
    model: mujoco.MjModel, name: str, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Accelerometer (specific force) and gyro of unit ``name`` in its site frame at each row of
    ``q, qd, qdd`` (``mj_inverse`` with the motion imposed)."""
    data = mujoco.MjData(model)
    sa, sg = sensor_slices(model, name)
    M = q.shape[0]
    acc = np.empty((M, 3))
    gyr = np.empty((M, 3))
    for k in range(M):
        data.qpos[:] = q[k]
        data.qvel[:] = qd[k]
        data.qacc[:] = qdd[k]
        mujoco.mj_inverse(model, data)
        acc[k] = data.sensordata[sa]
        gyr[k] = data.sensordata[sg]
    return acc, gyr


# ---------------------------------------------------------------------------------------- trajectory
def _minjerk(x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """10x^3 - 15x^4 + 6x^5 on [0, 1] and its first two derivatives."""
    x = np.clip(x, 0.0, 1.0)
    s = x**3 * (10 - 15 * x + 6 * x * x)
    ds = 30 * x**2 * (1 - x) ** 2
    dds = 60 * x * (1 - x) * (1 - 2 * x)
    return s, ds, dds


@dataclass(frozen=True)
class _Piece:
    kind: str  # "rest", "move", "excite"
    t0: float
    t1: float
    q0: np.ndarray
    q1: np.ndarray | None = None  # move target
    joint: int = -1
    amp: float = 0.0  # rad
    freq: float = 0.0  # Hz
    ramp: float = 0.5  # s

    def eval(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        M, n = t.shape[0], self.q0.shape[0]
        q = np.tile(self.q0, (M, 1))
        qd = np.zeros((M, n))
        qdd = np.zeros((M, n))
        T = self.t1 - self.t0
        u = np.clip(t - self.t0, 0.0, T)
        if self.kind == "move":
            s, ds, dds = _minjerk(u / T)
            dq = self.q1 - self.q0
            q += s[:, None] * dq
            qd = (ds / T)[:, None] * dq
            qdd = (dds / T**2)[:, None] * dq
        elif self.kind == "excite":
            Tr = self.ramp
            rise, drise, ddrise = _minjerk(u / Tr)
            fall, dfall, ddfall = _minjerk((T - u) / Tr)
            up = u < Tr
            down = u > T - Tr
            w = np.where(up, rise, np.where(down, fall, 1.0))
            dw = np.where(up, drise / Tr, np.where(down, -dfall / Tr, 0.0))
            ddw = np.where(up, ddrise / Tr**2, np.where(down, ddfall / Tr**2, 0.0))
            om = 2 * np.pi * self.freq
            s, c = np.sin(om * u), np.cos(om * u)
            j, B = self.joint, self.amp
            q[:, j] += B * s * w
            qd[:, j] = B * (om * c * w + s * dw)
            qdd[:, j] = B * (-(om**2) * s * w + 2 * om * c * dw + s * ddw)
        return q, qd, qdd


@dataclass(frozen=True)
class Trajectory:
    pieces: list[_Piece]

    @property
    def duration(self) -> float:
        return self.pieces[-1].t1

    def __call__(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        t = np.asarray(t, dtype=float)
        starts = np.array([p.t0 for p in self.pieces])
        idx = np.clip(np.searchsorted(starts, t, side="right") - 1, 0, len(self.pieces) - 1)
        n = self.pieces[0].q0.shape[0]
        q = np.empty((t.shape[0], n))
        qd = np.empty_like(q)
        qdd = np.empty_like(q)
        for k in np.unique(idx):
            sel = idx == k
            q[sel], qd[sel], qdd[sel] = self.pieces[k].eval(t[sel])
        return q, qd, qdd


@dataclass(frozen=True)
class ProtocolSegment:
    t_start: float
    t_end: float
    kind: int  # 0 static, 1 dynamic
    pose: int
    joint: int  # 0-based, -1 when static


def make_protocol(
    spec: RobotSpec,
    rng: np.random.Generator,
    n_poses: int,
    *,
    first_rest_s: float = 2.0,
    excite_s: tuple[float, float] = (2.0, 3.0),
    rest_s: tuple[float, float] = (1.0, 2.0),
    speed: tuple[float, float] = (1.0, 1.5),
    freq_hz: tuple[float, float] = (0.5, 1.0),
    pose_fraction: float = 0.6,
) -> tuple[Trajectory, list[ProtocolSegment], np.ndarray]:
    """The calibration motion: random poses, rest, one-joint excitations, rests, moves.
    Returns the trajectory, its segments and the poses ``(P, n)``."""
    n = spec.n
    mid = 0.5 * (spec.lower + spec.upper)
    half = 0.5 * (spec.upper - spec.lower)
    poses = mid + pose_fraction * half * rng.uniform(-1, 1, size=(n_poses, n))
    pieces: list[_Piece] = []
    segs: list[ProtocolSegment] = []
    t = 0.0
    for k, pose in enumerate(poses):
        if k > 0:
            prev = poses[k - 1]
            dq = np.abs(pose - prev)
            T = max(2.0, float(np.max(1.875 * dq / (0.7 * spec.velocity_limit))))
            pieces.append(_Piece("move", t, t + T, prev, pose))
            t += T
        pieces.append(_Piece("rest", t, t + first_rest_s, pose))
        segs.append(ProtocolSegment(t, t + first_rest_s, 0, k, -1))
        t += first_rest_s
        for j in range(n):
            T = float(rng.uniform(*excite_s))
            f = float(rng.uniform(*freq_hz))
            om = 2 * np.pi * f
            A = min(float(rng.uniform(*speed)), 0.9 * float(spec.velocity_limit[j]))
            B = A / om
            # room to the limits
            room = min(spec.upper[j] - pose[j], pose[j] - spec.lower[j]) - 0.02
            B = min(B, room)
            piece = _Piece("excite", t, t + T, pose, joint=j, amp=B, freq=f, ramp=0.5)
            # the window's slope adds a little speed: keep the true peak under the limit
            tt = np.linspace(t, t + T, 2001)
            peak = np.abs(piece.eval(tt)[1][:, j]).max()
            if peak > 0.95 * spec.velocity_limit[j]:
                piece = _Piece("excite", t, t + T, pose, joint=j, amp=B * 0.95 * spec.velocity_limit[j] / peak,
                               freq=f, ramp=0.5)
            pieces.append(piece)
            segs.append(ProtocolSegment(t, t + T, 1, k, j))
            t += T
            r = float(rng.uniform(*rest_s))
            pieces.append(_Piece("rest", t, t + r, pose))
            segs.append(ProtocolSegment(t, t + r, 0, k, -1))
            t += r
    return Trajectory(pieces), segs, poses


# ---------------------------------------------------------------------------------------- sensors
ACCEL_RANGE = 8 * 9.80665
ACCEL_LSB = 2 * ACCEL_RANGE / 65536
GYRO_RANGE = np.radians(2000.0)
GYRO_LSB = 2 * GYRO_RANGE / 65536


def quantise(x: np.ndarray, lsb: float) -> np.ndarray:
    """16-bit two's-complement ADC: round to the LSB, saturate at -32768..32767 counts."""
    return np.clip(np.round(x / lsb), -32768, 32767) * lsb


@dataclass(frozen=True)
class UnitTruth:
    """What the generator did to one unit.

    ``R`` is the accelerometer's polar frame in the link frame (written to ``/truth``; what a
    calibration must find); ``R_site`` the board/site frame (MuJoCo's). ``accel_matrix`` is
    ``P`` of ``a = P f_site + b``; ``accel_sym`` the symmetric ``A`` of ``a = A f_U + b``.
    ``time_offset_s`` is the latency at t = 0; with clock drift the latency at host time ``t`` is
    about ``time_offset_s + clock_drift_ppm * 1e-6 * t``. ``bias_drift_mps2`` is the total change
    of the accelerometer bias (vector, unit frame) from the start to the end of the session.
    """

    name: str
    link: int
    position: np.ndarray
    R: np.ndarray
    R_site: np.ndarray
    accel_matrix: np.ndarray
    accel_sym: np.ndarray
    accel_bias: np.ndarray
    gyro_bias: np.ndarray
    time_offset_s: float
    clock_drift_ppm: float
    bias_drift_mps2: np.ndarray
    n_samples: int
    n_dropped: int

    def mean_time_offset(self, duration_s: float) -> float:
        """The latency averaged over a session of ``duration_s`` (what a constant-offset fit sees)."""
        return self.time_offset_s + self.clock_drift_ppm * 1e-6 * duration_s / 2


@dataclass(frozen=True)
class Truth:
    path: Path
    robot: RobotSpec
    units: dict[str, UnitTruth]
    duration_s: float
    gravity_true: float
    segments: list[ProtocolSegment]
    poses: np.ndarray
    n_joint_samples: int
    seed: int
    generation_s: float
    placements: list[Placement] = field(default_factory=list)
    trajectory: Trajectory | None = None


def _place_units(
    spec: RobotSpec, rng: np.random.Generator, n_units: int, units_on_link1: int
) -> list[Placement]:
    n = spec.n
    links = list(rng.choice(np.arange(2, n + 1), size=n_units, replace=n_units > n - 1))
    if n_units >= n - 1:  # make sure the distal link is covered
        links[0] = n
    out = []
    all_links = [1] * units_on_link1 + [int(x) for x in links]
    for k, link in enumerate(all_links):
        direction = rng.normal(size=3)
        direction /= np.linalg.norm(direction)
        position = direction * rng.uniform(0.02, 0.15)
        out.append(Placement(f"u{k + 1}", int(link), position, random_rotation(rng)))
    return out


def _timing_param(value: float | tuple[float, float], rng: np.random.Generator) -> float:
    if isinstance(value, tuple):
        return float(rng.uniform(*value))
    return float(value)


def make_dataset(
    path: str | Path,
    *,
    robot: str = "arm6",
    seed: int = 0,
    n_units: int = 5,
    units_on_link1: int = 0,
    n_poses: int | None = None,
    segments: bool = True,
    # joint stream (a controller)
    joint_rate_hz: float = 500.0,
    joint_noise: bool = True,
    qd_noise_std: float = 3e-3,
    encoder_bits: int | None = 18,
    joint_jitter_s: float = 1e-4,
    # IMUs
    imu_rate_hz: float = 100.0,
    imu_faults: bool = True,
    accel_bias_std: float = 0.3,
    accel_scale_std: float = 0.02,
    accel_misalignment_std: float = 0.01,
    gyro_bias_std: float = np.radians(5.0),
    accel_noise: float = 0.01 * np.sqrt(50.0),
    gyro_noise: float = 2e-3 * np.sqrt(50.0),
    drop_fraction: float = 0.01,
    imu_jitter_s: float = 1e-3,
    time_offset_s: float | tuple[float, float] = (0.005, 0.03),
    clock_drift_ppm: float = 0.0,
    bias_drift: float = 0.0,
    gravity_true: float = G_FILE,
    write_sensor_truth: bool = False,
) -> Truth:
    """Simulate one calibration session and write it to ``path`` (HDF5, dataset contract v1).

    ``time_offset_s``: a number (every unit) or a ``(lo, hi)`` range drawn per unit.
    ``joint_noise=False`` gives exact ``q, qd`` at exact stamps; ``imu_faults=False`` gives the
    exact specific force and rate in the board frame (unit frame = site frame), still sampled at
    the IMU instants with the latency but without jitter or drops.
    Returns the :class:`Truth` (true poses, sensor errors, timing).
    """
    t_start = time.perf_counter()
    path = Path(path)
    rng = np.random.default_rng(seed)
    spec = robot_spec(robot)
    n = spec.n
    if n_poses is None:
        n_poses = 6 if n <= 6 else 5
    placements = _place_units(spec, rng, n_units, units_on_link1)
    traj, segs, poses = make_protocol(spec, rng, n_poses)
    T_total = traj.duration + 2.0  # a last rest at the final pose
    traj = Trajectory(traj.pieces + [_Piece("rest", traj.duration, T_total, poses[-1])])
    segs = segs + [ProtocolSegment(T_total - 2.0, T_total, 0, n_poses - 1, -1)]

    # ---- joint stream: a controller at joint_rate_hz
    tau_j = np.arange(0.0, T_total + 1e-9, 1.0 / joint_rate_hz)
    q, qd, _ = traj(tau_j)
    if joint_noise:
        if encoder_bits:
            step = 2 * np.pi / 2**encoder_bits
            q = np.round(q / step) * step
        qd = qd + rng.normal(0.0, qd_noise_std, size=qd.shape)
        t_j = tau_j + rng.normal(0.0, joint_jitter_s, size=tau_j.shape)
        t_j = np.maximum.accumulate(t_j)
        assert np.all(np.diff(t_j) > 0)
    else:
        t_j = tau_j

    # ---- IMUs
    model = build_model(spec, placements, gravity=gravity_true)
    units: dict[str, UnitTruth] = {}
    imu: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
    for pl in placements:
        offset = _timing_param(time_offset_s, rng)
        phase = rng.uniform(0.0, 1.0 / imu_rate_hz)
        tau = np.arange(phase, T_total, 1.0 / imu_rate_hz)
        if imu_faults:
            keep = rng.random(tau.shape[0]) >= drop_fraction
            n_dropped = int(np.sum(~keep))
            tau = tau[keep]
        else:
            n_dropped = 0
        qs, qds, qdds = traj(tau)
        f_site, w_site = mujoco_readings(model, pl.name, qs, qds, qdds)
        kappa = clock_drift_ppm * 1e-6
        stamps = tau + offset + kappa * tau
        if imu_faults:
            jitter = np.clip(rng.normal(0.0, imu_jitter_s, size=tau.shape), -3 * imu_jitter_s, 3 * imu_jitter_s)
            stamps = stamps + jitter
            stamps = np.maximum.accumulate(stamps)
            assert np.all(np.diff(stamps) > 0)
            scale = 1.0 + rng.normal(0.0, accel_scale_std, size=3)
            Mis = np.eye(3) + rng.normal(0.0, accel_misalignment_std, size=(3, 3))
            P = Mis @ np.diag(scale)
            U, S, Vt = np.linalg.svd(P)
            Rm = U @ Vt
            A = U @ np.diag(S) @ U.T
            b = rng.normal(0.0, accel_bias_std, size=3)
            bg = rng.normal(0.0, gyro_bias_std, size=3)
            drift_dir = rng.normal(size=3)
            drift_vec = bias_drift * drift_dir / np.linalg.norm(drift_dir)
            frac = (tau / T_total)[:, None]
            accel = f_site @ P.T + b + frac * drift_vec + rng.normal(0.0, accel_noise, size=f_site.shape)
            gyro = w_site @ Rm.T + bg + rng.normal(0.0, gyro_noise, size=w_site.shape)
            accel = quantise(accel, ACCEL_LSB)
            gyro = quantise(gyro, GYRO_LSB)
        else:
            P = A = Rm = np.eye(3)
            b = bg = drift_vec = np.zeros(3)
            accel, gyro = f_site, w_site
            if bias_drift:
                raise ValueError("bias_drift needs imu_faults=True")
        R_unit = pl.R_site @ Rm.T
        units[pl.name] = UnitTruth(
            name=pl.name, link=pl.link, position=pl.position.copy(), R=R_unit, R_site=pl.R_site.copy(),
            accel_matrix=P, accel_sym=A, accel_bias=b, gyro_bias=bg, time_offset_s=offset,
            clock_drift_ppm=clock_drift_ppm, bias_drift_mps2=drift_vec, n_samples=int(tau.shape[0]),
            n_dropped=n_dropped,
        )
        imu[pl.name] = (stamps, accel, gyro)

    # ---- write (h5py, contract v1)
    path.parent.mkdir(parents=True, exist_ok=True)
    with h5py.File(path, "w") as f:
        f.attrs["format"] = "skincal-dataset"
        f.attrs["version"] = np.int64(1)
        f.attrs["description"] = (
            f"independent generator (tests/independent): robot {robot}, seed {seed}, {n_poses} poses, "
            f"{len(placements)} units"
        )
        r = f.create_group("robot")
        r.attrs["name"] = spec.name
        r.attrs["convention"] = "modified"
        r.attrs["gravity"] = np.array([0.0, 0.0, -G_FILE])
        r.create_dataset("dh", data=spec.dh.astype(np.float64))
        r.create_dataset("joint_lower", data=spec.lower.astype(np.float64))
        r.create_dataset("joint_upper", data=spec.upper.astype(np.float64))
        r.create_dataset("velocity_limit", data=spec.velocity_limit.astype(np.float64))
        j = f.create_group("joints")
        j.create_dataset("t", data=t_j)
        j.create_dataset("q", data=q)
        j.create_dataset("qd", data=qd)
        g = f.create_group("imu", track_order=True)
        for name, (t_u, acc, gyr) in imu.items():
            u = g.create_group(name)
            u.create_dataset("t", data=t_u)
            u.create_dataset("accel", data=acc)
            u.create_dataset("gyro", data=gyr)
        if segments:
            s = f.create_group("segments")
            s.create_dataset("t_start", data=np.array([x.t_start for x in segs]))
            s.create_dataset("t_end", data=np.array([x.t_end for x in segs]))
            s.create_dataset("kind", data=np.array([x.kind for x in segs], dtype=np.int8))
            s.create_dataset("pose", data=np.array([x.pose for x in segs], dtype=np.int32))
            s.create_dataset("joint", data=np.array([x.joint for x in segs], dtype=np.int32))
        tr = f.create_group("truth", track_order=True)
        for name, ut in units.items():
            u = tr.create_group(name)
            u.attrs["link"] = np.int64(ut.link)
            u.attrs["position"] = ut.position
            u.attrs["quaternion_wxyz"] = quat_wxyz(ut.R)
            if write_sensor_truth:
                u.attrs["accel_bias"] = ut.accel_bias
                u.attrs["gyro_bias"] = ut.gyro_bias
                u.attrs["time_offset_s"] = np.float64(ut.time_offset_s)

    return Truth(
        path=path, robot=spec, units=units, duration_s=T_total, gravity_true=gravity_true, segments=segs,
        poses=poses, n_joint_samples=int(t_j.shape[0]), seed=seed, generation_s=time.perf_counter() - t_start,
        placements=placements, trajectory=traj,
    )
