"""The paper's methods (OM, OM-joint, mMM, MM): model equations against independent kinematics,
pose recovery on small noise-free datasets, link discovery, and bad input."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from skincal.calib import METHODS, calibrate, discover_link, evaluate, unit_samples
from skincal.calib.paper_model import (
    centripetal,
    dynamic_data,
    predicted_specific_force,
    second_difference,
    static_data,
    static_error,
    tangential_fd,
)
from skincal.calib.preprocess import UnitSamples
from skincal.data.dataset import ImuStream
from skincal.errors import ConfigError
from skincal.kinematics import get_robot
from skincal.kinematics.chain import GRAVITY_BASE
from skincal.protocol import build_trajectory, get_protocol
from skincal.sim.analytic import simulate
from skincal.skin.imu import get_imu_model
from skincal.skin.placement import random_placement
from skincal.skin.pose import SkinUnitPose

SMALL = dict(n_poses=4, rate_hz=200.0, excite_duration=1.5, rest_duration=1.0, static_duration=0.5)
"""A short paper-sim protocol (4 poses, 1.5 s per joint) for fast tests."""
EXACT = dict(stopval=0.0, xtol=1e-6, maxeval_static=400, maxeval_dynamic=600)
"""OM settings for a near-exact fit: no early stop on the static error, tight local tolerance."""


def small_dataset(seed: int, links: list[int], n_units: int | None = None, **protocol):
    chain = get_robot("panda")
    rng = np.random.default_rng(seed)
    cfg = replace(get_protocol("paper-sim"), **{**SMALL, **protocol})
    placements = random_placement(chain, n_units or len(links), rng, links=links)
    return simulate(chain, placements, build_trajectory(chain, cfg, rng), get_imu_model("none"), rng)


@pytest.fixture(scope="module")
def two_units():
    return small_dataset(3, [4, 7])


# ---------------------------------------------------------------------------- model equations
def test_fd_tangential_equals_analytic(rng):
    """Paper Eq. 5-6 (finite difference, h = 1e-3, projected on e_tan) == Eq. 4 (qdd z x r)."""
    n = 200
    z = rng.normal(size=(n, 3))
    z /= np.linalg.norm(z, axis=1, keepdims=True)
    r = rng.uniform(-0.5, 0.5, (n, 3))
    qd, qdd = rng.uniform(-2.5, 2.5, n), rng.uniform(-15, 15, n)
    analytic = qdd[:, None] * np.cross(z, r)
    np.testing.assert_allclose(tangential_fd(r, z, qd, qdd), analytic, atol=1e-5 * np.abs(analytic).max())
    # The unprojected second difference is the full acceleration: tangential + centripetal.
    full = analytic + np.cross(qd[:, None] * z, np.cross(qd[:, None] * z, r))
    np.testing.assert_allclose(second_difference(r, z, qd, qdd), full, atol=1e-5 * np.abs(full).max())
    np.testing.assert_allclose(centripetal(r, z, qd), full - analytic, atol=1e-12)


def _one_joint_samples(chain, link, joint, rng, n=50) -> UnitSamples:
    """Samples where only ``joint`` (0-based) moves; the accelerometer column is filled later."""
    q = rng.uniform(-1.0, 1.0, (n, chain.n_joints))
    qd = np.zeros_like(q)
    qdd = np.zeros_like(q)
    qd[:, joint] = rng.uniform(-2, 2, n)
    qdd[:, joint] = rng.uniform(-12, 12, n)
    ones = np.ones(n, dtype=int)
    return UnitSamples("su", np.arange(n) * 0.01, np.zeros((n, 3)), None, q, qd, qdd, ones, ones, joint * ones, ones)


@pytest.mark.parametrize("model", ["om", "mmm", "mm"])
def test_prediction_against_link_motion(chain, rng, model):
    """Eq. 2 with the FD tangential term equals the exact specific force of a point on link n
    (SerialChain.link_motion) when only joint d moves; mMM adds a second centripetal term, MM
    drops gravity. Checked on modified (panda) and standard DH (sawyer, ur5e) chains."""
    link = chain.n_joints - 1
    pose = SkinUnitPose.from_dh6(link, [0.7, 0.05, -1.2, 0.06, 0.03, 1.3])
    for joint in range(link - 3, link):
        samples = _one_joint_samples(chain, link, joint, rng)
        motion = chain.link_motion(samples.q, samples.qd, samples.qdd)
        x, _, a = motion.point(link, pose.p_link_su)
        R_base_su = motion.T_base_link[:, link, :3, :3] @ pose.R_link_su
        f_exact = np.einsum("nji,nj->ni", R_base_su, a - GRAVITY_BASE)
        data = dynamic_data(chain, samples, link, GRAVITY_BASE)
        f = predicted_specific_force(pose.R_link_su, pose.p_link_su, data, model)
        if model == "om":
            expected = f_exact
        else:
            c, z = chain.joint_axes(motion.T_base_link)
            w = samples.qd[:, joint, None] * z[:, joint]
            a_cen = np.cross(w, np.cross(w, x - c[:, joint]))
            extra = a_cen if model == "mmm" else GRAVITY_BASE
            expected = f_exact + np.einsum("nji,nj->ni", R_base_su, np.broadcast_to(extra, a.shape))
        np.testing.assert_allclose(f, expected, atol=1e-4)


def test_static_error_vanishes_at_truth(two_units):
    name = "su1"
    true = two_units.truth[name]
    st = static_data(two_units.robot, unit_samples(two_units, name), true.link, two_units.gravity)
    assert static_error(true.R_link_su, st) < 1e-12
    tilted = true.R_link_su @ np.array([[1, 0, 0], [0, np.cos(0.01), -np.sin(0.01)], [0, np.sin(0.01), np.cos(0.01)]])
    # Closed form: |R_x(t) a - a| = 2 sin(t / 2) |a_perp| with a_perp the part of a normal to x.
    a_perp2 = np.sum(st.accel_su[:, 1:] ** 2, axis=1)
    assert static_error(tilted, st) == pytest.approx(np.mean(4 * np.sin(0.005) ** 2 * a_perp2), rel=1e-6)


# ---------------------------------------------------------------------------- pose recovery
def _errors(result, truth):
    ev = evaluate(result, truth)
    return np.array([[u.position_error_mm, u.rotation_error_deg] for u in ev.units.values()])


def test_methods_registered():
    assert {"om", "om-joint", "mmm", "mm"} <= set(METHODS)


def test_om_near_exact_without_early_stop(two_units):
    """Noise-free, exact qdd, no stop on E_s: OM recovers the pose to < 0.2 mm and 0.001 deg
    (the residual comes from interpolating the 200 Hz joint stream to the IMU instants)."""
    r = calibrate(two_units, "om", seed=0, use_truth_links=True, use_dataset_qdd=True, **EXACT)
    err = _errors(r, two_units)
    assert np.all(err[:, 0] < 0.2) and np.all(err[:, 1] < 1e-3), err
    assert r.units["su1"].extras["dh6"].shape == (6,)


def test_om_paper_settings_and_ordering(two_units):
    """Paper settings (stop at E_s < 0.01): OM within 3 mm / 1 deg; om-joint within 2 cm / 1 deg;
    mm within 1 cm / 2 deg; mMM (double-counted centripetal term) within 5 cm / 1.5 deg; OM < mMM.
    The mMM and mm bounds are ~2-3x what they achieve here (mMM 21.8 and 7.0 mm, 0.68 and 0.16 deg;
    mm 1.3 and 3.6 mm); README's Table I run gives mMM 28 +- 15 mm (the paper: 44 +- 59 mm)."""
    res = {
        m: _errors(calibrate(two_units, m, seed=0, use_truth_links=True, maxeval_joint=1500), two_units)
        for m in ("om", "om-joint", "mmm", "mm")
    }
    assert np.all(res["om"][:, 0] < 3.0) and np.all(res["om"][:, 1] < 1.0), res["om"]
    assert np.all(res["om-joint"][:, 0] < 20.0) and np.all(res["om-joint"][:, 1] < 1.0), res["om-joint"]
    assert np.all(res["mm"][:, 0] < 10.0) and np.all(res["mm"][:, 1] < 2.0), res["mm"]
    assert np.all(res["mmm"][:, 0] < 50.0) and np.all(res["mmm"][:, 1] < 1.5), res["mmm"]
    assert res["om"][:, 0].mean() < res["mmm"][:, 0].mean()


def test_seeded_runs_repeat(two_units):
    a = calibrate(two_units, "om", seed=5, use_truth_links=True, units=["su2"], maxeval_dynamic=300)
    b = calibrate(two_units, "om", seed=5, use_truth_links=True, units=["su2"], maxeval_dynamic=300)
    np.testing.assert_array_equal(a.units["su2"].extras["dh6"], b.units["su2"].extras["dh6"])


# ---------------------------------------------------------------------------- link discovery
def test_link_discovery_on_random_placements():
    ds = small_dataset(11, [2, 3, 4, 5, 6, 7], n_poses=3)
    for name in ds.units:
        assert discover_link(unit_samples(ds, name), 7).link == ds.truth[name].link, name
    r = calibrate(ds, "om", seed=0, units=["su3"], maxeval_dynamic=300)  # no links given: discovered
    assert r.units["su3"].pose.link == ds.truth["su3"].link
    assert 0.0 <= r.units["su3"].link_confidence <= 1.0


# ---------------------------------------------------------------------------- bad input
def test_unit_without_dynamic_segments_fails_alone():
    ds = small_dataset(5, [3, 7], excited_joints=(0, 1, 2), n_poses=3)
    r = calibrate(ds, "om", seed=0, use_truth_links=True, maxeval_dynamic=300)
    assert set(r.units) == {"su1"}
    reason = r.failed_units["su2"]
    assert "no dynamic samples" in reason and "\n" not in reason


def test_units_that_never_move(two_units):
    still = {
        u: ImuStream(s.t, np.broadcast_to(s.accel[0], s.accel.shape).copy(), s.gyro) for u, s in two_units.imu.items()
    }
    r = calibrate(replace(two_units, imu=still), "om", seed=0)  # still a result: every unit with its reason
    assert r.units == {} and set(r.failed_units) == set(two_units.units)
    assert all(reason and "\n" not in reason for reason in r.failed_units.values())


def test_nan_readings_are_dropped(two_units):
    s = two_units.imu["su1"]
    accel = s.accel.copy()
    accel[::7] = np.nan
    ds = replace(two_units, imu={**two_units.imu, "su1": ImuStream(s.t, accel, s.gyro)})
    r = calibrate(ds, "om", seed=0, use_truth_links=True, units=["su1"])
    assert _errors(r, ds)[0, 0] < 3.0


def test_unknown_method_and_option(two_units):
    with pytest.raises(ConfigError, match="unknown method 'xyz'"):
        calibrate(two_units, "xyz")
    with pytest.raises(ConfigError, match="unknown option"):
        calibrate(two_units, "om", use_truth_links=True, maxevals=3)
    with pytest.raises(ConfigError, match="non-negative"):
        calibrate(two_units, "om", use_truth_links=True, xtol=-1)
