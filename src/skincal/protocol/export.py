"""Writing and reading protocol trajectories: CSV (the sampled stream) and JSON (the definition).

* CSV: header ``t,q1..qn,qd1..qdn``, one row per sample, s, rad, rad/s, 17 significant digits
  (exact float64 round trip): the stream a joint controller replays.
* JSON: ``format = "skincal-protocol"``, ``version = 1``, the robot name, the config, the poses,
  the segments and the piecewise closed form (``knots``, ``coef``, ``sine_amplitude``,
  ``sine_omega``), from which :func:`read_trajectory_json` rebuilds the exact trajectory; also
  ``joint_names`` and ``rate_hz`` (the sample rate of the stream handed to the robot).
* YAML: a ROS ``trajectory_msgs/JointTrajectory`` message (``header``, ``joint_names``, ``points``
  with ``positions``, ``velocities``, ``accelerations``, ``effort`` and ``time_from_start`` as
  ``{sec, nanosec}``), one point per sample, 17 significant digits, as ``ros2 topic pub`` or a
  ``FollowJointTrajectory`` goal takes it; comment lines name the robot, protocol and segments file.

Writes are atomic (:func:`skincal.io.atomic.atomic_path`: a temporary file in the target's
directory is fsynced and moved onto the target with :func:`os.replace`): readers never see half a file.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import Any, TextIO

import numpy as np

from skincal.data.dataset import Segments
from skincal.data.validate import validate_segments
from skincal.errors import ConfigError, DatasetError
from skincal.io.atomic import atomic_path, remove_debris
from skincal.io.jsonio import load_json
from skincal.kinematics.transforms import FloatArray
from skincal.protocol.config import ProtocolConfig
from skincal.protocol.trajectory import Trajectory

FORMAT = "skincal-protocol"
VERSION = 1
MAX_RATE_HZ = 10_000.0
"""Highest sample rate :func:`read_trajectory_json` evaluates, Hz (``skincal protocol --rate``'s)."""
MAX_SAMPLES = 20_000_000
"""Most samples :func:`read_trajectory_json` evaluates (a hostile file could ask for terabytes)."""
MAX_JOINT_VALUE = 1e6
"""Largest joint position, velocity or acceleration magnitude of a trajectory read back."""


def _write_atomic(path: Path, write: Callable[[TextIO], object]) -> None:
    with atomic_path(path) as tmp, open(tmp, "w", newline="") as fh:
        write(fh)


TRAJECTORY_SUFFIXES = (".csv", ".json", ".yaml", ".yml", ".bag", "")
"""File suffixes :func:`export_trajectory` writes (``""``: a ROS 2 bag directory)."""
TRAJECTORY_TOPIC = "/joint_trajectory"
"""Topic of the one ``trajectory_msgs/JointTrajectory`` message in a bag written by :func:`export_trajectory`."""


def export_trajectory(traj: Trajectory, path: str | Path, joint_names: tuple[str, ...] | None = None) -> Path:
    """Write ``traj`` to ``path``: ``.csv`` (samples), ``.json`` (definition), ``.yaml``/``.yml`` (ROS
    JointTrajectory), ``.bag`` (ROS 1 bag) or no suffix (ROS 2 bag directory, sqlite3; the path must not
    exist), chosen by suffix. A bag holds one JointTrajectory message on :data:`TRAJECTORY_TOPIC`.
    ``joint_names``: the robot's (default ``joint1`` .. ``jointn``)."""
    path = Path(path)
    suffix = path.suffix.lower()
    names = tuple(joint_names) if joint_names is not None else tuple(f"joint{i + 1}" for i in range(traj.n_joints))
    if len(names) != traj.n_joints:
        raise ConfigError(f"{path}: {len(names)} joint names for a {traj.n_joints}-joint trajectory")
    if suffix == ".csv":
        n = traj.n_joints
        header = ",".join(["t"] + [f"q{i + 1}" for i in range(n)] + [f"qd{i + 1}" for i in range(n)])
        table = np.column_stack([traj.t, traj.q, traj.qd])
        _write_atomic(path, lambda fh: np.savetxt(fh, table, fmt="%.17g", delimiter=",", header=header, comments=""))
    elif suffix == ".json":
        doc = trajectory_to_json(traj)
        doc["joint_names"] = list(names)
        doc["rate_hz"] = traj.config.rate_hz
        _write_atomic(path, lambda fh: json.dump(doc, fh))
    elif suffix in (".yaml", ".yml"):
        _write_atomic(path, lambda fh: _write_joint_trajectory_yaml(fh, traj, names))
    elif suffix in (".bag", ""):
        _write_bag(traj, path, names, ros_version=1 if suffix == ".bag" else 2)
    else:
        raise ConfigError(f"{path}: unknown trajectory format '{path.suffix}' (use .csv, .json, .yaml, .bag or "
                          "a bag folder name without suffix)")  # fmt: skip
    return path


def _write_bag(traj: Trajectory, path: Path, names: tuple[str, ...], ros_version: int) -> None:
    """One ``trajectory_msgs/JointTrajectory`` message in a ROS 1 bag file (written atomically) or a
    new ROS 2 bag directory (written next to it under a temporary name, then renamed)."""
    import os
    import secrets
    import shutil

    from rosbags.rosbag1 import Writer as Writer1
    from rosbags.rosbag2 import StoragePlugin
    from rosbags.rosbag2 import Writer as Writer2
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS1_NOETIC if ros_version == 1 else Stores.ROS2_HUMBLE)
    T = ts.types
    kind = "trajectory_msgs/msg/JointTrajectory"
    ns = np.rint(np.asarray(traj.t) * 1e9).astype(np.int64)

    def duration(k: int):
        return T["builtin_interfaces/msg/Duration"](sec=int(ns[k] // 1_000_000_000), nanosec=int(ns[k] % 1_000_000_000))

    points = [
        T["trajectory_msgs/msg/JointTrajectoryPoint"](
            positions=np.array(traj.q[k], float), velocities=np.array(traj.qd[k], float),
            accelerations=np.array(traj.qdd[k], float), effort=np.zeros(0), time_from_start=duration(k),
        )
        for k in range(ns.size)
    ]  # fmt: skip
    stamp = T["builtin_interfaces/msg/Time"](sec=0, nanosec=0)
    header = T["std_msgs/msg/Header"](stamp=stamp, frame_id="", **({"seq": 0} if ros_version == 1 else {}))
    msg = T[kind](header=header, joint_names=list(names), points=points)
    if ros_version == 1:
        with atomic_path(path) as tmp:
            tmp.unlink()  # the writer creates the file itself
            with Writer1(tmp) as writer:
                conn = writer.add_connection(TRAJECTORY_TOPIC, kind, typestore=ts)
                writer.write(conn, 1, ts.serialize_ros1(msg, kind))
        return
    if path.exists():
        raise ConfigError(f"{path} exists; a ROS 2 bag folder is never overwritten")
    remove_debris(path, folders=True)
    # the bag is written as <tmp>/<name> (rosbags names its storage file after its folder), then moved
    tmp = path.parent / f".{path.name}.{os.getpid()}.{secrets.token_hex(6)}.tmp"
    try:
        os.mkdir(tmp)
        with Writer2(tmp / path.name, version=9, storage_plugin=StoragePlugin.SQLITE3) as writer:
            conn = writer.add_connection(TRAJECTORY_TOPIC, kind, typestore=ts)
            writer.write(conn, 1, ts.serialize_cdr(msg, kind))
        os.rename(tmp / path.name, path)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def _flow(values: FloatArray) -> str:
    return "[" + ", ".join(repr(float(v)) for v in values) + "]"


def _write_joint_trajectory_yaml(fh: TextIO, traj: Trajectory, names: tuple[str, ...]) -> None:
    """The ROS ``trajectory_msgs/JointTrajectory`` of ``traj`` as YAML (names as JSON strings, which
    are YAML double-quoted scalars)."""
    ns = np.rint(np.asarray(traj.t) * 1e9).astype(np.int64)
    sec, nanosec = ns // 1_000_000_000, ns % 1_000_000_000
    fh.write(
        f"# trajectory_msgs/JointTrajectory: skincal protocol {json.dumps(traj.config.name)} for robot "
        f"{json.dumps(traj.robot)}, {traj.t.size} points at {traj.config.rate_hz:g} Hz, {traj.duration:.3f} s\n"
    )
    fh.write("# positions rad or m, velocities rad/s or m/s, accelerations rad/s^2 or m/s^2\n")
    fh.write("header:\n  stamp: {sec: 0, nanosec: 0}\n  frame_id: ''\n")
    fh.write("joint_names: [" + ", ".join(json.dumps(n) for n in names) + "]\n")
    fh.write("points:\n")
    for k in range(traj.t.size):
        fh.write(f"- positions: {_flow(traj.q[k])}\n  velocities: {_flow(traj.qd[k])}\n"
                 f"  accelerations: {_flow(traj.qdd[k])}\n  effort: []\n"
                 f"  time_from_start: {{sec: {int(sec[k])}, nanosec: {int(nanosec[k])}}}\n")  # fmt: skip


def trajectory_to_json(traj: Trajectory) -> dict[str, Any]:
    """The JSON document of :func:`export_trajectory` as a dictionary."""
    seg = traj.segments
    return {
        "format": FORMAT,
        "version": VERSION,
        "robot": traj.robot,
        "duration_s": traj.duration,
        "config": traj.config.to_dict(),
        "poses": traj.poses.tolist(),
        "segments": {
            "t_start": np.asarray(seg.t_start).tolist(),
            "t_end": np.asarray(seg.t_end).tolist(),
            "kind": np.asarray(seg.kind).tolist(),
            "pose": np.asarray(seg.pose).tolist(),
            "joint": np.asarray(seg.joint).tolist(),
        },
        "knots": traj.knots.tolist(),
        "coef": traj.coef.tolist(),
        "sine_amplitude": traj.sine_amplitude.tolist(),
        "sine_omega": traj.sine_omega.tolist(),
    }


def read_trajectory_csv(path: str | Path) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Read a CSV written by :func:`export_trajectory`: ``t`` ``(N,)``, ``q`` and ``qd`` ``(N, n)``."""
    path = Path(path)
    try:
        with open(path) as fh:
            header = fh.readline().strip().split(",")
            data = np.loadtxt(fh, delimiter=",", ndmin=2)
    except OSError as exc:
        raise DatasetError(f"{path}: cannot read trajectory CSV ({exc.strerror or exc})") from None
    except ValueError as exc:
        raise DatasetError(f"{path}: trajectory CSV holds non-numeric rows ({exc})") from None
    n = (len(header) - 1) // 2
    expected = ["t"] + [f"q{i + 1}" for i in range(n)] + [f"qd{i + 1}" for i in range(n)]
    if header != expected or data.shape[1] != len(header):
        raise DatasetError(f"{path}: trajectory CSV header must be t,q1..qn,qd1..qdn, got {','.join(header)}")
    return data[:, 0], data[:, 1 : n + 1], data[:, n + 1 :]


def read_trajectory_json(path: str | Path) -> Trajectory:
    """Rebuild the exact trajectory from a JSON written by :func:`export_trajectory`.

    The samples are re-evaluated from the piecewise form at ``config.rate_hz``.
    """
    path = Path(path)
    doc = load_json(path, "trajectory file (.json)", DatasetError)
    if not isinstance(doc, dict) or doc.get("format") != FORMAT:
        raise DatasetError(f"{path}: field 'format' must be '{FORMAT}'")
    if doc.get("version") != VERSION:
        raise DatasetError(f"{path}: unsupported version {doc.get('version')!r} (this reader knows {VERSION})")
    try:
        config = ProtocolConfig.from_dict(doc["config"], source=str(path))
        seg = doc["segments"]
        segments = Segments(
            t_start=np.asarray(seg["t_start"], dtype=float),
            t_end=np.asarray(seg["t_end"], dtype=float),
            kind=np.asarray(seg["kind"], dtype=np.int8),
            pose=np.asarray(seg["pose"], dtype=np.int32),
            joint=np.asarray(seg["joint"], dtype=np.int32),
        )
        knots = np.asarray(doc["knots"], dtype=float)
        coef = np.asarray(doc["coef"], dtype=float)
        B = np.asarray(doc["sine_amplitude"], dtype=float)
        w = np.asarray(doc["sine_omega"], dtype=float)
        poses = np.asarray(doc["poses"], dtype=float)
    except KeyError as exc:
        raise DatasetError(f"{path}: missing field {exc}") from None
    except (TypeError, ValueError, OverflowError) as exc:
        raise DatasetError(f"{path}: malformed trajectory field ({exc})") from None
    K = knots.size - 1
    if (
        K < 1
        or coef.ndim != 3
        or coef.shape[0] != K
        or coef.shape[2] != 6
        or not (B.shape == w.shape == coef.shape[:2])
    ):
        raise DatasetError(f"{path}: fields 'knots', 'coef', 'sine_amplitude', 'sine_omega' have inconsistent shapes")
    if knots.ndim != 1 or not np.all(np.diff(knots) > 0):
        raise DatasetError(f"{path}: field 'knots' must be strictly increasing times")
    samples = (knots[-1] - knots[0]) * config.rate_hz
    if config.rate_hz > MAX_RATE_HZ or not samples <= MAX_SAMPLES:
        raise DatasetError(
            f"{path}: {knots[-1] - knots[0]:.6g} s at {config.rate_hz:.6g} Hz is beyond what this reader "
            f"evaluates (at most {MAX_RATE_HZ:g} Hz and {MAX_SAMPLES:g} samples)"
        )
    validate_segments(segments, coef.shape[1], f"{path}: field 'segments'")
    traj = Trajectory(
        t=np.empty(0), q=np.empty((0, coef.shape[1])), qd=np.empty((0, coef.shape[1])),
        qdd=np.empty((0, coef.shape[1])), segments=segments, config=config, poses=poses, knots=knots,
        coef=coef, sine_amplitude=B, sine_omega=w, robot=str(doc.get("robot", "")),
    )  # fmt: skip
    from dataclasses import replace

    t = np.arange(int(np.floor(traj.duration * config.rate_hz + 1e-9)) + 1) / config.rate_hz
    with np.errstate(all="ignore"):  # huge coefficients are refused below, not warned about
        q, qd, qdd = traj.evaluate(t)
    if not all(np.all(np.abs(x) <= MAX_JOINT_VALUE) for x in (q, qd, qdd)):
        raise DatasetError(f"{path}: the motion leaves +-{MAX_JOINT_VALUE:g} rad (or m, per s, per s^2): not a robot's")
    return replace(traj, t=t, q=q, qd=qd, qdd=qdd)
