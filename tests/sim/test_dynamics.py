"""Torque-level robot (skincal.sim.dynamics): model options, inverse dynamics against Pinocchio, tracking,
gravity, torque limits, bad input."""

from __future__ import annotations

import numpy as np
import pytest

from skincal.errors import ConfigError
from skincal.kinematics.chain import GRAVITY_BASE
from skincal.kinematics.inertia import LinkInertial
from skincal.kinematics.presets import get_robot, iiwa14, panda, sawyer, ur5e
from skincal.sim.mujoco_model import (
    IIWA14_INERTIALS,
    build_mjcf,
    build_model,
    default_inertials,
    motor_name,
    published_inertials,
)
from skincal.skin.pose import SkinUnitPose

mujoco = pytest.importorskip("mujoco")

from skincal.sim.dynamics import (  # noqa: E402 - after the importorskip
    PUBLISHED_LIMITS,
    TorqueConfig,
    TorqueRobot,
    effort_limits,
    torque_model,
)

ROBOTS = ("panda", "ur5e", "iiwa14")
PANDA_Q = np.array([0.3, -0.4, 0.2, -2.0, 0.3, 1.6, 0.5])
H = 0.001


def _q_start(chain):
    return PANDA_Q if chain.name == "panda" else np.linspace(0.2, -0.3, chain.n_joints)


# --------------------------------------------------------------------------------------- the model
def test_motor_actuators_armature_damping_are_written_only_when_asked():
    chain = panda()
    plain = build_mjcf(chain)
    assert "motor" not in plain and "armature" not in plain and "damping" not in plain
    model = build_model(chain, motor_limits=PUBLISHED_LIMITS["panda"].effort, armature=0.2, damping=[0.5] * 7)
    assert model.nu == 7
    assert model.actuator(motor_name(5)).ctrlrange.tolist() == [-12.0, 12.0]
    assert model.actuator(motor_name(1)).ctrlrange.tolist() == [-87.0, 87.0]
    np.testing.assert_array_equal(model.dof_armature, 0.2)
    np.testing.assert_array_equal(model.dof_damping, 0.5)


@pytest.mark.adversarial
@pytest.mark.parametrize(
    "kwargs", [{"motor_limits": 0.0}, {"motor_limits": [1.0, 2.0]}, {"armature": -0.1}, {"damping": float("nan")}]
)
def test_bad_motor_options_are_one_line_errors(kwargs):
    with pytest.raises(ConfigError) as err:
        build_mjcf(panda(), **kwargs)
    assert "\n" not in str(err.value)


def test_published_inertials_leave_the_kinematic_models_alone():
    """UR5e and iiwa14 gain published inertials for dynamics only; build_mjcf's default stays the capsules."""
    for chain in (ur5e(), iiwa14()):
        assert default_inertials(chain) is None
        assert len(published_inertials(chain)) == chain.n_joints
    assert published_inertials(sawyer()) is None
    assert sum(li.mass for li in published_inertials(ur5e())) == pytest.approx(
        3.761 + 8.058 + 2.846 + 1.37 + 1.3 + 0.365
    )


# Drake's iiwa14 as MuJoCo Menagerie writes it: its own link frames, inertials in those frames.
DRAKE_IIWA14 = """<mujoco><compiler angle="radian" autolimits="true"/><option timestep="0.001"/><worldbody>
<body name="b1" pos="0 0 0.1575"><inertial mass="5.76" pos="0 -0.03 0.12" diaginertia="0.0333 0.033 0.0123"/>
<joint name="j1" axis="0 0 1"/>
<body name="b2" pos="0 0 0.2025" quat="0 0 1 1"><inertial mass="6.35" pos="0.0003 0.059 0.042" diaginertia="0.0305 0.0304 0.011"/>
<joint name="j2" axis="0 0 1"/>
<body name="b3" pos="0 0.2045 0" quat="0 0 1 1"><inertial mass="3.5" pos="0 0.03 0.13" diaginertia="0.025 0.0238 0.0076"/>
<joint name="j3" axis="0 0 1"/>
<body name="b4" pos="0 0 0.2155" quat="1 1 0 0"><inertial mass="3.5" pos="0 0.067 0.034" diaginertia="0.017 0.0164 0.006"/>
<joint name="j4" axis="0 0 1"/>
<body name="b5" pos="0 0.1845 0" quat="0 0 1 1"><inertial mass="3.5" pos="0.0001 0.021 0.076" diaginertia="0.01 0.0087 0.00449"/>
<joint name="j5" axis="0 0 1"/>
<body name="b6" pos="0 0 0.2155" quat="1 1 0 0"><inertial mass="1.8" pos="0 0.0006 0.0004" diaginertia="0.0049 0.0047 0.0036"/>
<joint name="j6" axis="0 0 1"/>
<body name="b7" pos="0 0.081 0" quat="0 0 1 1"><inertial mass="1.2" pos="0 0 0.02" diaginertia="0.001 0.001 0.001"/>
<joint name="j7" axis="0 0 1"/>
</body></body></body></body></body></body></body></worldbody></mujoco>"""  # noqa: E501


def test_iiwa14_inertials_in_dh_frames_give_drakes_dynamics():
    """The DH-frame inertials (moved from Drake's link frames) give Drake's model's mass matrix and
    gravity torques at random configurations: the frame change is right."""
    drake = mujoco.MjModel.from_xml_string(DRAKE_IIWA14)
    ours = build_model(iiwa14(), inertials=IIWA14_INERTIALS, board_geoms=False)
    d1, d2 = mujoco.MjData(drake), mujoco.MjData(ours)
    rng = np.random.default_rng(3)
    for _ in range(5):
        q = rng.uniform(-2.0, 2.0, 7)
        for m, d in ((drake, d1), (ours, d2)):
            d.qpos[:] = q
            mujoco.mj_forward(m, d)
        M1, M2 = np.zeros((7, 7)), np.zeros((7, 7))
        mujoco.mj_fullM(drake, d1, M1)
        mujoco.mj_fullM(ours, d2, M2)
        np.testing.assert_allclose(M2, M1, atol=1e-12)
        np.testing.assert_allclose(d2.qfrc_bias, d1.qfrc_bias, atol=1e-10)
        assert np.abs(d2.qfrc_bias).max() > 10  # gravity loads the joints: a real comparison


# --------------------------------------------------------------------------------------- inverse dynamics
def _pinocchio_model(pin, chain, inertials):
    """Pinocchio model of the chain built from its joint transforms (joint i's frame = T_parent_joint
    in the previous link frame; link frame = moved joint frame x T_joint_link), not from MuJoCo's."""
    model = pin.Model()
    model.gravity.linear = GRAVITY_BASE
    parent, before = 0, np.eye(4)
    for i in range(chain.n_joints):
        A, B = chain.T_parent_joint[i], chain.T_joint_link[i]
        P = before @ A
        jid = model.addJoint(
            parent, pin.JointModelRevoluteUnaligned(chain.axis[i]), pin.SE3(P[:3, :3], P[:3, 3]), f"j{i + 1}"
        )
        li = inertials[i].transformed(B)
        model.appendBodyToJoint(jid, pin.Inertia(li.mass, li.com, li.tensor), pin.SE3.Identity())
        parent, before = jid, B
    return model


@pytest.mark.parametrize("name", ROBOTS)
def test_inverse_dynamics_matches_pinocchio_rnea(name):
    """TorqueRobot.inverse_dynamics (MuJoCo's mj_inverse) = Pinocchio's RNEA on the same chain and
    inertials + armature qdd + damping qd, at random states."""
    pin = pytest.importorskip("pinocchio")
    chain = get_robot(name)
    robot = TorqueRobot(chain, torque_model(chain, armature=0.15, damping=0.7))
    pmodel = _pinocchio_model(pin, chain, published_inertials(chain))
    pdata = pmodel.createData()
    rng = np.random.default_rng(5)
    for _ in range(5):
        q, qd, qdd = rng.uniform(-1.5, 1.5, (3, chain.n_joints))
        ref = pin.rnea(pmodel, pdata, q, qd, qdd) + 0.15 * qdd + 0.7 * qd
        np.testing.assert_allclose(robot.inverse_dynamics(q, qd, qdd), ref, rtol=1e-9, atol=1e-9)


# --------------------------------------------------------------------------------------- tracking
def _scaled_model(chain, factor):
    """The chain's torque model with every link ``factor`` times heavier (same CoMs)."""
    inertials = [LinkInertial(li.mass * factor, li.com, li.inertia * factor) for li in published_inertials(chain)]
    return torque_model(chain, inertials=inertials)


def _track(robot, q0, amplitude, seconds=2.0):
    """Largest |q - q_kin| over a 0.5 Hz sine velocity command, q_kin the kinematic integration."""
    robot.reset(q0)
    q_kin, err = q0.copy(), 0.0
    for k in range(int(seconds / H)):
        cmd = amplitude * np.sin(np.pi * k * H)
        robot.step(cmd, H)
        q_kin = q_kin + cmd * H
        err = max(err, float(np.abs(robot.q - q_kin).max()))
    return err


@pytest.mark.parametrize("name", ROBOTS)
@pytest.mark.parametrize("mode", ["computed-torque", "impedance"])
def test_torque_robot_follows_the_kinematic_integration(name, mode):
    """A 0.5 Hz sine velocity command at half the velocity limits (within the acceleration limits): with
    an exact model q equals the kinematic integration to 1e-9 rad; with the robot 20 % heavier than the
    controller believes, to 1e-2 rad (measured over 2 s: 4.9-7.0e-3 rad, mostly the gravity error over
    the feedback stiffness); with almost no feedback (kp = 1, kd = 2) it drifts 10x further (measured >1 rad)."""
    chain = get_robot(name)
    amp = 0.5 * chain.velocity_limit
    exact = TorqueRobot(chain, config=TorqueConfig(mode=mode))
    assert _track(exact, _q_start(chain), amp) < 1e-9
    assert exact.saturation_steps == 0
    heavy = _scaled_model(chain, 1.2)
    wrong = TorqueRobot(chain, heavy, TorqueConfig(mode=mode), control_model=torque_model(chain))
    err = _track(wrong, _q_start(chain), amp)
    assert 1e-7 < err < 1e-2
    loose = TorqueRobot(chain, heavy, TorqueConfig(mode=mode, kp=1.0, kd=2.0), control_model=torque_model(chain))
    assert _track(loose, _q_start(chain), amp) > 10 * err


@pytest.mark.parametrize("name", ROBOTS)
def test_gravity_is_compensated_at_rest(name):
    """Commanded still for 2 s the robot does not move (exact model: 1e-12 rad; 20 % heavier than the
    controller believes: a steady sag below 8e-3 rad that does not grow, measured 0.6-5.4e-3 rad);
    without torques it falls."""
    chain = get_robot(name)
    q0 = _q_start(chain)
    robot = TorqueRobot(chain, q0=q0)
    for _ in range(2000):
        robot.step(np.zeros(chain.n_joints), H)
    assert np.abs(robot.q - q0).max() < 1e-12
    assert np.abs(robot.torque).max() > 1.0  # it holds the arm up: gravity is really there
    heavy = TorqueRobot(chain, _scaled_model(chain, 1.2), q0=q0, control_model=torque_model(chain))
    sag = []
    for _ in range(2):
        for _ in range(1000):
            heavy.step(np.zeros(chain.n_joints), H)
        sag.append(np.abs(heavy.q - q0).max())
    assert 1e-5 < sag[1] < 8e-3 and sag[1] <= sag[0] * 1.01 + 1e-9
    limp = TorqueRobot(chain, q0=q0)
    for _ in range(300):
        mujoco.mj_step(limp.model, limp.data)  # ctrl stays 0
    assert np.abs(limp.q - q0).max() > 0.05


@pytest.mark.parametrize("name", ROBOTS)
def test_torques_never_exceed_the_effort_limits(name):
    """A velocity step at the velocity limits with the acceleration limit lifted asks for far more torque
    than the motors have: every applied torque stays within the limits, saturation is flagged, and the
    robot still reaches the commanded velocity."""
    chain = get_robot(name)
    limit = effort_limits(chain)
    robot = TorqueRobot(chain, config=TorqueConfig(acceleration_limit=(1e4,) * chain.n_joints), q0=_q_start(chain))
    flagged, worst = False, 0.0
    cmd = 0.8 * chain.velocity_limit * np.where(np.arange(chain.n_joints) % 2, 1.0, -1.0)
    for _ in range(200):
        robot.step(cmd, H)
        worst = max(worst, float(np.max(np.abs(robot.data.actuator_force) / limit)))
        flagged |= bool(robot.saturated.any())
    assert flagged and robot.saturation_steps > 0
    assert worst <= 1.0 + 1e-12
    assert worst == pytest.approx(1.0)
    np.testing.assert_allclose(robot.qd, cmd, atol=0.05 * np.abs(cmd).max())


def test_velocity_command_is_scaled_into_the_limits_keeping_its_direction():
    chain = panda()
    robot = TorqueRobot(chain, q0=PANDA_Q)
    cmd = 3.0 * chain.velocity_limit * np.array([1, -1, 1, -1, 1, -1, 1])
    for _ in range(500):
        robot.step(cmd, H)
    ratio = robot.qd / cmd
    np.testing.assert_allclose(ratio, ratio[0], rtol=1e-9)
    assert np.abs(robot.qd).max() / chain.velocity_limit[np.argmax(np.abs(robot.qd))] == pytest.approx(1.0)


def test_control_period_of_several_physics_steps():
    """step(dt = 4 h) takes four 1 ms physics steps: the same trajectory as four step(h) calls."""
    chain = ur5e()
    a, b = TorqueRobot(chain, q0=_q_start(chain)), TorqueRobot(chain, q0=_q_start(chain))
    cmd = 0.3 * chain.velocity_limit
    for _ in range(50):
        a.step(cmd, 4 * H)
        for _ in range(4):
            b.step(cmd, H)
    assert a.time == pytest.approx(0.2)
    np.testing.assert_array_equal(a.q, b.q)


# --------------------------------------------------------------------------------------- bad input
@pytest.mark.adversarial
def test_bad_commands_and_models_are_one_line_errors():
    chain = panda()
    robot = TorqueRobot(chain)
    for bad in (np.zeros(6), [np.nan] * 7, "fast", [[0.0] * 7]):
        with pytest.raises(ConfigError):
            robot.step(bad, H)
    for dt in (0.0, 0.0015, -0.001):
        with pytest.raises(ConfigError):
            robot.step(np.zeros(7), dt)
    with pytest.raises(ConfigError, match="torque actuator"):
        TorqueRobot(chain, build_model(chain))
    with pytest.raises(ConfigError, match="torque mode"):
        TorqueConfig(mode="position")
    with pytest.raises(ConfigError, match="torque limits"):
        TorqueRobot(sawyer())
    with pytest.raises(ConfigError):
        TorqueRobot(chain, config=TorqueConfig(kp=-1.0))
    with pytest.raises(ConfigError, match="exactly the 6 joints"):
        TorqueRobot(ur5e(), torque_model(chain))


def test_sensors_are_skipped_during_steps_unless_asked_and_the_flags_restored():
    """The skin's sensors cost most of a step: TorqueRobot leaves them to the caller (sensordata stays
    untouched, the model's flags are as before), or computes them with sensors=True (an accelerometer on
    link 1 of a robot held still reads gravity, 9.81 m/s^2)."""
    chain = panda()
    placements = {"u1": SkinUnitPose(1, np.eye(3), np.array([0.05, 0.0, -0.1]))}
    model = torque_model(chain, placements)
    flags = model.opt.disableflags
    quiet = TorqueRobot(chain, model, q0=PANDA_Q)
    quiet.data.sensordata[:] = 0.0
    for _ in range(20):
        quiet.step(np.zeros(7), H)
    assert model.opt.disableflags == flags
    assert not quiet.data.sensordata.any()
    loud = TorqueRobot(chain, model, TorqueConfig(sensors=True), q0=PANDA_Q)
    for _ in range(20):
        loud.step(np.zeros(7), H)
    accel = loud.data.sensordata[model.sensor("su/u1/accel").adr[0] :][:3]
    assert np.linalg.norm(accel) == pytest.approx(9.81, rel=1e-4)
