"""Dataset files: HDF5 ``format = "skincal-dataset"``, ``version = 2`` (``docs/interfaces.md``);
version 1 files (a DH robot only) read as well.

Layout (optional parts in brackets)::

    /            attrs format, version, [description], [gravity (3,) m/s^2: a dataset without /robot]
    [/robot]     attrs name, convention ("modified", "standard": DH; "urdf"), gravity (3,) m/s^2,
                       joint_names (n,) str, link_names (n + 1,) str                  (version 2)
    /robot/T_parent_joint (n, 4, 4), /robot/axis (n, 3), /robot/T_joint_link (n, 4, 4),
    /robot/joint_type (n,) int8 0 = revolute, 1 = prismatic                          (version 2)
    [/robot/dh]  (n, 4) [theta_offset, d, a, alpha], rad and m (a DH robot; version 1: required)
    [/robot/urdf] uint8 UTF-8 text of the URDF the chain came from                   (version 2)
    [/robot/joint_lower, /robot/joint_upper]   (n,) rad or m (+-inf: a continuous joint)
    [/robot/velocity_limit, acceleration_limit, effort_limit]  (n,)
    [/robot/T_link_flange]                     (4, 4)
    [/joints/t (N,) s, /joints/q, /joints/qd (N, n), [/joints/qdd]]   (absent: IMU-only; then /robot optional)
    /imu/<unit>/t (M,) s, accel (M, 3) m/s^2, [gyro (M, 3) rad/s]
    [/tof/<unit>/t (K,) s, range (K,) m, NaN = no target]
    [/segments/t_start, t_end (S,) s, kind int8, pose int32, joint int32]
    [/truth/<unit> attrs link, position (3,), quaternion_wxyz (4,) and/or body (str), T_body_su (4, 4),
                   [accel_bias, accel_scale, accel_misalignment, time_offset_s, ...]]
    [/events/<k>   attrs unit (str), t_change_s, t_detected_s (s), [link], [T_link_su_before, T_link_su_after
                   (4, 4)], [statistic, threshold, t_recalibrated_s]: moved-unit events, k = 0, 1, ...]

Reading opens the file read-only, checks the structure, builds a :class:`Dataset` and runs
:func:`~skincal.data.validate.validate_dataset`; writing validates first, then writes atomically.
:func:`open_dataset` reads the same way but keeps the file open and reads each unit's IMU stream
only when asked (:class:`LazyImu`), so that a large file is streamed one unit at a time.

The reader (:class:`~skincal.data.hdf5_reader.DatasetReader`, whose module holds the limits) trusts
nothing in the file's structure: it follows only hard links (a soft or external link, an external
raw-data file or a virtual dataset could put another file's data, or another unit's, in place of a
stream), refuses two paths that are the same HDF5 object (a hard link making ``/imu/su1`` a second
name of ``/imu/su2``), and checks each dataset's declared shape and type before reading it: a
dataset may not declare more bytes than it stores (times :data:`MAX_COMPRESSION_RATIO` when
compressed, plus :data:`SMALL_ARRAY_BYTES`), and all arrays of a file together may not declare more
than ``max(MAX_READ_BYTES, READ_BYTES_PER_FILE_BYTE * file size)``; so a small file cannot make the
reader allocate gigabytes.
Written datasets carry Fletcher-32 checksums (and the HDF5 1.8+ format, whose metadata is
checksummed too), so bit rot becomes a read error instead of silently different samples; files
without checksums (other writers) read just as well. Unit groups keep their creation order.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from pathlib import Path
from typing import cast

from skincal.data.dataset import Dataset, ImuStream
from skincal.data.hdf5_reader import H5PY_ERRORS, READABLE_VERSIONS, DatasetReader, damaged, open_file
from skincal.data.validate import validate_dataset
from skincal.data.writer import DatasetWriter
from skincal.errors import DatasetError
from skincal.io.atomic import atomic_path
from skincal.names import printable

__all__ = ["READABLE_VERSIONS", "LazyImu", "open_dataset", "read_dataset", "write_dataset"]


class LazyImu(Mapping[str, ImuStream]):
    """The ``/imu`` streams of an open file, read one unit at a time on access (never kept: each
    access reads the unit again), with every check of :func:`read_dataset`; see :func:`open_dataset`."""

    def __init__(self, reader: DatasetReader, names: list[str]) -> None:
        self._reader = reader
        self._names = dict.fromkeys(names)

    def __getitem__(self, unit: str) -> ImuStream:
        if unit not in self._names:
            raise KeyError(unit)
        if not self._reader.f.id.valid:
            raise DatasetError(f"{self._reader.source}: read /imu/{printable(unit)} after the file was closed")
        try:
            return self._reader.imu_unit(unit)
        except DatasetError:
            raise
        except H5PY_ERRORS as exc:
            raise damaged(self._reader.source, exc) from None

    def __iter__(self) -> Iterator[str]:
        return iter(self._names)

    def __len__(self) -> int:
        return len(self._names)

    def __contains__(self, unit: object) -> bool:
        return unit in self._names


@contextmanager
def open_dataset(path: str | Path) -> Iterator[Dataset]:
    """A dataset file opened for streaming: within the ``with`` block, a validated :class:`Dataset`
    whose ``imu`` is a :class:`LazyImu` (each unit read from the file when accessed, so that memory
    holds one unit's IMU data at a time); everything else is read at once, as by :func:`read_dataset`.

    The same checks as :func:`read_dataset` run before the dataset is given (every unit is read once
    for the validation, then dropped), and every later read of a unit repeats the structural ones.

    Raises:
        DatasetError: as :func:`read_dataset`; also on reading a unit after the block.
    """
    f, r = open_file(Path(path))
    with f:
        ds = _build(r, lazy=True)
        yield ds


def _build(r: DatasetReader, lazy: bool) -> Dataset:
    """Read the open file's parts (the IMU streams as a :class:`LazyImu` when ``lazy``) and validate."""
    source = r.source
    try:
        description = r.header()
        robot, gravity = r.robot_if_any(has_joints=r.link("/joints"))
        joints = r.joints(None if robot is None else robot.n_joints)
        imu = cast("dict[str, ImuStream]", LazyImu(r, r.imu_names())) if lazy else r.imu()
        tof = r.tof()
        segments = r.segments()
        truth, truth_sensor, truth_body = r.truth()
        events = r.events(list(imu))
    except DatasetError:
        raise
    except H5PY_ERRORS as exc:
        raise damaged(source, exc) from None
    ds = Dataset(
        robot=robot,
        joints=joints,
        imu=imu,
        tof=tof,
        segments=segments,
        truth=truth,
        gravity=gravity,
        description=description,
        truth_sensor=truth_sensor,
        truth_body=truth_body,
        events=events,
    )
    validate_dataset(ds, source=source)
    return ds


def read_dataset(path: str | Path) -> Dataset:
    """Read and validate a dataset file (opened read-only; the file is never modified).

    Raises:
        DatasetError: missing, truncated or non-HDF5 file, wrong format string or version, missing
            group or field, or any validation failure; one line naming the file and the field.
    """
    f, r = open_file(Path(path))
    with f:
        return _build(r, lazy=False)


def write_dataset(dataset: Dataset, path: str | Path) -> None:
    """Validate ``dataset`` and write it to ``path`` atomically (temporary file, fsync, rename).

    On any error the temporary file is removed and an existing file at ``path`` stays as it was.

    Raises:
        DatasetError: the dataset fails validation (one line naming the field).
        OSError: the directory is not writable or the disk is full.
    """
    path = Path(path)
    validate_dataset(dataset, source=str(path))
    with atomic_path(path) as tmp, DatasetWriter(tmp, libver=("v108", "latest")) as writer:
        writer.write(dataset)
