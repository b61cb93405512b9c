"""3D viewer: scene geometry as numbers, ToF points, the viser server on loopback, a Chromium screenshot."""

from __future__ import annotations

import dataclasses
import os
import urllib.request
from pathlib import Path

import numpy as np
import pytest

from skincal.cli import main
from skincal.data.hdf5 import write_dataset
from skincal.data.result import CalibrationResult, UnitResult, write_result
from skincal.kinematics import get_robot
from skincal.kinematics.geometry import Capsule
from skincal.kinematics.transforms import rot_x
from skincal.protocol import build_trajectory, get_protocol
from skincal.sim.analytic import simulate
from skincal.skin.imu import get_imu_model
from skincal.skin.placement import paper_placement
from skincal.skin.pose import SkinUnitPose
from skincal.skin.tof import Plane, get_tof_model
from skincal.viz.model import (
    ELLIPSOID_FLOOR_M,
    ELLIPSOID_SIGMA,
    UNOBSERVABLE_SEMI_AXIS_M,
    Recording,
    cylinder_pose,
    ellipsoid_semi_axes,
    error_color,
    project_to_image,
    tof_points_base,
    unit_poses_base,
)

Q_VIEW = np.array([0.0, -0.4, 0.0, -2.0, 0.0, 1.8, 0.8])
"""A posture that spreads the Panda out in front of the default camera, rad."""


@pytest.fixture(scope="module")
def tof_dataset():
    """Noise-free IMUs, an ideal single-ray ToF per unit and the floor (z = 0) as the only target."""
    chain = get_robot("panda")
    rng = np.random.default_rng(11)
    config = dataclasses.replace(get_protocol("paper-sim"), n_poses=2)
    return simulate(
        chain, paper_placement(chain), build_trajectory(chain, config, rng), get_imu_model("none"), rng,
        tof_model=get_tof_model("ideal-ray"), scene=[Plane(point=np.zeros(3), normal=np.array([0.0, 0.0, 1.0]))],
    )


def _result(truth: dict[str, SkinUnitPose], shift_mm: float = 4.0) -> CalibrationResult:
    """Truth poses, one unit moved by ``shift_mm`` along x, with a per-axis std."""
    units = {}
    for k, (name, pose) in enumerate(truth.items()):
        dp = np.array([shift_mm * 1e-3, 0.0, 0.0]) if k == 2 else np.zeros(3)
        units[name] = UnitResult(
            SkinUnitPose(pose.link, pose.R_link_su, pose.p_link_su + dp), position_std_m=np.array([1e-3, 2e-3, 3e-4])
        )
    return CalibrationResult("mle", "panda", "", 0.0, units)


# ------------------------------------------------------------------------------------------ model
def test_cylinder_pose_puts_the_local_z_axis_on_the_capsule_core():
    cap = Capsule(link=2, p0=np.array([0.1, -0.2, 0.3]), p1=np.array([0.4, 0.2, 0.3]), radius=0.05)
    T, length = cylinder_pose(cap)
    assert length == pytest.approx(0.5)
    R = T[:3, :3]
    assert np.allclose(R.T @ R, np.eye(3)) and np.linalg.det(R) == pytest.approx(1.0)
    assert np.allclose(T[:3, 3] + 0.5 * length * R[:, 2], cap.p1)
    assert np.allclose(T[:3, 3] - 0.5 * length * R[:, 2], cap.p0)


def test_ellipsoid_semi_axes_scale_floor_and_unobservable():
    semi, unknown = ellipsoid_semi_axes(np.array([1e-6, 2e-3, np.nan]))
    assert semi[0] == ELLIPSOID_FLOOR_M and semi[1] == pytest.approx(ELLIPSOID_SIGMA * 2e-3)
    assert semi[2] == UNOBSERVABLE_SEMI_AXIS_M and unknown.tolist() == [False, False, True]
    assert np.all(ellipsoid_semi_axes(None)[0] == ELLIPSOID_FLOOR_M)


def test_error_color_runs_green_to_red():
    reds = [error_color(e)[0] for e in (0.0, 2.0, 5.0, 8.0, 20.0)]
    greens = [error_color(e)[1] for e in (0.0, 2.0, 5.0, 8.0, 20.0)]
    assert reds == sorted(reds) and greens == sorted(greens, reverse=True)
    assert error_color(0.0)[0] == 0 and error_color(20.0)[1] == 0


def test_unit_poses_in_the_base_frame_match_point_kinematics():
    chain = get_robot("panda")
    poses = paper_placement(chain)
    T = unit_poses_base(chain, poses, Q_VIEW)
    zeros = np.zeros((1, 7))
    motion = chain.link_motion(Q_VIEW[None], zeros, zeros)
    for name, pose in poses.items():
        x, _, _ = motion.point(pose.link, pose.p_link_su)
        assert np.allclose(T[name][:3, 3], x[0])


def test_projection_of_a_known_point():
    eye, target = np.array([2.0, 0.0, 0.0]), np.zeros(3)
    fov = np.radians(60.0)
    px, depth = project_to_image([[0.0, 0.0, 0.0], [0.0, np.tan(fov / 2) * 2.0, 0.0], [0.0, 0.0, 1.0]],
                                 eye, target, fov, 800, 600)
    assert np.allclose(px[0], [400, 300]) and depth[0] == pytest.approx(2.0)
    # Camera looks along -x with z up: base +y is screen right; a point at half the fov is at the edge.
    assert px[1, 0] == pytest.approx(400 + 300)
    assert px[2, 1] < 300


def test_tof_points_with_true_poses_lie_on_the_target(tof_dataset):
    """Readings of a single-ray ToF against the floor, mapped with the true unit poses, land on
    z = 0 (the simulator's closed-form ray cast is the independent computation); a 3 deg error in
    the poses moves them off it."""
    rec = Recording.from_dataset(tof_dataset)
    chain = tof_dataset.robot
    origins, points, names = tof_points_base(chain, tof_dataset.truth, rec, rec.t_start, rec.t_end)
    above = origins[:, 2] > 1e-3  # the protocol swings some units below the floor (range 0 there)
    assert np.count_nonzero(above) > 100 and len(set(np.array(names)[above])) >= 3
    assert np.abs(points[above, 2]).max() < 1e-4
    tilted = {n: SkinUnitPose(p.link, p.R_link_su @ rot_x(np.radians(3.0)), p.p_link_su)
              for n, p in tof_dataset.truth.items()}
    o_off, off, _ = tof_points_base(chain, tilted, rec, rec.t_start, rec.t_end)
    assert np.abs(off[o_off[:, 2] > 1e-3, 2]).max() > 5e-3


def test_recording_interpolates_joint_angles(tof_dataset):
    rec = Recording.from_dataset(tof_dataset)
    t = 0.5 * (rec.t[10] + rec.t[11])
    assert np.allclose(rec.q_at(t), 0.5 * (rec.q[10] + rec.q[11]))
    assert np.allclose(rec.q_at(rec.t_end + 5.0), rec.q[-1])


# ----------------------------------------------------------------------------------------- server
@pytest.fixture
def viewer(tof_dataset):
    pytest.importorskip("viser")
    from skincal.viz.viewer import start_viewer

    v = start_viewer(_result(tof_dataset.truth), tof_dataset.robot, truth=tof_dataset.truth, q0=Q_VIEW)
    yield v
    v.close()


def test_viewer_serves_on_loopback_and_sliders_move_the_robot(viewer):
    from skincal.viz.viewer import start_viewer  # noqa: F401  (viser present: fixture skipped otherwise)

    assert viewer.url.startswith("http://127.0.0.1:") and viewer.server.get_host() == "127.0.0.1"
    with urllib.request.urlopen(viewer.url, timeout=10) as resp:
        assert resp.status == 200 and b"<html" in resp.read(4096).lower()
    chain = viewer.chain
    T = chain.link_frames(Q_VIEW[None])[0]
    for handle, T_i in zip(viewer.link_frames, T, strict=True):
        assert np.allclose(handle.position, T_i[:3, 3], atol=1e-6)
    viewer.sliders[1].value = 30.0  # deg; the slider's callback moves every link after joint 2
    q = np.radians([s.value for s in viewer.sliders])
    assert q[1] == pytest.approx(np.radians(30.0))
    T = chain.link_frames(q[None])[0]
    for handle, T_i in zip(viewer.link_frames, T, strict=True):
        assert np.allclose(handle.position, T_i[:3, 3], atol=1e-6)


def test_viewer_playback_follows_the_recording(tof_dataset):
    pytest.importorskip("viser")
    from skincal.viz.viewer import start_viewer

    rec = Recording.from_dataset(tof_dataset)
    v = start_viewer(_result(tof_dataset.truth), tof_dataset.robot, recording=rec)
    try:
        t = rec.t_start + 0.6 * (rec.t_end - rec.t_start)
        v.time_slider.value = t
        T = v.chain.link_frames(rec.q_at(t)[None])[0]
        assert np.allclose(v.link_frames[-1].position, T[-1, :3, 3], atol=1e-6)
        assert np.allclose(np.radians([s.value for s in v.sliders]), rec.q_at(t), atol=1e-9)
    finally:
        v.close()


def test_cli_view_refuses_a_public_host_and_prints_the_url(tmp_path: Path, tof_dataset, capsys):
    pytest.importorskip("viser")
    ds_path, res_path = tmp_path / "ds.h5", tmp_path / "res.json"
    write_dataset(tof_dataset, ds_path)
    write_result(_result(tof_dataset.truth), res_path)
    assert main(["view", str(res_path), "--host", "0.0.0.0"]) == 2
    assert "not a loopback address" in capsys.readouterr().err
    assert main(["view", str(res_path), "--truth", str(ds_path), "--play", str(ds_path), "--duration", "0.2"]) == 0
    out = capsys.readouterr().out
    assert "http://127.0.0.1:" in out and "viser" not in out.lower().replace("skincal viewer", "")


def test_viewer_screenshot_in_headless_chromium(viewer, tmp_path: Path):
    """The scene renders (WebGL in software): around every link the pixels differ from the white
    background, the estimated unit boxes show blue, and empty sky stays white."""
    from skincal.viz.browser import capture_page, find_chromium
    from skincal.viz.viewer import CAMERA_FOV_DEG, CAMERA_LOOK_AT, CAMERA_POSITION, ESTIMATE_COLOR

    exe = find_chromium()
    if exe is None:
        pytest.skip("no Chromium: apt-get install chromium (Debian package) to run the screenshot test")
    import matplotlib.image as mpimg

    from skincal.kinematics.geometry import link_capsules

    width, height = 1280, 800
    chain = viewer.chain
    T = chain.link_frames(Q_VIEW[None])[0]
    mids = np.array([T[c.link, :3, :3] @ (0.5 * (c.p0 + c.p1)) + T[c.link, :3, 3] for c in link_capsules(chain)])
    cam = (CAMERA_POSITION, CAMERA_LOOK_AT, np.radians(CAMERA_FOV_DEG), width, height)
    px, _ = project_to_image(mids, *cam)
    # Software WebGL on a loaded machine may not have drawn the scene by the end of the settle time:
    # a capture where no link is drawn yet is taken again once, with a longer settle.
    for settle_s in (2.5, 8.0):
        shot = capture_page(
            viewer.url, width=width, height=height, chromium=exe, settle_s=settle_s,
            ready_js="!!document.querySelector('canvas') && document.body.innerText.includes('Joints')",
        )
        png = tmp_path / "viewer.png"
        png.write_bytes(shot.png)
        img = mpimg.imread(png)[..., :3]
        if img.shape[:2] == (height, width) and min(
            img[y - 4:y + 5, x - 4:x + 5].mean() for x, y in np.round(px).astype(int)
        ) < 0.85:
            break
    assert shot.errors == [], shot.errors
    save = os.environ.get("SKINCAL_SAVE_SCREENSHOTS")
    if save:
        Path(save).mkdir(parents=True, exist_ok=True)
        (Path(save) / "viewer.png").write_bytes(shot.png)
    assert img.shape[:2] == (height, width)
    for x, y in np.round(px).astype(int):
        window = img[y - 4:y + 5, x - 4:x + 5]
        assert window.mean() < 0.85, f"no robot drawn around pixel ({x}, {y}): mean {window.mean():.3f}"
    # Estimated unit boxes: some clearly blue pixels near each projected unit origin.
    est = np.array(ESTIMATE_COLOR) / 255.0
    units = unit_poses_base(chain, viewer.poses, Q_VIEW)
    pu, _ = project_to_image(np.array([M[:3, 3] for M in units.values()]), *cam)
    for x, y in np.round(pu).astype(int):
        window = img[y - 12:y + 13, x - 12:x + 13].reshape(-1, 3)
        blue = (window[:, 2] - window[:, 0] > 0.25) & (window[:, 2] > 0.5 * est[2])
        assert blue.any(), f"no blue unit near pixel ({x}, {y})"
    # Sky well above the robot's highest projected point stays the background.
    top = int(px[:, 1].min()) - 80
    assert top > 60 and img[20:top, 450:850].mean() > 0.97


def test_view_plays_an_avoidance_scenario_with_truth_poses(capsys):
    """``skincal view --scenario``: the run is simulated and served (its URL printed)."""
    pytest.importorskip("viser")
    assert main(["view", "--scenario", "hand", "--placement", "paper", "--duration", "0"]) == 0
    out = capsys.readouterr().out
    assert "running scenario hand" in out and "skincal viewer: http://127.0.0.1:" in out
