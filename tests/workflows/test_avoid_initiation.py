"""Issue 28 in the closed loop: who initiated a contact, and the torque robot inside S_p.

* a person who walks into the stopped robot (a hand onto the base column, which no joint can move away) touches
  it: the contact is person-initiated (the robot point's speed toward the hand 0 at the touch), within the hand's
  limits, and the robot never approached a perceived point inside its ``S_p``: the standard's pass;
* the torque robot in ``arm`` (Panda, ``--margin iso``): before the commands were kept within the drive's
  acceleration limits, the drive's reversal lagged the retreat command and the arm approached a point inside
  ``S_p`` for 0.020 s at up to 0.19 m/s (simulated); now it never does.

(The robot that would hit a hand, classified robot-initiated blind and prevented with ``S_p``, is
``tests/workflows/test_avoid_pfl.py``.)
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from skincal.control import ControllerConfig
from skincal.control.separation import SeparationParams, StoppingModel
from skincal.kinematics import panda
from skincal.perception import RobotBody
from skincal.protocol.flange import Circle
from skincal.sim.scenarios import get_scenario, parse_scenario
from skincal.skin.placement import ring_placement
from skincal.workflows.avoidance import robot_mass_matrix, run_scenario
from skincal.workflows.experiment import ExperimentConfig, StoppingModels, run_experiment, scenario_regions, summarize

pytest.importorskip("mujoco")

SEPARATION = SeparationParams(human_speed_mps=1.6, stopping=StoppingModel.constant_deceleration(4.0, 0.021))


def _walk_into_the_base(chain):
    """A hand (sphere r = 5 cm) at 1.6 m/s from 0.8 m behind the Panda onto its base column (capsule r = 6 cm
    about the z axis up to the shoulder), 2 cm into it at 0.15 m height, held there 0.4 s; the robot holds
    its start pose (a circle of radius 0: the task does not move)."""
    hand = {"name": "hand", "shape": "sphere", "radius": 0.05, "speed": 1.6, "relative_to": "base"}
    hand["waypoints"] = [{"p": [-0.8, 0.0, 0.15]}, {"p": [-0.09, 0.0, 0.15], "hold": 0.4}]
    hand["arrive"] = {"waypoint": 2, "at": 0.8}
    sc = parse_scenario({"people": [hand], "duration": 1.3, "human_speed": 1.6}, "test", chain)
    x0 = sc.task.at(0.0)[0][0]
    return replace(sc, task=Circle(x0, 0.0, np.array([0.0, 1.0, 0.0]), np.array([0.0, 0.0, 1.0]), 5.0))


@pytest.mark.slow  # one kinematic closed-loop run of 1.3 s: about 5 s
def test_a_person_walking_into_the_stopped_robot_is_person_initiated_and_passes():
    chain = panda()
    poses = ring_placement(chain)
    sc = _walk_into_the_base(chain)
    mass = robot_mass_matrix(chain)
    ctl = ControllerConfig(separation=SEPARATION, stop_never_approaches=True)
    log = run_scenario(chain, sc, poses, poses, np.random.default_rng(0), controller=ctl, mass_matrix=mass)
    m = summarize(log, RobotBody.of(chain), "truth", judged=("ssm", scenario_regions(sc), mass))
    iso = m.iso
    assert m.contacts >= 1 and iso["contacts_person_initiated"] == m.contacts
    assert iso["contacts_robot_initiated"] == 0
    for e in iso["contact_events"]:
        assert e["region"] == "hand" and not e["robot_initiated"] and e["within_limits"]
        assert abs(e["v_robot"]) <= 1e-3  # the base column cannot move toward the hand
        assert e["v_person"] == pytest.approx(1.6, abs=0.1)  # the hand's own speed at the touch
    assert iso["sp_violation_steps"] == 0 and iso["iso_pass"]


@pytest.mark.slow  # a 7 s torque-mode run and the Panda's stopping model: about 30 s
def test_the_torque_panda_never_approaches_a_point_inside_sp_in_arm():
    chain = panda()
    poses = ring_placement(chain)
    sc = get_scenario("arm", chain, 7.0)
    config = ExperimentConfig(chain, sc, poses, poses, "truth", None, "iso", False, "torque", 0)
    run = run_experiment(config, stopping=StoppingModels())
    iso = run.metrics.iso
    assert run.controller.acceleration_limit is not None
    assert run.metrics.contacts == 0
    assert iso["sp_violation_steps"] == 0 and iso["iso_pass"]
    # the commands the drive was given stay within its acceleration limits: it reaches each within the step
    qdd = np.abs(np.diff(run.log.qd, axis=0)) / 1e-3
    excess = qdd - np.asarray(run.controller.acceleration_limit)
    assert excess.max() <= 0.01, excess.max()  # rad/s^2: the QP solver's bound tolerance over dt
