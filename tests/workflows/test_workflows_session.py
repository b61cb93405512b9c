"""The one session factory (workflows.session), sim.simulate's backend registry and progress reporting."""

from __future__ import annotations

import numpy as np
import pytest

from skincal.cli import main
from skincal.data.hdf5 import read_dataset
from skincal.errors import ConfigError
from skincal.kinematics import get_robot
from skincal.protocol import get_protocol
from skincal.sim import BACKENDS, Session, simulate
from skincal.workflows.session import fit_protocol, make_session, simulate_dataset


def same_streams(a, b) -> bool:
    return list(a.imu) == list(b.imu) and all(
        np.array_equal(a.imu[u].t, b.imu[u].t) and np.array_equal(a.imu[u].accel, b.imu[u].accel) for u in a.imu
    )


@pytest.mark.parametrize("robot", ["sawyer", "ur5e"])
def test_simulate_cli_runs_every_robot_with_the_default_protocol(robot, tmp_path):
    """paper-sim's 2 rad/s exceeds the Sawyer's joint 1-2 limits: the factory caps it (failed before)."""
    out = tmp_path / "s.h5"
    assert main(["simulate", "--robot", robot, "--placement", "random", "--units", "1", "-o", str(out)]) == 0
    ds = read_dataset(out)
    limit = get_robot(robot).velocity_limit
    assert np.all(np.abs(ds.joints.qd) <= limit + 1e-9)
    assert np.max(np.abs(ds.joints.qd)) > 0.5 * np.min(limit)  # it moved


def test_fit_protocol_caps_only_above_95_percent_of_the_limit():
    sawyer, panda = get_robot("sawyer"), get_robot("panda")
    capped = fit_protocol(sawyer, "paper-sim").amplitude_per_joint(sawyer.n_joints)
    original = get_protocol("paper-sim").amplitude_per_joint(sawyer.n_joints)
    assert np.all(capped <= 0.95 * sawyer.velocity_limit + 1e-12)
    over = original > 0.95 * sawyer.velocity_limit
    assert over.any() and np.allclose(capped[over], 0.95 * sawyer.velocity_limit[over])
    assert np.array_equal(capped[~over], original[~over])
    assert np.array_equal(
        fit_protocol(panda, "paper-sim").amplitude_per_joint(7), get_protocol("paper-sim").amplitude_per_joint(7)
    )


def test_every_user_gets_the_same_session_for_the_same_presets():
    from skincal.bench.mle import simulate_session
    from skincal.bench.table1 import Table1Config, set_dataset

    cli = simulate_dataset("panda", "random", 2, "none", "fast", seed=3)
    mle = simulate_session("panda", "random", 2, "none", "fast", 3)
    assert same_streams(cli, mle)
    cfg = Table1Config(sets=1, runs=1, methods=("om",), links=(3, 6), protocol=get_protocol("fast"), seed=5)
    table = set_dataset(cfg, 0)
    direct = simulate(make_session("panda", "random", None, "none", "fast", [5, 0], links=(3, 6)))
    assert same_streams(table, direct)
    assert [p.link for p in table.truth.values()] == [3, 6]


def test_backend_registry_is_one_signature_and_unknown_backends_are_refused():
    from skincal.sim.analytic import simulate as analytic

    session = make_session("panda", "random", 3, "realistic", "fast", seed=1)
    s = session
    direct = analytic(
        s.chain, s.placements, s.trajectory, s.imu_model, np.random.default_rng(9),
        joint_model=s.joint_model, clock_model=s.clock_model,
    )  # fmt: skip
    from dataclasses import replace

    via = simulate(replace(session, rng=np.random.default_rng(9)), "analytic")
    assert same_streams(direct, via) and np.array_equal(direct.joints.q, via.joints.q)
    assert set(BACKENDS) >= {"analytic", "mujoco"}
    with pytest.raises(ConfigError, match="unknown backend 'bullet'"):
        simulate(session, "bullet")
    assert isinstance(session, Session)


def test_simulators_report_progress_per_unit():
    calls = []
    ds = simulate_dataset("panda", "random", 4, "none", "fast", seed=2, progress=lambda d, t: calls.append((d, t)))
    assert calls == [(1, 4), (2, 4), (3, 4), (4, 4)]
    assert len(ds.imu) == 4


def test_mujoco_backend_through_the_registry_reports_progress():
    pytest.importorskip("mujoco")
    calls = []
    ds = simulate_dataset(
        "panda", "random", 2, "none", "fast", seed=2, backend="mujoco", progress=lambda d, t: calls.append((d, t))
    )
    assert calls == [(1, 2), (2, 2)]
    assert "backend=mujoco mode=kinematic" in ds.description


def test_core_benchmark_reports_every_step():
    from skincal.bench.core import run_core_benchmark

    calls = []
    doc = run_core_benchmark(units=(1,), protocol="fast", repeat=1, progress=lambda d, t, w: calls.append((d, t, w)))
    assert [c[0] for c in calls] == [0, 1, 2, 3, 4] and all(c[1] == 4 for c in calls)
    assert calls[3][2] == "simulating 1 unit(s)"
    assert doc["simulation"][0]["imu_samples"] > 0


def test_simulator_options_are_one_frozen_dataclass():
    """``simulate(session, backend, options=SimOptions(...))``: the ToF scene reaches the simulator (every unit
    gets a range stream); an option of the mujoco backend only is refused by the analytic one, in one line."""
    import dataclasses
    from dataclasses import replace

    from skincal.sim import SimOptions
    from skincal.sim.scene import Scene, wall

    session = replace(make_session("panda", "random", 2, "none", "fast", seed=1), rng=np.random.default_rng(3))
    plain = simulate(session)
    assert plain.tof == {}
    scene = Scene((wall(distance=1.5, yaw=np.pi / 2),)).tof_primitives()
    with_tof = simulate(replace(session, rng=np.random.default_rng(3)), options=SimOptions(scene=scene))
    assert set(with_tof.tof) == set(with_tof.units) and same_streams(plain, with_tof)
    with pytest.raises(dataclasses.FrozenInstanceError):
        SimOptions().mode = "dynamic"  # type: ignore[misc]
    for bad in (SimOptions(mode="dynamic"), SimOptions(position_gain=5.0), SimOptions(model_options={"r": 1})):
        with pytest.raises(ConfigError, match="^mode, position_gain and model_options are options of the mujoco"):
            simulate(session, "analytic", options=bad)


def test_simulate_rehearses_the_motion_skincal_protocol_wrote(tmp_path):
    """Issue 27: ``simulate --protocol motion.json`` was refused, and ``simulate``'s fast motion is not
    ``protocol``'s (collision-checked, diverse poses), so a real session could not be rehearsed. The file's
    motion is now simulated as it is: the dataset's joints follow it, its segments are the file's, and
    ``segment --protocol motion.json`` finds them at t = 0 of the rehearsal; another robot's motion is refused."""
    from skincal.protocol import read_trajectory_json

    motion, data = tmp_path / "motion.json", tmp_path / "rehearsal.h5"
    assert main(["protocol", "--robot", "panda", "--protocol", "fast", "-o", str(motion)]) == 0
    args = ["--placement", "random", "--units", "2", "--noise", "realistic", "--joints", "ideal"]
    assert main(["simulate", "--protocol", str(motion), *args, "-o", str(data)]) == 0
    traj, ds = read_trajectory_json(motion), read_dataset(data)
    assert ds.duration == pytest.approx(traj.duration, abs=2e-3)
    q, _, _ = traj.evaluate(ds.joints.t)
    np.testing.assert_allclose(ds.joints.q, q, atol=1e-9)
    np.testing.assert_allclose(ds.segments.t_start, traj.segments.t_start, atol=1e-9)
    segmented = tmp_path / "segmented.h5"
    assert main(["segment", str(data), "--protocol", str(motion), "-o", str(segmented)]) == 0
    np.testing.assert_allclose(read_dataset(segmented).segments.t_start, traj.segments.t_start, atol=1e-3)
    with pytest.raises(ConfigError, match="a motion for robot 'panda' \\(7 joints\\), not 'ur5e'"):
        make_session("ur5e", "random", 1, "none", str(motion), 0)
