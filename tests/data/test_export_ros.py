"""ROS-ready exports (issue 14, item 6): complete URDFs that URDF parsers load and whose unit frames
are skincal's (every preset and registry URDFs), link names without a map, xacro macro, one static
TF node for ROS 1 and ROS 2, Range frames, 6x6 pose covariance."""

from __future__ import annotations

import ast
import json
import re
import shutil
import subprocess
import sys
import warnings
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
import yaml

from skincal.cli import main
from skincal.data.export import (
    T_SU_RANGE,
    UNKNOWN_VARIANCE,
    export_result,
    export_text,
    link_frames_for,
    robot_names,
    rpy_from_matrix,
    to_urdf,
    unit_frames,
)
from skincal.data.result import CalibrationResult, UnitResult, write_result
from skincal.errors import ConfigError
from skincal.kinematics import PRESETS, get_robot
from skincal.kinematics.urdf import chain_from_urdf
from skincal.skin.pose import SkinUnitPose

from registry_robots import REGISTRY_URDFS, random_chain, registry_urdf

yourdfpy = pytest.importorskip("yourdfpy")


def _result(robot: str, n_links: int, seed: int = 0, per_link: int = 2) -> CalibrationResult:
    """``per_link`` units with random poses on every link 1..n_links, per-axis std (a NaN on link 1)."""
    rng = np.random.default_rng(seed)
    units = {}
    for link in range(1, n_links + 1):
        for k in range(per_link):
            q = rng.normal(size=4)
            pose = SkinUnitPose.from_quaternion(link, rng.uniform(-0.15, 0.15, 3), q / np.linalg.norm(q))
            pos_std = rng.uniform(1e-5, 1e-3, 3)
            if link == 1:
                pos_std[2] = np.nan
            units[f"su{link}_{k}"] = UnitResult(
                pose=pose, observable=link != 1, position_std_m=pos_std, rotation_std_deg=rng.uniform(0.01, 1.0, 3)
            )
    return CalibrationResult(method="mle", robot=robot, dataset_sha256="", runtime_s=0.1, units=units)


def _load(path) -> yourdfpy.URDF:
    return yourdfpy.URDF.load(
        str(path),
        build_scene_graph=True,
        load_meshes=False,
        build_collision_scene_graph=False,
        load_collision_meshes=False,
    )


def _check_unit_frames(urdf_path, chain, result, n_configs: int = 20, seed: int = 1) -> None:
    """yourdfpy's unit frames (base -> unit link) equal skincal's link_frames(q) @ T_link_su to 1e-9 m
    over random configurations (joints outside the chain at 0)."""
    model = _load(urdf_path)
    base = robot_names(chain).links[0]
    rng = np.random.default_rng(seed)
    lo = np.where(np.isfinite(chain.joint_lower), chain.joint_lower, -np.pi)
    hi = np.where(np.isfinite(chain.joint_upper), chain.joint_upper, np.pi)
    names = robot_names(chain).joints
    worst = 0.0
    for _ in range(n_configs):
        q = rng.uniform(lo, hi)
        model.update_cfg(dict(zip(names, q, strict=True)))
        frames = chain.link_frames(q[None])[0]
        for unit, res in result.units.items():
            theirs = model.get_transform(unit, base)
            ours = frames[res.pose.link] @ res.pose.T_link_su
            worst = max(worst, np.abs(theirs - ours).max())
    assert worst < 1e-9, worst


def _parse_elsewhere(path) -> None:
    """urdf_parser_py (ROS's Python parser) and urdfdom's check_urdf (ROS's C++ parser: it refuses a
    fragment with 'No roots detected') accept the file, when installed."""
    try:
        from urdf_parser_py.urdf import URDF
    except ImportError:  # pragma: no cover - in the test extra
        pass
    else:
        robot = URDF.from_xml_string(path.read_bytes())
        assert robot.get_root() and len(robot.links) == len(robot.joints) + 1
    check = shutil.which("check_urdf") or shutil.which("check_urdf", path=str(Path(sys.executable).parent))
    if check is not None:
        done = subprocess.run([check, str(path)], capture_output=True, text=True, timeout=60)
        assert done.returncode == 0 and "Successfully Parsed" in done.stdout, done.stdout + done.stderr


@pytest.mark.parametrize("preset", sorted(PRESETS))
def test_complete_urdf_of_every_preset_gives_skincals_unit_frames(tmp_path, preset):
    chain = get_robot(preset)
    result = _result(preset, chain.n_joints, seed=len(preset))
    out = tmp_path / "skin.urdf"
    export_result(result, "urdf", out)  # no link map: names from the robot
    _parse_elsewhere(out)
    _check_unit_frames(out, chain, result)
    links = {link.get("name") for link in ET.parse(out).getroot().findall("link")}
    if preset == "panda":  # Franka's frames: panda_link0..8 (8 = flange, 0.107 m along z of link 7)
        assert {f"panda_link{i}" for i in range(9)} <= links
        model = _load(out)
        np.testing.assert_allclose(model.get_transform("panda_link8", "panda_link7")[:3, 3], [0, 0, 0.107], atol=1e-15)
    elif preset == "xarm7":
        assert {"link_base", *(f"link{i}" for i in range(1, 8))} <= links
    elif chain.source is not None:  # a preset from its maker's description (gen3): the maker's names
        assert set(chain.link_names) <= links
    else:  # DH frames that are not the maker's URDF frames are not called by the maker's names
        assert {f"{preset}_dh_link{i}" for i in range(chain.n_joints + 1)} <= links


@pytest.mark.parametrize("seed", range(4))
def test_complete_urdf_of_a_general_chain_folds_t_joint_link_exactly(tmp_path, seed):
    """Random joint origins and axes, prismatic joints, and a T_joint_link that does not commute with
    the joint's motion (URDF has no post-joint transform): the unit frames still match to 1e-9 m."""
    chain = random_chain(np.random.default_rng(seed), 6)
    chain = type(chain)(
        **{
            **{k: getattr(chain, k) for k in ("name", "T_parent_joint", "axis", "T_joint_link", "joint_type")},
            "joint_lower": np.full(6, -1.0),
            "joint_upper": np.full(6, 1.0),
        }
    )
    result = _result("random", 6, seed=seed)
    text = to_urdf(result, unit_frames(result, link_frames_for(chain)), chain)
    (tmp_path / "g.urdf").write_text(text)
    _check_unit_frames(tmp_path / "g.urdf", chain, result)
    _parse_elsewhere(tmp_path / "g.urdf")
    assert "link3_joint" in text  # a revolute joint whose T_joint_link is not along its axis: an extra link


@pytest.mark.parametrize("robot", sorted(REGISTRY_URDFS))
def test_complete_urdf_of_a_registry_urdf_extends_the_users_file(tmp_path, robot):
    """--robot arm.urdf: the user's URDF, unchanged, plus one fixed joint and link per unit on the
    user's own link names; unit frames match skincal's chain of that URDF."""
    path = registry_urdf(robot)
    chain = chain_from_urdf(path)
    result = _result(chain.name, chain.n_joints, seed=3, per_link=1)
    out = tmp_path / "skin.urdf"
    export_result(result, "urdf", out, robot=str(path), prefix="skin_")
    result = CalibrationResult(
        result.method, result.robot, "", 0.1, {f"skin_{u}": r for u, r in result.units.items()}
    )  # the links carry the prefix
    _check_unit_frames(out, chain, result, n_configs=20, seed=2)
    _parse_elsewhere(out)
    theirs, ours = ET.parse(path).getroot(), ET.parse(out).getroot()
    for e in [*theirs, *ours]:
        e.tail = None  # white space between elements only
    assert [ET.tostring(e) for e in theirs] == [ET.tostring(e) for e in ours[: len(theirs)]]  # user's part intact
    assert {k: v for k, v in theirs.attrib.items()} == ours.attrib
    added = ours[len(theirs) :]
    joints = [e for e in added if e.tag == "joint"]
    assert [j.find("parent").get("link") for j in joints] == [
        chain.link_name(r.pose.link) for r in result.units.values()
    ]


def test_urdf_robot_chain_between_base_and_tip_and_name_clash(tmp_path):
    path = registry_urdf("panda")
    chain = get_robot(str(path), base_link="panda_link2", tip_link="panda_link6")
    result = _result("panda", chain.n_joints, per_link=1)
    out = tmp_path / "s.urdf"
    export_result(result, "urdf", out, robot=str(path), base_link="panda_link2", tip_link="panda_link6")
    _check_unit_frames(out, chain, result, n_configs=5)
    # su1_0 sits on link 1 of this chain = panda_link3
    joint = next(j for j in ET.parse(out).getroot().findall("joint") if j.get("name") == "su1_0_joint")
    assert joint.find("parent").get("link") == "panda_link3"
    clash = CalibrationResult("mle", "panda", "", 0.1, {"panda_hand": next(iter(result.units.values()))})
    with pytest.raises(ConfigError, match="'panda_hand' is already a link or joint of the robot; choose a --prefix"):
        export_result(clash, "urdf", tmp_path / "c.urdf", robot=str(path))
    assert not (tmp_path / "c.urdf").exists()


def test_cli_exports_ur5e_without_a_link_map(tmp_path, capsys):
    """The issue's first finding: `skincal export ur.json -f urdf` on the built-in UR5e failed."""
    write_result(_result("ur5e", 6), tmp_path / "ur.json")
    assert main(["export", str(tmp_path / "ur.json"), "-f", "urdf", "-o", str(tmp_path / "ur.urdf")]) == 0
    _check_unit_frames(tmp_path / "ur.urdf", get_robot("ur5e"), _result("ur5e", 6), n_configs=3)
    assert "ur5e_dh_link1" in capsys.readouterr().out
    # a robot that is not a preset needs --robot or --robot-links: one line, exit 2, nothing written
    write_result(_result("myarm", 3), tmp_path / "my.json")
    capsys.readouterr()
    assert main(["export", str(tmp_path / "my.json"), "-f", "yaml", "-o", str(tmp_path / "my.yaml")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: robot 'myarm' is not a preset; give the robot (--robot") and err.count("\n") == 1
    assert not (tmp_path / "my.yaml").exists()


def _xacro_expand(text: str, prefix: str, parent: str) -> bytes:
    """The macro body with ${prefix}/${parent} substituted (what xacro does for these two params; no
    other expression occurs), wrapped in a robot: a URDF fragment."""
    root = ET.fromstring(text)
    ns = "{http://www.ros.org/wiki/xacro}"
    (macro,) = root.findall(f"{ns}macro")
    assert macro.get("name") == "skincal_skin_units" and macro.get("params") == "prefix:='' parent:=''"
    out = ET.Element("robot", name="r")
    for e in macro:
        if not isinstance(e.tag, str):
            continue
        for node in e.iter():
            for key, value in node.attrib.items():
                assert re.sub(r"\$\{(prefix|parent)\}", "", value).count("${") == 0
                node.set(key, value.replace("${prefix}", prefix).replace("${parent}", parent))
        out.append(e)
    return ET.tostring(out)


def test_xacro_macro_with_prefix_and_parent(tmp_path):
    chain = get_robot("panda")
    result = _result("panda", 7)
    text, frames = export_text(result, "xacro")
    assert not text.count('<link name="panda_link')  # the robot is not in it: only the units
    frag = ET.fromstring(_xacro_expand(text, "left_skin_", "left_"))
    joints = {j.find("child").get("link"): j for j in frag.findall("joint")}
    assert set(joints) == {f"left_skin_{u}" for u in result.units}
    for unit, res in result.units.items():
        j = joints[f"left_skin_{unit}"]
        assert j.find("parent").get("link") == f"left_panda_link{res.pose.link}"
        xyz = [float(v) for v in j.find("origin").get("xyz").split()]
        rpy = [float(v) for v in j.find("origin").get("rpy").split()]
        T = np.eye(4)
        T[:3, :3] = _rpy_matrix(rpy)
        T[:3, 3] = xyz
        np.testing.assert_allclose(T, res.pose.T_link_su, atol=1e-14)
    # a name with xacro syntax stays literal text: ${...} and $(...) get xacro's $$ escape
    crafted = CalibrationResult("mle", "panda", "", 0.1, {"a${x}$(find y)$${z}": result.units["su2_0"]})
    text, _ = export_text(crafted, "xacro")
    child = ET.fromstring(text).find(".//joint/child").get("link")
    assert child == "${prefix}a$${x}$$(find y)$$${z}"
    assert chain.n_joints == 7


def _rpy_matrix(rpy) -> np.ndarray:
    r, p, y = rpy
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    Rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    Ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    Rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    return Rz @ Ry @ Rx


def test_rpy_round_trip_including_gimbal_lock():
    rng = np.random.default_rng(5)
    from scipy.spatial.transform import Rotation

    mats = list(Rotation.random(200, random_state=rng).as_matrix())
    mats += [
        _rpy_matrix([a, s * np.pi / 2 - s * d, b])
        for a, b in rng.uniform(-3, 3, (20, 2))
        for s in (1, -1)
        for d in (0.0, 1e-9, 1e-13)
    ]
    for R in mats:
        np.testing.assert_allclose(_rpy_matrix(rpy_from_matrix(R)), R, atol=2e-15)


def _nodes(text: str) -> tuple[ast.Module, dict]:
    tree = ast.parse(text)
    assigned = {s.targets[0].id: ast.literal_eval(s.value) for s in tree.body if isinstance(s, ast.Assign)}
    return tree, assigned


@pytest.mark.parametrize("fmt", ["tf", "tf-ros2", "tf-ros1"])
def test_tf_node_files_parse_and_carry_every_unit(tmp_path, fmt):
    result = _result("panda", 7)
    frames = export_result(result, fmt, tmp_path / "skin_tf.py", frame="unit")
    text = (tmp_path / "skin_tf.py").read_text()
    tree, assigned = _nodes(text)
    transforms = assigned["TRANSFORMS"]
    assert [t[1] for t in transforms] == list(result.units)  # every unit, one node
    functions = {f.name for f in tree.body if isinstance(f, ast.FunctionDef)}
    assert {"main", "transforms"} <= functions
    if fmt == "tf-ros1":
        assert text.startswith("#!/usr/bin/env python3\n") and "rospy" in text and "rclpy" not in text
    else:
        assert "generate_launch_description" in functions and "rclpy" in text and "rospy" not in text
    assert text.count("StaticTransformBroadcaster(") == 1 and "sendTransform(" in text
    for (parent, child, xyz, quat), f, (unit, res) in zip(transforms, frames, result.units.items(), strict=True):
        assert parent == f.parent == f"panda_link{res.pose.link}" and child == f.child == unit
        np.testing.assert_allclose(xyz, res.pose.p_link_su, atol=1e-15)
        w = res.pose.quaternion_wxyz
        assert min(np.abs(np.array(quat) - [*w[1:], w[0]]).max(), np.abs(np.array(quat) + [*w[1:], w[0]]).max()) < 1e-12
    # the node's own message builder, run with stand-in message classes, gives the same numbers
    namespace: dict = {}
    exec(compile(tree, "skin_tf.py", "exec"), namespace)  # noqa: S102 - our generated file: functions only

    class Msg:
        def __init__(self):
            self.header = type("H", (), {})()
            self.transform = type("T", (), {})()
            self.transform.translation = type("V", (), {})()
            self.transform.rotation = type("Q", (), {})()

    messages = namespace["transforms"]("now", Msg)
    assert [m.child_frame_id for m in messages] == list(result.units)
    m = messages[3]
    t = transforms[3]
    assert (m.header.frame_id, m.header.stamp) == (t[0], "now")
    assert (m.transform.rotation.x, m.transform.rotation.w, m.transform.translation.z) == (t[3][0], t[3][3], t[2][2])


def test_range_frame_puts_the_beam_on_x(tmp_path):
    np.testing.assert_allclose(T_SU_RANGE[:3, :3] @ [1, 0, 0], [0, 0, 1])  # range +x = unit +z (the beam)
    np.testing.assert_allclose(np.linalg.det(T_SU_RANGE[:3, :3]), 1.0)
    result = _result("panda", 7)
    for fmt in ("yaml", "urdf"):
        frames = export_result(result, fmt, tmp_path / f"r.{fmt}", frame="range")
        for f, (unit, res) in zip(frames, result.units.items(), strict=True):
            assert f.child == f"{unit}_range"
            beam = res.pose.R_link_su[:, 2]  # the unit's +z in its link frame
            np.testing.assert_allclose(f.R_parent_child[:, 0], beam, atol=1e-15)
            np.testing.assert_allclose(f.p_parent_child, res.pose.p_link_su, atol=1e-15)
    doc = yaml.safe_load((tmp_path / "r.yaml").read_text())
    assert doc["frame"] == "range"
    _check_unit_frames(
        tmp_path / "r.urdf",
        get_robot("panda"),
        CalibrationResult(
            "mle",
            "panda",
            "",
            0.1,
            {
                f"{u}_range": UnitResult(
                    SkinUnitPose(r.pose.link, (r.pose.T_link_su @ T_SU_RANGE)[:3, :3], r.pose.p_link_su)
                )
                for u, r in result.units.items()
            },
        ),
        n_configs=3,
    )


def test_covariance_is_symmetric_with_the_variances_on_its_diagonal(tmp_path):
    result = _result("panda", 7)
    export_result(result, "json", tmp_path / "c.json")
    doc = json.loads((tmp_path / "c.json").read_text())
    assert doc["covariance_order"] == ["x", "y", "z", "rx", "ry", "rz"]
    for unit, res in result.units.items():
        entry = doc["units"][unit]
        C = np.array(entry["covariance"])
        assert C.shape == (6, 6) and entry["covariance_source"] == "std"
        np.testing.assert_array_equal(C, C.T)
        var = np.concatenate([res.position_std_m, np.radians(res.rotation_std_deg)]) ** 2
        known = np.isfinite(var)
        np.testing.assert_allclose(np.diag(C)[known], var[known], rtol=1e-12)
        assert np.all(np.diag(C)[~known] == UNKNOWN_VARIANCE) and np.all(C[~known][:, known] == 0)
        assert (entry["position_std_m"][2] is None) == (res.pose.link == 1)
    # an offset frame turns the covariance with it (R Sigma R^T per block); an undetermined axis marks
    # every parent axis it reaches
    (tmp_path / "map.yaml").write_text(
        "links:\n" + "".join(f"  {i}: {{frame: l{i}, rpy: [0, 0, 0.5]}}\n" for i in range(1, 8))
    )
    _, frames = export_text(result, "yaml", link_map=tmp_path / "map.yaml")
    R = _rpy_matrix([0, 0, 0.5])
    for f, res in zip(frames, result.units.values(), strict=True):
        if res.pose.link == 1:
            assert list(np.diag(f.covariance)[:3]) == [f.covariance[0, 0], f.covariance[1, 1], UNKNOWN_VARIANCE]
            continue
        B = np.kron(np.eye(2), R)
        expect = B @ np.diag(np.concatenate([res.position_std_m, np.radians(res.rotation_std_deg)]) ** 2) @ B.T
        np.testing.assert_allclose(f.covariance, expect, atol=1e-20)
        np.testing.assert_array_equal(f.covariance, f.covariance.T)
    # a full covariance in the result is used; no uncertainty at all gives ROS's "unknown" (-1 first)
    full = np.diag(np.arange(1.0, 7.0)) * 1e-6
    full[0, 4] = full[4, 0] = 2e-7
    res = result.units["su3_0"]
    units = {"a": UnitResult(res.pose, pose_covariance=full), "b": UnitResult(res.pose)}
    _, frames = export_text(CalibrationResult("mle", "panda", "", 0.1, units), "json")
    assert frames[0].covariance_source == "full" and frames[1].covariance_source == "none"
    np.testing.assert_allclose(frames[0].covariance, full, atol=1e-22)
    assert frames[1].covariance[0, 0] == -1 and np.count_nonzero(frames[1].covariance) == 1


def test_cli_urdf_robot_range_frames_and_one_line_errors(tmp_path, capsys):
    path = registry_urdf("ur5")
    chain = chain_from_urdf(path)
    write_result(_result(chain.name, 6, per_link=1), tmp_path / "r.json")
    out = tmp_path / "ur5_skin.urdf"
    args = ["export", str(tmp_path / "r.json"), "-f", "urdf", "-o", str(out), "--robot", str(path)]
    assert main([*args, "--frame", "range"]) == 0
    printed = capsys.readouterr().out
    assert "shoulder_link" in printed and "warning" not in printed
    links = {link.get("name") for link in ET.parse(out).getroot().findall("link")}
    assert {f"su{i}_0_range" for i in range(1, 7)} <= links and "upper_arm_link" in links
    # a result of another robot onto this one: refused in one line naming both, nothing written
    write_result(_result("panda", 6, per_link=1), tmp_path / "p.json")
    assert (
        main(["export", str(tmp_path / "p.json"), "-f", "yaml", "-o", str(tmp_path / "p.yaml"), "--robot", str(path)])
        == 2
    )
    err = capsys.readouterr().err
    assert "the result is for robot 'panda'" in err and "'ur5'" in err and err.count("\n") == 1, err
    assert not (tmp_path / "p.yaml").exists()
    for extra, message in (
        (["--frame", "beam"], "unknown frame 'beam' (use unit or range)"),
        (["--base-link", "nope"], "--base-link 'nope' is not a link of the URDF"),
        (["-f", "sdf"], "unknown export format 'sdf'"),
    ):
        assert main([*args[:-2], *extra, "--robot", str(path), "--force"]) == 2
        err = capsys.readouterr().err
        assert err.startswith("error: ") and message in err and err.count("\n") == 1, err
    assert (
        main(["export", str(tmp_path / "r.json"), "-f", "urdf", "-o", str(path), "--robot", str(path), "--force"]) == 2
    )  # the robot's URDF is an input: never overwritten
    assert "is the input" in capsys.readouterr().err


@pytest.mark.adversarial
@pytest.mark.parametrize(
    "bad",
    [
        "x",
        [[1.0] * 6] * 5,
        [["a"] * 6] * 6,
        {"k": 1},
        (np.eye(6) * -1).tolist(),
        (np.eye(6) + np.triu(np.ones((6, 6)), 1)).tolist(),
    ],
    ids=range(6),
)
def test_a_bad_full_covariance_in_the_result_is_one_line(tmp_path, capsys, bad):
    """Refused when the result file is read (the covariance is a typed field, checked on read), one line
    naming the file and the field."""
    import json

    result = _result("panda", 2, per_link=1)
    write_result(result, tmp_path / "r.json")
    doc = json.loads((tmp_path / "r.json").read_text())
    doc["units"]["su2_0"]["pose_covariance"] = bad
    (tmp_path / "r.json").write_text(json.dumps(doc))
    capsys.readouterr()
    assert main(["export", str(tmp_path / "r.json"), "-f", "yaml", "-o", str(tmp_path / "o.yaml")]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"error: {tmp_path / 'r.json'}: units.su2_0.pose_covariance must be"), err
    assert err.count("\n") == 1, err
    assert not (tmp_path / "o.yaml").exists()


@pytest.mark.adversarial
@pytest.mark.parametrize(("fmt", "variance", "std"), [("json", 1e308, None), ("yaml", 1e200, None),
                                                     ("json", None, 1e200), ("json", 2e12, None)])
def test_a_huge_covariance_or_std_exports_as_undetermined(tmp_path, capsys, fmt, variance, std):
    """A variance of 1e308 (or a std of 1e200) overflowed the frame rotation to inf, then NaN: exit 3 for
    json, NaN in yaml. Beyond MAX_EXPORT_VARIANCE an axis is exported as undetermined (-1, its row 0); the
    other axes keep theirs; no numpy warning."""
    result = _result("panda", 2, per_link=1)
    write_result(result, tmp_path / "r.json")
    doc = json.loads((tmp_path / "r.json").read_text())
    entry = doc["units"]["su2_0"]
    if variance is not None:
        cov = np.diag([1e-6, 2e-6, 3e-6, 1e-4, 2e-4, 3e-4])
        cov[1, 1] = variance
        entry["pose_covariance"] = cov.tolist()
    else:
        entry["position_std_m"][1] = std
    (tmp_path / "r.json").write_text(json.dumps(doc))
    capsys.readouterr()
    out = tmp_path / f"o.{fmt}"
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # numpy's overflow warning an error too
        assert main(["export", str(tmp_path / "r.json"), "-f", fmt, "-o", str(out)]) == 0
    text = out.read_text()
    assert "nan" not in text.lower() and "inf" not in text.lower()
    C = np.array((json.loads(text) if fmt == "json" else yaml.safe_load(text))["units"]["su2_0"]["covariance"])
    assert C[1, 1] == UNKNOWN_VARIANCE and np.count_nonzero(C[1]) == 1 and np.count_nonzero(C[:, 1]) == 1
    known = [0, 2, 3, 4, 5]
    assert np.all(np.diag(C)[known] > 0) and np.all(np.diag(C)[known] < 1)
