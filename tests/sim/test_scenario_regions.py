"""Body regions of person parts in scenario files (issue 28): optional, defaults by shape, old files unchanged."""

from __future__ import annotations

import numpy as np
import pytest

from skincal.errors import ConfigError
from skincal.kinematics import panda
from skincal.sim.scenarios import get_scenario, parse_scenario
from skincal.sim.scene import HUMAN_REGIONS
from skincal.workflows.experiment import scenario_regions


def _spec(**person):
    base = {"name": "p", "shape": "sphere", "radius": 0.05, "waypoints": [{"p": [0.5, 0.0, 0.5]}]}
    post = {"name": "post", "shape": "sphere", "radius": 0.1, "p": [1, 1, 0]}
    return {"people": [base | person], "obstacles": [post]}


def test_defaults_by_shape_and_the_key_given():
    chain = panda()
    sc = parse_scenario(_spec(), "t", chain)
    assert sc.scene.obstacles[0].body_regions == ("hand",) and sc.scene.obstacles[1].body_regions == ()
    cap = parse_scenario(_spec(shape="capsule", length=0.3), "t", chain)
    assert cap.scene.obstacles[0].body_regions == ("forearm",)
    chest = parse_scenario(_spec(body_region="chest"), "t", chain)
    assert [r.name if r else None for r in scenario_regions(chest)] == ["chest", None]
    walker = {"name": "w", "shape": "human", "waypoints": [{"p": [1.0, 0.0, 0.0]}]}
    people = parse_scenario({"people": [walker, walker | {"name": "v", "body_region": "back"}]}, "t", chain)
    assert people.scene.obstacles[0].body_regions == HUMAN_REGIONS
    assert people.scene.obstacles[1].body_regions == ("back",) * len(HUMAN_REGIONS)


def test_shipped_files_read_as_before_with_default_regions():
    """The shipped walk and hand: the same solids as the scene builds them, regions by default."""
    chain = panda()
    walk, hand = get_scenario("walk", chain), get_scenario("hand", chain)
    assert walk.scene.obstacles[0].body_regions == HUMAN_REGIONS
    assert hand.scene.obstacles[0].body_regions == ("hand",)
    assert len(walk.scene.tof_primitives()) == len(scenario_regions(walk)) == 8
    np.testing.assert_allclose(hand.scene.obstacles[0].p_base_obs, hand.scene.obstacles[0].positions(0.0)[0])


def test_an_unknown_region_is_one_line_naming_the_file_and_person():
    chain = panda()
    sc = parse_scenario(_spec(body_region="elbowz"), "bad.yaml", chain)
    with pytest.raises(ConfigError, match=r"bad.yaml: person 'p': unknown body region 'elbowz'") as e:
        scenario_regions(sc)
    assert "\n" not in str(e.value)
    with pytest.raises(ConfigError, match="body_region: must be a string"):
        parse_scenario(_spec(body_region=3), "bad.yaml", chain)


def test_the_pfl_controller_assumes_the_most_restrictive_part():
    """A hand and a chest: the chest (against an infinitely heavy robot 280 / sqrt(40 * 25000) = 0.28 m/s, the
    hand 280 / sqrt(0.6 * 75000) = 1.32 m/s); a human (with a head): the skull, no transient contact; nobody:
    the hand."""
    from skincal.workflows.experiment import assumed_region

    chain = panda()
    two = parse_scenario(
        {"people": [_spec()["people"][0], _spec(name="q", body_region="chest")["people"][0]]}, "t", chain
    )
    assert assumed_region(scenario_regions(two)).name == "chest"
    walker = {"name": "w", "shape": "human", "waypoints": [{"p": [1.0, 0.0, 0.0]}]}
    assert assumed_region(scenario_regions(parse_scenario({"people": [walker]}, "t", chain))).name == "skull"
    assert assumed_region([None]).name == "hand"
