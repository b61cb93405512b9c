"""MuJoCo simulator backend: same dataset as the analytic simulator, dynamic mode self-consistency."""

from __future__ import annotations

import dataclasses
import time

import numpy as np
import pytest

from skincal.errors import ConfigError
from skincal.kinematics import GRAVITY_BASE, get_robot
from skincal.protocol import build_trajectory, get_protocol
from skincal.sim.analytic import simulate
from skincal.sim.mujoco_backend import SensorIndex, servo_gains, servo_run, simulate_mujoco
from skincal.sim.mujoco_model import build_model
from skincal.sim.scene import Obstacle, Primitive, Scene, TimeTable, human, wall
from skincal.skin.imu import get_imu_model
from skincal.skin.placement import paper_placement, random_placement
from skincal.skin.pose import SkinUnitPose
from skincal.skin.tof import get_tof_model

mujoco = pytest.importorskip("mujoco")


def short_trajectory(chain, joints=None, seed=0):
    """One pose, a few excited joints: ~10-40 s of protocol."""
    cfg = dataclasses.replace(get_protocol("paper-sim"), n_poses=1, excited_joints=joints, amplitude=1.2)
    return build_trajectory(chain, cfg, np.random.default_rng(seed))


@pytest.mark.parametrize("robot", ["panda", "sawyer"])
def test_kinematic_mode_reproduces_the_analytic_simulator(robot: str) -> None:
    chain = get_robot(robot)
    placements = paper_placement(chain) if robot == "panda" else random_placement(chain, 6, np.random.default_rng(1))
    traj = short_trajectory(chain, joints=(0, 2, 4, 5))
    imu = dataclasses.replace(get_imu_model("none"), latency_s=0.012, jitter_s=0.001, drop_probability=0.02)
    ref = simulate(chain, placements, traj, imu, np.random.default_rng(5))
    got = simulate_mujoco(chain, placements, traj, imu, np.random.default_rng(5))
    assert list(got.imu) == list(ref.imu)
    dynamic = 0.0
    for unit in placements:
        a, b = ref.imu[unit], got.imu[unit]
        np.testing.assert_array_equal(a.t, b.t)  # same clocks, drops and jitter: same draws
        assert np.abs(a.accel - b.accel).max() <= 1e-6
        assert np.abs(a.gyro - b.gyro).max() <= 1e-9
        dynamic = max(dynamic, np.abs(np.linalg.norm(a.accel, axis=1) - 9.81).max(), np.abs(a.gyro).max())
    assert dynamic > 1.0  # the motion is real: accelerations and rates well away from rest
    np.testing.assert_array_equal(got.joints.q, ref.joints.q)
    np.testing.assert_array_equal(got.segments.t_start, ref.segments.t_start)
    assert got.truth.keys() == ref.truth.keys()
    assert got.truth_sensor["su1" if robot == "panda" else next(iter(placements))]["time_offset_s"] == 0.012


def test_kinematic_mode_with_sensor_errors_matches_draw_for_draw() -> None:
    chain = get_robot("panda")
    placements = paper_placement(chain)
    traj = short_trajectory(chain, joints=(3,))
    imu = get_imu_model("realistic")
    ref = simulate(chain, placements, traj, imu, np.random.default_rng(9))
    got = simulate_mujoco(chain, placements, traj, imu, np.random.default_rng(9))
    for unit in placements:
        np.testing.assert_allclose(got.imu[unit].accel, ref.imu[unit].accel, atol=1e-6)
        np.testing.assert_allclose(got.truth_sensor[unit]["accel_bias"], ref.truth_sensor[unit]["accel_bias"])


def test_dynamic_mode_records_the_state_the_sensors_saw() -> None:
    chain = get_robot("panda")
    placements = paper_placement(chain)
    traj = short_trajectory(chain, joints=(1, 3))
    model0 = build_model(chain, placements)
    kv = servo_gains(model0, traj.q[0])
    model = build_model(chain, placements, velocity_gain=kv, gravity_compensation=True)
    idx = SensorIndex.of(model, list(placements))
    run = servo_run(model, idx, traj, 6.0)
    # MuJoCo's accelerometer at each step equals skincal's kinematics of the recorded (q, qd, qdd).
    motion = chain.link_motion(run.q, run.qd, run.qdd)
    for u, pose in enumerate(placements.values()):
        _, _, a = motion.point(pose.link, pose.p_link_su)
        R = motion.T_base_link[:, pose.link, :3, :3] @ pose.R_link_su
        f = np.einsum("mji,mj->mi", R, a - GRAVITY_BASE)
        assert np.abs(run.sensors.accel[:, u] - f).max() <= 1e-6
    # Tracking: close to the reference, but not equal (a real servo lags).
    err_q = np.abs(run.q - run.q_ref).max()
    err_qd = np.abs(run.qd - run.qd_ref).max()
    assert 1e-4 < err_q < 0.05 and 1e-3 < err_qd < 0.5
    # At rest (first second: rest at the pose) gravity compensation holds the pose still.
    rest = run.t < traj.segments.t_start[0] + 0.5
    assert np.abs(run.qd[rest]).max() < 1e-6


def test_dynamic_mode_dataset_has_actual_joint_states_and_imu_streams() -> None:
    chain = get_robot("sawyer")
    placements = random_placement(chain, 4, np.random.default_rng(2))
    traj = short_trajectory(chain, joints=(2,))
    ds = simulate_mujoco(chain, placements, traj, get_imu_model("none"), np.random.default_rng(3), mode="dynamic")
    assert ds.joints.q.shape == traj.q.shape and ds.joints.qdd is not None
    assert 0 < np.abs(ds.joints.q - traj.q).max() < 0.05
    ref = simulate(chain, placements, traj, get_imu_model("none"), np.random.default_rng(3))
    for unit in placements:
        np.testing.assert_array_equal(ds.imu[unit].t, ref.imu[unit].t)
        # Same motion up to tracking error: readings close on average, not identical.
        diff = np.abs(ds.imu[unit].accel - ref.imu[unit].accel)
        assert 0 < np.median(diff) < 0.5


def test_tof_streams_match_analytic_ray_casting() -> None:
    chain = get_robot("panda")
    placements = paper_placement(chain)
    traj = short_trajectory(chain, joints=(0,))
    scene = Scene((human(position=(0.9, 0.0, 0.0)), wall(distance=1.5, yaw=np.pi / 2)))
    no_robot = {"link_radius": 1e-6, "board_geoms": False}  # the analytic cast does not see the robot
    for tof_name in ("ideal-ray", "vl53l1x"):
        tof_model = get_tof_model(tof_name)
        ref = simulate(
            chain,
            placements,
            traj,
            get_imu_model("none"),
            np.random.default_rng(4),
            tof_model=tof_model,
            scene=scene.tof_primitives(),
        )
        got = simulate_mujoco(
            chain,
            placements,
            traj,
            get_imu_model("none"),
            np.random.default_rng(4),
            scene=scene,
            tof_model=tof_model,
            model_options=no_robot,
        )
        hits = 0
        for unit in placements:
            a, b = ref.tof[unit], got.tof[unit]
            np.testing.assert_array_equal(a.t, b.t)
            np.testing.assert_array_equal(np.isnan(a.range), np.isnan(b.range))
            np.testing.assert_allclose(
                a.range, b.range, atol=1e-9 if tof_name == "ideal-ray" else 1e-3 + 1e-9, equal_nan=True
            )
            hits += np.isfinite(b.range).sum()
        assert hits > 100


def test_moving_obstacle_is_seen_approaching() -> None:
    chain = get_robot("panda")
    pose = SkinUnitPose(1, np.array([[0.0, 0, 1], [0, 1, 0], [-1, 0, 0]]), [0.08, 0.0, -0.1])  # z along +x
    cfg = dataclasses.replace(get_protocol("paper-sim"), n_poses=1, excited_joints=(6,), amplitude=1.2)
    traj = build_trajectory(chain, cfg, poses=[[0.0, 0.0, 0.0, -1.5, 0.0, 1.5, 0.0]])  # link 1 frame = base + 0.333 z
    t_end = float(traj.t[-1])
    ball = Obstacle(
        "ball", (Primitive("sphere", [0.1]),), path=TimeTable([0.0, t_end], [[2.0, 0, 0.233], [0.5, 0, 0.233]])
    )
    ds = simulate_mujoco(
        chain,
        {"front": pose},
        traj,
        get_imu_model("none"),
        np.random.default_rng(0),
        scene=Scene((ball,)),
        tof_model=get_tof_model("ideal-ray"),
    )
    tof = ds.tof["front"]
    x_ball = 2.0 - 1.5 * tof.t / t_end
    np.testing.assert_allclose(tof.range, x_ball - 0.1 - 0.08, atol=1e-9)


def test_bad_arguments_raise_config_error() -> None:
    chain = get_robot("panda")
    traj = short_trajectory(chain, joints=(0,))
    placements = paper_placement(chain)
    with pytest.raises(ConfigError, match="mode"):
        simulate_mujoco(chain, placements, traj, get_imu_model("none"), np.random.default_rng(0), mode="magic")
    with pytest.raises(ConfigError, match="no skin units"):
        simulate_mujoco(chain, {}, traj, get_imu_model("none"), np.random.default_rng(0))
    with pytest.raises(ConfigError, match="joints"):
        unit = {"a": SkinUnitPose(1, np.eye(3), np.zeros(3))}
        simulate_mujoco(get_robot("ur5e"), unit, traj, get_imu_model("none"), np.random.default_rng(0))


@pytest.mark.slow
def test_paper_length_protocol_runs_and_reports_time() -> None:
    chain = get_robot("panda")
    traj = build_trajectory(chain, get_protocol("paper-sim"), np.random.default_rng(0))
    placements = paper_placement(chain)
    start = time.perf_counter()
    ds = simulate_mujoco(chain, placements, traj, get_imu_model("datasheet"), np.random.default_rng(1))
    elapsed = time.perf_counter() - start
    print(f"paper-sim: {traj.duration:.0f} s of protocol, {len(placements)} units, kinematic MuJoCo {elapsed:.1f} s")
    assert ds.imu["su1"].t.size > 0.99 * traj.duration * 100
