"""The protocol fitted to the IMUs' full-scale ranges (``skincal.protocol.imu_range``, issue 27 item 2)."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from skincal.calib.preprocess import screen_channels
from skincal.errors import ConfigError
from skincal.kinematics import get_robot, panda
from skincal.protocol import build_trajectory, get_protocol
from skincal.protocol.imu_range import ImuRange, build_within_imu_range, imu_bounds
from skincal.protocol.limits import fit_to_limits
from skincal.sim.analytic import simulate
from skincal.skin.imu import get_imu_model
from skincal.skin.placement import random_placement

from registry_robots import registry_urdf

REALISTIC = ImuRange.parse("realistic")  # +-2 g, +-245 deg/s (4.276 rad/s)


def _fast(chain):
    return replace(fit_to_limits(chain, get_protocol("fast")), collision_check=True, pose_selection="diverse")


def test_parse_takes_si_g_dps_and_presets():
    assert ImuRange.parse("19.6,4.28") == ImuRange(19.6, 4.28)
    r = ImuRange.parse("2g, 245dps")
    assert r.accel_mps2 == pytest.approx(2 * 9.80665) and r.gyro_rps == pytest.approx(math.radians(245))
    assert REALISTIC == ImuRange(get_imu_model("realistic").accel_range, get_imu_model("realistic").gyro_range)
    assert ImuRange.parse("inf,inf") == ImuRange()
    for bad in ("2g", "2x,3", "a,b", "-1,2", "0,1", "nan,1"):
        with pytest.raises(ConfigError, match="IMU range|--imu-range"):
            ImuRange.parse(bad)


def test_bounds_hold_every_simulated_reading_and_the_gyroscope_bound_is_exact():
    """Noise-free IMUs anywhere on the link surfaces (simulated, any orientation): every accelerometer axis
    below the link's specific-force bound at that instant, every gyroscope axis below its rate, and the
    norm of the gyroscope reading equal to the link's rate (a rate is the same at every point of a link)."""
    chain = panda()
    rng = np.random.default_rng(3)
    traj = build_trajectory(chain, replace(get_protocol("fast").for_chain(chain), n_poses=2), rng)
    placements = random_placement(chain, 14, rng)  # two per link
    ds = simulate(chain, placements, traj, get_imu_model("none"), rng)
    for name, pose in placements.items():
        s = ds.imu[name]
        b = imu_bounds(chain, traj, t=s.t)  # an ideal IMU measures at its stamps
        force = np.linalg.norm(s.accel, axis=1)
        assert np.all(force <= b.accel_mps2[:, pose.link] * (1 + 1e-9)), name
        np.testing.assert_allclose(np.linalg.norm(s.gyro, axis=1), b.rate_rps[:, pose.link], atol=1e-9)
        assert force.max() > 0.5 * b.accel_mps2[:, pose.link].max()  # the bound is not loose by far


@pytest.fixture(scope="module")
def so101():
    return get_robot(str(registry_urdf("so101")))


def test_so101_fast_fitted_to_a_realistic_imu_never_reaches_its_rails(so101):
    """SO-101's `fast` drives joints to 9 rad/s: a realistic gyroscope (4.28 rad/s) clips in percents of
    the samples. Fitted to the range, no simulated unit anywhere on the arm reaches a rail (the screen
    names none) and the motion is as long as before."""
    chain = so101
    config = _fast(chain)
    plain = build_trajectory(chain, config, np.random.default_rng(0))
    fitted_config, fitted = build_within_imu_range(chain, config, REALISTIC, np.random.default_rng(0))
    assert not imu_bounds(chain, fitted).exceeds(REALISTIC, 0.95 + 1e-9)
    assert any("gyroscope's range" in n for n in fitted_config.notes)
    assert fitted.duration == pytest.approx(plain.duration, rel=0.05)
    imu = get_imu_model("realistic")
    for traj, clips in ((plain, True), (fitted, False)):
        rng = np.random.default_rng(5)
        ds = simulate(chain, random_placement(chain, 6, rng), traj, imu, rng)
        rail = [np.mean(np.abs(s.gyro) >= imu.gyro_range) + np.mean(np.abs(s.accel) >= imu.accel_range)
                for s in ds.imu.values()]  # fmt: skip
        named = [w for u, s in ds.imu.items() for w in screen_channels(u, s.accel, s.gyro, s.t).warnings]
        if clips:
            assert max(rail) > 0.02 and any("gyroscope" in w and "saturates" in w for w in named)
        else:
            assert max(rail) == 0.0 and not any("saturates" in w for w in named), named


def test_an_accelerometer_below_one_g_is_refused():
    with pytest.raises(ConfigError, match="needs more than 1 g"):
        build_within_imu_range(panda(), _fast(panda()), ImuRange(9.0, 10.0), np.random.default_rng(0))
