"""Issue 28 in the closed loop: the standard's criteria judged on real runs (kinematic, short)."""

from __future__ import annotations

import numpy as np
import pytest

from skincal.control import ControllerConfig
from skincal.control.body_regions import body_region
from skincal.control.separation import SeparationParams, StoppingModel
from skincal.kinematics import panda
from skincal.perception import RobotBody
from skincal.sim.scenarios import parse_scenario
from skincal.skin.placement import ring_placement
from skincal.workflows.avoidance import robot_mass_matrix, run_scenario
from skincal.workflows.experiment import scenario_regions, summarize

pytest.importorskip("mujoco")

SEPARATION = SeparationParams(human_speed_mps=2.0, stopping=StoppingModel.constant_deceleration(4.0, 0.021))


def _hand_in_path(chain, duration=1.8):
    """A still hand (sphere r = 5 cm) 9 cm beyond the top of the circle the flange runs (the top reached at
    1.25 s, moving along -y): the task drives the flange into it at about 0.13 m/s."""
    hand = {"name": "hand", "shape": "sphere", "radius": 0.05, "relative_to": "flange"}
    hand["waypoints"] = [{"p": [0.0, -0.19, 0.1]}]
    return parse_scenario({"people": [hand], "duration": duration}, "test", chain)


pytestmark = pytest.mark.slow  # three closed-loop runs of 1.8 s: 10-20 s


@pytest.fixture(scope="module")
def runs():
    chain = panda()
    poses = ring_placement(chain)
    sc = _hand_in_path(chain)
    regions = scenario_regions(sc)
    mass = robot_mass_matrix(chain)
    out = {}
    for name, ctl, beliefs in (
        ("blind", ControllerConfig(), {}),
        ("ssm", ControllerConfig(separation=SEPARATION), poses),
        ("pfl", ControllerConfig(separation=SEPARATION, pfl=body_region("hand")), poses),
    ):
        log = run_scenario(chain, sc, poses, beliefs, np.random.default_rng(0), controller=ctl, mass_matrix=mass)
        crit = "pfl" if name == "pfl" else "ssm"
        out[name] = summarize(log, RobotBody.of(chain), name, judged=(crit, regions, mass))
    return out


def test_the_blind_robot_hits_the_hand_robot_initiated_and_fails(runs):
    iso = runs["blind"].iso
    assert runs["blind"].contacts >= 1 and not iso["iso_pass"]
    first = iso["contact_events"][0]
    assert first["region"] == "hand" and first["robot_initiated"] and first["v_robot"] > 0.05
    assert first["v_person"] == pytest.approx(0.0, abs=1e-9)
    assert first["within_limits"]  # slow enough for the hand's Annex A limit: PFL would allow it, SSM not


def test_ssm_prevents_the_contact_and_never_approaches_inside_sp(runs):
    m = runs["ssm"]
    assert m.contacts == 0 and m.iso["iso_pass"] and m.iso["sp_violation_steps"] == 0
    assert m.iso["max_approach_inside_sp_mps"] <= 1e-3
    assert m.min_clearance_m > 0.0


def test_pfl_approaches_inside_sp_but_within_the_hand_limit(runs):
    m = runs["pfl"]
    assert m.iso["iso_pass"] and m.iso["sp_violation_steps"] == 0
    assert m.iso["inside_sp_s"] > 0.05
    assert m.iso["max_approach_inside_sp_mps"] > 0.01  # it does approach inside S_p (PFL), unlike pure SSM
    assert m.min_clearance_m < runs["ssm"].min_clearance_m
    for e in m.iso["contact_events"]:
        assert e["within_limits"] and not e["robot_initiated"]
