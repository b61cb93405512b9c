"""Exports of a calibration result: URDF (checked through Franka's own joint origins), YAML, CSV,
ROS 2 static-transform launch file (quaternion order checked by name), link maps, CLI."""

from __future__ import annotations

import ast
import csv
import xml.etree.ElementTree as ET

import numpy as np
import pytest
import yaml

from skincal.cli import main
from skincal.data.export import export_result, load_link_map, unit_frames
from skincal.data.result import CalibrationResult, UnitResult, write_result
from skincal.errors import ConfigError
from skincal.kinematics import get_robot
from skincal.skin.pose import SkinUnitPose

# franka_description (panda_arm.xacro): joint i joins panda_link{i-1} -> panda_link{i},
# origin (xyz [m], rpy [rad]) then a revolute joint about the child's z axis.
FRANKA_JOINT_ORIGINS = [
    ((0, 0, 0.333), (0, 0, 0)),
    ((0, 0, 0), (-np.pi / 2, 0, 0)),
    ((0, -0.316, 0), (np.pi / 2, 0, 0)),
    ((0.0825, 0, 0), (np.pi / 2, 0, 0)),
    ((-0.0825, 0.384, 0), (-np.pi / 2, 0, 0)),
    ((0, 0, 0), (np.pi / 2, 0, 0)),
    ((0.088, 0, 0), (np.pi / 2, 0, 0)),
]


def _rx(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def _ry(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def _rz(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def _urdf_origin(xyz, rpy) -> np.ndarray:
    """URDF <origin>: translation then fixed-axis roll, pitch, yaw: R = Rz(yaw) Ry(pitch) Rx(roll)."""
    T = np.eye(4)
    T[:3, :3] = _rz(rpy[2]) @ _ry(rpy[1]) @ _rx(rpy[0])
    T[:3, 3] = xyz
    return T


def _franka_link_frames(q: np.ndarray) -> list[np.ndarray]:
    """T_base_panda_link{i}, i = 0..7, from Franka's URDF joint origins."""
    frames = [np.eye(4)]
    for (xyz, rpy), qi in zip(FRANKA_JOINT_ORIGINS, q, strict=True):
        Rq = np.eye(4)
        Rq[:3, :3] = _rz(qi)
        frames.append(frames[-1] @ _urdf_origin(xyz, rpy) @ Rq)
    return frames


def _result(robot: str = "panda", links=range(1, 8), seed: int = 0) -> CalibrationResult:
    rng = np.random.default_rng(seed)
    units = {}
    for k, link in enumerate(links):
        q = rng.normal(size=4)
        pose = SkinUnitPose.from_quaternion(link, rng.uniform(-0.1, 0.1, 3), q / np.linalg.norm(q))
        units[f"su{k + 1}"] = UnitResult(pose=pose, observable=link != 1)
    return CalibrationResult(method="mle", robot=robot, dataset_sha256="", runtime_s=0.1, units=units)


def test_panda_urdf_link_frames_are_our_modified_dh_frames():
    chain = get_robot("panda")
    rng = np.random.default_rng(4)
    for q in rng.uniform(-2.5, 2.5, size=(5, 7)):
        ours = chain.link_frames(q[None])[0]
        franka = _franka_link_frames(q)
        for i in range(8):
            np.testing.assert_allclose(ours[i], franka[i], atol=1e-12)


def test_urdf_parses_and_encodes_the_pose_through_the_franka_chain(tmp_path):
    """The complete URDF of the panda: its joints are Franka's (same origins, about z), and the unit
    joints put each unit at T_link_su on panda_link<i>."""
    result = _result()
    out = tmp_path / "skin.urdf"
    export_result(result, "urdf", out)
    root = ET.parse(out).getroot()
    assert root.tag == "robot"
    all_joints = {j.find("child").get("link"): j for j in root.findall("joint")}
    joints = {c: j for c, j in all_joints.items() if c in result.units}
    assert set(joints) == set(result.units) and set(result.units) <= {link.get("name") for link in root.findall("link")}
    for i, (xyz, rpy) in enumerate(FRANKA_JOINT_ORIGINS, start=1):
        j = all_joints[f"panda_link{i}"]
        assert j.get("name") == f"panda_joint{i}" and j.find("parent").get("link") == f"panda_link{i - 1}"
        origin = j.find("origin")
        T = _urdf_origin([float(v) for v in origin.get("xyz").split()], [float(v) for v in origin.get("rpy").split()])
        np.testing.assert_allclose(T, _urdf_origin(xyz, rpy), atol=1e-15)
        np.testing.assert_allclose([float(v) for v in j.find("axis").get("xyz").split()], [0, 0, 1], atol=1e-15)
    q = np.random.default_rng(9).uniform(-2, 2, 7)
    franka = _franka_link_frames(q)
    chain_frames = get_robot("panda").link_frames(q[None])[0]
    for unit, res in result.units.items():
        j = joints[unit]
        assert j.get("type") == "fixed"
        parent = j.find("parent").get("link")
        assert parent == f"panda_link{res.pose.link}"
        origin = j.find("origin")
        T = _urdf_origin([float(v) for v in origin.get("xyz").split()], [float(v) for v in origin.get("rpy").split()])
        np.testing.assert_allclose(T, res.pose.T_link_su, atol=1e-12)
        # base -> unit through Franka's URDF chain equals our kinematics with our pose
        np.testing.assert_allclose(franka[res.pose.link] @ T, chain_frames[res.pose.link] @ res.pose.T_link_su,
                                   atol=1e-12)
    assert "not fully observable" in out.read_text()  # su1 on link 1


def test_yaml_and_csv_round_trip_values(tmp_path):
    result = _result()
    export_result(result, "yaml", tmp_path / "s.yaml", prefix="skin_")
    export_result(result, "csv", tmp_path / "s.csv")
    doc = yaml.safe_load((tmp_path / "s.yaml").read_text())
    rows = {r["unit"]: r for r in csv.DictReader((tmp_path / "s.csv").open())}
    assert doc["robot"] == "panda" and set(doc["units"]) == set(rows) == set(result.units)
    assert list(next(iter(rows.values())))[7:11] == ["qw", "qx", "qy", "qz"]
    for unit, res in result.units.items():
        y, c = doc["units"][unit], rows[unit]
        assert y["parent"] == c["parent"] == f"panda_link{res.pose.link}" and y["child"] == f"skin_{unit}"
        assert y["link"] == int(c["link"]) == res.pose.link
        assert y["observable"] == (c["observable"] == "true") == res.observable
        np.testing.assert_allclose(y["xyz"], res.pose.p_link_su, rtol=0, atol=1e-15)
        np.testing.assert_allclose([float(c[k]) for k in ("x_m", "y_m", "z_m")], res.pose.p_link_su, atol=1e-15)
        q_ref = res.pose.quaternion_wxyz
        for q in (np.array(y["quaternion_wxyz"]), np.array([float(c[k]) for k in ("qw", "qx", "qy", "qz")])):
            assert min(np.abs(q - q_ref).max(), np.abs(q + q_ref).max()) < 1e-12


def _transforms(text: str) -> list[tuple]:
    """The TRANSFORMS literal of a generated TF node (the file is not run)."""
    for stmt in ast.parse(text).body:
        if isinstance(stmt, ast.Assign) and stmt.targets[0].id == "TRANSFORMS":
            return ast.literal_eval(stmt.value)
    raise AssertionError("no TRANSFORMS")


@pytest.mark.parametrize("fmt", ["tf", "tf-ros1"])
def test_tf_node_holds_ros_quaternion_order(tmp_path, fmt):
    # 60 deg about x: (w, x, y, z) = (cos 30, sin 30, 0, 0): w and x differ, so a swap shows.
    pose = SkinUnitPose(3, _rx(np.pi / 3), [0.01, 0.02, 0.03])
    result = CalibrationResult("mle", "panda", "", 0.0, {"su1": UnitResult(pose=pose)})
    export_result(result, fmt, tmp_path / "skin_tf.py")
    ((parent, child, xyz, (qx, qy, qz, qw)),) = _transforms((tmp_path / "skin_tf.py").read_text())
    assert parent == "panda_link3" and child == "su1"
    assert qw == pytest.approx(np.cos(np.pi / 6), abs=1e-12) and qx == pytest.approx(np.sin(np.pi / 6), abs=1e-12)
    assert qy == qz == 0.0
    assert list(xyz) == [0.01, 0.02, 0.03]
    text = (tmp_path / "skin_tf.py").read_text()
    assert "rotation.x, rotation.y, rotation.z, rotation.w = quaternion" in text  # consumed in ROS order


def test_user_link_map_with_offset(tmp_path):
    result = _result("ur5e", links=(2, 4))
    # a preset needs no map: its DH frames by name (not UR's URDF frames, which differ)
    assert [f.parent for f in unit_frames(result)] == ["ur5e_dh_link2", "ur5e_dh_link4"]
    with pytest.raises(ConfigError, match="is not a preset; give the robot .*--robot-links"):
        unit_frames(_result("myarm", links=(2, 4)))
    (tmp_path / "map.yaml").write_text(
        "links:\n  2: upper_arm_link\n  4: {frame: wrist_1_link, xyz: [0.1, 0, -0.2], rpy: [0.3, -0.2, 1.0]}\n")
    links = load_link_map(tmp_path / "map.yaml")
    frames = {f.unit: f for f in unit_frames(result, links)}
    offset = _urdf_origin([0.1, 0, -0.2], [0.3, -0.2, 1.0])
    for unit, res in result.units.items():
        f = frames[unit]
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = f.R_parent_child, f.p_parent_child
        expect = (offset if res.pose.link == 4 else np.eye(4)) @ res.pose.T_link_su
        np.testing.assert_allclose(T, expect, atol=1e-12)
    assert frames["su2"].parent == "wrist_1_link"
    with pytest.raises(ConfigError, match="--robot-links does not apply to -f urdf"):
        export_result(result, "urdf", tmp_path / "x.urdf", link_map=tmp_path / "map.yaml")
    (tmp_path / "bad.yaml").write_text("links:\n  3: {frame: x, xyz: [1, 2]}\n")
    with pytest.raises(ConfigError, match="links.3"):
        load_link_map(tmp_path / "bad.yaml")


def test_cli_export_atomic_and_one_line_errors(tmp_path, capsys):
    write_result(_result(), tmp_path / "r.json")
    written = {"urdf": "s.urdf", "xacro": "s.xacro", "yaml": "s.yaml", "json": "s.json", "tf": "s.launch.py",
               "tf-ros1": "s_ros1.py", "csv": "s.csv"}
    for fmt, name in written.items():
        assert main(["export", str(tmp_path / "r.json"), "--format", fmt, "--out", str(tmp_path / name)]) == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(["r.json", *written.values()])
    capsys.readouterr()
    assert main(["export", str(tmp_path / "r.json"), "--format", "sdf", "--out", str(tmp_path / "x")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: unknown export format 'sdf'") and "\n" not in err
    assert not (tmp_path / "x").exists()


def test_exports_of_a_result_with_undetermined_std_and_failed_units(tmp_path, capsys):
    """A NaN std component and a unit without a pose (never lose a result): every format is written,
    no 'nan' text anywhere, only the units with a pose are exported, the CLI says which were not."""
    result = _result(links=(1, 3))
    su1 = result.units["su1"]
    units = {**result.units, "su1": UnitResult(su1.pose, observable=False, position_std_m=[1e-4, 6e-4, np.nan],
                                               rotation_std_deg=[0.01, np.nan, np.nan], warnings=("yaw undetermined",))}
    result = CalibrationResult("mle", "panda", "", 0.1, units, failed_units={"su3": "diverged"})
    write_result(result, tmp_path / "r.json")
    capsys.readouterr()
    for fmt, name in (("urdf", "s.urdf"), ("xacro", "s.xacro"), ("yaml", "s.yaml"), ("json", "s.json"),
                      ("tf", "s.launch.py"), ("tf-ros1", "s.py"), ("csv", "s.csv")):
        assert main(["export", str(tmp_path / "r.json"), "--format", fmt, "--out", str(tmp_path / name)]) == 0
        text = (tmp_path / name).read_text()
        assert "nan" not in text.lower() and "su3" not in text, fmt
        out = capsys.readouterr().out
        assert "2 unit(s)" in out and "unit su3 not exported (not calibrated: diverged)" in out
    rows = list(csv.DictReader((tmp_path / "s.csv").open()))
    assert [r["unit"] for r in rows] == ["su1", "su2"] and all(v != "" for r in rows for v in r.values())
