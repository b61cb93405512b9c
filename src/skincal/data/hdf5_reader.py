"""The checked reader of dataset files (``docs/interfaces.md``): :class:`DatasetReader` reads each
part of an opened HDF5 file into the :mod:`skincal.data.dataset` types, trusting nothing in its structure
(see :mod:`skincal.data.hdf5` for the layout and the limits below)."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Literal, overload

import h5py
import numpy as np

from skincal.data.dataset import BodyPose, ImuStream, JointStates, Segments, TofStream
from skincal.data.events import MoveEvent, check_events
from skincal.data.validate import TRUTH_BODY_ATTRS, check_unit_name, shape_mismatch, shown
from skincal.data.writer import FORMAT, JOINT_TYPE_CODES, VERSION
from skincal.errors import ConfigError, DatasetError
from skincal.errors import first_line as _first_line
from skincal.io.files import DATASET_FILE, regular_file
from skincal.kinematics.chain import CONVENTIONS, GRAVITY_BASE, SerialChain
from skincal.names import printable
from skincal.skin.pose import SkinUnitPose

READABLE_VERSIONS = (1, 2)
"""``/robot/joint_type`` codes."""
_QUAT_NORM_TOL = 1e-3

MAX_COMPRESSION_RATIO = 1100
"""Largest declared/stored size ratio accepted for a compressed dataset (deflate cannot beat ~1032:1)."""
SMALL_ARRAY_BYTES = 1 << 20
"""Declared bytes a dataset may have beyond what it stores (fill values of small arrays), 1 MiB."""
MAX_READ_BYTES = 1 << 31
"""Bytes the arrays of any file may declare in total (2 GiB), more only in proportion to its size."""
READ_BYTES_PER_FILE_BYTE = 8
"""Beyond :data:`MAX_READ_BYTES`, the arrays of a file may declare this many bytes per byte of file."""
MAX_ATTR_BYTES = 1 << 20
"""Largest attribute read, bytes (the contract's attributes are a few numbers)."""
_NO_COMPRESSION = {h5py.h5z.FILTER_FLETCHER32, h5py.h5z.FILTER_SHUFFLE}


class DatasetReader:
    """Reads fields of one open file, turning every structural problem into a one-line DatasetError."""

    def __init__(self, f: h5py.File, source: str, file_size: int) -> None:
        self.f = f
        self.source = source
        self.file_size = file_size
        self.budget = max(MAX_READ_BYTES, READ_BYTES_PER_FILE_BYTE * file_size)
        self.declared = 0  # bytes declared by the arrays read so far
        self.counted: set[str] = set()  # paths whose declared bytes are in ``declared`` (a re-read counts once)
        self.version = VERSION  # set by header()
        self.seen: dict[object, str] = {}  # HDF5 object id -> the first path it was reached by

    def fail(self, field: str, problem: str) -> DatasetError:
        return DatasetError(f"{self.source}: {printable(field)} {printable(problem)}")

    def link(self, path: str) -> bool:
        """Whether ``path`` exists, following hard links only: a soft or external link on the way is refused."""
        parts = [p for p in path.split("/") if p]
        grp: h5py.Group = self.f
        for i, name in enumerate(parts):
            here = "/" + "/".join(parts[: i + 1])
            try:
                link = grp.get(name, getlink=True)
            except (OSError, KeyError, ValueError, TypeError) as exc:
                raise self.fail(here, f"cannot be read ({_first_line(exc)})") from None
            if link is None:
                return False
            if isinstance(link, h5py.SoftLink):
                raise self.fail(here, f"is a soft link to {link.path}; only ordinary (hard-linked) objects are read")
            if isinstance(link, h5py.ExternalLink):
                raise self.fail(
                    here, f"is an external link to {link.filename}:{link.path}; only data inside the file is read"
                )
            if not isinstance(link, h5py.HardLink):
                raise self.fail(here, f"is a {type(link).__name__}; only ordinary (hard-linked) objects are read")
            if i < len(parts) - 1:
                try:
                    grp = grp[name]
                except (OSError, KeyError, ValueError) as exc:
                    raise self.fail(here, f"cannot be read ({_first_line(exc)})") from None
                if not isinstance(grp, h5py.Group):
                    raise self.fail(here, "must be a group")
        return True

    def node(
        self, path: str, kind: type[h5py.Group] | type[h5py.Dataset], required: bool = True
    ) -> h5py.Group | h5py.Dataset | None:
        if not self.link(path):
            if required:
                raise self.fail(path, "is missing")
            return None
        try:
            obj: Any = self.f.get(path)
        except (OSError, KeyError, ValueError) as exc:
            raise self.fail(path, f"cannot be read ({_first_line(exc)})") from None
        if not isinstance(obj, kind):
            want = "a group" if kind is h5py.Group else "a dataset"
            raise self.fail(path, f"must be {want}")
        first = self.seen.setdefault(obj.id, path)
        if first != path:
            raise self.fail(
                path, f"is the same HDF5 object as {first} (a hard link); every group and dataset is stored once"
            )
        return obj

    def check_declared(self, path: str, obj: h5py.Dataset) -> None:
        """Refuse a dataset whose declared size the file cannot back, before reading it."""
        if obj.external:
            files = ", ".join(str(e[0]) for e in obj.external[:3])
            raise self.fail(path, f"keeps its samples in external file(s) {files}; only data inside the file is read")
        if obj.is_virtual:
            raise self.fail(path, "is a virtual dataset mapping other files; only data inside the file is read")
        if obj.shape is None:
            return  # an empty dataspace: no samples (refused by the dtype/shape checks)
        declared = math.prod(obj.shape) * obj.dtype.itemsize
        stored = min(int(obj.id.get_storage_size()), self.file_size)
        plist = obj.id.get_create_plist()
        filters = {plist.get_filter(i)[0] for i in range(plist.get_nfilters())}
        ratio = 1 if filters <= _NO_COMPRESSION else MAX_COMPRESSION_RATIO
        if declared > SMALL_ARRAY_BYTES + ratio * stored:
            raise self.fail(
                path,
                f"declares shape {obj.shape} of {obj.dtype} ({declared} bytes) but stores {stored} bytes; "
                "refused before reading",
            )
        if path in self.counted:
            return
        self.counted.add(path)
        self.declared += declared
        if self.declared > self.budget:
            raise self.fail(
                path,
                f"brings the arrays read to {self.declared} bytes, more than a {self.file_size}-byte file may "
                f"declare ({self.budget}); refused before reading",
            )

    @overload
    def group(self, path: str, required: Literal[True] = True) -> h5py.Group: ...
    @overload
    def group(self, path: str, required: bool) -> h5py.Group | None: ...
    def group(self, path: str, required: bool = True) -> h5py.Group | None:
        return self.node(path, h5py.Group, required)  # type: ignore[return-value]

    def unit_names(self, grp: h5py.Group, path: str) -> list[str]:
        """Member names of a unit group (``/imu``, ``/tof``, ``/truth``), each checked by the one name rule."""
        try:
            names = list(grp)
        except (OSError, KeyError, ValueError, TypeError) as exc:
            raise self.fail(path, f"cannot be read ({_first_line(exc)})") from None
        for unit in names:
            check_unit_name(unit, self.source, path)
        return names

    @overload
    def array(
        self, path: str, required: Literal[True] = True, dtype: type | None = None,
        shape: tuple[int | None, ...] | None = None,
    ) -> np.ndarray: ...
    @overload
    def array(
        self, path: str, required: bool, dtype: type | None = None, shape: tuple[int | None, ...] | None = None
    ) -> np.ndarray | None: ...
    def array(
        self, path: str, required: bool = True, dtype: type | None = None, shape: tuple[int | None, ...] | None = None
    ) -> np.ndarray | None:
        """Dataset ``path`` as an array; numbers are converted to ``dtype`` (float64 by default). ``shape``
        (``None`` entries free) is checked on the declared shape, before anything is read or decompressed."""
        obj = self.node(path, h5py.Dataset, required)
        if obj is None:
            return None
        want = dtype or np.float64
        allowed = "iu" if np.issubdtype(want, np.integer) else "fiu"
        what = "integers" if allowed == "iu" else "real numbers"
        try:
            declared_dtype = obj.dtype
        except (OSError, KeyError, ValueError, TypeError) as exc:
            raise self.fail(path, f"cannot be read ({_first_line(exc)})") from None
        if declared_dtype.kind not in allowed:  # checked before reading: no strings or objects are read
            raise self.fail(path, f"has dtype {declared_dtype}, expected {what}")
        self.check_declared(path, obj)
        problem = "" if shape is None else shape_mismatch(obj.shape or (), shape)
        if problem:
            raise self.fail(path, problem)
        try:
            value = np.asarray(obj[()])
        except (OSError, KeyError, ValueError, TypeError) as exc:
            raise self.fail(path, f"cannot be read ({_first_line(exc)})") from None
        if value.dtype.kind not in allowed:
            raise self.fail(path, f"has dtype {value.dtype}, expected {what}")
        return value.astype(want, copy=False)

    def attr(self, path: str, name: str, required: bool = True) -> object:
        obj = self.f if path == "/" else self.group(path)
        size = 0
        try:
            present = name in obj.attrs
            if present:
                aid = obj.attrs.get_id(name)
                size = (math.prod(aid.shape) if aid.shape is not None else 0) * aid.dtype.itemsize
            value = obj.attrs[name] if present and size <= MAX_ATTR_BYTES else None
        except (OSError, ValueError, TypeError) as exc:
            raise self.fail(self.attr_field(path, name), f"cannot be read ({_first_line(exc)})") from None
        if size > MAX_ATTR_BYTES:
            raise self.fail(self.attr_field(path, name), f"declares {size} bytes (at most {MAX_ATTR_BYTES})")
        if not present and required:
            raise self.fail(self.attr_field(path, name), "is missing")
        return value

    @staticmethod
    def attr_field(path: str, name: str) -> str:
        return f"root attr '{name}'" if path == "/" else f"{path} attr '{name}'"

    def str_attr(self, path: str, name: str, required: bool = True) -> str | None:
        value = self.attr(path, name, required)
        if value is None:
            return None
        if isinstance(value, np.ndarray) and value.shape == ():
            value = value[()]
        if isinstance(value, bytes | np.bytes_):
            try:
                value = value.decode("utf-8")
            except UnicodeDecodeError:
                raise self.fail(self.attr_field(path, name), "is not valid UTF-8 text") from None
        if not isinstance(value, str):
            raise self.fail(self.attr_field(path, name), f"must be a string, got {shown(value)}")
        return str(value)

    def num_attr(self, path: str, name: str, shape: tuple[int, ...], integer: bool = False) -> np.ndarray:
        value = np.asarray(self.attr(path, name))
        field = self.attr_field(path, name)
        kinds = "iu" if integer else "fiu"
        if value.dtype.kind not in kinds:
            raise self.fail(field, f"must be {'an integer' if integer else 'numeric'}, got {value.dtype}")
        if value.shape != shape:
            raise self.fail(field, f"has shape {value.shape}, expected {shape}")
        return value if integer else value.astype(np.float64)

    # ------------------------------------------------------------------ parts
    def header(self) -> str:
        fmt = self.str_attr("/", "format", required=False)
        if fmt is None:
            raise self.fail("root attr 'format'", f"is missing (not a {FORMAT} file)")
        if fmt != FORMAT:
            raise self.fail("root attr 'format'", f"is {shown(fmt)}, expected '{FORMAT}'")
        version = self.attr("/", "version")
        if isinstance(version, np.ndarray) and version.shape == ():
            version = version[()]
        if isinstance(version, bool | np.bool_) or not isinstance(version, int | np.integer):
            version_shown = version.item() if isinstance(version, np.generic) else version
            raise self.fail("root attr 'version'", f"must be an integer, got {shown(version_shown)}")
        if int(version) not in READABLE_VERSIONS:
            raise self.fail(
                "root attr 'version'",
                f"is {int(version)}; this skincal reads versions {', '.join(map(str, READABLE_VERSIONS))}",
            )
        self.version = int(version)
        return self.str_attr("/", "description", required=False) or ""

    def str_list_attr(self, path: str, name: str, count: int) -> tuple[str, ...] | None:
        value = self.attr(path, name, required=False)
        if value is None:
            return None
        field = self.attr_field(path, name)
        items = np.atleast_1d(np.asarray(value, dtype=object))
        if items.ndim != 1 or items.shape[0] != count:
            raise self.fail(field, f"has shape {items.shape}, expected ({count},)")
        out = []
        for item in items:
            if isinstance(item, bytes | np.bytes_):
                try:
                    item = item.decode("utf-8")
                except UnicodeDecodeError:
                    raise self.fail(field, "is not valid UTF-8 text") from None
            if not isinstance(item, str):
                raise self.fail(field, f"must hold strings, got {shown(item)}")
            out.append(str(item))
        return tuple(out)

    def robot(self) -> tuple[SerialChain, np.ndarray]:
        self.group("/robot")
        name = self.str_attr("/robot", "name")
        convention = self.str_attr("/robot", "convention")
        allowed = CONVENTIONS if self.version == 1 else (*CONVENTIONS, "urdf")
        if convention not in allowed:
            raise self.fail("/robot attr 'convention'", f"is {shown(convention)}, expected one of {allowed}")
        gravity = self.num_attr("/robot", "gravity", (3,))
        dh = self.array("/robot/dh", required=self.version == 1 or convention in CONVENTIONS)
        if dh is not None and (dh.ndim != 2 or dh.shape[1] != 4 or dh.shape[0] < 1):
            raise self.fail("/robot/dh", f"has shape {dh.shape}, expected (n, 4) with n >= 1")
        if self.version == 1:
            if dh is None:  # pragma: no cover - required above
                raise self.fail("/robot/dh", "is missing")
            n = dh.shape[0]
            general: dict[str, object] = {}
        else:
            axis = self.array("/robot/axis")
            if axis.ndim != 2 or axis.shape[1] != 3 or axis.shape[0] < 1:
                raise self.fail("/robot/axis", f"has shape {axis.shape}, expected (n, 3) with n >= 1")
            n = axis.shape[0]
            general = {"axis": axis}
            for key in ("T_parent_joint", "T_joint_link"):
                transforms = self.array(f"/robot/{key}")
                if transforms.shape != (n, 4, 4):
                    raise self.fail(f"/robot/{key}", f"has shape {transforms.shape}, expected ({n}, 4, 4)")
                general[key] = transforms
            codes = self.array("/robot/joint_type", dtype=np.int8)
            names = {v: k for k, v in JOINT_TYPE_CODES.items()}
            if codes.shape != (n,) or any(int(c) not in names for c in codes):
                raise self.fail("/robot/joint_type", f"must be ({n},) codes {JOINT_TYPE_CODES}")
            general["joint_type"] = tuple(names[int(c)] for c in codes)
            general["joint_names"] = self.str_list_attr("/robot", "joint_names", n)
            general["link_names"] = self.str_list_attr("/robot", "link_names", n + 1)
            text = self.array("/robot/urdf", required=False, dtype=np.uint8)
            if text is not None:
                try:
                    general["source"] = bytes(text.astype(np.uint8)).decode("utf-8")
                except UnicodeDecodeError:
                    raise self.fail("/robot/urdf", "is not valid UTF-8 text") from None
            if dh is not None and dh.shape[0] != n:
                raise self.fail("/robot/dh", f"has {dh.shape[0]} rows for a chain of {n} joints")
        optional = {}
        for key, shape in (
            ("joint_lower", (n,)),
            ("joint_upper", (n,)),
            ("velocity_limit", (n,)),
            ("acceleration_limit", (n,)),
            ("effort_limit", (n,)),
            ("T_link_flange", (4, 4)),
        ):
            value = self.array(f"/robot/{key}", required=False)
            if value is not None:
                if value.shape != shape:
                    raise self.fail(f"/robot/{key}", f"has shape {value.shape}, expected {shape}")
                optional[key] = value
        try:
            if self.version == 1:
                chain = SerialChain.from_dh(name, convention, dh, **optional)
            else:
                chain = SerialChain(name=name, convention=convention, dh=dh, **general, **optional)
                if dh is not None:  # the DH table and the general arrays must be one robot
                    ref = SerialChain.from_dh(name, convention, dh)
                    for key in ("T_parent_joint", "T_joint_link", "axis"):
                        if not np.allclose(getattr(ref, key), getattr(chain, key), atol=1e-9):
                            raise self.fail(f"/robot/{key}", "disagrees with /robot/dh")
        except ConfigError as exc:
            raise self.fail("/robot", f"is not a valid chain: {exc}") from None
        return chain, gravity

    def robot_if_any(self, has_joints: bool) -> tuple[SerialChain | None, np.ndarray]:
        """The robot and gravity; an IMU-only file (no ``/joints``) may have no ``/robot``, its gravity
        then in the optional root attr ``gravity`` (default ``[0, 0, -9.81]``)."""
        if self.link("/robot"):
            return self.robot()
        if has_joints:
            raise self.fail("/robot", "is missing (a dataset with /joints needs its robot)")
        if self.attr("/", "gravity", required=False) is None:
            return None, GRAVITY_BASE.copy()
        return None, self.num_attr("/", "gravity", (3,))

    def joints(self, n: int | None = None) -> JointStates | None:
        """``/joints`` (``n``: the robot's joint count, checked on the declared shapes with the samples of
        ``t`` before the arrays are read), or ``None`` for an IMU-only dataset."""
        if self.group("/joints", required=False) is None:
            return None  # an IMU-only dataset
        t = self.array("/joints/t", shape=(None,))
        rows = (t.shape[0], n)
        return JointStates(
            t=t,
            q=self.array("/joints/q", shape=rows),
            qd=self.array("/joints/qd", shape=rows),
            qdd=self.array("/joints/qdd", required=False, shape=rows),
        )

    def imu_names(self) -> list[str]:
        return self.unit_names(self.group("/imu"), "/imu")

    def imu_unit(self, unit: str) -> ImuStream:
        """The IMU stream of one unit (``/imu/<unit>``), read with every check of :meth:`array`."""
        base = f"/imu/{unit}"
        self.group(base)
        t = self.array(f"{base}/t", shape=(None,))
        return ImuStream(  # the (M, 3) streams' shapes checked before they are read or decompressed
            t=t,
            accel=self.array(f"{base}/accel", shape=(t.shape[0], 3)),
            gyro=self.array(f"{base}/gyro", required=False, shape=(t.shape[0], 3)),
        )

    def imu(self) -> dict[str, ImuStream]:
        return {unit: self.imu_unit(unit) for unit in self.imu_names()}

    def tof(self) -> dict[str, TofStream]:
        grp = self.group("/tof", required=False)
        out = {}
        for unit in self.unit_names(grp, "/tof") if grp is not None else ():
            base = f"/tof/{unit}"
            self.group(base)
            out[unit] = TofStream(t=self.array(f"{base}/t"), range=self.array(f"{base}/range"))
        return out

    def segments(self) -> Segments | None:
        if self.group("/segments", required=False) is None:
            return None
        return Segments(
            t_start=self.array("/segments/t_start"),
            t_end=self.array("/segments/t_end"),
            kind=self.array("/segments/kind", dtype=np.int8),
            pose=self.array("/segments/pose", dtype=np.int32),
            joint=self.array("/segments/joint", dtype=np.int32),
        )

    def truth(
        self,
    ) -> tuple[dict[str, SkinUnitPose], dict[str, dict[str, np.ndarray | float]], dict[str, BodyPose]]:
        """True poses on the robot's links (attrs ``link``, ``position``, ``quaternion_wxyz``), true
        poses on named rigid bodies (IMU-only: attrs ``body``, ``T_body_su``; a unit may have both)
        and the numeric extras (true sensor errors)."""
        grp = self.group("/truth", required=False)
        poses: dict[str, SkinUnitPose] = {}
        sensor: dict[str, dict[str, np.ndarray | float]] = {}
        bodies: dict[str, BodyPose] = {}
        for unit in self.unit_names(grp, "/truth") if grp is not None else ():
            base = f"/truth/{unit}"
            node = self.group(base)
            body = self.str_attr(base, "body", required=False)
            if body is not None:
                bodies[unit] = BodyPose(body=body, T_body_su=self.num_attr(base, "T_body_su", (4, 4)))
            if body is None or self.attr(base, "link", required=False) is not None:
                poses[unit] = self.link_pose(base)
            extra: dict[str, np.ndarray | float] = {}
            for key in node.attrs:
                if key in ("link", "position", "quaternion_wxyz", *TRUTH_BODY_ATTRS):
                    continue
                value = np.asarray(self.attr(base, key))
                if value.dtype.kind not in "fiu":  # non-numeric extras (notes, labels) are not sensor errors
                    continue
                extra[key] = float(value) if value.shape == () else value.astype(np.float64)
            if extra:
                sensor[unit] = extra
        return poses, sensor, bodies

    def events(self, units: list[str]) -> tuple[MoveEvent, ...]:
        """Moved-unit events (``/events/<k>``, k = 0, 1, ... in order; absent: none), each a checked
        :class:`~skincal.data.events.MoveEvent`, its unit one of ``units``."""
        grp = self.group("/events", required=False)
        if grp is None:
            return ()
        names = list(grp.keys())
        if names != [str(k) for k in range(len(names))]:
            raise self.fail("/events", f"must hold groups 0, 1, ... in order, got {shown(names[:5])}")
        out = []
        for name in names:
            base = f"/events/{name}"
            node = self.group(base)
            event: dict[str, Any] = {}
            for key in node.attrs:
                value = self.attr(base, key)
                text = isinstance(value, bytes | np.bytes_ | str)
                if text or (isinstance(value, np.ndarray) and value.dtype.kind in "OSU"):
                    event[key] = self.str_attr(base, key)
                else:
                    arr = np.asarray(value)
                    if arr.dtype.kind not in "fiu":
                        raise self.fail(self.attr_field(base, key), f"must be a number or text, got {arr.dtype}")
                    event[key] = arr.astype(np.float64) if arr.shape else arr.item()
            try:
                out.append(check_events([event], base, units=units)[0])
            except DatasetError as exc:
                raise self.fail(base, f"is not a valid event: {exc}") from None
        return tuple(out)

    def link_pose(self, base: str) -> SkinUnitPose:
        """A unit's true pose on a link of the robot (attrs ``link``, ``position``, ``quaternion_wxyz``)."""
        link = int(self.num_attr(base, "link", (), integer=True))
        position = self.num_attr(base, "position", (3,))
        quat = self.num_attr(base, "quaternion_wxyz", (4,))
        norm = float(np.linalg.norm(quat)) if np.all(np.isfinite(quat)) else float("nan")
        if not abs(norm - 1.0) <= _QUAT_NORM_TOL:
            raise self.fail(f"{base} attr 'quaternion_wxyz'", f"is not a unit quaternion (norm {norm:.6g})")
        try:
            return SkinUnitPose.from_quaternion(link, position, quat)
        except ConfigError as exc:
            raise self.fail(base, f"is not a valid pose: {exc}") from None


def open_file(path: Path) -> tuple[h5py.File, DatasetReader]:
    """The file opened read-only and its :class:`DatasetReader` (one-line DatasetError when it cannot be)."""
    source = str(path)
    size = regular_file(path, DATASET_FILE, DatasetError)  # before opening: a FIFO would block
    try:
        # No chunk cache: every dataset is read whole, once; the default 1 MB cache per dataset left
        # ~70 MB of freed-but-held heap after reading a 100-unit file (issue 19, report memory).
        f = h5py.File(path, "r", rdcc_nbytes=0)
    except OSError as exc:
        raise DatasetError(f"{source}: not a readable HDF5 file ({_first_line(exc)})") from None
    return f, DatasetReader(f, source, size)


def damaged(source: str, exc: Exception) -> DatasetError:
    return DatasetError(f"{source}: damaged file ({_first_line(exc)})")


H5PY_ERRORS = (OSError, RuntimeError, KeyError, ValueError, TypeError)  # what h5py raises on damaged files
