"""Closed-loop scenarios in MuJoCo, the `skincal avoid` command, the plot and the pose degradation."""

from __future__ import annotations

import json

import numpy as np
import pytest

from skincal.cli import main
from skincal.kinematics import panda, rotation_angle
from skincal.perception import RobotBody
from skincal.sim.scenarios import degrade_poses, get_scenario
from skincal.skin.placement import paper_placement, ring_placement
from skincal.skin.tof import Sphere
from skincal.workflows.avoid_plot import below_intervals, plot_run
from skincal.workflows.avoidance import run_scenario
from skincal.workflows.experiment import summarize
from skincal.workflows.playback import recording_from_run

pytest.importorskip("mujoco")


@pytest.fixture(scope="module")
def quiet_run():
    chain = panda()
    poses = paper_placement(chain)
    sc = get_scenario("none", chain, duration=2.0)
    return chain, run_scenario(chain, sc, poses, poses, np.random.default_rng(0))


def test_no_obstacle_tracks_the_circle_within_1mm(quiet_run):
    chain, log = quiet_run
    assert log.tracking_error.max() < 1e-3
    # the reference really is the 0.1 m circle and the flange really went round part of it
    r = np.linalg.norm(log.x - log.scenario.circle.center, axis=1)
    np.testing.assert_allclose(r, 0.1, atol=1e-3)
    assert np.linalg.norm(log.x[-1] - log.x[0]) > 0.1
    # flange position from the logged joints (independent FK) matches the logged x
    np.testing.assert_allclose(chain.flange_pose(log.q[::100])[:, :3, 3], log.x[::100], atol=1e-12)
    assert log.feasible.all() and (log.n_obstacles == 0).all()
    m = summarize(log, RobotBody.of(chain), "truth")
    assert m.contacts == 0 and m.min_clearance_m == np.inf and m.steps == 2000


def test_units_read_at_50hz_with_staggered_phases(quiet_run):
    _, log = quiet_run
    dt = np.diff(log.tof_t, axis=0)
    np.testing.assert_allclose(dt[np.isfinite(dt)], 0.02, atol=1e-9)
    assert len(set(np.round(log.tof_t[0], 6))) == len(log.units)
    assert np.isnan(log.tof_range).all()  # nobody there, and the robot's own hull is not seen


def test_plot_writes_png_and_svg(quiet_run, tmp_path):
    _, log = quiet_run
    files = plot_run(log, tmp_path / "fig.png")
    assert [f.suffix for f in files] == [".png", ".svg"] and all(f.stat().st_size > 1000 for f in files)
    assert below_intervals(np.arange(6.0), np.array([2, 0.5, 0.4, 2, np.nan, 0.1]), 1.0) == [(1.0, 2.0), (5.0, 5.0)]


def test_degrade_moves_each_unit_by_exactly_the_amount(rng):
    poses = paper_placement(panda())
    bad = degrade_poses(poses, 0.05, 5.0, rng)
    for name, pose in poses.items():
        assert np.linalg.norm(bad[name].p_link_su - pose.p_link_su) == pytest.approx(0.05)
        assert float(rotation_angle(bad[name].R_link_su, pose.R_link_su)) == pytest.approx(np.deg2rad(5.0))
        assert bad[name].link == pose.link


def test_cli_json_and_errors(capsys):
    assert main(["avoid", "--scenario", "none", "--duration", "0.3", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["scenario"] == "none" and out["contacts"] == 0 and out["max_tracking_error_m"] < 1e-3
    assert main(["avoid", "--scenario", "nowhere"]) == 2
    assert main(["avoid", "--degrade", "5cm"]) == 2
    assert "nowhere" in capsys.readouterr().err
    assert main(["avoid", "--placement", "everywhere"]) == 2
    assert "unknown placement 'everywhere'" in capsys.readouterr().err


def test_cli_rejects_a_result_of_another_skin(tmp_path, capsys):
    """A result calibrated on the six-unit paper skin names su1..su6 too, but on other links than the
    ring skin's su1..su6: using it would place every reading wrongly, so it is refused."""
    from skincal.data import CalibrationResult, UnitResult, write_result

    paper = paper_placement(panda())
    result = CalibrationResult("mle", "panda", "", 0.1, {u: UnitResult(pose=p) for u, p in paper.items()})
    path = tmp_path / "paper_result.json"
    write_result(result, path)
    before = path.read_bytes()
    assert main(["avoid", "--scenario", "none", "--duration", "0.05", "--result", str(path)]) == 2
    assert "other links than the simulated skin" in capsys.readouterr().err
    args = ["avoid", "--scenario", "none", "--duration", "0.05", "--result", str(path), "--json"]
    assert main([*args, "--placement", "paper"]) == 0
    assert "paper_result.json" in json.loads(capsys.readouterr().out)["poses"]
    assert path.read_bytes() == before


def test_recording_from_run_carries_q_readings_and_obstacle_tracks():
    chain = panda()
    poses = paper_placement(chain)
    sc = get_scenario("walk", chain, duration=0.5)
    log = run_scenario(chain, sc, poses, poses, np.random.default_rng(0))
    rec = recording_from_run(log)
    np.testing.assert_array_equal(rec.t, log.t)
    np.testing.assert_array_equal(rec.q, log.q)
    assert set(rec.tof_t) == set(log.units) and all(rec.tof_t[u].size == 25 for u in log.units)
    # every capsule of the walker is covered by sphere tracks whose centres lie on its segment, at its radius
    t = np.array([0.1, 0.37])
    prims = sc.scene.tof_primitives(t)
    assert len({name.split(".")[0] for name in rec.obstacles}) == len(prims)
    for j, prim in enumerate(prims):
        tracks = [tr for name, tr in rec.obstacles.items() if name.split(".")[0] == f"walker/{j}"]
        centres = np.stack([[np.interp(t, tr.t, tr.p_base[:, k]) for k in range(3)] for tr in tracks], axis=1).T
        ends = (prim.center, prim.center) if isinstance(prim, Sphere) else (prim.p0, prim.p1)
        a, b = (np.broadcast_to(e, (2, 3)) for e in ends)
        np.testing.assert_allclose(centres[:, 0], a, atol=1e-9)  # from one end ...
        np.testing.assert_allclose(centres[:, -1], b, atol=1e-9)  # ... to the other
        gap = np.linalg.norm(np.diff(centres, axis=1), axis=-1)
        assert np.all(gap <= float(prim.radius) + 1e-9)
        assert all(tr.radius == pytest.approx(float(prim.radius)) for tr in tracks)


@pytest.mark.slow
@pytest.mark.parametrize("name", ["arm", "hand", "walk", "fast"])
def test_dense_skin_keeps_02m_where_blind_comes_within_01m(name):
    """The scenarios discriminate: unavoided, the person comes within 0.1 m of the robot; perceived
    through the dense ring skin at its true poses, the controller keeps >= 0.2 m, never touches and
    tracks again within 2 s of the person leaving."""
    chain = panda()
    poses = ring_placement(chain)
    sc = get_scenario(name, chain)
    body = RobotBody.of(chain)
    seeing = summarize(run_scenario(chain, sc, poses, poses, np.random.default_rng(0)), body)
    blind = summarize(run_scenario(chain, sc, poses, {}, np.random.default_rng(0)), body)
    assert blind.min_clearance_m < 0.1 and blind.active_time_s == 0
    assert seeing.contacts == 0 and seeing.min_clearance_m >= 0.2 and seeing.active_time_s > 0
    assert seeing.recovery_s <= 2.0


@pytest.mark.slow
def test_cli_view_plays_a_scenario(capsys):
    pytest.importorskip("viser")
    assert main(["view", "--scenario", "fast", "--duration", "0.2"]) == 0
    assert "http://127.0.0.1:" in capsys.readouterr().out
