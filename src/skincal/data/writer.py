"""The one writer of the dataset file layout (HDF5 ``format = "skincal-dataset"``, ``version = 2``;
``docs/interfaces.md``, read by :mod:`skincal.data.hdf5`).

:class:`DatasetWriter` is an open file being written, a context manager that closes it on exit. It is
filled in one of two ways, both in the same layout:

* :meth:`DatasetWriter.write`: a whole :class:`~skincal.data.dataset.Dataset` at once, every array a
  fixed-size dataset with a Fletcher-32 checksum (:func:`skincal.data.hdf5.write_dataset`, which wraps
  it in an atomic replacement);
* :meth:`DatasetWriter.start` then :meth:`DatasetWriter.append` as often as rows arrive: each array a
  chunked dataset of unlimited length grown by the new rows (the crash-safe recorder,
  :class:`skincal.hw.recorder.Recorder`, which flushes between appends).

Root attributes ``format`` and ``version`` and the ``/robot`` group (:meth:`DatasetWriter.robot`) are
written here only.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from types import TracebackType

import h5py
import numpy as np
from numpy.typing import ArrayLike

from skincal.data.dataset import Dataset
from skincal.data.events import check_events
from skincal.kinematics.chain import GRAVITY_BASE, SerialChain

FORMAT = "skincal-dataset"
VERSION = 2
"""Version written; :data:`skincal.data.hdf5.READABLE_VERSIONS` are read."""
JOINT_TYPE_CODES = {"revolute": 0, "prismatic": 1}
"""``/robot/joint_type`` codes."""


def _write_floats(grp: h5py.Group, name: str, value: object) -> None:
    grp.create_dataset(name, data=np.asarray(value, dtype=np.float64), fletcher32=True)


class DatasetWriter:
    """A dataset file open for writing (see the module docstring); ``with DatasetWriter(path) as w: ...``.

    Args:
        path: the file, created or truncated.
        libver: HDF5 format bounds (``("v108", "latest")``: checksummed metadata); None: h5py's default.

    Attributes:
        path: the file.
        file: the open ``h5py.File`` (for what lies outside the layout: a recorder's own attributes, copies).
    """

    def __init__(
        self, path: str | Path, *, libver: str | tuple[str, str] | None = None, exclusive: bool = False
    ) -> None:
        self.path = Path(path)
        # exclusive: create the file only if it does not exist (h5py mode "x"), never truncate another's
        self.file = h5py.File(self.path, "x" if exclusive else "w", libver=libver)

    def __enter__(self) -> DatasetWriter:
        return self

    def __exit__(
        self, kind: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()

    def close(self) -> None:
        """Close the file (idempotent)."""
        if self.file.id.valid:
            self.file.close()

    def flush(self) -> None:
        """Flush everything written so far to disk."""
        self.file.flush()

    def __contains__(self, path: str) -> bool:
        return path in self.file

    def start(
        self,
        attrs: Mapping[str, object] = {},
        robot: SerialChain | None = None,
        gravity: ArrayLike | None = GRAVITY_BASE,
    ) -> None:
        """Root attributes ``format``, ``version``, then ``attrs`` in their order; then ``/robot`` when
        ``robot`` is given (with ``gravity``, m/s^2, base frame; default :data:`GRAVITY_BASE`), else the root
        attribute ``gravity`` unless ``gravity`` is None (a recording without a robot writes none)."""
        f = self.file
        f.attrs["format"] = FORMAT
        f.attrs["version"] = np.int64(VERSION)
        f.attrs.update(attrs)
        if robot is not None:
            self.robot(robot, GRAVITY_BASE if gravity is None else gravity)
        elif gravity is not None:  # IMU-only without a robot: gravity at the root
            f.attrs["gravity"] = np.asarray(gravity, dtype=np.float64)

    def robot(self, chain: SerialChain, gravity: object) -> None:
        """The ``/robot`` group of a version-2 file (the general chain; a DH robot's table besides)."""
        robot = self.file.create_group("robot")
        robot.attrs["name"] = chain.name
        robot.attrs["convention"] = chain.convention
        robot.attrs["gravity"] = np.asarray(gravity, dtype=np.float64)
        n = chain.n_joints
        text = h5py.string_dtype("utf-8")
        robot.attrs["joint_names"] = np.array([chain.joint_name(i) for i in range(1, n + 1)], dtype=text)
        robot.attrs["link_names"] = np.array([chain.link_name(i) for i in range(n + 1)], dtype=text)
        _write_floats(robot, "T_parent_joint", chain.T_parent_joint)
        _write_floats(robot, "axis", chain.axis)
        _write_floats(robot, "T_joint_link", chain.T_joint_link)
        robot.create_dataset(
            "joint_type", data=np.array([JOINT_TYPE_CODES[t] for t in chain.joint_type], dtype=np.int8), fletcher32=True
        )
        if chain.dh is not None:
            _write_floats(robot, "dh", chain.dh)
        if chain.source is not None:
            data = np.frombuffer(chain.source.encode("utf-8"), dtype=np.uint8)
            robot.create_dataset("urdf", data=data, fletcher32=True)
        for key in ("joint_lower", "joint_upper", "velocity_limit", "acceleration_limit", "effort_limit"):
            value = getattr(chain, key)
            if value is not None:
                _write_floats(robot, key, value)
        if not np.array_equal(chain.T_link_flange, np.eye(4)):
            _write_floats(robot, "T_link_flange", chain.T_link_flange)

    def append(
        self, group: str, rows: Mapping[str, np.ndarray], attrs: Mapping[str, object] = {}, chunk_rows: int = 1024
    ) -> None:
        """Append ``rows`` (name -> ``(m, ...)`` array, one length ``m``, dtypes as they are) to the datasets
        of ``group`` (a path such as ``imu/su1``), each created at first use as a chunked dataset of
        unlimited length (``chunk_rows`` rows a chunk); ``attrs`` are set when the group is new."""
        h = self.file.require_group(group)
        if not h.attrs:
            h.attrs.update(attrs)
        for name, value in rows.items():
            n = len(value)
            if name not in h:
                row_shape = value.shape[1:]
                h.create_dataset(name, shape=(0, *row_shape), maxshape=(None, *row_shape), dtype=value.dtype,
                                 chunks=(chunk_rows, *row_shape))
            ds = h[name]
            old = ds.shape[0]
            ds.resize(old + n, axis=0)
            ds[old:] = value

    def copy_from(self, src: h5py.File) -> None:
        """Every root attribute and top-level object of ``src`` copied into this (still empty) file."""
        self.file.attrs.update(src.attrs)
        for name in src:
            src.copy(src[name], self.file, name=name)

    def write(self, ds: Dataset) -> None:
        """The whole dataset ``ds`` (validated by the caller) into this empty file, fixed-size datasets with
        Fletcher-32 checksums; unit groups keep the dataset's order."""
        f = self.file
        self.start({"description": ds.description} if ds.description else {}, ds.robot, ds.gravity)

        if ds.joints is not None:
            joints = f.create_group("joints")
            for key in ("t", "q", "qd", "qdd"):
                value = getattr(ds.joints, key)
                if value is not None:
                    _write_floats(joints, key, value)

        imu = f.create_group("imu", track_order=True)  # keep the unit order
        for unit, stream in ds.imu.items():
            g = imu.create_group(unit)
            _write_floats(g, "t", stream.t)
            _write_floats(g, "accel", stream.accel)
            if stream.gyro is not None:
                _write_floats(g, "gyro", stream.gyro)

        if ds.tof:
            tof = f.create_group("tof", track_order=True)
            for unit, ranges in ds.tof.items():
                g = tof.create_group(unit)
                _write_floats(g, "t", ranges.t)
                _write_floats(g, "range", ranges.range)

        if ds.segments is not None:
            seg = f.create_group("segments")
            _write_floats(seg, "t_start", ds.segments.t_start)
            _write_floats(seg, "t_end", ds.segments.t_end)
            seg.create_dataset("kind", data=np.asarray(ds.segments.kind, dtype=np.int8), fletcher32=True)
            seg.create_dataset("pose", data=np.asarray(ds.segments.pose, dtype=np.int32), fletcher32=True)
            seg.create_dataset("joint", data=np.asarray(ds.segments.joint, dtype=np.int32), fletcher32=True)

        if ds.truth or ds.truth_body:
            truth = f.create_group("truth", track_order=True)
            for unit in [*ds.truth, *(u for u in ds.truth_body if u not in ds.truth)]:
                g = truth.create_group(unit)
                pose = ds.truth.get(unit)
                if pose is not None:
                    g.attrs["link"] = np.int64(pose.link)
                    g.attrs["position"] = np.asarray(pose.p_link_su, dtype=np.float64)
                    g.attrs["quaternion_wxyz"] = np.asarray(pose.quaternion_wxyz, dtype=np.float64)
                body = ds.truth_body.get(unit)
                if body is not None:
                    g.attrs["body"] = body.body
                    g.attrs["T_body_su"] = np.asarray(body.T_body_su, dtype=np.float64)
                for key, value in ds.truth_sensor.get(unit, {}).items():
                    g.attrs[key] = np.asarray(value, dtype=np.float64)

        if ds.events:
            events = f.create_group("events", track_order=True)
            for k, event in enumerate(check_events(list(ds.events), "events", units=set(ds.imu))):
                g = events.create_group(str(k))
                for key, value in event.fields().items():
                    g.attrs[key] = value if isinstance(value, str) else np.asarray(value, dtype=np.float64)
                if event.link is not None:
                    g.attrs["link"] = np.int64(event.link)
