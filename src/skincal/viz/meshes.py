"""A URDF's visual meshes for the viewer, found and read only inside known folders ("roots").

A URDF names its mesh files in three ways, resolved here without any network access:

* ``package://pkg/path``: ``path`` inside the folder of package ``pkg``, looked up, in this order,
  in the ``--package-path`` folders, in the URDF's own folder and its parents, and in the
  ``ROS_PACKAGE_PATH`` folders (a folder named ``pkg`` itself or a ``pkg`` folder inside it; one
  found from the URDF's folder must hold a ``package.xml``, so ``package://home/...`` does not make
  ``/home`` a package);
* a relative path: against the URDF file's folder (its root is the enclosing ROS package, the
  nearest ancestor with a ``package.xml``, else that folder); a URDF from a dataset has no folder,
  so the package paths are tried as roots;
* an absolute path or ``file://`` URL: only when inside one of the roots above.

The rule against crafted names is lexical and is checked before the file system is touched: the
normalised path must stay inside its root (``package://pkg/../../etc/passwd``, an absolute
``/etc/passwd`` and a package named ``..`` are refused unread). Symbolic links the user put inside
a root are followed (a ``colcon --symlink-install`` package is made of them). A mesh must be a
regular file of at most :data:`MAX_MESH_BYTES` in one of :data:`MESH_SUFFIXES`; it is read from
its own bytes only: files it references (materials, textures, buffers) are not opened.
"""

from __future__ import annotations

import io
import os
import stat
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from skincal.errors import ConfigError
from skincal.names import name_problem, printable

MAX_MESH_BYTES = 50 * 1024 * 1024
"""Largest mesh file read, bytes."""
MAX_TOTAL_MESH_BYTES = 500 * 1024 * 1024
"""Largest sum of the mesh files of one robot, bytes."""
MESH_SUFFIXES = (".stl", ".obj", ".dae", ".ply", ".glb", ".off")
"""Mesh formats read (trimesh; ``.dae`` needs ``pycollada``)."""
PACKAGE_SCHEME = "package://"
FILE_SCHEME = "file://"


class MeshRefused(Exception):  # noqa: N818 - a reason, not a failure of the program
    """A mesh file name that is not resolved or not read, with the reason (one line)."""


def _inside(path: Path, root: Path) -> bool:
    return path == root or root in path.parents


def _normalised(base: Path, name: str) -> Path:
    """``base / name`` made absolute and normalised lexically (``..`` folded, links not followed)."""
    return Path(os.path.normpath(os.path.join(os.path.abspath(base), name)))


def _package_root(folder: Path) -> Path:
    """The nearest ancestor of ``folder`` (itself included) holding a ``package.xml``, else ``folder``."""
    for candidate in (folder, *folder.parents):
        if (candidate / "package.xml").is_file():
            return candidate
    return folder


@dataclass(frozen=True)
class MeshResolver:
    """Resolves a URDF's mesh file names (see the module docstring).

    Attributes:
        urdf_dir: the URDF file's folder (``None``: the URDF came from a dataset).
        package_paths: the ``--package-path`` folders, absolute.
        ros_package_paths: the ``ROS_PACKAGE_PATH`` folders, absolute.
    """

    urdf_dir: Path | None = None
    package_paths: tuple[Path, ...] = ()
    ros_package_paths: tuple[Path, ...] = ()

    @classmethod
    def from_options(
        cls,
        urdf_dir: str | Path | None,
        package_paths: Iterable[str | Path] = (),
        environ: Mapping[str, str] | None = None,
    ) -> MeshResolver:
        """A resolver for a URDF in ``urdf_dir`` with the ``--package-path`` folders (each must be a
        folder, else a :class:`ConfigError`) and the existing folders of ``ROS_PACKAGE_PATH``
        (``os.pathsep``-separated) of ``environ`` (default: this process's environment)."""
        explicit = []
        for entry in package_paths:
            if not Path(entry).is_dir():
                raise ConfigError(f"--package-path {printable(str(entry))}: not a folder")
            explicit.append(Path(os.path.abspath(entry)))
        env = os.environ if environ is None else environ
        ros = [Path(os.path.abspath(e)) for e in env.get("ROS_PACKAGE_PATH", "").split(os.pathsep) if e]
        return cls(
            None if urdf_dir is None else Path(os.path.abspath(urdf_dir)),
            tuple(explicit),
            tuple(p for p in ros if p.is_dir()),
        )

    def _package_dir(self, package: str) -> Path:
        problem = name_problem(package)
        if problem is not None:
            raise MeshRefused(f"package name {printable(repr(package))} {problem}")
        vouched = list(self.package_paths)  # folders the user named: any folder of that name is the package
        nearby = [] if self.urdf_dir is None else [self.urdf_dir, *self.urdf_dir.parents]
        for folder, needs_manifest in (
            [(f, False) for f in vouched] + [(f, True) for f in nearby] + [(f, False) for f in self.ros_package_paths]
        ):
            for candidate in (folder, folder / package):
                if candidate.name != package or not candidate.is_dir():
                    continue
                if not needs_manifest or (candidate / "package.xml").is_file():
                    return candidate
        raise MeshRefused(f"package '{printable(package)}' not found (give its folder or a parent with --package-path)")

    def _roots(self) -> list[Path]:
        """Folders that relative and absolute names may point into: the URDF's package (or folder),
        then the package paths."""
        roots = [] if self.urdf_dir is None else [_package_root(self.urdf_dir)]
        return roots + list(self.package_paths) + list(self.ros_package_paths)

    def resolve(self, filename: str) -> Path:
        """The file a URDF mesh ``filename`` names, checked lexically against its root and then as a
        regular file of at most :data:`MAX_MESH_BYTES`; :class:`MeshRefused` otherwise."""
        shown = printable(filename)
        name = filename.strip()
        if not name or "\x00" in name:
            raise MeshRefused(f"mesh file name {shown!r} is empty or contains NUL")
        if name.startswith(PACKAGE_SCHEME):
            package, _, rest = name[len(PACKAGE_SCHEME) :].partition("/")
            if not rest:
                raise MeshRefused(f"mesh {shown}: no file after the package name")
            root = self._package_dir(package)
            path = _normalised(root, rest)
            candidates = [(path, root)]
        elif "://" in name and not name.startswith(FILE_SCHEME):
            raise MeshRefused(f"mesh {shown}: only package:// and local files are read (no network)")
        else:
            local = name[len(FILE_SCHEME) :] if name.startswith(FILE_SCHEME) else name
            if os.path.isabs(local):
                path = Path(os.path.normpath(local))
                candidates = [(path, root) for root in self._roots()]
            elif self.urdf_dir is not None:
                candidates = [(_normalised(self.urdf_dir, local), self._roots()[0])]
            else:
                candidates = [(_normalised(root, local), root) for root in self._roots()]
        inside = [(p, r) for p, r in candidates if _inside(p, r)]
        if not inside:
            where = ", ".join(str(r) for _, r in candidates) or "no folder (give --package-path)"
            raise MeshRefused(f"mesh {shown} is outside the folders meshes are read from ({printable(where)})")
        if Path(name).suffix.lower() not in MESH_SUFFIXES:
            raise MeshRefused(f"mesh {shown}: not one of the formats read ({', '.join(MESH_SUFFIXES)})")
        for path, _ in inside:
            try:
                info = path.stat()
            except OSError:
                continue
            if not stat.S_ISREG(info.st_mode):
                raise MeshRefused(f"mesh {shown}: {printable(str(path))} is not a regular file")
            if info.st_size > MAX_MESH_BYTES:
                raise MeshRefused(f"mesh {shown}: {info.st_size} bytes is over the {MAX_MESH_BYTES} byte limit")
            return path
        raise MeshRefused(f"mesh {shown}: no such file ({printable(str(inside[0][0]))})")


def _no_other_files() -> Any:
    """A trimesh resolver that opens nothing: a mesh's materials, textures and buffers are skipped."""
    from trimesh.resolvers import Resolver

    class _Nothing(Resolver):
        def __init__(self) -> None:
            pass

        def get(self, key: str) -> bytes:
            raise FileNotFoundError(key)

        def write(self, name: str, data: Any) -> None:
            raise PermissionError(name)

        def namespaced(self, namespace: str) -> Any:
            return self

        def keys(self) -> Iterable[str]:
            return iter(())

    return _Nothing()


def load_mesh(path: Path) -> Any:
    """One ``trimesh.Trimesh`` of the triangles of mesh file ``path`` (its scene graph applied), read
    from the file's own bytes (at most :data:`MAX_MESH_BYTES`); :class:`MeshRefused` otherwise."""
    import trimesh

    suffix = path.suffix.lower()
    if suffix == ".dae":
        try:
            import collada  # noqa: F401
        except ImportError:
            raise MeshRefused(f"mesh {printable(str(path))}: reading .dae needs pycollada") from None
    try:
        with open(path, "rb") as handle:
            data = handle.read(MAX_MESH_BYTES + 1)
    except OSError as exc:
        raise MeshRefused(f"mesh {printable(str(path))}: {exc.strerror or exc}") from None
    if len(data) > MAX_MESH_BYTES:
        raise MeshRefused(f"mesh {printable(str(path))}: over the {MAX_MESH_BYTES} byte limit")
    try:
        scene = trimesh.load(
            io.BytesIO(data), file_type=suffix[1:], resolver=_no_other_files(), force="scene", skip_materials=True
        )
        parts = []
        for node in scene.graph.nodes_geometry:
            T, geometry_name = scene.graph.get(node)
            geometry = scene.geometry[geometry_name]
            if isinstance(geometry, trimesh.Trimesh) and len(geometry.faces):
                parts.append(geometry.copy().apply_transform(T))
    except Exception as exc:  # noqa: BLE001 - every parser error of every format alike
        first = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
        raise MeshRefused(f"mesh {printable(str(path))}: cannot be read ({printable(first)[:200]})") from None
    if not parts:
        raise MeshRefused(f"mesh {printable(str(path))}: no triangles")
    mesh = trimesh.util.concatenate(parts)
    if not np.all(np.isfinite(mesh.vertices)):
        raise MeshRefused(f"mesh {printable(str(path))}: non-finite vertices")
    return mesh


@dataclass
class UrdfVisuals:
    """A robot's URDF with its visual meshes loaded, ready for ``viser.extras.ViserUrdf``.

    Attributes:
        urdf: the ``yourdfpy.URDF`` (visual scene graph built, meshes added as triangles).
        joint_names: the URDF joint of each chain joint, in chain order.
        T_base_root: ``(4, 4)`` pose of the URDF's root link in the chain's base frame {0}.
        files: the mesh files read.
    """

    urdf: Any
    joint_names: tuple[str, ...]
    T_base_root: np.ndarray
    files: tuple[Path, ...]

    def configuration(self, q: np.ndarray) -> dict[str, float]:
        """The URDF configuration of chain joint angles ``q`` ``(n,)`` (other URDF joints keep 0)."""
        return {name: float(value) for name, value in zip(self.joint_names, q, strict=True)}


def _visual_scale(mesh: Any) -> np.ndarray:
    scale = getattr(mesh, "scale", None)
    if scale is None:
        return np.eye(4)
    S = np.eye(4)
    S[:3, :3] = np.diag(np.broadcast_to(np.asarray(scale, dtype=float), (3,)))
    return S


def urdf_visuals(chain: Any, resolver: MeshResolver) -> UrdfVisuals:
    """The visual geometry of ``chain``'s URDF (``chain.source``) with every mesh resolved by
    ``resolver`` and read (:func:`load_mesh`); :class:`MeshRefused` naming the first problem (a
    mesh not resolved or not read, a link or visual name no scene path can carry, a chain joint
    the URDF lacks, no visual geometry at all)."""
    if chain.source is None:
        raise MeshRefused(f"robot '{printable(chain.name)}' has no URDF")
    import yourdfpy

    from skincal.kinematics.urdf import parse_urdf

    try:
        robot = parse_urdf(chain.source, "the robot's URDF").robot
    except ConfigError as exc:
        raise MeshRefused(str(exc)) from None
    for link in robot.links:
        for what, name in [("link", link.name)] + [("visual", v.name) for v in link.visuals if v.name is not None]:
            problem = name_problem(name)
            if problem is not None:
                raise MeshRefused(f"URDF {what} name {printable(repr(name))} {problem}")
    moving = {j.name for j in robot.joints if j.type != "fixed" and j.mimic is None}
    missing = [n for n in chain.joint_names if n not in moving]
    if missing:
        raise MeshRefused(f"joint '{printable(missing[0])}' of the chain is not a moving joint of its URDF")
    meshes: dict[str, Any] = {}
    files: list[Path] = []
    total = 0
    for link in robot.links:
        for visual in link.visuals:
            mesh = visual.geometry.mesh if visual.geometry is not None else None
            if mesh is None or mesh.filename in meshes:
                continue
            path = resolver.resolve(mesh.filename)
            total += path.stat().st_size
            if total > MAX_TOTAL_MESH_BYTES:
                raise MeshRefused(f"the URDF's meshes exceed {MAX_TOTAL_MESH_BYTES} bytes in all")
            meshes[mesh.filename] = load_mesh(path)
            files.append(path)
    try:
        urdf = yourdfpy.URDF(robot=robot, build_scene_graph=True, load_meshes=False)
    except Exception as exc:  # noqa: BLE001 - the parser's scene graph errors alike
        first = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
        raise MeshRefused(f"the URDF's scene graph cannot be built ({printable(first)[:200]})") from None
    for link in robot.links:
        for k, visual in enumerate(link.visuals):
            mesh = visual.geometry.mesh if visual.geometry is not None else None
            if mesh is None:
                continue
            origin = np.eye(4) if visual.origin is None else np.asarray(visual.origin, dtype=float)
            geometry = meshes[mesh.filename].copy().apply_transform(_visual_scale(mesh))
            urdf.scene.add_geometry(
                geometry, geom_name=f"{link.name}:visual{k}", parent_node_name=link.name, transform=origin
            )
    if not urdf.scene.geometry:
        raise MeshRefused("the URDF has no visual geometry")
    base = chain.link_name(0)
    if base not in urdf.link_map:
        raise MeshRefused(f"base link '{printable(base)}' of the chain is not a link of its URDF")
    T_root_base = urdf.get_transform(frame_to=base, frame_from=urdf.base_link)
    return UrdfVisuals(urdf, tuple(chain.joint_names), np.linalg.inv(T_root_base), tuple(files))
