"""One ToF measurement for its three users, one simulator pipeline: the backends agree draw for draw."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from skincal.kinematics import get_robot, panda
from skincal.protocol import build_trajectory, get_protocol
from skincal.sim.analytic import simulate
from skincal.sim.joint_states import get_joint_model
from skincal.sim.scene import Obstacle, Primitive, Scene, TimeTable, human, wall
from skincal.skin.clock import get_clock_model
from skincal.skin.imu import get_imu_model
from skincal.skin.placement import paper_placement
from skincal.skin.tof import TofModel, get_tof_model


@dataclasses.dataclass(frozen=True)
class RecordingTof(TofModel):
    """A real ToF model that also keeps every ``measure`` call: ``(true distances, rng state before, reading)``."""

    def __post_init__(self) -> None:
        super().__post_init__()
        object.__setattr__(self, "calls", [])

    def measure(self, true_distance, rng=None):
        state = None if rng is None else rng.bit_generator.state
        out = super().measure(true_distance, rng)
        self.calls.append((np.array(true_distance, dtype=float), state, out))
        return out


def recording(name: str, **changes) -> RecordingTof:
    fields = {f.name: getattr(get_tof_model(name), f.name) for f in dataclasses.fields(TofModel)}
    return RecordingTof(**(fields | changes))


def replay(call) -> np.ndarray:
    """The reading ``TofModel.measure`` gives for a recorded call, from the recorded rng state."""
    true, state, _ = call
    rng = np.random.default_rng()
    rng.bit_generator.state = state
    return get_tof_model("vl53l1x").measure(true, rng)


def short_session(seed: int = 0):
    chain = get_robot("panda")
    cfg = dataclasses.replace(get_protocol("paper-sim"), n_poses=1, excited_joints=(0, 3), amplitude=1.2)
    traj = build_trajectory(chain, cfg, np.random.default_rng(seed))
    t_end = float(traj.t[-1])
    ball = Obstacle("ball", (Primitive("sphere", [0.1]),), path=TimeTable([0.0, t_end], [[1.5, 0, 0.5], [0.4, 0, 0.5]]))
    scene = Scene((human(position=(0.9, 0.0, 0.0)), wall(distance=1.5, yaw=np.pi / 2), ball))
    return chain, paper_placement(chain), traj, scene


def test_analytic_simulator_reads_tof_through_measure():
    chain, placements, traj, scene = short_session()
    tof = recording("vl53l1x")
    ds = simulate(chain, placements, traj, get_imu_model("none"), np.random.default_rng(4), tof_model=tof,
                  scene=scene.tof_primitives())  # fmt: skip
    assert len(tof.calls) == len(placements)  # one call per unit, nothing else measures
    for unit, call in zip(placements, tof.calls, strict=True):
        np.testing.assert_array_equal(ds.tof[unit].range, call[2])
        np.testing.assert_array_equal(replay(call), call[2])
    assert sum(np.isfinite(c[2]).sum() for c in tof.calls) > 100


def test_mujoco_simulator_reads_tof_through_measure():
    pytest.importorskip("mujoco")
    from skincal.sim.mujoco_backend import simulate_mujoco

    chain, placements, traj, scene = short_session()
    for mode in ("kinematic", "dynamic"):
        tof = recording("vl53l1x")
        ds = simulate_mujoco(chain, placements, traj, get_imu_model("none"), np.random.default_rng(4), mode=mode,
                             scene=scene, tof_model=tof)  # fmt: skip
        assert len(tof.calls) == len(placements)
        for unit, call in zip(placements, tof.calls, strict=True):
            np.testing.assert_array_equal(ds.tof[unit].range, call[2])
            np.testing.assert_array_equal(replay(call), call[2])
        assert sum(np.isfinite(c[2]).sum() for c in tof.calls) > 100


def test_avoidance_loop_reads_tof_through_measure():
    pytest.importorskip("mujoco")
    from skincal.sim.scenarios import get_scenario
    from skincal.workflows.avoidance import run_scenario

    chain = panda()
    poses = paper_placement(chain)
    tof = recording("vl53l1x")
    log = run_scenario(chain, get_scenario("walk", chain, duration=0.8), poses, poses, np.random.default_rng(0),
                       tof_model=tof)  # fmt: skip
    assert len(tof.calls) == np.isfinite(log.tof_t).sum() > 0  # one call per reading instant (one or more units)
    readings = np.concatenate([c[2] for c in tof.calls])
    assert np.isfinite(readings).sum() > 10
    order = np.argsort(log.tof_t, axis=None, kind="stable")
    logged = log.tof_range.ravel()[order][np.isfinite(log.tof_t.ravel()[order])]
    np.testing.assert_array_equal(np.sort(logged[np.isfinite(logged)]), np.sort(readings[np.isfinite(readings)]))
    # the loop's only random draws are measure's: replaying from the seed reproduces every reading
    rng = np.random.default_rng(0)
    for true, state, out in tof.calls:
        assert rng.bit_generator.state == state
        np.testing.assert_array_equal(get_tof_model("vl53l1x").measure(true, rng), out)


def test_backends_agree_draw_for_draw_with_every_random_model():
    """Same seed: same IMU stamps (clock, jitter, drops), errors, noise, joint stream and ToF noise."""
    pytest.importorskip("mujoco")
    from skincal.sim.mujoco_backend import simulate_mujoco

    chain, placements, traj, scene = short_session()
    tof = dataclasses.replace(get_tof_model("vl53l1x"), resolution_m=0.0)  # noise visible without rounding
    common = {
        "tof_model": tof,
        "joint_model": get_joint_model("controller"),
        "clock_model": get_clock_model("wifi"),
    }
    imu = get_imu_model("realistic")
    ref = simulate(chain, placements, traj, imu, np.random.default_rng(9), scene=scene.tof_primitives(), **common)
    no_robot = {"link_radius": 1e-6, "board_geoms": False}  # the analytic cast does not see the robot
    got = simulate_mujoco(chain, placements, traj, imu, np.random.default_rng(9), scene=scene,
                          model_options=no_robot, **common)  # fmt: skip
    for name in ("t", "q", "qd"):
        np.testing.assert_array_equal(getattr(got.joints, name), getattr(ref.joints, name))
    assert list(got.imu) == list(ref.imu) == list(placements)
    finite = 0
    for unit in placements:
        np.testing.assert_array_equal(got.imu[unit].t, ref.imu[unit].t)
        np.testing.assert_allclose(got.imu[unit].accel, ref.imu[unit].accel, rtol=0, atol=1e-6)
        np.testing.assert_allclose(got.imu[unit].gyro, ref.imu[unit].gyro, rtol=0, atol=1e-9)
        for key, value in ref.truth_sensor[unit].items():
            np.testing.assert_array_equal(got.truth_sensor[unit][key], value)
        a, b = ref.tof[unit], got.tof[unit]
        np.testing.assert_array_equal(a.t, b.t)
        np.testing.assert_allclose(a.range, b.range, rtol=0, atol=1e-6, equal_nan=True)  # same 5 mm noise draws
        finite += np.isfinite(a.range).sum()
    assert finite > 500
