"""Every calibration method runs on a dataset made by MuJoCo, physics that skincal did not write."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("mujoco")

from skincal.calib import METHODS, calibrate, evaluate  # noqa: E402
from skincal.kinematics import panda  # noqa: E402
from skincal.protocol import ProtocolConfig, build_trajectory  # noqa: E402
from skincal.sim.mujoco_backend import simulate_mujoco  # noqa: E402
from skincal.skin.imu import get_imu_model  # noqa: E402
from skincal.skin.placement import paper_placement  # noqa: E402

CONFIG = ProtocolConfig(n_poses=5, amplitude=1.5, excite_duration=1.0, rest_duration=0.6, static_duration=0.3)


@pytest.fixture(scope="module")
def mujoco_dataset():
    chain = panda()
    rng = np.random.default_rng(21)
    placements = {k: v for k, v in paper_placement(chain).items() if k in ("su2", "su5")}
    traj = build_trajectory(chain, CONFIG, rng)
    return simulate_mujoco(chain, placements, traj, get_imu_model("none"), rng)


@pytest.mark.parametrize("method", sorted(METHODS))
def test_method_runs_on_mujoco_data(method, mujoco_dataset):
    options = {} if method == "mle" else {"maxeval_static": 300, "maxeval_dynamic": 300, "maxeval_joint": 600}
    result = calibrate(mujoco_dataset, method, use_truth_links=method != "mle", seed=1, **options)
    ev = evaluate(result, mujoco_dataset)
    assert ev["units_total"] == 2 and not ev["units_failed"]
    assert ev["links_correct"] == 2
    if method == "mle":  # the default method is exact on noise-free physics it did not write
        assert ev["mean_position_error_mm"] < 0.01
        assert ev["mean_rotation_error_deg"] < 1e-3
    elif method == "om":  # the paper's method, on a small budget, is within millimetres
        assert ev["mean_position_error_mm"] < 5.0
    else:
        assert np.isfinite(ev["mean_position_error_mm"])
