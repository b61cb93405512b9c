"""`skincal calibrate DATA --follow --watch`: the streaming calibrator followed to the data's end with the
moved-unit monitor; a unit knocked 2 deg mid-session is flagged at the knock, re-calibrated from the
data after it, and the event lands in the result (issue 16)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from skincal.cli import main


@pytest.fixture(scope="module")
def knocked(tmp_path_factory):
    from skincal.data.hdf5 import write_dataset
    from skincal.workflows.monitoring import knocked_dataset, work_session

    session = work_session("panda", "realistic", "teleop", 280.0, seed=0)
    path = tmp_path_factory.mktemp("watch") / "knock.h5"
    write_dataset(knocked_dataset(session, "su4", 240.0, 0.0, 2.0, seed=0), path)
    return path


def test_watch_flags_the_knocked_unit_and_records_the_event(knocked, tmp_path, capsys):
    from skincal.data.hdf5 import read_dataset
    from skincal.kinematics.transforms import rotation_angle

    out = tmp_path / "watch.json"
    code = main(["calibrate", str(knocked), "--follow", "--watch", "--speed", "0", "-o", str(out)])
    text = capsys.readouterr().out
    assert code == 0, text
    assert "moved: unit su4" in text and "1 unit move(s)" in text
    doc = json.loads(out.read_text())
    (event,) = doc["events"]
    assert event["unit"] == "su4" and event["link"] == 5
    assert abs(event["t_change_s"] - 240.0) < 1.0 and 0.0 <= event["t_detected_s"] - 240.0 < 5.0
    assert doc["units"]["su4"]["moved_at_s"] == [event["t_change_s"]]
    truth = read_dataset(knocked).truth_sensor["su4"]
    before, after = np.asarray(truth["knock_T_link_su_before"]), np.asarray(truth["knock_T_link_su_after"])
    est_before, est_after = np.asarray(event["T_link_su_before"]), np.asarray(event["T_link_su_after"])
    # both poses recovered: the one before from the data before, the one after from the 40 s after
    assert np.degrees(rotation_angle(est_before[:3, :3], before[:3, :3])) < 0.1
    assert np.degrees(rotation_angle(est_after[:3, :3], after[:3, :3])) < 0.3
    assert np.linalg.norm(est_before[:3, 3] - before[:3, 3]) < 1e-3
    assert np.linalg.norm(est_after[:3, 3] - after[:3, 3]) < 3e-3
    others = [u for u in doc["units"] if u != "su4"]
    assert all("moved_at_s" not in doc["units"][u] for u in others)  # the others untouched


@pytest.mark.adversarial
def test_watch_without_follow_is_a_usage_error(knocked, tmp_path, capsys):
    code = main(["calibrate", str(knocked), "--watch", "-o", str(tmp_path / "x.json")])
    err = capsys.readouterr().err.strip()
    assert code == 2 and err == "error: --watch applies to --follow only"
    assert not (tmp_path / "x.json").exists()
