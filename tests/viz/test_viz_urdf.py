"""The viewer draws a URDF robot's visual meshes (viser's ``ViserUrdf``) at skincal's forward
kinematics, finds ``package://`` meshes, falls back to capsules with one note, and reads no file
outside its roots whatever the URDF names."""

from __future__ import annotations

import dataclasses
import os
import shutil
import sys
import threading
from pathlib import Path

import numpy as np
import pytest

from skincal.cli import main
from skincal.data.result import CalibrationResult, UnitResult, write_result
from skincal.kinematics import get_robot
from skincal.kinematics.transforms import matrix_from_quat_wxyz
from skincal.kinematics.urdf import chain_from_urdf, read_urdf_text
from skincal.skin.pose import SkinUnitPose
from skincal.viz.meshes import MAX_MESH_BYTES, MeshRefused, MeshResolver, load_mesh
from skincal.viz.viewer import scene_nodes

from registry_robots import registry_urdf, robots_dir

SHARE = robots_dir().parent
"""``.../share/example-robot-data``: the folder of the package the registry URDFs name."""
Q_XARM = np.array([0.3, -0.5, 0.4, 0.9, -0.6, 1.1, 0.7])

# -------------------------------------------------------------------------- reads seen by the test
_OPENED: list[str] = []
_WATCH = threading.local()


def _audit(event: str, args: tuple) -> None:  # a real hook of the interpreter: every open() is reported
    if event == "open" and getattr(_WATCH, "on", False) and isinstance(args[0], (str, bytes, os.PathLike)):
        _OPENED.append(os.fsdecode(args[0]))


sys.addaudithook(_audit)


class _Watch:
    """Within the block, every file this thread opens is recorded in :attr:`opened`."""

    def __enter__(self) -> _Watch:
        _OPENED.clear()
        _WATCH.on = True
        return self

    def __exit__(self, *exc: object) -> None:
        _WATCH.on = False
        self.opened = list(_OPENED)


# ------------------------------------------------------------------------------------------ helpers
def _write_stl(path: Path, size: float = 0.05) -> None:
    """A small closed box mesh (binary STL)."""
    import trimesh

    path.parent.mkdir(parents=True, exist_ok=True)
    trimesh.creation.box(extents=(size, size, 2 * size)).export(path)


def _urdf(base_mesh: str, link_mesh: str) -> str:
    """A one-joint robot whose base and link visuals are the given mesh file names."""
    return f"""<?xml version="1.0"?>
<robot name="crafted">
  <link name="base"><visual><geometry><mesh filename="{base_mesh}"/></geometry></visual></link>
  <link name="arm"><visual><origin xyz="0 0 0.1"/><geometry><mesh filename="{link_mesh}"/></geometry></visual></link>
  <joint name="j1" type="revolute"><parent link="base"/><child link="arm"/><origin xyz="0 0 0.2"/>
    <axis xyz="0 0 1"/><limit lower="-3" upper="3" effort="10" velocity="2"/></joint>
</robot>
"""


def _world_pose(server, name: str) -> np.ndarray:
    """The world pose of viser scene node ``name``: its ancestors' poses composed (viser's scene
    handles by node name; a missing ancestor is an identity frame)."""
    handles = scene_nodes(server)
    parts = name.strip("/").split("/")
    T = np.eye(4)
    for k in range(1, len(parts) + 1):
        handle = handles.get("/" + "/".join(parts[:k]))
        if handle is None:
            continue
        local = np.eye(4)
        local[:3, :3] = matrix_from_quat_wxyz(np.asarray(handle.wxyz, dtype=float))
        local[:3, 3] = handle.position
        T = T @ local
    return T


def _mesh_nodes(server) -> dict[str, str]:
    """Mesh node name by the URDF link it belongs to (``.../<link>/<link>:visual0``)."""
    out = {}
    for name, handle in scene_nodes(server).items():
        if name.startswith("/robot/urdf/") and type(handle).__name__ == "MeshHandle":
            out[name.rsplit("/", 1)[1].split(":visual")[0]] = name
    return out


def _check_meshes_at_fk(viewer, q: np.ndarray, links: range | None = None) -> int:
    """Every chain link with a mesh node is drawn at ``chain.link_frames(q)``; returns how many."""
    chain = viewer.chain
    T = chain.link_frames(np.asarray(q, dtype=float)[None])[0]
    nodes = _mesh_nodes(viewer.server)
    checked = 0
    for i in links if links is not None else range(chain.n_joints + 1):
        name = chain.link_name(i)
        if name in nodes:
            assert np.allclose(_world_pose(viewer.server, nodes[name]), T[i], atol=1e-6), name
            checked += 1
    return checked


def _empty_result(chain) -> CalibrationResult:
    pose = SkinUnitPose(1, np.eye(3), np.array([0.0, 0.05, 0.1]))
    return CalibrationResult("mle", chain.name, "", 0.0, {"su1": UnitResult(pose)})


@pytest.fixture
def viser_server():
    pytest.importorskip("viser")
    started = []

    def start(*args, **kwargs):
        from skincal.viz.viewer import start_viewer

        started.append(start_viewer(*args, **kwargs))
        return started[-1]

    yield start
    for v in started:
        v.close()


# ------------------------------------------------------------------------------------- resolution
def test_package_urls_resolve_from_the_urdf_folder_upwards_and_from_package_paths(tmp_path: Path):
    name = "package://example-robot-data/robots/xarm_description/meshes/xarm7/visual/link1.stl"
    expected = robots_dir() / "xarm_description/meshes/xarm7/visual/link1.stl"
    found = MeshResolver.from_options(registry_urdf("xarm7").parent, environ={}).resolve(name)
    assert found.samefile(expected)
    with pytest.raises(MeshRefused, match="package 'example-robot-data' not found"):
        MeshResolver.from_options(None, environ={}).resolve(name)  # a dataset's URDF: no folder
    assert MeshResolver.from_options(None, [SHARE.parent], environ={}).resolve(name).samefile(expected)
    assert MeshResolver.from_options(None, [SHARE], environ={}).resolve(name).samefile(expected)  # the package itself
    ros = os.pathsep.join([str(tmp_path / "missing"), str(SHARE.parent)])
    assert MeshResolver.from_options(None, environ={"ROS_PACKAGE_PATH": ros}).resolve(name).samefile(expected)


def test_packages_next_to_the_urdf_need_a_manifest(tmp_path: Path):
    _write_stl(tmp_path / "robots" / "arm_meshes" / "arm.stl")
    (tmp_path / "robots" / "arm_description" / "urdf").mkdir(parents=True)
    resolver = MeshResolver.from_options(tmp_path / "robots" / "arm_description" / "urdf", environ={})
    with pytest.raises(MeshRefused, match="package 'arm_meshes' not found"):
        resolver.resolve("package://arm_meshes/arm.stl")
    (tmp_path / "robots" / "arm_meshes" / "package.xml").write_text("<package/>")
    assert resolver.resolve("package://arm_meshes/arm.stl") == tmp_path / "robots" / "arm_meshes" / "arm.stl"
    # A folder the user names is trusted as it is.
    bare = MeshResolver.from_options(None, [tmp_path / "robots"], environ={})
    assert bare.resolve("package://arm_meshes/arm.stl") == tmp_path / "robots" / "arm_meshes" / "arm.stl"


def test_relative_mesh_names_resolve_inside_the_urdf_package(tmp_path: Path):
    pkg = tmp_path / "my_robot"
    _write_stl(pkg / "meshes" / "arm.stl")
    (pkg / "urdf").mkdir()
    resolver = MeshResolver.from_options(pkg / "urdf", environ={})
    with pytest.raises(MeshRefused, match="outside"):  # no package.xml: the URDF's folder is the root
        resolver.resolve("../meshes/arm.stl")
    (pkg / "package.xml").write_text("<package/>")
    assert resolver.resolve("../meshes/arm.stl") == pkg / "meshes" / "arm.stl"
    assert resolver.resolve(str(pkg / "meshes" / "arm.stl")) == pkg / "meshes" / "arm.stl"  # absolute, inside
    assert resolver.resolve("file://" + str(pkg / "meshes" / "arm.stl")) == pkg / "meshes" / "arm.stl"


def test_package_path_that_is_no_folder_is_refused(tmp_path: Path):
    from skincal.errors import ConfigError

    with pytest.raises(ConfigError, match="--package-path .*not a folder"):
        MeshResolver.from_options(None, [tmp_path / "nope"], environ={})


@pytest.mark.adversarial
@pytest.mark.parametrize(
    "name",
    [
        "package://../../etc/passwd",
        "package://..",
        "package://pkg/../../outside/secret.stl",
        "package://pkg/meshes/../../../outside/secret.stl",
        "package://pkg//{tmp}/outside/secret.stl",
        "{tmp}/outside/secret.stl",
        "file://{tmp}/outside/secret.stl",
        "../outside/secret.stl",
        "package://{top}/outside/secret.stl",  # an ancestor's folder without package.xml is no package
        "/etc/passwd",
        "http://127.0.0.1:9/secret.stl",
    ],
)
def test_crafted_mesh_names_outside_the_roots_are_refused_unread(tmp_path: Path, name: str):
    """A URDF naming a file outside the roots (``..``, absolute, another scheme) is refused, and the
    file is never opened (the interpreter's audit hook sees every open)."""
    root = tmp_path / "root"
    _write_stl(root / "pkg" / "meshes" / "ok.stl")
    _write_stl(tmp_path / "outside" / "secret.stl")  # a valid mesh: refused for where it is, not what
    (root / "pkg" / "urdf").mkdir()
    resolver = MeshResolver.from_options(root / "pkg" / "urdf", [root], environ={})
    with _Watch() as watch, pytest.raises(MeshRefused):
        path = resolver.resolve(name.format(tmp=tmp_path, top="/".join(tmp_path.parts[1:])))
        load_mesh(path)
    assert not [p for p in watch.opened if "outside" in p or p.startswith("/etc")], watch.opened


@pytest.mark.adversarial
def test_any_resolved_mesh_name_stays_inside_a_root(tmp_path: Path):
    """Names built from ``..``, ``/``, ``.``, schemes and real folder names: whatever resolves is a
    file inside the package or the URDF's package, never the file beside them."""
    from hypothesis import given, settings
    from hypothesis import strategies as st

    root = tmp_path / "ws"
    _write_stl(root / "pkg" / "meshes" / "ok.stl")
    (root / "pkg" / "package.xml").write_text("<package/>")
    (root / "pkg" / "urdf").mkdir()
    _write_stl(root / "secret.stl")  # beside the package, inside no root
    resolver = MeshResolver.from_options(root / "pkg" / "urdf", environ={})
    allowed = {root / "pkg" / "meshes" / "ok.stl"}
    tmp = str(tmp_path)
    prefixes = st.sampled_from(
        ["", "../", "package://pkg/", "package://ws/", "package://", f"{tmp}/ws/", f"file://{tmp}/ws/pkg/", "/"]
    )
    middle = st.lists(st.sampled_from(["..", ".", "", "pkg", "meshes", "ws", "urdf"]), max_size=4)

    @settings(max_examples=500, deadline=None, derandomize=True)
    @given(prefixes, middle, st.sampled_from(["ok.stl", "secret.stl"]))
    def check(prefix: str, segments: list[str], target: str) -> None:
        try:
            path = resolver.resolve(prefix + "/".join([*segments, target]))
        except MeshRefused:
            return
        assert path in allowed, path

    check()


@pytest.mark.adversarial
def test_special_and_oversized_files_inside_a_root_are_refused_unread(tmp_path: Path):
    meshes = tmp_path / "pkg" / "meshes"
    meshes.mkdir(parents=True)
    (meshes / "zero.stl").symlink_to("/dev/zero")  # endless
    os.mkfifo(meshes / "fifo.stl")  # opening it would block
    with open(meshes / "big.stl", "wb") as f:  # sparse: costs no disk
        f.truncate(MAX_MESH_BYTES + 1)
    (meshes / "notes.txt").write_text("not a mesh")
    resolver = MeshResolver.from_options(None, [tmp_path], environ={})
    with _Watch() as watch:
        for name, reason in [
            ("zero.stl", "not a regular file"),
            ("fifo.stl", "not a regular file"),
            ("big.stl", "byte limit"),
            ("notes.txt", "not one of the formats"),
        ]:
            with pytest.raises(MeshRefused, match=reason):
                resolver.resolve(f"package://pkg/meshes/{name}")
    assert watch.opened == []


@pytest.mark.adversarial
def test_a_mesh_that_is_not_a_mesh_is_refused(tmp_path: Path):
    bad = tmp_path / "bad.stl"
    bad.write_bytes(b"solid x\nfacet normal nan\n" * 10)
    with pytest.raises(MeshRefused, match="bad.stl"):
        load_mesh(bad)


# ---------------------------------------------------------------------------------------- viewer
def test_viewer_draws_registry_meshes_at_the_chain_kinematics(viser_server):
    """xarm7 (example-robot-data, .stl visuals): one mesh node per link, each at
    ``chain.link_frames(q)`` for the posture shown, following the joint sliders and the playback;
    no capsules; units still drawn on their link frames."""
    from skincal.viz.model import Recording

    path = registry_urdf("xarm7")
    chain = get_robot(str(path))
    t = np.linspace(0.0, 2.0, 21)
    q = np.outer(np.sin(t), Q_XARM)
    rec = Recording(t=t, q=q, tof_t={}, tof_range={}, obstacles={})
    v = viser_server(_empty_result(chain), chain, recording=rec, meshes=MeshResolver.from_options(path.parent))
    assert v.notes == [] and v.urdf is not None
    names = list(scene_nodes(v.server))
    assert not [n for n in names if "/capsule" in n]
    assert any(n.startswith("/robot/link1/est_su1") for n in names)
    assert _check_meshes_at_fk(v, rec.q_at(rec.t_start)) == chain.n_joints  # link 0 ('world') has no visual
    v.time_slider.value = 1.3
    assert _check_meshes_at_fk(v, rec.q_at(1.3)) == chain.n_joints
    v.sliders[3].value = -40.0  # deg: the slider's callback moves the meshes too
    q_now = np.radians([s.value for s in v.sliders])
    assert q_now[3] == pytest.approx(np.radians(-40.0))
    _check_meshes_at_fk(v, q_now)
    # The mesh is the URDF's file, placed by the visual's origin: link3's vertices in the world frame.
    import trimesh
    import yourdfpy

    urdf = yourdfpy.URDF.load(str(path), build_scene_graph=False, load_meshes=False)
    visual = urdf.link_map["link3"].visuals[0]
    raw = trimesh.load(robots_dir() / "xarm_description/meshes/xarm7/visual/link3.stl", force="mesh")
    node = _mesh_nodes(v.server)["link3"]
    handle = scene_nodes(v.server)[node]
    origin = np.eye(4) if visual.origin is None else visual.origin
    T = chain.link_frames(q_now[None])[0][chain.link_names.index("link3")] @ origin
    drawn = _world_pose(v.server, node)
    world = np.asarray(handle.vertices) @ drawn[:3, :3].T + drawn[:3, 3]
    assert np.allclose(world, raw.vertices @ T[:3, :3].T + T[:3, 3], atol=1e-6)


def test_viewer_places_the_urdf_root_when_the_chain_starts_further_out(viser_server):
    """A chain from link2 on (``--base-link link2``): the URDF is placed so that link2 is the base frame."""
    path = registry_urdf("xarm7")
    chain = get_robot(str(path), base_link="link2")
    assert chain.link_name(0) == "link2"
    v = viser_server(_empty_result(chain), chain, q0=Q_XARM[2:], meshes=MeshResolver.from_options(path.parent))
    assert v.notes == []
    assert _check_meshes_at_fk(v, Q_XARM[2:]) == chain.n_joints + 1
    assert not np.allclose(v.visuals.T_base_root, np.eye(4))


def test_viewer_keeps_joints_outside_the_chain_at_zero(viser_server):
    """Panda (.dae visuals): the 7 arm links follow the chain; the fingers (a prismatic joint and
    its mimic, not in the chain) stay at 0: each finger node sits at its joint origin on the hand."""
    pytest.importorskip("collada")
    import yourdfpy

    path = registry_urdf("panda")
    chain = get_robot(str(path))
    assert "panda_finger_joint1" not in chain.joint_names
    q = np.array([0.2, -0.4, 0.1, -2.0, 0.3, 1.6, 0.5])
    v = viser_server(_empty_result(chain), chain, q0=q, meshes=MeshResolver.from_options(path.parent))
    assert v.notes == []
    assert _check_meshes_at_fk(v, q) == chain.n_joints + 1
    urdf = yourdfpy.URDF.load(str(path), build_scene_graph=False, load_meshes=False)
    nodes = _mesh_nodes(v.server)
    hand = _world_pose(v.server, nodes["panda_hand"])
    for finger, joint in (("panda_leftfinger", "panda_finger_joint1"), ("panda_rightfinger", "panda_finger_joint2")):
        expected = hand @ urdf.joint_map[joint].origin
        assert np.allclose(_world_pose(v.server, nodes[finger]), expected, atol=1e-9), finger


def test_a_dataset_urdf_finds_its_meshes_through_package_paths_only(viser_server):
    """The URDF text alone (as a dataset stores it): no folder, so capsules and one note, unless a
    package path holds the package."""
    chain = chain_from_urdf(text=read_urdf_text(registry_urdf("xarm7")))
    bare = viser_server(_empty_result(chain), chain, meshes=MeshResolver.from_options(None, environ={}))
    assert bare.urdf is None and len(bare.notes) == 1 and "capsules" in bare.notes[0]
    assert "example-robot-data" in bare.notes[0]
    assert any("/capsule" in n for n in scene_nodes(bare.server))
    found = viser_server(_empty_result(chain), chain, meshes=MeshResolver.from_options(None, [SHARE], environ={}))
    assert found.notes == [] and _check_meshes_at_fk(found, np.zeros(7)) == chain.n_joints


@pytest.mark.adversarial
@pytest.mark.parametrize(
    ("crafted", "reason"),
    [
        ("package://pkg/../../outside/secret.stl", "is outside the folders meshes are read from"),
        ("{tmp}/outside/secret.stl", "is outside the folders meshes are read from"),
        ("package://../../etc/passwd", "package name '..'"),
    ],
)
def test_viewer_with_a_crafted_urdf_draws_capsules_and_reads_nothing_outside(
    tmp_path: Path, viser_server, crafted: str, reason: str
):
    root = tmp_path / "root"
    _write_stl(root / "pkg" / "meshes" / "base.stl")
    _write_stl(tmp_path / "outside" / "secret.stl")
    chain = chain_from_urdf(text=_urdf("package://pkg/meshes/base.stl", crafted.format(tmp=tmp_path)))
    with _Watch() as watch:
        v = viser_server(_empty_result(chain), chain, meshes=MeshResolver.from_options(None, [root], environ={}))
    assert not [p for p in watch.opened if "outside" in p or p.startswith("/etc")], watch.opened
    assert any(p.endswith("base.stl") for p in watch.opened)  # (the hook does see the reads there are)
    assert v.urdf is None and len(v.notes) == 1 and "robot drawn as capsules" in v.notes[0] and reason in v.notes[0]
    names = list(scene_nodes(v.server))
    assert not [n for n in names if n.startswith("/robot/urdf")] and any("/capsule" in n for n in names)


def test_viewer_draws_a_small_urdf_with_local_meshes(tmp_path: Path, viser_server):
    """A hand-written URDF whose meshes sit in its package: drawn, the arm mesh at the joint's FK."""
    pkg = tmp_path / "pkg"
    _write_stl(pkg / "meshes" / "base.stl")
    _write_stl(pkg / "meshes" / "arm.stl", size=0.03)
    (pkg / "urdf").mkdir()
    (pkg / "urdf" / "r.urdf").write_text(_urdf("package://pkg/meshes/base.stl", "../meshes/arm.stl"))
    (pkg / "package.xml").write_text("<package/>")
    chain = get_robot(str(pkg / "urdf" / "r.urdf"))
    result = CalibrationResult("mle", chain.name, "", 0.0, {})
    v = viser_server(result, chain, q0=np.array([0.7]), meshes=MeshResolver.from_options(pkg / "urdf", environ={}))
    assert v.notes == [] and _check_meshes_at_fk(v, np.array([0.7])) == 2


# ------------------------------------------------------------------------------------------- CLI
def test_cli_view_draws_urdf_meshes_or_notes_the_fallback_once(tmp_path: Path, capsys):
    pytest.importorskip("viser")
    path = registry_urdf("xarm7")
    chain = get_robot(str(path))
    res = tmp_path / "res.json"
    write_result(_empty_result(chain), res)
    assert main(["view", str(res), "--robot", str(path), "--duration", "0"]) == 0
    out, err = capsys.readouterr()
    assert "skincal viewer: http://127.0.0.1:" in out and "note:" not in err
    copy = tmp_path / "elsewhere" / "xarm7.urdf"  # the URDF without its package around it
    copy.parent.mkdir()
    shutil.copy(path, copy)
    assert main(["view", str(res), "--robot", str(copy), "--duration", "0"]) == 0
    out, err = capsys.readouterr()
    assert err.count("note:") == 1 and "robot drawn as capsules" in err and "Traceback" not in err
    assert main(["view", str(res), "--robot", str(copy), "--package-path", str(SHARE), "--duration", "0"]) == 0
    assert "note:" not in capsys.readouterr().err
    assert main(["view", str(res), "--robot", str(copy), "--package-path", str(tmp_path / "nope")]) == 2
    err = capsys.readouterr().err
    assert "error: --package-path" in err and "not a folder" in err and "Traceback" not in err


def test_cli_view_plays_a_urdf_dataset_with_meshes_from_a_package_path(tmp_path: Path, capsys):
    """A dataset stores the URDF text only: its meshes come from --package-path (else capsules, one note)."""
    pytest.importorskip("viser")
    from skincal.data.hdf5 import read_dataset

    urdf, ds, res = tmp_path / "xarm7.urdf", tmp_path / "ds.h5", tmp_path / "r.json"
    shutil.copy(registry_urdf("xarm7"), urdf)
    args = ["--placement", "random", "--units", "2", "--protocol", "fast", "--seed", "2", "-o", str(ds)]
    assert main(["simulate", "--robot", str(urdf), *args]) == 0
    data = read_dataset(ds)
    write_result(
        CalibrationResult("truth", data.robot.name, "", 0.0, {n: UnitResult(p) for n, p in data.truth.items()}), res
    )
    capsys.readouterr()
    assert main(["view", str(res), "--play", str(ds), "--duration", "0"]) == 0
    err = capsys.readouterr().err
    assert err.count("note:") == 1 and "package 'example-robot-data' not found" in err
    assert main(["view", str(res), "--play", str(ds), "--package-path", str(SHARE), "--duration", "0"]) == 0
    out, err = capsys.readouterr()
    assert "note:" not in err and "skincal viewer: http://127.0.0.1:" in out


def test_viewer_screenshot_shows_the_meshes(viser_server, tmp_path: Path):
    """Headless Chromium renders the xarm7's meshes: around the centre of every link's mesh the
    pixels differ from the white background; the sky above stays white."""
    from skincal.viz.browser import capture_page, find_chromium
    from skincal.viz.model import project_to_image
    from skincal.viz.viewer import CAMERA_FOV_DEG, CAMERA_LOOK_AT, CAMERA_POSITION

    exe = find_chromium()
    if exe is None:
        pytest.skip("no Chromium: apt-get install chromium (Debian package) to run the screenshot test")
    import matplotlib.image as mpimg

    path = registry_urdf("xarm7")
    chain = get_robot(str(path))
    q = np.array([0.0, -0.3, 0.0, 0.8, 0.0, 1.0, 0.0])
    v = viser_server(_empty_result(chain), chain, q0=q, meshes=MeshResolver.from_options(path.parent, environ={}))
    centres = []
    for name in _mesh_nodes(v.server).values():
        T = _world_pose(v.server, name)
        centres.append(T[:3, :3] @ np.asarray(scene_nodes(v.server)[name].vertices).mean(0) + T[:3, 3])
    assert len(centres) == 8  # link_base and link1..link7
    width, height = 1280, 800
    cam = (CAMERA_POSITION, CAMERA_LOOK_AT, np.radians(CAMERA_FOV_DEG), width, height)
    px, _ = project_to_image(np.array(centres), *cam)
    for settle_s in (2.5, 8.0):  # software WebGL on a loaded machine: one retry with a longer settle
        shot = capture_page(
            v.url,
            width=width,
            height=height,
            chromium=exe,
            settle_s=settle_s,
            ready_js="!!document.querySelector('canvas') && document.body.innerText.includes('Joints')",
        )
        png = tmp_path / "viewer_meshes.png"
        png.write_bytes(shot.png)
        img = mpimg.imread(png)[..., :3]
        drawn = [img[y - 4 : y + 5, x - 4 : x + 5].mean() < 0.9 for x, y in np.round(px).astype(int)]
        if img.shape[:2] == (height, width) and all(drawn):
            break
    assert shot.errors == [], shot.errors
    save = os.environ.get("SKINCAL_SAVE_SCREENSHOTS")
    if save:
        Path(save).mkdir(parents=True, exist_ok=True)
        (Path(save) / "viewer_meshes.png").write_bytes(shot.png)
    assert all(drawn), f"no mesh drawn around {np.round(px[~np.array(drawn)])}"
    top = int(px[:, 1].min()) - 80
    assert top > 60 and img[20:top, 450:850].mean() > 0.97


@pytest.mark.adversarial
def test_cli_view_never_opens_a_file_named_only_inside_the_result(tmp_path: Path, capsys, monkeypatch):
    """A result whose robot is 'ok.urdf' (or a URDF robot named like a preset) is not drawn on
    whatever that name finds: the robot comes from --robot or a dataset; a preset name is used only
    when the result's link names are the preset's."""
    pytest.importorskip("viser")
    chain = get_robot(str(registry_urdf("ur5")))  # example-robot-data's UR5 is <robot name="ur5">
    res = tmp_path / "res.json"
    result = _empty_result(chain)
    write_result(dataclasses.replace(result, robot="ok.urdf"), res)
    (tmp_path / "ok.urdf").write_text("<robot name='trap'/>")
    monkeypatch.chdir(tmp_path)
    assert main(["view", str(res), "--duration", "0"]) == 2
    assert "is not a preset: give its description with --robot" in capsys.readouterr().err
    assert main(["view", str(res), "--base-link", "base_link", "--duration", "0"]) == 2
    assert "apply to a URDF robot given with --robot" in capsys.readouterr().err
    pose = SkinUnitPose(2, np.eye(3), np.array([0.0, 0.05, 0.1]))
    unit = UnitResult(pose, extras={"link_name": "upper_arm_link"})
    urdf_ur5 = CalibrationResult("mle", "ur5", "", 0.0, {"su1": unit})
    write_result(urdf_ur5, res)
    assert main(["view", str(res), "--duration", "0"]) == 2  # not drawn on the DH preset's frames
    assert "the result is of another robot of that name" in capsys.readouterr().err
