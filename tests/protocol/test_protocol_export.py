"""Hostile protocol files for ``skincal import/segment --protocol`` and the ROS 2 bag folder of
``skincal protocol`` (found by the new-user/attacker review): every malformed definition is one
DatasetError line, never a terabyte allocation, an int32 overflow, an IndexError or a flood of numpy
warnings; a bag folder's storage file carries the folder's name, and a killed writer's temporary
folder is removed by the next write."""

from __future__ import annotations

import json
import os
import warnings
from dataclasses import replace

import numpy as np
import pytest

from skincal.errors import DatasetError
from skincal.kinematics import panda
from skincal.protocol import build_trajectory, export_trajectory, get_protocol, read_trajectory_json


@pytest.fixture(scope="module")
def doc(tmp_path_factory):
    cfg = replace(get_protocol("fast"), n_poses=2, rate_hz=100.0)
    traj = build_trajectory(panda(), cfg, np.random.default_rng(3))
    path = export_trajectory(traj, tmp_path_factory.mktemp("p") / "motion.json")
    return json.loads(path.read_text())


def _write(tmp_path, doc, change):
    bad = json.loads(json.dumps(doc))
    change(bad)
    path = tmp_path / "hostile.json"
    path.write_text(json.dumps(bad))
    return path


def test_the_unchanged_file_reads_back(doc, tmp_path):
    traj = read_trajectory_json(_write(tmp_path, doc, lambda d: None))
    assert traj.q.shape == (traj.t.size, 7) and np.all(np.isfinite(traj.q))


def _set_last_knot(d):
    d["knots"][-1] = 1e12


def _set_rate(d):
    d["config"]["rate_hz"] = 1e9


def _reverse_knots(d):
    d["knots"] = d["knots"][::-1]


def _huge_coefficient(d):
    d["coef"][0][0][0] = 1e308


def _short_segments(d):
    d["segments"]["t_start"] = d["segments"]["t_start"][:1]


def _pose_beyond_int32(d):
    d["segments"]["pose"] = [2**40] * len(d["segments"]["pose"])


def _kind_seven(d):
    d["segments"]["kind"] = [7] * len(d["segments"]["kind"])


@pytest.mark.adversarial
@pytest.mark.parametrize(
    ("change", "message"),
    [
        (_set_last_knot, "beyond what this reader evaluates"),  # was: MemoryError, 728 TiB
        (_set_rate, "beyond what this reader evaluates"),  # was: MemoryError, 696 GiB
        (_reverse_knots, "'knots' must be strictly increasing"),  # was: RuntimeWarnings, RMS inf
        (_huge_coefficient, "not a robot's"),  # was: overflow warnings from the evaluation and alignment
        (_short_segments, "/segments/t_end has shape"),  # was: IndexError in the alignment
        (_pose_beyond_int32, "malformed trajectory field"),  # was: OverflowError
        (_kind_seven, "/segments/kind must be 0"),  # was: refused only when the dataset was written
    ],
)
def test_a_hostile_protocol_file_is_one_dataset_error(doc, tmp_path, change, message):
    path = _write(tmp_path, doc, change)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a warning would be more than the one error line
        with pytest.raises(DatasetError, match=message) as info:
            read_trajectory_json(path)
    assert str(path) in str(info.value) and "\n" not in str(info.value)


@pytest.mark.adversarial
def test_a_ros2_bag_folder_is_named_after_itself_and_debris_is_removed(tmp_path):
    pytest.importorskip("rosbags")
    cfg = replace(get_protocol("fast"), n_poses=2, rate_hz=50.0)
    traj = build_trajectory(panda(), cfg, np.random.default_rng(3))
    dead = tmp_path / ".motion.999999999.0123456789ab.tmp"  # a writer killed mid-write (no such pid)
    (dead / "motion").mkdir(parents=True)
    (dead / "motion" / "motion.db3").write_bytes(b"half")
    alive = tmp_path / f".motion.{os.getpid()}.0123456789ab.tmp"  # a live writer's: left alone
    alive.mkdir()
    export_trajectory(traj, tmp_path / "motion")
    assert sorted(p.name for p in tmp_path.iterdir()) == [alive.name, "motion"]
    stored = sorted(p.name for p in (tmp_path / "motion").iterdir())
    assert stored == ["metadata.yaml", "motion.db3"]  # was: ".motion.<pid>.<hex>.tmp.db3"
    assert "tmp" not in (tmp_path / "motion" / "metadata.yaml").read_text()
    from rosbags.rosbag2 import Reader

    with Reader(tmp_path / "motion") as reader:
        assert reader.message_count == 1
