"""Automatic segmentation against simulated recordings whose segments are known."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from skincal.cli import main
from skincal.data.dataset import DYNAMIC, STATIC, JointStates, Segments
from skincal.data.hdf5 import read_dataset, write_dataset
from skincal.data.segment import SegmentationConfig, segment_dataset
from skincal.errors import DatasetError
from skincal.kinematics import get_robot
from skincal.protocol import ProtocolConfig, build_trajectory
from skincal.sim.analytic import simulate
from skincal.skin.imu import get_imu_model
from skincal.skin.placement import random_placement

REST = 2.5


def _simulate(robot: str = "panda", seed: int = 1, **protocol):
    chain = get_robot(robot)
    rng = np.random.default_rng(seed)
    # static window = whole rest, whole sine periods (no stop phase): every rest and sine is known exactly
    cfg = ProtocolConfig(**{"n_poses": 3, "rest_duration": REST, "static_duration": REST, "rate_hz": 200.0,
                            "frequency": 1.0, "excite_duration": 3.0, **protocol})
    traj = build_trajectory(chain, cfg, rng)
    return simulate(chain, random_placement(chain, 2, rng), traj, get_imu_model("realistic"), rng)


def _all_true_segments(ds) -> Segments:
    """The simulator's segments plus the rest after every excitation (same pose, robot at rest
    for ``REST`` s right after each sine, known from the protocol timeline)."""
    s = ds.segments
    dyn = np.flatnonzero(s.kind == DYNAMIC)
    t0 = np.concatenate([s.t_start, s.t_end[dyn]])
    t1 = np.concatenate([s.t_end, s.t_end[dyn] + REST])
    kind = np.concatenate([s.kind, np.full(dyn.size, STATIC)])
    pose = np.concatenate([s.pose, s.pose[dyn]])
    joint = np.concatenate([s.joint, np.full(dyn.size, -1)])
    o = np.argsort(t0)
    return Segments(t0[o], t1[o], kind[o].astype(np.int8), pose[o].astype(np.int32), joint[o].astype(np.int32))


def _iou(a0, a1, b0, b1):
    inter = np.clip(np.minimum(a1, b1) - np.maximum(a0, b0), 0, None)
    return inter / (np.maximum(a1, b1) - np.minimum(a0, b0))


def _check_against_truth(found: Segments, truth: Segments) -> None:
    assert len(found) == len(truth)
    iou = _iou(found.t_start, found.t_end, truth.t_start, truth.t_end)
    assert iou.min() > 0.9, iou.min()
    np.testing.assert_array_equal(found.kind, truth.kind)
    np.testing.assert_array_equal(found.joint, truth.joint)
    np.testing.assert_array_equal(found.pose, truth.pose)


@pytest.mark.parametrize("robot,protocol", [
    ("panda", {}),
    ("ur5e", {"excited_joints": (1, 2, 4), "n_poses": 4, "move_speed": 2.5}),
])
def test_recovers_known_segments(robot, protocol):
    ds = _simulate(robot, **protocol)
    seg_ds, report = segment_dataset(replace(ds, segments=None))
    truth = _all_true_segments(ds)
    _check_against_truth(report.segments, truth)
    assert seg_ds.segments is report.segments
    n_poses = protocol.get("n_poses", 3)
    assert report.n_poses == n_poses
    # the moves between poses are rejected as multi-joint motion, nothing else is rejected
    assert [r.reason for r in report.rejected] == ["multi-joint motion"] * (n_poses - 1)
    assert all(len(r.joints) > 1 for r in report.rejected)


def test_short_motions_and_rests_are_rejected_with_reasons():
    ds = _simulate(excite_duration=0.5, frequency=2.0, n_poses=2)  # 0.5 s sines < min_dynamic_s = 1 s
    _, report = segment_dataset(ds)
    assert report.n_dynamic == 0 and report.n_static > 0
    short = [r for r in report.rejected if r.reason == "too short"]
    assert sorted(r.joints[0] for r in short) == sorted(list(range(7)) * 2)
    # no rest is long enough once trimmed by the margins: only the dynamic segments remain
    _, strict = segment_dataset(_simulate(n_poses=1), SegmentationConfig(min_static_s=REST))
    assert strict.n_static == 0 and strict.n_dynamic == 7
    assert sum("rest of" in r.detail for r in strict.rejected) == 8


def _drop_joint_samples(ds, t_from: float, t_to: float):
    js = ds.joints
    keep = (js.t < t_from) | (js.t > t_to)
    return replace(ds, segments=None, joints=JointStates(js.t[keep], js.q[keep], js.qd[keep], js.qdd[keep]))


def test_accelerometers_decide_across_joint_gaps():
    ds = _simulate(n_poses=2)
    truth = _all_true_segments(ds)
    # a gap inside a rest: the IMUs are still, the rest continues across it
    k = 2  # the rest after the first excitation
    assert truth.kind[k] == STATIC
    mid = 0.5 * (truth.t_start[k] + truth.t_end[k])
    _, report = segment_dataset(_drop_joint_samples(ds, mid - 0.3, mid + 0.3))
    assert report.gaps_bridged == 1 and report.gaps_broken == 0
    _check_against_truth(report.segments, truth)
    # a gap hiding a whole excitation: the joints are at rest in the same configuration on both
    # sides, only the accelerometers show the motion; the rests on either side stay apart
    d = 3
    assert truth.kind[d] == DYNAMIC
    gapped = _drop_joint_samples(ds, truth.t_start[d] - 0.2, truth.t_end[d] + 0.2)
    _, report = segment_dataset(gapped)
    assert report.gaps_broken == 1 and report.gaps_bridged == 0
    assert any(r.reason == "joint states missing" for r in report.rejected)
    keep = np.arange(len(truth)) != d
    t_start, t_end = truth.t_start.copy(), truth.t_end.copy()
    t_end[d - 1], t_start[d + 1] = t_start[d] - 0.2, t_end[d] + 0.2  # the rests end/start at the gap
    expect = Segments(t_start[keep], t_end[keep], truth.kind[keep], truth.pose[keep], truth.joint[keep])
    _check_against_truth(report.segments, expect)
    # blind to the IMUs (huge tolerance) the gap would be bridged: the two rests merge into one
    _, blind = segment_dataset(gapped, SegmentationConfig(accel_tolerance=1e3))
    assert blind.gaps_bridged == 1 and len(blind.segments) == len(expect) - 1


def test_no_segment_is_an_error():
    ds = _simulate(n_poses=1)
    js = ds.joints
    moving = replace(ds, joints=JointStates(js.t, js.q, js.qd + 1.0))  # every joint always "moving"
    with pytest.raises(DatasetError, match="no static or single-joint dynamic segment"):
        segment_dataset(moving)


def test_cli_segment(tmp_path, capsys):
    ds = _simulate(n_poses=2)
    write_dataset(replace(ds, segments=None), tmp_path / "rec.h5")
    assert main(["segment", str(tmp_path / "rec.h5"), "--out", str(tmp_path / "seg.h5")]) == 0
    out = capsys.readouterr().out
    assert "segments found" in out and "multi-joint motion" in out
    seg = read_dataset(tmp_path / "seg.h5").segments
    _check_against_truth(seg, _all_true_segments(ds))


def test_default_thresholds_leave_room_for_every_preset_protocol():
    """The defaults are derived from the presets: the shortest rest less both margins is above
    min_static_s, and the shortest excitation (detected ~2 x 15 ms short) above min_dynamic_s, each with
    at least 50 ms to spare."""
    from skincal.protocol import PROTOCOLS

    cfg = SegmentationConfig()
    for name, protocol in PROTOCOLS.items():
        assert protocol.rest_duration - 2 * cfg.static_margin_s - cfg.min_static_s >= 0.05, name
        assert protocol.excite_duration - 2 * cfg.smooth_s - cfg.min_dynamic_s >= 0.05, name


@pytest.mark.parametrize("protocol", ["fast", "paper-sim", "paper-real"])
def test_every_preset_protocol_segments_with_defaults(protocol):
    """A simulated recording of each preset (controller joint noise), its /segments dropped, is cut by
    the default thresholds into exactly the simulated dynamic segments (same joints and poses, ends
    within 30 ms; the return after a non-whole-period sine belongs to the motion) and static segments
    covering >= 90 % of every simulated static window; only the moves between poses are rejected."""
    from skincal.protocol import get_protocol
    from skincal.workflows.session import simulate_dataset

    ds = simulate_dataset("panda", "random", 1, "realistic", protocol, seed=0)
    sim = ds.segments
    _, report = segment_dataset(replace(ds, segments=None))
    found = report.segments
    sd, fd = np.flatnonzero(sim.kind == DYNAMIC), np.flatnonzero(found.kind == DYNAMIC)
    assert fd.size == sd.size
    np.testing.assert_array_equal(found.joint[fd], sim.joint[sd])
    np.testing.assert_array_equal(found.pose[fd], sim.pose[sd])
    np.testing.assert_allclose(found.t_start[fd], sim.t_start[sd], atol=0.03)
    assert np.all(found.t_end[fd] >= sim.t_end[sd] - 0.03)
    whole_periods = float(get_protocol(protocol).frequency_per_joint(7)[0] * get_protocol(protocol).excite_duration)
    if whole_periods.is_integer():
        np.testing.assert_allclose(found.t_end[fd], sim.t_end[sd], atol=0.03)
    fs = found.kind == STATIC
    for k in np.flatnonzero(sim.kind == STATIC):
        overlap = np.minimum(sim.t_end[k], found.t_end[fs]) - np.maximum(sim.t_start[k], found.t_start[fs])
        assert overlap.max() >= 0.9 * (sim.t_end[k] - sim.t_start[k])
    assert {r.reason for r in report.rejected} == {"multi-joint motion"}


def _recording_of(json_path, seed: int, shift_s: float):
    """A simulated recording (controller joint stream, realistic IMUs) of the motion in ``json_path``,
    its clock starting ``shift_s`` s before the motion and without /segments."""
    from skincal.protocol import read_trajectory_json

    traj = read_trajectory_json(json_path)
    chain = get_robot(traj.robot)
    rng = np.random.default_rng(seed)
    ds = simulate(chain, random_placement(chain, 1, rng), traj, get_imu_model("realistic"), rng)
    js = ds.joints
    imu = {u: replace(s, t=np.asarray(s.t) + shift_s) for u, s in ds.imu.items()}
    shifted = replace(ds, joints=replace(js, t=np.asarray(js.t) + shift_s), imu=imu, segments=None)
    return shifted, ds.segments


def test_cli_segment_takes_segments_from_the_protocol_file(tmp_path, capsys):
    """`segment --protocol motion.json`: the protocol's segments, aligned to a recording whose clock is
    7.3 s off by cross-correlation of joint positions, land within 2 ms of the true ones; a recording
    of another draw of poses (seed) is refused in one line."""
    motion = tmp_path / "motion.json"
    assert main(["protocol", "--robot", "panda", "--rate", "1000", "--seed", "4", "--out", str(motion)]) == 0
    rec, truth = _recording_of(motion, 0, 7.3)
    write_dataset(rec, tmp_path / "rec.h5")
    capsys.readouterr()
    assert main(["segment", str(tmp_path / "rec.h5"), "--protocol", str(motion), "-o", str(tmp_path / "seg.h5")]) == 0
    assert "protocol t=0 at 7.30" in capsys.readouterr().out
    seg = read_dataset(tmp_path / "seg.h5").segments
    np.testing.assert_allclose(seg.t_start, truth.t_start + 7.3, atol=2e-3)
    np.testing.assert_allclose(seg.t_end, truth.t_end + 7.3, atol=2e-3)
    np.testing.assert_array_equal(seg.joint, truth.joint)
    np.testing.assert_array_equal(seg.kind, truth.kind)
    other = tmp_path / "other.json"
    assert main(["protocol", "--robot", "panda", "--rate", "1000", "--seed", "5", "--out", str(other)]) == 0
    capsys.readouterr()
    assert main(["segment", str(tmp_path / "rec.h5"), "--protocol", str(other), "-o", str(tmp_path / "x.h5")]) == 2
    err = capsys.readouterr().err
    assert "does not follow the protocol" in err and err.count("\n") == 1
    assert not (tmp_path / "x.h5").exists()


def test_cli_import_takes_segments_from_the_protocol_file(tmp_path, capsys):
    """`import bag --protocol motion.json` with a recording of the `fast` motion that starts 2 s into it
    (the import counts time from the bag's first message): the protocol's segments, aligned, those
    before the recording dropped."""
    from skincal.data.ros import write_bag

    motion = tmp_path / "motion.json"
    assert main(["protocol", "--robot", "panda", "--rate", "1000", "--out", str(motion)]) == 0
    rec, truth = _recording_of(motion, 1, 12.5)
    js, late = rec.joints, lambda t: np.asarray(t) >= 14.5
    rec = replace(rec, joints=JointStates(js.t[late(js.t)], js.q[late(js.t)], js.qd[late(js.t)]),
                  imu={u: replace(s, t=s.t[late(s.t)], accel=s.accel[late(s.t)], gyro=s.gyro[late(s.t)])
                       for u, s in rec.imu.items()})  # fmt: skip
    write_bag(rec, tmp_path / "rec")
    capsys.readouterr()
    code = main(["import", str(tmp_path / "rec"), "--robot", "panda", "--protocol", str(motion), "-o",
                 str(tmp_path / "ds.h5")])  # fmt: skip
    assert code == 0, capsys.readouterr()
    assert "protocol t=0 at -2.00" in capsys.readouterr().out
    seg = read_dataset(tmp_path / "ds.h5").segments
    kept = truth.t_start >= 2.0
    assert 0 < kept.sum() < len(truth)
    np.testing.assert_allclose(seg.t_start, truth.t_start[kept] - 2.0, atol=5e-3)
    np.testing.assert_array_equal(seg.joint, truth.joint[kept])
