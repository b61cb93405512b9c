"""``skincal info``: summary of a dataset file, and one-line errors with exit code 2."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from skincal.cli import main
from skincal.data import DYNAMIC, STATIC, Dataset, ImuStream, JointStates, Segments, TofStream, write_dataset
from skincal.kinematics import panda
from skincal.skin.pose import SkinUnitPose


@pytest.fixture
def data_file(tmp_path: Path) -> Path:
    rng = np.random.default_rng(3)
    t = np.arange(501) * 0.004  # 250 Hz, 2.0 s
    t_imu = np.arange(200) * 0.01 + 0.002  # 100 Hz
    ds = Dataset(
        robot=panda(),
        joints=JointStates(t, rng.normal(size=(501, 7)), rng.normal(size=(501, 7))),
        imu={
            "su1": ImuStream(t_imu, rng.normal(size=(200, 3)), rng.normal(size=(200, 3))),
            "su7": ImuStream(t_imu[::4], rng.normal(size=(50, 3))),  # 25 Hz, no gyro
        },
        tof={"su7": TofStream(t_imu[::2], np.full(100, np.nan))},
        segments=Segments(
            t_start=np.array([0.0, 0.5, 1.0, 1.5]),
            t_end=np.array([0.4, 0.9, 1.4, 1.9]),
            kind=np.array([STATIC, DYNAMIC, STATIC, DYNAMIC], dtype=np.int8),
            pose=np.array([0, 0, 1, 1], dtype=np.int32),
            joint=np.array([-1, 2, -1, 6], dtype=np.int32),
        ),
        truth={"su7": SkinUnitPose.from_dh6(7, [0.0, 0.02, 0.0, 0.05, 0.0, 1.5])},
    )
    path = tmp_path / "session.h5"
    write_dataset(ds, path)
    return path


def test_info_summarises_the_dataset(data_file: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["info", str(data_file)]) == 0
    out = capsys.readouterr().out
    assert "panda (modified DH, 7 joints)" in out
    assert "2.000 s" in out
    assert "501 samples, 250 Hz, no qdd" in out
    assert "4 (2 static, 2 dynamic), 2 poses" in out
    rows = {line.split()[1]: line.split()[2:] for line in out.splitlines() if line.startswith("│ su")}
    assert rows["su1"] == ["│", "200", "│", "100", "│", "yes", "│", "no", "│", "-", "│"]
    assert rows["su7"] == ["│", "50", "│", "25", "│", "no", "│", "yes", "│", "7", "│"]


@pytest.mark.parametrize(
    ("content", "expected"),
    [(None, "session.h5: no such file"), ("not hdf5", "session.h5: not a readable HDF5 file")],
)
def test_info_errors_are_one_line_exit_2(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], content: str | None, expected: str
) -> None:
    path = tmp_path / "session.h5"
    if content is not None:
        path.write_text(content)
    assert main(["info", str(path)]) == 2
    captured = capsys.readouterr()
    assert captured.out == ""
    assert captured.err.startswith("error: ") and expected in captured.err
    assert captured.err.count("\n") == 1 and "Traceback" not in captured.err


def _console_script() -> str:
    script = shutil.which("skincal") or str(Path(sys.executable).with_name("skincal"))
    if not Path(script).exists():
        pytest.skip("skincal console script not installed")
    return script


def test_console_script(data_file: Path, tmp_path: Path) -> None:
    script = _console_script()
    ok = subprocess.run([script, "info", str(data_file)], capture_output=True, text=True, timeout=60)
    assert ok.returncode == 0, ok.stderr
    assert "panda (modified DH, 7 joints)" in ok.stdout and "su7" in ok.stdout
    cut = tmp_path / "cut.h5"
    cut.write_bytes(data_file.read_bytes()[:4000])
    bad = subprocess.run([script, "info", str(cut)], capture_output=True, text=True, timeout=60)
    assert bad.returncode == 2
    assert bad.stderr.startswith(f"error: {cut}: not a readable HDF5 file") and bad.stderr.count("\n") == 1
    assert "Traceback" not in bad.stderr


def test_info_of_a_urdf_prints_the_chain_and_what_it_leaves_out(capsys):
    """``skincal info arm.urdf`` (issue 27): the links the chain runs between, each joint with its link
    frame and limits, and the gripper joint the default chain leaves out."""
    from registry_robots import registry_urdf

    path = str(registry_urdf("z1"))
    assert main(["info", path]) == 0
    out = capsys.readouterr().out
    assert "z1_description (URDF, 6 joints)" in out and "world -> gripperStator" in out
    assert "left out" in out and "jointGripper" in out
    for k in range(1, 7):
        assert f"joint{k}" in out and f"link0{k}" in out
    assert main(["info", path, "--tip-link", "gripperMover"]) == 0
    out = capsys.readouterr().out
    assert "7 joints" in out and "left out" not in out
    assert main(["info", path, "--tip-link", "nowhere"]) == 2
    assert "'nowhere' is not a link of the URDF" in capsys.readouterr().err
