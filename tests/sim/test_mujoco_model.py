"""MuJoCo model of DH chains: frames, IMU sensors and range sensors against skincal's own kinematics."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from skincal.errors import ConfigError
from skincal.kinematics import GRAVITY_BASE, SerialChain, get_robot
from skincal.kinematics.geometry import link_capsules
from skincal.kinematics.urdf import chain_from_urdf
from skincal.sim.mujoco_model import (
    PANDA_INERTIALS,
    SensorIndex,
    build_mjcf,
    build_model,
    link_body_ids,
    require_mujoco,
)
from skincal.sim.scene import Obstacle, Primitive, Scene, TimeTable, human, table, wall
from skincal.skin.pose import SkinUnitPose

mujoco = pytest.importorskip("mujoco")


def random_placements(chain: SerialChain, rng: np.random.Generator, per_link: int = 2) -> dict[str, SkinUnitPose]:
    out = {}
    for link in range(1, chain.n_joints + 1):
        for k in range(per_link):
            R = Rotation.random(random_state=int(rng.integers(1 << 31))).as_matrix()
            out[f"l{link}_{k}"] = SkinUnitPose(link, R, rng.uniform(-0.15, 0.15, 3))
    return out


def random_chain(n: int, convention: str, rng: np.random.Generator) -> SerialChain:
    dh = np.column_stack(
        [
            rng.uniform(-np.pi, np.pi, n),
            rng.uniform(-0.3, 0.3, n),
            rng.uniform(-0.3, 0.3, n),
            rng.choice([-np.pi / 2, 0.0, np.pi / 2, 0.3], n),
        ]
    )
    name, lim = f"random{n}{convention[0]}", np.full(n, 3.0)
    return SerialChain.from_dh(name, convention, dh, joint_lower=-lim, joint_upper=lim)


def random_state(chain: SerialChain, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    n = chain.n_joints
    return rng.uniform(-np.pi, np.pi, n), rng.uniform(-2.5, 2.5, n), rng.uniform(-15.0, 15.0, n)


def analytic_imu(chain: SerialChain, placements: dict[str, SkinUnitPose], q, qd, qdd):
    """skincal's f = R_base_su^T (a - g) and omega_su = R_base_su^T omega, (U, 3) each."""
    motion = chain.link_motion(q, qd, qdd)
    f, w, T_su = [], [], []
    for pose in placements.values():
        _, _, a = motion.point(pose.link, pose.p_link_su)
        T = motion.T_base_link[0, pose.link] @ pose.T_link_su
        f.append(T[:3, :3].T @ (a[0] - GRAVITY_BASE))
        w.append(T[:3, :3].T @ motion.omega[0, pose.link])
        T_su.append(T)
    return np.array(f), np.array(w), np.array(T_su)


CHAINS = ["panda", "sawyer", "ur5e", "random12m", "random12s", "urdf:ur5", "urdf:xarm7", "urdf:kinova", "general"]


def get_chain(name: str) -> SerialChain:
    """A preset, a random DH chain, a registry URDF, or a random general chain (random joint
    origins and axes, prismatic joints among the revolute ones)."""
    if name.startswith("urdf:"):
        from registry_robots import registry_urdf

        return chain_from_urdf(registry_urdf(name[5:]))
    if name == "general":
        from registry_robots import random_chain as random_general_chain

        return random_general_chain(np.random.default_rng(8), 7)
    if name.startswith("random"):
        return random_chain(12, "modified" if name.endswith("m") else "standard", np.random.default_rng(7))
    return get_robot(name)


@pytest.mark.parametrize("name", CHAINS)
def test_body_and_site_frames_and_imu_match_analytic_kinematics(name: str) -> None:
    rng = np.random.default_rng(11)
    chain = get_chain(name)
    placements = random_placements(chain, rng)
    model = build_model(chain, placements)
    data = mujoco.MjData(model)
    bodies = link_body_ids(model, chain.n_joints)
    idx = SensorIndex.of(model, list(placements))
    err = {"frame": 0.0, "site": 0.0, "accel": 0.0, "gyro": 0.0}
    for _ in range(25):
        q, qd, qdd = random_state(chain, rng)
        data.qpos[:], data.qvel[:], data.qacc[:] = q, qd, qdd
        mujoco.mj_inverse(model, data)
        T = chain.link_frames(q)[0]
        err["frame"] = max(
            err["frame"],
            np.abs(data.xpos[bodies] - T[:, :3, 3]).max(),
            np.abs(data.xmat[bodies].reshape(-1, 3, 3) - T[:, :3, :3]).max(),
        )
        f, w, T_su = analytic_imu(chain, placements, q, qd, qdd)
        err["site"] = max(
            err["site"],
            np.abs(data.site_xpos[idx.site] - T_su[:, :3, 3]).max(),
            np.abs(data.site_xmat[idx.site].reshape(-1, 3, 3) - T_su[:, :3, :3]).max(),
        )
        err["accel"] = max(err["accel"], np.abs(data.sensordata[idx.accel] - f).max())
        err["gyro"] = max(err["gyro"], np.abs(data.sensordata[idx.gyro] - w).max())
    assert err["frame"] <= 1e-9 and err["site"] <= 1e-9, err
    assert err["accel"] <= 1e-6, err
    assert err["gyro"] <= 1e-9, err


def test_accelerometer_at_rest_reads_plus_g_along_up() -> None:
    chain = get_robot("panda")
    model = build_model(chain, {"up": SkinUnitPose(1, np.eye(3), [0.05, 0.0, -0.1])})
    data = mujoco.MjData(model)
    mujoco.mj_inverse(model, data)  # q = qd = qdd = 0: link 1 z axis is the base z axis
    np.testing.assert_allclose(data.sensordata[SensorIndex.of(model, ["up"]).accel[0]], [0, 0, 9.81], atol=1e-12)


def test_panda_uses_franka_inertials_in_link_frames() -> None:
    model = build_model(get_robot("panda"))
    bodies = link_body_ids(model, 7)[1:]
    for body, li in zip(bodies, PANDA_INERTIALS, strict=True):
        assert model.body_mass[body] == pytest.approx(li.mass, abs=1e-12)
        np.testing.assert_allclose(model.body_ipos[body], li.com, atol=1e-12)
        # MuJoCo stores principal moments + principal axes; rebuild the tensor in the link frame.
        R = Rotation.from_quat(model.body_iquat[body], scalar_first=True).as_matrix()
        I = R @ np.diag(model.body_inertia[body]) @ R.T
        xx, yy, zz, xy, xz, yz = li.inertia
        np.testing.assert_allclose(I, [[xx, xy, xz], [xy, yy, yz], [xz, yz, zz]], atol=1e-9)
    assert model.body_mass[bodies].sum() == pytest.approx(16.06, abs=0.01)


def test_other_chains_get_capsule_masses_and_boards_do_not_change_dynamics() -> None:
    chain = get_robot("sawyer")
    rng = np.random.default_rng(3)
    placements = random_placements(chain, rng)
    with_boards = build_model(chain, placements, board_geoms=True)
    without = build_model(chain, placements, board_geoms=False)
    assert with_boards.ngeom == without.ngeom + len(placements)
    assert np.all(with_boards.body_mass[2:] > 0.5)  # every moving link has a plausible mass
    np.testing.assert_array_equal(with_boards.body_mass, without.body_mass)
    d1, d2 = mujoco.MjData(with_boards), mujoco.MjData(without)
    for model, d in ((with_boards, d1), (without, d2)):
        d.qpos[:], d.qvel[:], d.qacc[:] = random_state(chain, np.random.default_rng(5))
        mujoco.mj_inverse(model, d)
    np.testing.assert_allclose(d1.qfrc_inverse, d2.qfrc_inverse, atol=1e-12)
    assert np.abs(d1.qfrc_inverse).max() > 1.0  # gravity and inertia really act


def test_malformed_input_gives_config_error() -> None:
    with pytest.raises(ConfigError, match="NaN"):
        SerialChain.from_dh("bad", "modified", [[0.0, np.nan, 0.0, 0.0]])
    with pytest.raises(ConfigError, match="empty"):
        SerialChain.from_dh("bad", "standard", np.zeros((0, 4)))
    chain = get_robot("ur5e")
    with pytest.raises(ConfigError, match="link 7"):
        build_mjcf(chain, {"x": SkinUnitPose(7, np.eye(3), np.zeros(3))})
    with pytest.raises(ConfigError, match="inertials"):
        build_mjcf(chain, inertials=PANDA_INERTIALS)
    with pytest.raises(ConfigError, match="SkinUnitPose"):
        build_mjcf(chain, {"x": (1, np.eye(3), np.zeros(3))})  # type: ignore[dict-item]
    with pytest.raises(ConfigError, match="velocity_gain"):
        build_mjcf(chain, velocity_gain=-1.0)


def test_velocity_actuators_are_added_on_request() -> None:
    model = build_model(get_robot("panda"), velocity_gain=[50, 50, 40, 40, 20, 10, 5])
    assert model.nu == 7
    np.testing.assert_allclose(model.actuator_gainprm[:, 0], [50, 50, 40, 40, 20, 10, 5])
    assert build_model(get_robot("panda")).nu == 0


def test_core_imports_and_mjcf_text_work_without_mujoco() -> None:
    code = (
        "import sys; sys.modules['mujoco'] = None\n"
        "from skincal.kinematics import get_robot\n"
        "from skincal.sim.mujoco_model import build_mjcf, require_mujoco\n"
        "from skincal.errors import ConfigError\n"
        "assert '<mujoco' in build_mjcf(get_robot('panda'))\n"
        "try:\n    require_mujoco()\nexcept ConfigError as e:\n    print(e)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert "pip install 'skincal[mujoco]'" in out.stdout
    assert require_mujoco() is mujoco


# ---------------------------------------------------------------------------------------------- range
def aimed_units(targets: np.ndarray, rng: np.random.Generator) -> dict[str, SkinUnitPose]:
    """Units on link 1 (Panda at q = 0: link frame 1 = base frame shifted up 0.333 m) looking at targets."""
    out = {}
    for k, target in enumerate(targets):
        origin = rng.uniform([-2.0, -2.0, 0.2], [2.0, 2.0, 2.0])
        z = target - origin
        z /= np.linalg.norm(z)
        x = np.cross(z, rng.normal(size=3))
        x /= np.linalg.norm(x)
        R = np.column_stack([x, np.cross(z, x), z])
        out[f"ray{k}"] = SkinUnitPose(1, R, origin - [0.0, 0.0, 0.333])
    return out


def test_rangefinder_matches_closed_form_ray_casts() -> None:
    rng = np.random.default_rng(21)
    R = Rotation.random(random_state=2).as_matrix()
    scene = Scene(
        (
            Obstacle("ball", (Primitive("sphere", [0.25]),), [1.0, 0.5, 0.8]),
            Obstacle("floor", (Primitive("plane", [0.0, 0.0]),), [0.0, 0.0, -0.2]),
            Obstacle("pole", (Primitive("capsule", [0.1, 0.4]),), [-0.8, 0.9, 0.9], R),
            Obstacle("crate", (Primitive("box", [0.3, 0.2, 0.1]),), [0.3, -1.2, 0.5], R.T),
        )
    )
    centres = np.array([o.p_base_obs for o in scene.obstacles])
    targets = centres[rng.integers(0, 4, 200)] + rng.normal(scale=0.2, size=(200, 3))
    placements = aimed_units(targets, rng)
    model = build_model(get_robot("panda"), placements, scene=scene, link_radius=1e-6, board_geoms=False)
    data = mujoco.MjData(model)
    mujoco.mj_inverse(model, data)
    idx = SensorIndex.of(model, list(placements))
    mj = data.sensordata[idx.range[:, 0]]
    mj = np.where(mj < 0, np.nan, mj)
    origin = data.site_xpos[idx.site]
    direction = data.site_xmat[idx.site].reshape(-1, 3, 3)[:, :, 2]
    closed = scene.ray_distance(origin, direction)
    assert np.array_equal(np.isnan(mj), np.isnan(closed))
    assert np.isfinite(closed).sum() > 120
    np.testing.assert_allclose(mj, closed, atol=1e-9, equal_nan=True)
    # Sphere and plane in plain closed form, independent of Scene.ray_distance.
    for k, (o, d) in enumerate(zip(origin, direction, strict=True)):
        c = o - centres[0]
        b = c @ d
        disc = b * b - (c @ c - 0.25**2)
        s_sphere = -b - np.sqrt(disc) if disc >= 0 and -b - np.sqrt(disc) >= 0 else np.inf
        s_plane = (o[2] + 0.2) / -d[2] if d[2] < 0 else np.inf
        if np.isfinite(mj[k]) and min(s_sphere, s_plane) < np.inf:
            assert mj[k] <= min(s_sphere, s_plane) + 1e-9
            if np.isclose(mj[k], s_sphere) or np.isclose(mj[k], s_plane):
                assert min(abs(mj[k] - s_sphere), abs(mj[k] - s_plane)) < 1e-9


def test_rangefinder_sees_other_links_but_not_its_own() -> None:
    chain = get_robot("panda")
    capsules = link_capsules(chain)
    T = chain.link_frames(np.zeros(7))[0]
    # A unit on link 1 looking straight up (+z) along the robot's column hits link 2/3's capsules above it.
    placements = {"up": SkinUnitPose(1, np.eye(3), [0.0, 0.0, -0.2])}
    model = build_model(chain, placements, board_geoms=False)
    data = mujoco.MjData(model)
    mujoco.mj_inverse(model, data)
    reading = data.sensordata[SensorIndex.of(model, ["up"]).range[0, 0]]
    # Nearest surface above the site that is not on link 1: lowest capsule end below a radius.
    z_site = 0.333 - 0.2
    z_hits = [T[c.link, 2, 3] + (T[c.link, :3, :3] @ c.p0)[2] - c.radius for c in capsules if c.link >= 2]
    assert reading == pytest.approx(min(z for z in z_hits if z > z_site) - z_site, abs=1e-6)


def test_scene_time_table_and_mocap_playback() -> None:
    path = TimeTable([1.0, 3.0], [[2.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    np.testing.assert_allclose(path.at([0.0, 2.0, 5.0]), [[2, 0, 0], [1.5, 0, 0], [1, 0, 0]])
    scene = Scene((Obstacle("ball", (Primitive("sphere", [0.1]),), path=path), table(), wall(distance=2.5)))
    pos = scene.mocap_positions([2.0])
    assert pos.shape == (1, 3, 3)
    placements = {"fwd": SkinUnitPose(1, Rotation.from_euler("y", 90, degrees=True).as_matrix(), [0.0, 0.3, 0.1])}
    model = build_model(get_robot("panda"), placements, scene=scene, link_radius=1e-6, board_geoms=False)
    data = mujoco.MjData(model)
    idx = SensorIndex.of(model, ["fwd"])
    readings = []
    for t in (0.0, 2.0, 4.0):
        data.mocap_pos[:] = scene.mocap_positions([t])[0]
        mujoco.mj_inverse(model, data)
        readings.append(data.sensordata[idx.range[0, 0]])
    # Ray along +x at y = 0.3, z = 0.433 m: under the table top, between its legs, below the ball: the wall.
    np.testing.assert_allclose(readings, 2.5, atol=1e-9)
    scene2 = Scene(
        (
            Obstacle(
                "ball",
                (Primitive("sphere", [0.1]),),
                path=TimeTable([1.0, 3.0], [[2.0, 0.3, 0.433], [1.0, 0.3, 0.433]]),
            ),
        )
    )
    model2 = build_model(get_robot("panda"), placements, scene=scene2, link_radius=1e-6, board_geoms=False)
    data2 = mujoco.MjData(model2)
    got = []
    for t in (0.0, 2.0, 4.0):
        data2.mocap_pos[:] = scene2.mocap_positions([t])[0]
        mujoco.mj_inverse(model2, data2)
        got.append(data2.sensordata[SensorIndex.of(model2, ["fwd"]).range[0, 0]])
    np.testing.assert_allclose(got, [1.9, 1.4, 0.9], atol=1e-9)


def test_human_preset_is_seen_by_closed_form_ray() -> None:
    person = human(position=(1.0, 0.0, 0.0))
    scene = Scene((person,))
    d = scene.ray_distance([[0.0, 0.0, 1.2]], [[1.0, 0.0, 0.0]])  # torso at chest height, radius 0.15
    assert d[0] == pytest.approx(0.85, abs=1e-9)
    assert np.isnan(scene.ray_distance([[0.0, 0.0, 1.2]], [[-1.0, 0.0, 0.0]])[0])
