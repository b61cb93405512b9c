"""Crafted names and free text through every exporter (issue 19, "data injected"): the launch file
carries user text only as string constants, the URDF is well-formed XML whose link names round-trip,
the CSV neutralises spreadsheet formulas, bad names are refused with one line (exit 2 from the CLI)."""

from __future__ import annotations

import ast
import csv
import functools
import io
import json
import re
import xml.etree.ElementTree as ET
from dataclasses import replace

import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from skincal.cli import main
from skincal.data.export import export_result, load_link_map
from skincal.data.result import CalibrationResult, UnitResult, result_to_dict
from skincal.errors import ConfigError, DatasetError
from skincal.kinematics import get_robot
from skincal.names import name_problem
from skincal.skin.pose import SkinUnitPose

pytestmark = pytest.mark.adversarial

CODE = 'import os; os.system("echo pwned")'
METHODS = [
    f'mle"""\n{CODE}\n"""',
    f"mle'''\n{CODE}\n'''",
    "mle --> <script>alert(1)</script> -- & \"quoted\" 'single'",
    "mle\x1b[31m red \x1b]0;title\x07 \r\n\t end-",
    '=HYPERLINK("http://x") \\ \\" \\n',
    "m\u00e9thode \u65b9\u6cd5 \U0001f916 \u202e reversed \ud800 -",
]
# names that pass skincal.names.name_problem but carry XML, Python and CSV syntax
UNIT_NAMES = [
    'su"""' + CODE.replace("/", "") + '"""',
    "su'''x'''",
    "a--b",
    "c-->",
    "<script>&amp;<x y=\"1\">",
    "it's \"quoted\"",
    '=HYPERLINK("x")',
    "+1",
    "-1",
    "@SUM(A1)",
    "Unterarm-links \u00fc\u00df \u65b9 \U0001f916",
    "\\",
    "$(env HOME)${__import__('os').system('x')}$$(a)",
]
ROBOT = 'panda"""; ' + CODE.replace("/", "") + '; """'


def _result(names, method: str = "mle", robot: str = "panda", seed: int = 0) -> CalibrationResult:
    rng = np.random.default_rng(seed)
    units = {}
    for k, name in enumerate(names):
        q = rng.normal(size=4)
        pose = SkinUnitPose.from_quaternion(k % 7 + 1, rng.uniform(-0.1, 0.1, 3), q / np.linalg.norm(q))
        units[name] = UnitResult(pose=pose, observable=k % 2 == 1)
    return CalibrationResult(method=method, robot=robot, dataset_sha256="", runtime_s=0.1, units=units)


def _panda_map(tmp_path):
    path = tmp_path / "map.yaml"
    path.write_text(yaml.safe_dump({"links": {i: f"panda_link{i}" for i in range(1, 8)}}))
    return path


def _skeleton(text: str) -> tuple[str, dict]:
    """A TF node file with its three data literals (CALIBRATION, NODE_NAME, TRANSFORMS) replaced by
    None: ``ast.dump`` of what is left (the code) and the literals (read with literal_eval)."""
    tree = ast.parse(text)
    data = {}
    for stmt in tree.body:
        if isinstance(stmt, ast.Assign):
            data[stmt.targets[0].id] = ast.literal_eval(stmt.value)  # literals only, or this raises
            stmt.value = ast.Constant(None)
    return ast.dump(tree), data


@functools.cache
def _reference() -> dict[str, str]:
    """The TF nodes' code and the URDF's per-unit comment for a plain result."""
    import tempfile
    from pathlib import Path

    plain = _result(["su0"])
    out = {}
    with tempfile.TemporaryDirectory() as tmp:
        for fmt in ("tf", "tf-ros1"):
            export_result(plain, fmt, Path(tmp) / "p.py")
            out[fmt] = _skeleton((Path(tmp) / "p.py").read_text())[0]
            (Path(tmp) / "p.py").unlink()
        export_result(plain, "urdf", Path(tmp) / "p.urdf")
        parser = ET.XMLParser(target=ET.TreeBuilder(insert_comments=True))
        root = ET.fromstring((Path(tmp) / "p.urdf").read_bytes(), parser=parser)
    comments = [c.text for c in root if c.tag is ET.Comment]
    assert len(comments) == 3 and not plain.units["su0"].observable and "su0" not in comments[2]
    return {**out, "robot": comments[1], "comment": comments[2]}


def _check_node(fmt: str, text: str, result: CalibrationResult, prefix: str) -> None:
    """The TF node parses; its code is the plain result's, node for node, and every crafted string
    is a constant in the data literals that reads back exactly."""
    code, data = _skeleton(text)
    assert code == _reference()[fmt]  # fixed code and docstring, whatever the result holds
    assert data["CALIBRATION"] == {"robot": result.robot, "method": result.method, "frame": "unit"}
    assert data["NODE_NAME"] == "skincal_skin_tf"
    assert [t[1] for t in data["TRANSFORMS"]] == [prefix + u for u in result.units]
    assert all(isinstance(t[0], str) and len(t[2]) == 3 and len(t[3]) == 4 for t in data["TRANSFORMS"])


def _check_launch(text: str, result: CalibrationResult, prefix: str) -> None:
    _check_node("tf", text, result, prefix)


def _check_ros1(text: str, result: CalibrationResult, prefix: str) -> None:
    _check_node("tf-ros1", text, result, prefix)


HEAD = re.compile(r' skin units calibrated by skincal, method ("(?:[^"\\]|\\.)*"), robot ("(?:[^"\\]|\\.)*"); '
                  r"unit frames in the parent link frames ")


def _comments(root) -> list[str]:
    return [c.text for c in root.iter() if c.tag is ET.Comment]


def _check_head(comment: str, result: CalibrationResult) -> None:
    head = HEAD.fullmatch(comment)
    assert head is not None, comment
    assert json.loads(head.group(1)) == result.method and json.loads(head.group(2)) == result.robot


def _check_urdf(data: bytes, result: CalibrationResult, prefix: str) -> None:
    """Well-formed XML (ElementTree's expat), unit link names round-trip exactly, comments hold no
    crafted text except the method and robot as JSON string literals."""
    parser = ET.XMLParser(target=ET.TreeBuilder(insert_comments=True))
    root = ET.fromstring(data, parser=parser)
    assert root.tag == "robot" and root.get("name") == f"{result.robot}_skin"
    units = [prefix + u for u in result.units]
    names = [link.get("name") for link in root.findall("link")]
    assert names[-len(units):] == units and not set(names[:-len(units)]) & set(units)
    joints = root.findall("joint")[-len(units):]
    assert [j.find("child").get("link") for j in joints] == units
    assert [j.get("name") for j in joints] == [f"{prefix}{u}_joint" for u in result.units]
    comments = _comments(root)
    assert len(comments) == 2 + sum(not u.observable for u in result.units.values())
    _check_head(comments[0], result)
    assert comments[1] == _reference()["robot"]
    assert set(comments[2:]) <= {_reference()["comment"]}  # fixed text, no unit name


def _xacro_literal(text: str) -> str:
    """What xacro makes of attribute text without expressions: a run of $ before { or ( loses one."""
    return re.sub(r"\$(\$+)(?=[{(])", r"\1", text)


def _check_xacro(text: str, result: CalibrationResult, prefix: str) -> None:
    """Well-formed XML; in the macro every name is ${prefix}/${parent} and then text that xacro
    reads as exactly the name (no expression, no substitution argument)."""
    parser = ET.XMLParser(target=ET.TreeBuilder(insert_comments=True))
    root = ET.fromstring(text.encode("utf-8"), parser=parser)
    (macro,) = root.findall("{http://www.ros.org/wiki/xacro}macro")
    links = [e.get("name") for e in macro.findall("link")]
    assert all(n.startswith("${prefix}") for n in links)
    rest = [n[len("${prefix}"):] for n in links]
    assert not any(re.search(r"(?<!\$)\$[{(]", r) for r in rest)  # every ${ or $( is part of a $$ escape
    assert [_xacro_literal(r) for r in rest] == [prefix + u for u in result.units]
    parents = [j.find("parent").get("link") for j in macro.findall("joint")]
    assert parents == [f"${{parent}}panda_link{r.pose.link}" for r in result.units.values()]
    _check_head(_comments(root)[0], result)


def _neutral(text: str) -> str:
    return "'" + text if text[:1] in ("=", "+", "-", "@", "\t", "\r") else text


def _check_csv(text: str, result: CalibrationResult, prefix: str) -> None:
    rows = list(csv.reader(io.StringIO(text)))
    assert rows[0][0] == "unit" and len(rows) == 1 + len(result.units)
    for row, (unit, res) in zip(rows[1:], result.units.items(), strict=True):
        assert row[0] == _neutral(unit) and row[2] == _neutral(prefix + unit)
        assert row[1] == f"panda_link{res.pose.link}"
        assert int(row[3]) == res.pose.link
        # numbers are numbers (a negative coordinate is not "neutralised")
        np.testing.assert_allclose([float(v) for v in row[4:7]], res.pose.p_link_su, atol=1e-15)
        assert row[11] in ("true", "false")
        assert not any(cell[:1] in "=+@\t\r" for cell in row) and not any(c.startswith("-") for c in row[:3])


def _check_yaml(text: str, result: CalibrationResult, prefix: str) -> None:
    _check_doc(yaml.safe_load(text), result, prefix)


def _check_doc(doc: dict, result: CalibrationResult, prefix: str) -> None:
    assert doc["robot"] == result.robot and doc["method"] == result.method
    assert list(doc["units"]) == list(result.units)
    assert [u["child"] for u in doc["units"].values()] == [prefix + u for u in result.units]


def _check_json(text: str, result: CalibrationResult, prefix: str) -> None:
    _check_doc(json.loads(text), result, prefix)


CHECKS = {"tf": _check_launch, "tf-ros1": _check_ros1, "csv": _check_csv, "yaml": _check_yaml, "json": _check_json,
          "xacro": _check_xacro}


@pytest.mark.parametrize("method", METHODS, ids=range(len(METHODS)))
@pytest.mark.parametrize("prefix", ["", "skin_", "=-"])
def test_crafted_method_unit_and_robot_names_are_carried_as_data(tmp_path, method, prefix):
    result = _result(UNIT_NAMES, method=method, robot=ROBOT)
    link_map = _panda_map(tmp_path)  # the crafted robot name has no preset
    for fmt, check in {"urdf": None, **CHECKS}.items():
        out = tmp_path / f"skin.{fmt}"
        if fmt == "urdf":  # a complete URDF takes the robot, not a link map; its dataset's chain names the robot
            export_result(result, fmt, out, robot="panda", prefix=prefix, source=get_robot("panda"))
        else:
            export_result(result, fmt, out, link_map=link_map, prefix=prefix)
        if check is None:
            _check_urdf(out.read_bytes(), result, prefix)
        else:
            check(out.read_bytes().decode("utf-8"), result, prefix)


def test_formula_cells_are_neutralised_and_hyperlink_with_slash_is_refused(tmp_path):
    result = _result(['=HYPERLINK("x")', "+cmd", "-2+3", "@SUM(A1)", "plain", "x=1"])
    export_result(result, "csv", tmp_path / "s.csv")
    rows = list(csv.DictReader((tmp_path / "s.csv").open(newline="")))
    assert [r["unit"] for r in rows] == ["'=HYPERLINK(\"x\")", "'+cmd", "'-2+3", "'@SUM(A1)", "plain", "x=1"]
    with pytest.raises(DatasetError, match="contains '/'"):  # a URL holds '/', which no unit name may
        export_result(_result(['=HYPERLINK("http://x")']), "csv", tmp_path / "t.csv")
    assert not (tmp_path / "t.csv").exists()


BAD_NAMES = ["", "a/b", ".", "..", "su\x1b[2Jx", "su\n1", "su\x00", " su1", "su1\t", "a\u202eb", "x" * 129,
             "su\ud800", "su\uffff"]


@pytest.mark.parametrize("fmt", ["urdf", "xacro", "yaml", "json", "tf", "tf-ros1", "csv"])
@pytest.mark.parametrize("bad", BAD_NAMES, ids=range(len(BAD_NAMES)))
def test_bad_unit_and_robot_names_are_refused_before_writing(tmp_path, fmt, bad):
    out = tmp_path / "out"
    with pytest.raises(DatasetError, match=r"^unit name '.*' (is|has|contains|starts)") as info:
        export_result(_result(["su0", bad]), fmt, out)
    assert "\n" not in str(info.value) and "\x1b" not in str(info.value) and "\x00" not in str(info.value)
    str(info.value).encode("utf-8")  # printable: no lone surrogate either
    link_map = _panda_map(tmp_path)
    with pytest.raises(DatasetError, match=r"^robot name"):
        if fmt == "urdf":
            export_result(_result(["su0"], robot=bad), fmt, out, robot="panda")
        else:
            export_result(_result(["su0"], robot=bad), fmt, out, link_map=link_map)
    assert not out.exists() and sorted(p.name for p in tmp_path.iterdir()) == ["map.yaml"]


def test_frame_names_from_link_map_and_prefix_are_checked(tmp_path):
    (tmp_path / "esc.yaml").write_text('links:\n  1: "link\\e]0;x\\a"\n')
    with pytest.raises(ConfigError, match=r"links\.1: frame name 'link\\x1b\]0;x\\x07' contains a control"):
        load_link_map(tmp_path / "esc.yaml")
    (tmp_path / "ns.yaml").write_text("links:\n  1: robot1/base_link\n  2: {frame: '', xyz: [0, 0, 0]}\n")
    with pytest.raises(ConfigError, match=r"links\.2"):
        load_link_map(tmp_path / "ns.yaml")
    (tmp_path / "ok.yaml").write_text("links:\n  1: robot1/panda_link1\n")
    result = _result(["su1"])
    export_result(result, "xacro", tmp_path / "s.xacro", link_map=tmp_path / "ok.yaml", prefix="robot1/skin_")
    joint = ET.parse(tmp_path / "s.xacro").getroot().find(".//joint")
    assert joint.find("parent").get("link") == "${parent}robot1/panda_link1"
    assert joint.find("child").get("link") == "${prefix}robot1/skin_su1"
    for prefix in ("/", "a//", "\x1b", " "):
        with pytest.raises(ConfigError, match="prefix"):
            export_result(result, "tf", tmp_path / "x.py", prefix=prefix)
    assert not (tmp_path / "x.py").exists()


def _exportable(name: str) -> bool:
    """Accepted names (name_problem) that XML can carry (U+FFFE and U+FFFF are refused)."""
    return name_problem(name) is None and not re.search("[\ufffe\uffff]", name)


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(method=st.text(min_size=1, max_size=40),
       names=st.lists(st.text(min_size=1, max_size=12).filter(_exportable), min_size=1,
                      max_size=4, unique=True))
def test_any_text_and_any_accepted_name_round_trip(tmp_path, method, names):
    result = _result(names, method=method)
    for fmt, check in {"urdf": None, **CHECKS}.items():
        out = tmp_path / f"h.{fmt}"
        export_result(result, fmt, out, prefix="p_")
        if check is None:
            _check_urdf(out.read_bytes(), result, "p_")
        else:
            check(out.read_bytes().decode("utf-8"), result, "p_")


def _write_doc(path, doc) -> None:
    path.write_text(json.dumps(doc))


@pytest.mark.parametrize(("unit", "robot", "shown"), [
    ("su\x1b[2J\nx", "panda", "su\\x1b[2J\\nx"),  # refused by the result reader or the exporter
    ("su\ud800", "panda", "su\\ud800"),  # a lone surrogate (no UTF-8 for it)
    ("su\uffff", "panda", "su\\uffff"),  # not an XML character
    ("su2", "panda\ud800", "robot"),  # the result reader names the field
])
def test_cli_refuses_a_bad_unit_or_robot_name_with_one_line(tmp_path, capsys, unit, robot, shown):
    doc = result_to_dict(_result(["su1", "su2"]))
    doc["units"][unit] = doc["units"].pop("su2")
    doc["robot"] = robot
    _write_doc(tmp_path / "r.json", doc)
    link_map = _panda_map(tmp_path)
    for fmt in ("urdf", "xacro", "tf", "tf-ros1", "csv", "yaml", "json"):
        capsys.readouterr()
        robot = ["--robot", "panda"] if fmt == "urdf" else ["--robot-links", str(link_map)]
        code = main(["export", str(tmp_path / "r.json"), "-f", fmt, "-o", str(tmp_path / "out"), *robot])
        err = capsys.readouterr().err
        assert code == 2, (fmt, err)
        assert err.startswith("error: ") and err.count("\n") == 1 and "\x1b" not in err, err
        assert shown in err and "internal error" not in err
        assert not (tmp_path / "out").exists()


def test_cli_prints_names_and_reasons_without_markup(tmp_path, capsys):
    """Names and reasons in the export summary are shown as written (rich markup not interpreted:
    a '[/x]' in a reason used to crash the command with a MarkupError)."""
    result = _result(["[red]su1"])
    result = replace(result, failed_units={"[bold]su2": "diverged [/x] \x1b[31m"})
    _write_doc(tmp_path / "r.json", result_to_dict(result))
    capsys.readouterr()
    assert main(["export", str(tmp_path / "r.json"), "-f", "csv", "-o", str(tmp_path / "s.csv")]) == 0
    out = capsys.readouterr().out
    assert "unit [bold]su2 not exported (not calibrated: diverged [/x] \\x1b[31m)" in out
    assert "\x1b" not in out


def test_trajectory_export_carries_crafted_names_as_json_data(tmp_path):
    """skincal.protocol.export writes JSON through json (robot and protocol names escaped there)
    and a CSV of numbers under a fixed header: a crafted chain or protocol name round-trips."""
    from skincal.kinematics import panda
    from skincal.protocol import build_trajectory, export_trajectory, get_protocol, read_trajectory_json

    cfg = replace(get_protocol("fast"), n_poses=1, rate_hz=50.0)
    traj = build_trajectory(panda(), cfg, np.random.default_rng(3))
    crafted = METHODS[0] + METHODS[3] + "\ud800"
    traj = replace(traj, robot=crafted, config=replace(traj.config, name=crafted))
    export_trajectory(traj, tmp_path / "t.json")
    export_trajectory(traj, tmp_path / "t.csv")
    back = read_trajectory_json(tmp_path / "t.json")
    assert back.robot == crafted and back.config.name == crafted
    assert (tmp_path / "t.json").read_bytes().isascii()
    assert (tmp_path / "t.csv").read_text().splitlines()[0] == "t," + ",".join(
        [f"q{i}" for i in range(1, 8)] + [f"qd{i}" for i in range(1, 8)])


def test_urdf_with_crafted_names_loads_in_yourdfpy(tmp_path):
    """Beyond well-formed XML: a URDF library reads the same link and joint names back."""
    yourdfpy = pytest.importorskip("yourdfpy")
    result = _result(UNIT_NAMES, method=METHODS[2])
    export_result(result, "urdf", tmp_path / "s.urdf", prefix="skin_")
    urdf = yourdfpy.URDF.load(str(tmp_path / "s.urdf"), build_scene_graph=False, load_meshes=False,
                              build_collision_scene_graph=False)
    assert [link.name for link in urdf.robot.links][-len(result.units):] == [f"skin_{u}" for u in result.units]
    assert [(j.parent, j.child) for j in urdf.robot.joints][-len(result.units):] == [
        (f"panda_link{r.pose.link}", f"skin_{u}") for u, r in result.units.items()]
