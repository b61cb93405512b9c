"""Scenario files (issue 17): the shipped ones, positions relative to robot points, start configurations on
any robot, the pick-and-place task, and one-line errors naming the field of a bad file."""

from __future__ import annotations

import json

import numpy as np
import pytest

from skincal.errors import ConfigError
from skincal.kinematics import get_robot, panda
from skincal.kinematics.points import Q_START, robot_points
from skincal.sim.scenarios import get_scenario, load_scenario, parse_scenario, shipped_scenarios

# The legacy (issue 7) scenario geometry on the Panda, as the former Python definitions had it
SU6 = (np.array([0.466, -0.22, 0.686]), np.array([0.408, -0.898, 0.164]))
SU4 = (np.array([0.306, -0.02, 0.68]), np.array([0.329, 0.944, 0.034]))
HAND_FAR, HAND_NEAR = SU6[0] + 1.6 * SU6[1], SU6[0] + 0.1 * SU6[1]
ARM_FAR, ARM_NEAR = SU4[0] + 1.6 * SU4[1], SU4[0] + 0.12 * SU4[1]
WALK = np.array([[1.6, -1.9, 0.0], [0.74, -0.1, 0.0], [0.9, 1.8, 0.0]])


def test_shipped_files_are_the_legacy_four_and_the_issue_17_approaches():
    assert set(shipped_scenarios()) == {"none", "arm", "hand", "walk", "fast", "elbow", "lower", "pinch", "walk-at"}
    for name in shipped_scenarios():
        sc = get_scenario(name, panda())
        assert sc.name == name and sc.duration > sc.t_leave >= 0
        assert sc.human_speed in (1.6, 2.0)


@pytest.mark.parametrize(
    ("name", "far", "near", "speed"),
    [("hand", HAND_FAR, HAND_NEAR, 0.3), ("fast", HAND_FAR, HAND_NEAR, 1.0), ("arm", ARM_FAR, ARM_NEAR, 0.3)],
)
def test_legacy_approaches_reproduce_the_python_definitions_on_the_panda(name, far, near, speed):
    """Come from far to near at `speed` arriving at 7 s, hold 3 s, go back at 0.5 m/s (to 1e-12 m)."""
    sc = get_scenario(name, panda())
    (obs,) = sc.scene.obstacles
    L = np.linalg.norm(near - far)
    t_in, t3 = 7.0 - L / speed, 10.0 + L / 0.5
    np.testing.assert_allclose(obs.path.t, [0.0, t_in, 7.0, 10.0, t3], atol=1e-12)
    np.testing.assert_allclose(obs.path.p_base, [far, far, near, near, far], atol=1e-12)
    assert sc.t_leave == pytest.approx(t3) and sc.duration == pytest.approx(t3 + 4.0)
    np.testing.assert_array_equal(sc.q0, Q_START)


def test_legacy_walk_reproduces_the_python_definition():
    sc = get_scenario("walk", panda())
    (person,) = sc.scene.obstacles
    t1 = 1.0 + np.linalg.norm(WALK[1] - WALK[0]) / 0.8
    t2 = t1 + np.linalg.norm(WALK[2] - WALK[1]) / 0.8
    t = np.linspace(0, 10, 101)
    expected = np.stack([np.interp(t, [1.0, t1, t2], WALK[:, k]) for k in range(3)], axis=1)
    np.testing.assert_allclose(person.positions(t), expected, atol=1e-12)
    heading = WALK[1] - WALK[0]
    yaw = np.arctan2(heading[1], heading[0])
    np.testing.assert_allclose(person.R_base_obs[:2, 0], [np.cos(yaw), np.sin(yaw)], atol=1e-12)
    assert len(person.primitives) == 8  # skincal.sim.scene.human


def test_speed_override_changes_the_approach_not_the_withdrawal():
    slow, quick = get_scenario("hand", panda()), get_scenario("hand", panda(), speed=2.0)
    L = np.linalg.norm(HAND_NEAR - HAND_FAR)
    assert quick.scene.obstacles[0].path.t[1] == pytest.approx(7.0 - L / 2.0)
    assert quick.t_leave == pytest.approx(slow.t_leave)  # arrival fixed, withdrawal at its own 0.5 m/s


def test_relative_positions_follow_the_robot_point():
    """A file relative to the elbow puts the hand at the same offset from each robot's elbow."""
    hand = {"name": "h", "shape": "sphere", "radius": 0.05, "relative_to": "elbow"}
    spec = {"people": [hand | {"waypoints": [{"p": [0.1, 0.2, 0.3]}]}]}
    for robot in ("panda", "ur5e"):
        chain = get_robot(robot)
        sc = parse_scenario(spec, "mem", chain)
        elbow = robot_points(chain, sc.q0)["elbow"]
        np.testing.assert_allclose(sc.scene.obstacles[0].positions([0.0])[0], elbow + [0.1, 0.2, 0.3], atol=1e-12)
    joint = {**spec["people"][0], "relative_to": {"joint": 4}}
    sc = parse_scenario({"people": [joint]}, "mem", panda())
    c = panda().joint_axes(panda().link_frames(Q_START))[0][0, 3]
    np.testing.assert_allclose(sc.scene.obstacles[0].p_base_obs, c + [0.1, 0.2, 0.3], atol=1e-12)


def _person(**over):
    p = {"name": "h", "shape": "sphere", "radius": 0.05, "waypoints": [{"p": [1, 0, 0]}, {"p": [0.5, 0, 0]}]}
    return {"people": [p | over]}


BAD = [
    ({"peple": []}, "peple", "unknown key"),
    (_person(raduis=0.1), "people[0].raduis", "unknown key"),
    (_person(radius=-0.1), "people[0].radius", "finite number"),
    (_person(radius=float("nan")), "people[0].radius", "finite number"),
    (_person(radius="big"), "people[0].radius", "must be a number"),
    (_person(speed=0), "people[0].speed", "finite number"),
    (_person(speed=-1.0), "people[0].speed", "finite number"),
    (_person(speed=1e9), "people[0].speed", "finite number"),
    (_person(waypoints=[]), "people[0].waypoints", "at least one"),
    ({"people": [{"name": "h", "shape": "sphere", "radius": 0.05}]}, "people[0].waypoints", "at least one"),
    (_person(waypoints=[{"p": [1, 0, 0]}] * 100000), "people[0].waypoints", "at most 256"),
    ({"people": [_person()["people"][0]] * 1000}, "people", "at most 16"),
    (
        {
            "people": [_person(name=f"p{i}")["people"][0] for i in range(9)],
            "obstacles": [{"name": f"o{i}", "shape": "sphere", "radius": 0.1, "p": [1, 1, 1]} for i in range(9)],
        },
        "obstacles",
        "at most 16 in all",
    ),
    (_person(waypoints=[{"p": [1, 0]}]), "people[0].waypoints[0].p", "3 numbers"),
    (_person(waypoints=[{"p": [1e300, 0, 0]}]), "people[0].waypoints[0].p", "within"),
    (_person(waypoints=[{"p": [1, 0, 0]}, {"p": [1, 0, 0]}]), "people[0].waypoints", "zero length"),
    (_person(waypoints=[{"p": [1, 0, 0], "hold": -1}]), "people[0].waypoints[0].hold", "finite number"),
    (_person(shape="cube"), "people[0].shape", "must be one of"),
    (_person(name="a/b"), "people[0].name", "contains '/'"),
    (_person(name="\x1b[2J"), "people[0].name", "control character"),
    (_person(relative_to="knee"), "people[0].relative_to", "unknown robot point 'knee'"),
    (_person(relative_to={"link": 99}), "people[0].relative_to", "link 99 does not exist"),
    (_person(arrive={"waypoint": 7, "at": 1.0}), "people[0].arrive.waypoint", "finite number"),
    (_person(start=1.0, arrive={"waypoint": 2, "at": 3.0}), "people[0].arrive", "not both"),
    (_person(height=1.8), "people[0].height", "does not apply to a sphere"),
    ({"duration": 1e9}, "duration", "finite number"),
    ({"duration": -1}, "duration", "finite number"),
    ({"people": [_person()["people"][0], _person()["people"][0]]}, "people", "unique"),
    ({"obstacles": [{"name": "s", "shape": "human", "p": [0, 0, 0]}]}, "obstacles[0].shape", "must be one of"),
    ([1, 2, 3], "top level", "must be a mapping"),
]


@pytest.mark.adversarial
@pytest.mark.parametrize(("spec", "field", "words"), BAD, ids=[f"{b[1]}-{i}" for i, b in enumerate(BAD)])
def test_bad_field_is_a_one_line_error_naming_it(spec, field, words):
    with pytest.raises(ConfigError) as exc:
        parse_scenario(spec, "bad.yaml", panda())
    msg = str(exc.value)
    assert "\n" not in msg and "\x1b" not in msg
    assert msg.startswith(f"bad.yaml: {field}") and words in msg, msg


@pytest.mark.adversarial
def test_hostile_files_through_the_guarded_loader(tmp_path):
    chain = panda()
    alias = tmp_path / "alias.yaml"
    alias.write_text("a: &x [1, 2]\nb: *x\n")
    dup = tmp_path / "dup.json"
    dup.write_text('{"duration": 5, "duration": 6}')
    nan = tmp_path / "nan.json"
    nan.write_text('{"duration": NaN}')
    for path in (alias, dup, nan, tmp_path):
        with pytest.raises(ConfigError) as exc:
            load_scenario(path, chain)
        assert str(path) in str(exc.value) and "\n" not in str(exc.value)
    ok = tmp_path / "ok.json"
    text = json.dumps(_person(speed=0.5))
    ok.write_text(text)
    sc = load_scenario(ok, chain)
    assert sc.name == "ok" and ok.read_text() == text  # name from the stem; input untouched
    with pytest.raises(ConfigError, match="unknown scenario 'nowhere'"):
        get_scenario("nowhere", chain)
    with pytest.raises(ConfigError, match="--speed"):
        get_scenario("hand", chain, speed=float("nan"))


@pytest.mark.adversarial
def test_a_huge_scenario_file_is_refused_before_parsing(tmp_path):
    """A YAML parser needs minutes for tens of MB: a scenario file over 1 MiB is refused in one line."""
    from skincal.errors import ConfigError
    from skincal.kinematics import panda
    from skincal.sim.scenarios import load_scenario

    path = tmp_path / "big.yaml"
    path.write_text("name: big\ndescription: " + "x" * (1 << 20) + "\n")
    with pytest.raises(ConfigError) as err:
        load_scenario(path, panda())
    assert "\n" not in str(err.value) and "big.yaml" in str(err.value)
