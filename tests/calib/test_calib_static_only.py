"""Static-only sessions (issue 24): rotations and links from the rests, positions null, no clock
search that nothing determines, and links compared by their likelihood over every rest."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from skincal.calib import calibrate
from skincal.data.dataset import STATIC, Dataset, ImuStream, JointStates, Segments
from skincal.data.result import has_position, read_result, write_result
from skincal.kinematics import get_robot
from skincal.kinematics.transforms import rotation_angle
from skincal.sim import simulate
from skincal.skin.pose import SkinUnitPose
from skincal.workflows.session import make_session


def rests_only(ds: Dataset) -> Dataset:
    """The session with each unit's IMU samples kept only inside the static segments, no gyroscope
    (the joint stream keeps its moves: the robot moved between poses while nothing was recorded)."""
    seg = ds.segments
    rests = [(a, b) for a, b, k in zip(seg.t_start, seg.t_end, seg.kind, strict=True) if k == STATIC]
    imu = {}
    for u, s in ds.imu.items():
        keep = np.zeros(s.t.shape, dtype=bool)
        for a, b in rests:
            keep |= (s.t >= a) & (s.t <= b)
        imu[u] = ImuStream(s.t[keep], s.accel[keep], None)
    return replace(ds, imu=imu)


@pytest.fixture(scope="module")
def static_session():
    ds = simulate(make_session("panda", "random", 3, "realistic", "paper-real", 1, links=[3, 4, 5]))
    return ds, rests_only(ds)


def test_static_only_gives_links_and_rotations_and_null_positions(static_session, tmp_path):
    ds, st = static_session
    result = calibrate(st, "mle")
    assert set(result.units) == set(ds.units)
    for name, unit in result.units.items():
        assert unit.pose.link == ds.truth[name].link
        rot_err = float(np.degrees(rotation_angle(unit.pose.R_link_su, ds.truth[name].R_link_su)))
        assert rot_err < 0.5, (name, rot_err)  # realistic noise, 12 rest poses: a few hundredths of a degree
        assert not unit.observable and not has_position(unit)
        assert np.all(np.isnan(unit.position_std_m)) and np.all(np.isfinite(unit.rotation_std_deg))
        assert any("position not determined (static poses only)" in w for w in unit.warnings)
        assert any("coarse clock search skipped" in n for n in unit.notes)
        assert unit.extras["time_offset_coarse_s"] is None
    path = tmp_path / "r.json"
    write_result(result, path)
    import json

    doc = json.loads(path.read_text())
    for name in ds.units:
        entry = doc["units"][name]
        assert entry["position_m"] is None and entry["quaternion_wxyz"] is not None and entry["observable"] is False
        assert entry["link"] == ds.truth[name].link
    back = read_result(path)
    assert set(back.units) == set(ds.units) and not back.failed_units
    for name, unit in back.units.items():
        assert not has_position(unit) and unit.pose.link == ds.truth[name].link
        assert rotation_angle(unit.pose.R_link_su, result.units[name].pose.R_link_su) < 1e-9


def test_time_offset_false_switches_the_clock_search_off():
    # a switch of the method, not an accuracy: one unit on the short fast protocol (its motion turns the
    # gyroscope, so the clock search runs when it is on)
    ds = simulate(make_session("panda", "random", 1, "realistic", "fast", 1, links=[4]))
    unit = "su1"
    on = calibrate(ds, "mle", units=[unit]).units[unit]
    off = calibrate(ds, "mle", units=[unit], time_offset=False).units[unit]
    assert on.extras["time_offset_coarse_s"] is not None
    assert off.extras["time_offset_coarse_s"] is None
    assert off.imu.time_offset_s == 0.0 and off.imu.time_offset_std_s is None
    assert any("time_offset=false" in n for n in off.notes)


def _decisive_session(seed: int = 0) -> tuple[Dataset, SkinUnitPose]:
    """A static-only Panda session of a unit on link 7 whose nine rests keep joint 7 at one angle but
    for one: only that rest tells links 6 and 7 apart (link 6 with a turned unit explains the others)."""
    rng = np.random.default_rng(seed)
    chain = get_robot("panda")
    poses = rng.uniform(-1.0, 1.0, size=(9, 7)) * np.array([1.5, 1.0, 1.5, 0.5, 1.5, 1.0, 0.0])
    poses[:, 3] -= 1.8  # the elbow bent as the Panda likes it
    poses[:, 5] += 1.5
    poses[4, 6] = 1.4  # the one decisive pose
    rest_s, move_s, rate = 2.0, 1.0, 100.0
    t_j, q_j, seg = [], [], []
    t0 = 0.0
    for k, q in enumerate(poses):
        t = t0 + np.arange(0, rest_s, 1 / rate)
        t_j.append(t)
        q_j.append(np.tile(q, (t.size, 1)))
        seg.append((t0 + 0.1, t0 + rest_s - 0.1))
        t0 += rest_s
        if k + 1 < len(poses):
            s = np.arange(0, move_s, 1 / rate) / move_s
            blend = (3 * s**2 - 2 * s**3)[:, None]
            t_j.append(t0 + s * move_s)
            q_j.append(q + blend * (poses[k + 1] - q))
            t0 += move_s
    t, q = np.concatenate(t_j), np.concatenate(q_j)
    qd = np.gradient(q, t, axis=0)
    R_su = rot = np.linalg.qr(rng.normal(size=(3, 3)))[0]
    if np.linalg.det(rot) < 0:
        R_su = -rot
    pose = SkinUnitPose(7, R_su, np.array([0.02, -0.03, 0.08]))
    rest_t = np.concatenate([np.arange(a, b, 1 / rate) for a, b in seg])
    i = np.searchsorted(t, rest_t).clip(0, t.size - 1)
    T = chain.link_motion(q[i], np.zeros_like(q[i]), np.zeros_like(q[i])).T_base_link[:, 7]
    R_base_su = T[:, :3, :3] @ R_su
    g = np.array([0.0, 0.0, -9.81])
    accel = np.einsum("mji,j->mi", R_base_su, -g) + rng.normal(scale=0.01, size=(rest_t.size, 3))
    segments = Segments(
        t_start=np.array([a for a, _ in seg]), t_end=np.array([b for _, b in seg]),
        kind=np.zeros(len(seg), dtype=np.int8), pose=np.arange(len(seg), dtype=np.int32),
        joint=np.full(len(seg), -1, dtype=np.int32),
    )  # fmt: skip
    ds = Dataset(robot=chain, joints=JointStates(t, q, qd), imu={"su1": ImuStream(rest_t, accel, None)},
                 segments=segments, gravity=g)  # fmt: skip
    return ds, pose


def test_one_decisive_rest_pose_decides_the_link():
    ds, pose = _decisive_session()
    unit = calibrate(ds, "mle").units["su1"]
    assert unit.pose.link == 7
    assert float(np.degrees(rotation_angle(unit.pose.R_link_su, pose.R_link_su))) < 0.5
    assert not any("ambiguous" in w for w in unit.warnings)
    # without the decisive pose, links 6 and 7 explain the rests equally: said, never silently chosen
    keep = ~((ds.imu["su1"].t > ds.segments.t_start[4] - 0.01) & (ds.imu["su1"].t < ds.segments.t_end[4] + 0.01))
    s = ds.imu["su1"]
    blind = replace(ds, imu={"su1": ImuStream(s.t[keep], s.accel[keep], None)})
    other = calibrate(blind, "mle").units["su1"]
    assert other.pose.link in (6, 7) and any("ambiguous" in w for w in other.warnings)


def test_a_null_position_is_neither_scored_nor_exported_at_the_link_origin(static_session, tmp_path, capsys):
    """A rests-only unit's p_link_su is a placeholder (0, 0, 0): evaluate gives it no position error
    (``null``, "-" in the table) and leaves it out of the mean; every export leaves it out with a
    warning naming it (a frame at the link origin would be a silent wrong answer); a result with no
    position at all is refused in one line, exit 2."""
    from skincal.calib import evaluate
    from skincal.cli import main
    from skincal.data.hdf5 import write_dataset

    ds, st = static_session
    result = calibrate(st, "mle")
    ev = evaluate(result, ds)
    assert all(np.isnan(u.position_error_mm) for u in ev.units.values()) and ev.mean_position_error_mm is None
    assert all(u["position_error_mm"] is None for u in ev.to_dict()["units"].values())
    # one unit from the moving session beside them: it is exported, the rests-only ones are not
    moving = calibrate(ds, "mle", units=["su1"]).units["su1"]
    mixed = replace(result, units={**result.units, "su1": moving})
    data, res, mixed_path = tmp_path / "d.h5", tmp_path / "r.json", tmp_path / "m.json"
    write_dataset(st, data)
    write_result(result, res)
    write_result(mixed, mixed_path)
    capsys.readouterr()
    assert main(["evaluate", str(res), "--truth", str(data), "--allow-other-dataset"]) == 0
    assert "not determined" in capsys.readouterr().out
    for fmt in ("urdf", "tf", "csv", "yaml"):
        out = tmp_path / f"skin.{fmt}"
        assert main(["export", str(mixed_path), "-f", fmt, "-o", str(out), "--robot", "panda"]) == 0
        said = capsys.readouterr().out
        for name in ("su2", "su3"):
            assert f"unit {name} not exported (position not determined" in said
            assert name not in out.read_text()
        assert "su1" in out.read_text()
    assert main(["export", str(res), "-f", "urdf", "-o", str(tmp_path / "none.urdf"), "--robot", "panda"]) == 2
    err = capsys.readouterr().err
    assert "no unit has a position to export" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "none.urdf").exists()


def test_streaming_calibrator_answers_a_static_only_session_like_mle(static_session):
    """``calibrate --follow`` of a stream recorded in the rests only: it used to absorb no sample (its
    clock waited for motion, the rests aged out of the grid) and wrote no unit; now the stamps are
    taken as they are (said in a note), every unit gets its link and its rotation from the rests, and
    the position is null as with ``mle``."""
    from skincal.workflows.live import follow_dataset

    ds, st = static_session
    result = follow_dataset(st, speed=None, stop_at_target=False).result
    assert set(result.units) == set(ds.units), result.failed_units
    for name, unit in result.units.items():
        assert unit.pose.link == ds.truth[name].link
        err = float(np.degrees(rotation_angle(unit.pose.R_link_su, ds.truth[name].R_link_su)))
        std = float(np.linalg.norm(unit.rotation_std_deg))
        # the rests' own precision (a few thousandths of a degree), not the 0.8 deg a prior on the
        # accelerometer's misalignment left when it could pose as the rotation
        assert std < 0.05 and err < 4 * std, (name, err, unit.rotation_std_deg)
        assert not unit.observable and not has_position(unit)
        assert any("position not determined (static poses only)" in w for w in unit.warnings)
        assert any("coarse clock search skipped" in n for n in unit.notes)
