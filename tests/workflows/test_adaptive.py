"""The adaptive loop in simulation (skincal.workflows.adaptive) and the next best motion on a real
streaming calibrator fed by a simulated robot (skincal.protocol.design)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from skincal.protocol.design import (
    DesignOptions,
    build_segment,
    excitable,
    motion_gain,
    next_motion,
    segment_config,
    unit_weights,
)
from skincal.protocol.limits import check_limits, position_bounds
from skincal.workflows.adaptive import SimulatedRobot, run_simulated, start_pose
from skincal.workflows.live import Target, make_calibrator
from skincal.workflows.session import make_session

TARGET = Target(3e-4, 0.05)


@pytest.fixture(scope="module")
def loop_run():
    records = []
    run = run_simulated("sawyer", "paper", None, "realistic", seed=0, max_motion_s=120.0, on_segment=records.append)
    return run, records


def test_loop_converges_in_simulation(loop_run):
    run, records = loop_run
    assert run.loop.reached
    assert [r.index for r in records] == list(range(1, len(records) + 1))  # progress once per segment
    # the motion time is the executed motion's, segment by segment
    assert run.motion_s == pytest.approx(sum(r.candidate.duration for r in records))
    assert run.motion_s == pytest.approx(run.trajectory.duration)
    assert records[-1].t_end == pytest.approx(run.motion_s)
    assert 0 < run.motion_s < 120.0
    # every unit on its true link, the TRUE error below 3x the target std
    units = run.errors["units"]
    assert len(units) == 6
    for name, e in units.items():
        assert e["link_estimated"] == e["link_true"], name
        assert e["position_error_mm"] < 3 * TARGET.position_m * 1e3, name
        assert e["rotation_error_deg"] < 3 * TARGET.rotation_deg, name
    # the result's std is what the loop stopped on
    for unit in run.result.units.values():
        assert np.all(unit.position_std_m <= TARGET.position_m)
        assert np.all(unit.rotation_std_deg <= TARGET.rotation_deg)


def test_every_chosen_segment_stays_within_the_limits(loop_run):
    run, records = loop_run
    from skincal.kinematics import get_robot

    chain = get_robot("sawyer")
    config = segment_config(chain)
    for r in records:
        traj = r.candidate.trajectory
        check_limits(chain, traj.t, traj.q, traj.qd, margin=config.limit_margin)  # raises if outside
    whole = run.trajectory
    check_limits(chain, whole.t, whole.q, whole.qd, margin=config.limit_margin)


def test_unit_errors_are_drawn_once_for_all_segments():
    """The simulated robot re-simulates the growing motion: each unit's IMU errors (the truth) never change."""
    session = make_session("panda", "paper", None, "realistic", "fast", 3, joints="controller")
    chain = session.chain
    q0 = start_pose(chain, np.random.default_rng(1))
    config = segment_config(chain)
    sim = SimulatedRobot(session, q0)
    sim.execute(build_segment(chain, config, q0, q0, 3))
    first = sim.dataset
    sim.execute(build_segment(chain, config, q0, q0, 5))
    second = sim.dataset
    assert second.joint_states.t[-1] > first.joint_states.t[-1] + 1.0
    for unit, truth in first.truth_sensor.items():
        for key, value in truth.items():
            np.testing.assert_array_equal(second.truth_sensor[unit][key], value, err_msg=f"{unit} {key}")
    bias = np.array([first.truth_sensor[u]["accel_bias"] for u in first.truth_sensor])
    assert np.abs(bias).max() > 0.05  # realistic IMUs: the bias is there, and kept


@pytest.fixture(scope="module")
def low_units():
    """A calibrator fed ~23 s of a robot whose units sit on links 2-4 only (joints 5-7 move none): joints 1-4
    excited at two poses, a move between them (every joint turns, so the links are decided)."""
    session = make_session("panda", "random", None, "realistic", "fast", 5, joints="controller", links=[2, 3, 4])
    chain = session.chain
    rng = np.random.default_rng(2)
    q0, q1 = start_pose(chain, rng), start_pose(chain, rng)
    cal = make_calibrator(chain, list(session.placements), session.gravity, TARGET)
    sim = SimulatedRobot(session, q0, cal)
    config = segment_config(chain, excite_s=2.0)
    for a, b, j in ((q0, q0, 1), (q0, q0, 3), (q0, q1, 2), (q1, q1, 1), (q1, q1, 0), (q1, q1, 3), (q1, q1, 2)):
        assert excitable(chain, config, b)[0, j]
        sim.execute(build_segment(chain, config, a, b, j))
    cal.finish()
    return chain, cal, q1, config


def test_gain_of_a_joint_that_moves_no_unit_is_zero(low_units):
    chain, cal, q, config = low_units
    status = cal.status()
    assert all(s.link in (2, 3, 4) and s.pose is not None for s in status.values())
    weights = unit_weights(status, 1.0)
    options = DesignOptions()
    rest = replace(config, excited_joints=(4,), amplitude=1e-12)  # same timeline, no motion
    still = build_segment(chain, rest, q, q, 4, check=False)
    gain_still = motion_gain(cal, still, weights, options)
    for j in (4, 5, 6):  # joints 5-7 move links 5-7: no unit
        if not excitable(chain, config, q)[0, j]:
            continue
        traj = build_segment(chain, config, q, q, j, check=False)
        assert traj.duration == pytest.approx(still.duration)
        assert motion_gain(cal, traj, weights, options) - gain_still == pytest.approx(0.0, abs=1e-9)
    # and a joint that moves them gains
    traj = build_segment(chain, config, q, q, 1, check=False)
    assert motion_gain(cal, traj, weights, options) > gain_still + 0.1


def test_a_candidate_outside_the_limits_is_never_chosen(low_units):
    chain, cal, q, config = low_units
    lower, upper = position_bounds(chain)
    # joints 2 and 4 pushed against their upper limits: their excitation (q_j grows) would leave the limits
    q_edge = q.copy()
    q_edge[1] = upper[1] - config.limit_margin - 1e-3
    q_edge[3] = upper[3] - config.limit_margin - 1e-3
    ok = excitable(chain, config, q_edge)[0]
    assert not ok[1] and not ok[3]
    rng = np.random.default_rng(0)
    for _ in range(4):
        cand = next_motion(cal, chain, q_edge, rng, config=config, options=DesignOptions(pose_candidates=3))
        if not cand.moves:
            assert cand.joint not in (1, 3)
        traj = cand.trajectory
        check_limits(chain, traj.t, traj.q, traj.qd, margin=config.limit_margin)


# ------------------------------------------------------------------ the live designer


def test_live_designer_proposes_waits_for_execution_and_records(tmp_path):
    """Against a real LiveFeed whose calibrator a simulated robot feeds: a segment is proposed, nothing is
    recorded until the robot executed it (data time and rest at its end pose), then it is recorded and the
    next one continues exactly from its planned end."""
    from skincal.workflows.adaptive import LiveDesigner
    from skincal.workflows.live import LiveFeed

    session = make_session("panda", "paper", None, "realistic", "fast", 4, joints="controller")
    chain = session.chain
    q0 = start_pose(chain, np.random.default_rng(9))
    cal = make_calibrator(chain, list(session.placements), session.gravity, TARGET)
    feed = LiveFeed(chain, TARGET, calibrator=cal)
    sim = SimulatedRobot(session, q0, cal)
    cal.add_joint_states([0.0, 0.01], np.stack([q0, q0]), np.zeros((2, chain.n_joints)))  # at rest before
    designer = LiveDesigner(chain, np.random.default_rng(0), max_motion_s=60.0)
    assert designer.tick(feed) is None and designer.pending is not None and designer.index == 1
    first = designer.pending
    np.testing.assert_allclose(first.evaluate([0.0])[0][0], q0, atol=1e-12)  # starts where the robot rests
    assert designer.tick(feed) is None and designer.pending is first  # not executed yet: waits
    sim.execute(first)
    feed.t_data = sim.trajectory.duration
    record = designer.tick(feed)
    assert record is not None and record.index == 1 and designer.pending is None
    assert record.t_end == pytest.approx(first.duration) and designer.motion_s == pytest.approx(first.duration)
    assert designer.tick(feed) is None and designer.index == 2
    second = designer.pending
    np.testing.assert_allclose(second.evaluate([0.0])[0][0], first.evaluate([first.duration])[0][0], atol=1e-12)
    sim.execute(second)
    feed.t_data = sim.trajectory.duration
    assert designer.tick(feed) is not None
    whole = designer.trajectory()
    assert whole.duration == pytest.approx(first.duration + second.duration)


# ------------------------------------------------------------------ the command


def _run(capsys, *args: str) -> tuple[int, str, str]:
    from skincal.cli import main

    code = main(["protocol", *args])
    out, err = capsys.readouterr()
    return code, out, err


def test_cli_adaptive_simulate_writes_segments_motion_and_result(tmp_path, capsys):
    from skincal.data.result import read_result
    from skincal.protocol import read_trajectory_json

    out = tmp_path / "motion.json"
    code, text, err = _run(capsys, "--robot", "panda", "--adaptive", "--simulate", "--max-motion", "8",
                           "--out", str(out), "--rate", "50")  # fmt: skip
    assert code == 0, err
    segments = sorted(tmp_path.glob("motion_[0-9][0-9][0-9].json"))
    assert len(segments) >= 1
    assert text.count("segment ") >= len(segments) and "motion_001.json" in text
    assert "true errors (simulated truth)" in text
    whole = read_trajectory_json(out)
    parts = [read_trajectory_json(p) for p in segments]
    assert whole.duration == pytest.approx(sum(p.duration for p in parts))
    result = read_result(tmp_path / "motion_result.json")
    assert result.method == "online"
    # a second run refuses to clobber the motion, its segments or the result without --force
    again = ["--robot", "panda", "--adaptive", "--simulate", "--max-motion", "8", "--out", str(out)]
    code, _, err = _run(capsys, *again)
    assert code == 2 and "exists" in err and "Traceback" not in err
    code, _, err = _run(capsys, *again[:-2], "--out", str(tmp_path / "other.csv"), "--result",
                        str(tmp_path / "motion_result.json"))  # fmt: skip
    assert code == 2 and "motion_result.json exists" in err
    code, _, err = _run(capsys, *again, "--force")
    assert code == 0, err


@pytest.mark.adversarial
@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--adaptive"], "--simulate, or --port and --record"),
        (["--adaptive", "--simulate", "--max-motion", "-1"], "--max-motion"),
        (["--adaptive", "--simulate", "--max-motion", "nan"], "--max-motion"),
        (["--adaptive", "--simulate", "--target", "0.3mm"], "--target"),
        (["--adaptive", "--simulate", "--port", "0"], "--port is for a real robot"),
        (["--adaptive", "--simulate", "--result", "r.yaml"], ".json"),
        (["--simulate"], "applies to --adaptive only"),
        (["--result", "r.json"], "applies to --adaptive only"),
        (["--noise", "real"], "applies to --adaptive only"),
        (["--max-motion", "10"], "applies to --adaptive only"),
        (["--adaptive", "--port", "0", "--record", "r.h5", "--units", "3"], "applies to --simulate only"),
        (["--adaptive", "--port", "0", "--record", "r.h5", "--bind", "0.0.0.0"], "--public"),
    ],
)
def test_cli_adaptive_bad_options_are_one_line_errors(tmp_path, capsys, monkeypatch, args, message):
    monkeypatch.chdir(tmp_path)
    code, out, err = _run(capsys, "--robot", "panda", "--out", "motion.yaml", *args)
    assert code == 2
    assert message in err and err.count("\n") == 1 and "Traceback" not in err
    assert not any(tmp_path.iterdir())  # nothing written


@pytest.mark.adversarial
def test_cli_adaptive_refuses_an_earlier_runs_segments(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "motion_001.yaml").write_text("earlier")
    code, _, err = _run(capsys, "--robot", "panda", "--out", "motion.yaml", "--adaptive", "--simulate")
    assert code == 2 and "motion_001.yaml exists" in err
    assert (tmp_path / "motion_001.yaml").read_text() == "earlier"


# ------------------------------------------------------------------ the live loop, end to end over UDP


def _window(ds, t_from: float, t_to: float):
    """The samples of ``ds`` stamped in ``[t_from, t_to)`` as a dataset (what the robot sends meanwhile)."""
    import dataclasses

    from skincal.data.dataset import ImuStream, JointStates

    j = ds.joints
    sel = (j.t >= t_from) & (j.t < t_to)
    joints = JointStates(t=j.t[sel], q=j.q[sel], qd=j.qd[sel], qdd=None if j.qdd is None else j.qdd[sel])
    imu = {}
    for unit, s in ds.imu.items():
        k = (s.t >= t_from) & (s.t < t_to)
        imu[unit] = ImuStream(t=s.t[k], accel=s.accel[k], gyro=None if s.gyro is None else s.gyro[k])
    return dataclasses.replace(ds, joints=joints, imu=imu, tof={}, segments=None)


def test_cli_adaptive_live_closes_the_loop_over_udp(tmp_path):
    """``skincal protocol --adaptive --port`` with a real UDP stream on loopback: a simulated robot streams
    its rest until the command writes segment 1, executes that file (read back from its JSON) and streams
    the motion (the real emulator); the command sees it executed, reports it, and proposes segment 2 from
    where segment 1 ended; stopped with SIGINT, it writes the executed motion, the result and the recording."""
    import signal
    import subprocess
    import sys
    import time

    from skincal.data.result import read_result
    from skincal.hw.emulator import SkinEmulator
    from skincal.protocol import build_trajectory, read_trajectory_json

    cli = [sys.executable, "-c", "import sys; from skincal.cli import main; sys.exit(main(sys.argv[1:]))"]
    out, rec, res = tmp_path / "motion.json", tmp_path / "rec.h5", tmp_path / "result.json"
    proc = subprocess.Popen([*cli, "protocol", "--robot", "panda", "--adaptive", "--port", "0", "--record", str(rec),
                             "--out", str(out), "--result", str(res), "--max-motion", "60"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)  # fmt: skip
    try:
        line = proc.stdout.readline()
        assert "listening on" in line, proc.stderr.read() if proc.poll() is not None else line
        port = int(line.strip().rsplit(":", 1)[1])
        session = make_session("panda", "paper", None, "realistic", "fast", 6, joints="controller")
        chain = session.chain
        step = session.joint_model.encoder_resolution_rad
        q = np.round(start_pose(chain, np.random.default_rng(4)) / step) * step  # on an encoder step: read exactly
        robot = SimulatedRobot(session, q)
        rest = lambda s: build_trajectory(  # noqa: E731
            chain,
            replace(segment_config(chain), excited_joints=(), rest_duration=s, static_duration=0.0),
            poses=q[None],
        )

        def stream(part) -> None:
            t_from = sum(p.duration for p in robot.parts)
            robot.execute(part)
            emu = SkinEmulator(_window(robot.dataset, t_from, robot.trajectory.duration), port,
                               rng=np.random.default_rng(len(robot.parts)))  # fmt: skip
            emu.run(max_wall_s=60)

        first, second = tmp_path / "motion_001.json", tmp_path / "motion_002.json"
        deadline = time.monotonic() + 90
        stream(rest(3.0))
        while not first.exists() and proc.poll() is None and time.monotonic() < deadline:
            stream(rest(1.0))  # the robot rests and keeps streaming while it waits
        time.sleep(0.2)
        segment = read_trajectory_json(first)
        np.testing.assert_allclose(segment.evaluate([0.0])[0][0], q, atol=1e-12)  # starts where the robot rests
        stream(segment)
        q = segment.evaluate([segment.duration])[0][0]
        while not second.exists() and proc.poll() is None and time.monotonic() < deadline:
            stream(rest(1.0))
        assert second.exists()
        time.sleep(0.5)
        proc.send_signal(signal.SIGINT)
        stdout, stderr = proc.communicate(timeout=60)
    finally:
        proc.kill()
    assert proc.returncode == 0, stderr
    assert "segment 1: " in stdout and "units at target" in stdout and "segment 2: " in stdout, stdout
    nxt = read_trajectory_json(second)
    np.testing.assert_allclose(nxt.evaluate([0.0])[0][0], q, atol=1e-12)  # continues from segment 1's end
    whole = read_trajectory_json(out)
    assert whole.duration == pytest.approx(segment.duration, abs=1e-6)  # the executed motion: segment 1
    result = read_result(res)
    assert result.method == "online" and set(result.units) <= {f"su{k}" for k in range(1, 7)}
    assert rec.exists()


def test_benchmark_reads_the_worst_unit_and_the_first_time_within_target():
    from skincal.bench.adaptive import first_within, worst

    def errors(pos, rot, right=True):
        return {"units": {"a": {"position_error_mm": 0.1, "rotation_error_deg": 0.01, "link_true": 2,
                                "link_estimated": 2},
                          "b": {"position_error_mm": pos, "rotation_error_deg": rot, "link_true": 3,
                                "link_estimated": 3 if right else 4}}}  # fmt: skip

    assert worst(errors(0.5, 0.02)) == (0.5, 0.02, True)
    assert worst({"units": {}}) == (float("inf"), float("inf"), False)
    history = [(5.0, errors(0.5, 0.01)), (9.0, errors(0.2, 0.01, right=False)), (12.0, errors(0.29, 0.06)),
               (15.0, errors(0.29, 0.04)), (20.0, errors(0.1, 0.01))]  # fmt: skip
    assert first_within(history, TARGET) == 15.0
    assert first_within(history[:4], Target(1e-4, 0.05)) is None
