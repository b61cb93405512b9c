"""``skincal calibrate --follow`` and ``skincal record --live`` as a user runs them: in a real terminal
(a pseudo-terminal, output captured), in a pipe, interrupted with Ctrl-C, and with hostile input."""

from __future__ import annotations

import os
import pty
import re
import select
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import h5py
import numpy as np
import pytest

from skincal.data.hdf5 import write_dataset
from skincal.data.result import read_result
from skincal.hw.emulator import SkinEmulator
from skincal.workflows.session import simulate_dataset

_CLI = [sys.executable, "-c", "import sys; from skincal.cli import main; sys.exit(main(sys.argv[1:]))"]
MARKUP_UNIT = "[blink]su1"
"""A valid unit name that is also rich markup: the meter must show it as stored."""
_REACHED = re.compile(r"reached by every unit after ([0-9.]+) s of data \(of ([0-9.]+) s\)")


@pytest.fixture(scope="module")
def data(tmp_path_factory) -> Path:
    """Six units on panda (realistic IMUs, controller joint states, fast protocol); unit su1 renamed to
    :data:`MARKUP_UNIT`."""
    import dataclasses

    ds = simulate_dataset("panda", "paper", noise="realistic", protocol="fast", seed=1)
    rename = lambda d: {(MARKUP_UNIT if k == "su1" else k): v for k, v in d.items()}  # noqa: E731
    ds = dataclasses.replace(ds, imu=rename(ds.imu), tof=rename(ds.tof), truth=rename(ds.truth),
                             truth_sensor=rename(ds.truth_sensor))  # fmt: skip
    path = tmp_path_factory.mktemp("follow") / "fast.h5"
    write_dataset(ds, path)
    return path


def _env(columns: int = 200) -> dict[str, str]:
    env = dict(os.environ, COLUMNS=str(columns), LINES="60", TERM="xterm-256color")
    env.pop("NO_COLOR", None)
    return env


def _run_in_pty(argv: list[str], cwd: Path, interrupt_when: bytes | None = None, timeout: float = 120.0):
    """Run the CLI on a pseudo-terminal (its stdin, stdout and stderr); returns ``(exit status, output)``.
    With ``interrupt_when``, Ctrl-C is typed once that text has appeared."""
    pid, fd = pty.fork()
    if pid == 0:  # child: the terminal is ours
        os.chdir(cwd)
        os.execvpe(_CLI[0], [*_CLI, *argv], _env())
    out = b""
    deadline = time.monotonic() + timeout
    interrupted = False
    try:
        while time.monotonic() < deadline:
            ready, _, _ = select.select([fd], [], [], 0.5)
            if ready:
                try:
                    chunk = os.read(fd, 65536)
                except OSError:  # EIO: the child closed the terminal
                    break
                if not chunk:
                    break
                out += chunk
            if interrupt_when is not None and not interrupted and interrupt_when in out:
                os.write(fd, b"\x03")  # Ctrl-C typed at the terminal: SIGINT to its foreground group
                interrupted = True
        else:
            os.kill(pid, signal.SIGKILL)
            raise AssertionError(f"timed out; output so far: {out[-2000:]!r}")
    finally:
        _, status = os.waitpid(pid, 0)
        os.close(fd)
    return os.waitstatus_to_exitcode(status), out.decode("utf-8", "replace")


def test_follow_in_a_real_terminal_shows_the_meter_and_stops_at_its_target(data, tmp_path):
    out = tmp_path / "online.json"
    code, text = _run_in_pty(["calibrate", str(data), "--follow", "--speed", "20", "--target", "1mm,0.05deg",
                              "-o", str(out)], tmp_path)  # fmt: skip
    assert code == 0, text[-3000:]
    assert "\x1b[" in text  # a terminal: rich drew (and redrew) the live table
    assert "pos std mm" in text and "rot std deg" in text and "units at target (1 mm, 0.05 deg)" in text
    assert MARKUP_UNIT in text  # shown as stored, not taken as markup
    m = _REACHED.search(text)
    assert m is not None, text[-3000:]
    t_stop, t_end = float(m.group(1)), float(m.group(2))
    print(f"\nterminal session: target 1 mm / 0.05 deg reached after {t_stop:.1f} s of {t_end:.1f} s of data")
    assert t_stop < t_end - 5.0  # stopped by itself, well before the data's end
    result = read_result(out)
    assert result.method == "online" and MARKUP_UNIT in result.units and len(result.units) == 6
    assert [p.name for p in tmp_path.iterdir()] == ["online.json"]


def test_follow_in_a_pipe_prints_a_line_per_second_and_refuses_to_clobber(data, tmp_path):
    out = tmp_path / "online.json"
    argv = [*_CLI, "calibrate", str(data), "--follow", "--speed", "40", "--target", "1mm,0.05deg", "-o", str(out)]
    proc = subprocess.run(argv, capture_output=True, text=True, timeout=120, env=_env())
    assert proc.returncode == 0, proc.stderr
    assert "\x1b" not in proc.stdout  # not a terminal: plain lines
    lines = [line for line in proc.stdout.splitlines() if line.startswith("data ")]
    assert lines and all("units at target" in line for line in lines)
    assert _REACHED.search(proc.stdout) and f"wrote {out}" in proc.stdout
    before = out.read_bytes()
    again = subprocess.run(argv, capture_output=True, text=True, timeout=120)
    assert again.returncode == 2 and again.stderr.startswith("error:") and "exists" in again.stderr
    assert len(again.stderr.strip().splitlines()) == 1 and out.read_bytes() == before


def test_ctrl_c_during_follow_writes_the_result_of_the_data_so_far(data, tmp_path):
    """The first Ctrl-C stops the follow and writes what the data until then gave (a user who stops a
    real-time replay half-way keeps its result), says so in the result and on the terminal, exit 0."""
    out = tmp_path / "online.json"
    code, text = _run_in_pty(["calibrate", str(data), "--follow", "--speed", "1", "-o", str(out)], tmp_path,
                             interrupt_when=b"units at target")  # fmt: skip
    assert "Traceback" not in text and "stopped" in text and "the result of the data so far" in text
    m = re.search(r"after ([0-9.]+) s of data \(of ([0-9.]+) s\)", text)
    assert m is not None and float(m.group(1)) < float(m.group(2)) - 5.0, text[-2000:]
    result = read_result(out)
    assert result.method == "online"  # every unit there: with its pose, or with why it has none yet
    assert set(result.units) | set(result.failed_units) == {MARKUP_UNIT, "su2", "su3", "su4", "su5", "su6"}
    assert all(result.failed_units.values())
    assert code == (0 if result.units else 1), text[-2000:]  # 1: written, no unit calibrated yet (the contract)
    assert any(n.startswith("stopped by the user after") for n in result.notes), result.notes
    assert [p.name for p in tmp_path.iterdir()] == ["online.json"]  # no temporary left


def test_a_second_signal_after_the_first_aborts_and_a_double_press_is_kept(tmp_path):
    """:func:`skincal.cli.signals.stop_on_signals` inside :func:`~skincal.cli.signals.unwinds`: the first
    SIGINT sets the event (no exception), a second one within the grace time is ignored, one after it
    raises as before (the command ends 130 and writes nothing); a second one within the grace time that lands
    after the command ended is ignored too (the command's own exit code is kept)."""
    code = """
import os, signal, time
from skincal.cli.signals import GRACE_S, stop_on_signals, unwinds
with unwinds(), stop_on_signals() as stop:
    os.kill(os.getpid(), signal.SIGINT)
    time.sleep(0.3)
    assert stop.is_set() and stop.signum == signal.SIGINT
    print("first: set", flush=True)
    os.kill(os.getpid(), signal.SIGINT)
    time.sleep(0.3)
    print("double press: ignored", flush=True)
    time.sleep(GRACE_S)
    try:
        os.kill(os.getpid(), signal.SIGINT)
        time.sleep(1.0)
    except KeyboardInterrupt:
        print("later: raised", flush=True)
with unwinds():
    with stop_on_signals() as stop:
        os.kill(os.getpid(), signal.SIGINT)
        time.sleep(0.2)
    print("stopped: " + str(stop.is_set()), flush=True)
os.kill(os.getpid(), signal.SIGINT)  # a double press's second signal as the command has ended
time.sleep(0.3)
print("exit code kept", flush=True)
"""
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.split("\n")[:5] == ["first: set", "double press: ignored", "later: raised", "stopped: True",
                                            "exit code kept"], proc.stdout  # fmt: skip


@pytest.mark.adversarial
@pytest.mark.parametrize(
    ("extra", "expected"),
    [
        (["--target", "0.3"], "--target"),
        (["--target", "-1mm,0.05deg"], "must be > 0"),
        (["--target", "nanmm,0.05deg"], "not a finite number"),
        (["--target", "0.3mm,\x1b[2Jdeg"], "\\x1b"),
        (["--speed", "-1"], "--speed"),
        (["--speed", "nan"], "--speed"),
        (["--method", "om"], "online calibrator"),
        (["--robot", "panda"], "--robot is for a bag"),
    ],
)
def test_follow_refuses_bad_options_in_one_line(data, tmp_path, extra, expected):
    out = tmp_path / "r.json"
    proc = subprocess.run([*_CLI, "calibrate", str(data), "--follow", "-o", str(out), *extra], capture_output=True,
                          text=True, timeout=60)  # fmt: skip
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr.startswith("error:") and len(proc.stderr.strip().splitlines()) == 1
    assert expected in proc.stderr and "\x1b" not in proc.stderr
    assert not out.exists()


@pytest.mark.adversarial
def test_follow_refuses_wrong_files_and_its_own_input(data, tmp_path):
    text_file = tmp_path / "notes.h5"
    text_file.write_text("not a dataset\n")
    hostile = tmp_path / "hostile.h5"
    with h5py.File(data, "r") as src, h5py.File(hostile, "w") as dst:  # a unit name with a terminal escape
        for key, value in src.attrs.items():
            dst.attrs[key] = value
        for name in src:
            src.copy(src[name], dst, name=name)
        for group in ("imu", "tof", "truth"):
            if group in dst and "su2" in dst[group]:
                dst[group].move("su2", "su2\x1b[2J")
    cases = [
        ([str(tmp_path / "missing.h5"), "-o", str(tmp_path / "a.json")], None),
        ([str(text_file), "-o", str(tmp_path / "b.json")], None),
        ([str(data), "-o", str(data)], "is the input"),
        ([str(hostile), "-o", str(tmp_path / "c.json")], "\\x1b"),
        ([str(data), str(data), "-o", str(tmp_path / "d.json")], "one dataset"),
        ([str(data), "--target", "1mm,1deg", "-o", str(tmp_path / "e.json")], "--follow only"),
    ]
    before = data.read_bytes()
    for args, expected in cases:
        follow = [] if "--follow only" == expected else ["--follow"]
        proc = subprocess.run([*_CLI, "calibrate", *args, *follow], capture_output=True, text=True, timeout=60)
        assert proc.returncode == 2, (args, proc.stderr)
        assert proc.stderr.startswith("error:") and len(proc.stderr.strip().splitlines()) == 1, proc.stderr
        assert "\x1b" not in proc.stderr and "Traceback" not in proc.stderr
        if expected is not None:
            assert expected in proc.stderr, proc.stderr
    assert data.read_bytes() == before  # inputs never modified
    assert sorted(p.name for p in tmp_path.iterdir()) == ["hostile.h5", "notes.h5"]


def test_follow_a_ros_bag(tmp_path):
    """A bag is read through skincal.data.ros.read_bag (the one door) and followed as fast as possible."""
    from skincal.data.ros import write_bag

    ds = simulate_dataset("panda", "random", units=2, noise="realistic", protocol="fast", seed=4)
    bag = tmp_path / "run.mcap"
    write_bag(ds, bag, storage="mcap")
    out = tmp_path / "bag.json"
    proc = subprocess.run([*_CLI, "calibrate", str(bag), "--follow", "--speed", "0", "--robot", "panda", "-o",
                           str(out)], capture_output=True, text=True, timeout=180)  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    result = read_result(out)
    assert result.method == "online" and sorted(result.units) == sorted(ds.units)
    assert {u: r.pose.link for u, r in result.units.items()} == {u: p.link for u, p in ds.truth.items()}


def _free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def test_record_live_with_the_emulator_writes_the_result(data, tmp_path):
    """``skincal record --live`` receives the emulator's real UDP stream on loopback, shows the meter
    (a line per second in a pipe), stops by itself at a loose target and writes the recording and the
    result; the result names the recording by its hash."""
    from skincal.data.hdf5 import read_dataset
    from skincal.data.result import sha256_file

    rec, res = tmp_path / "rec.h5", tmp_path / "live.json"
    port = _free_udp_port()
    proc = subprocess.Popen([*_CLI, "record", "--port", str(port), "--out", str(rec), "--live", "--robot", "panda",
                             "--target", "5mm,1deg", "--result", str(res), "--duration", "30", "--flush-every", "0.2"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)  # fmt: skip
    try:
        line = proc.stdout.readline()
        assert "listening on" in line, proc.stderr.read() if proc.poll() is not None else line
        ds = read_dataset(data)
        emu = SkinEmulator(ds, port, rng=np.random.default_rng(5), duration_s=20.0)  # the target: at 13.1 s of data
        emu.run(max_wall_s=35)
        out, err = proc.communicate(timeout=60)
    finally:
        proc.kill()
    assert proc.returncode == 0, err
    assert "data " in out and "units at target" in out and "reached by every unit after" in out, out
    result = read_result(res)
    assert result.method == "online" and len(result.units) == 6 and result.dataset_sha256 == sha256_file(rec)
    back = read_dataset(rec)
    # the target was met by the data before the emulator's 20 s ended (on a loaded machine the calibrator
    # may catch up only after the stream, so the recording can hold all of it), and the recording has it
    reached = float(re.search(r"reached by every unit after ([0-9.]+) s", out).group(1))
    assert reached < 19.0 and back.duration >= reached - 1.0, (reached, back.duration)
    recorded = {u: f"su{i}" for u, i in emu.plan.unit_ids.items()}  # the recorder names unit id k 'su<k>'
    assert {u: r.pose.link for u, r in result.units.items()} == {recorded[u]: p.link for u, p in ds.truth.items()}


@pytest.mark.adversarial
def test_record_live_needs_a_robot_and_a_sound_target(tmp_path):
    rec = tmp_path / "rec.h5"
    for extra, expected in ((["--live"], "--robot"), (["--live", "--robot", "panda", "--target", "1mm"], "--target"),
                            (["--result", str(tmp_path / "x.json")], "--live only"),
                            (["--live", "--robot", "panda", "--result", str(rec)], "--out")):  # fmt: skip
        proc = subprocess.run([*_CLI, "record", "--port", "0", "--out", str(rec), *extra], capture_output=True,
                              text=True, timeout=60)  # fmt: skip
        assert proc.returncode == 2 and proc.stderr.startswith("error:"), proc.stderr
        assert expected in proc.stderr and len(proc.stderr.strip().splitlines()) == 1
    assert list(tmp_path.iterdir()) == []


def test_view_follow_serves_the_live_viewer_and_refuses_a_result(data, tmp_path):
    pytest.importorskip("viser")
    # --duration counts from the start, the replay included: long enough for the replay to reach its target
    proc = subprocess.run([*_CLI, "view", "--follow", str(data), "--speed", "0", "--target", "1mm,0.05deg",
                           "--duration", "8"], capture_output=True, text=True, timeout=120)  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    assert "skincal viewer: http://127.0.0.1:" in proc.stdout and "units at target" in proc.stdout
    short = subprocess.run([*_CLI, "view", "--follow", str(data), "--speed", "0", "--duration", "0.5"],
                           capture_output=True, text=True, timeout=120)  # fmt: skip
    assert short.returncode == 0 and "--duration 0.5 s over during the replay: stopped" in short.stdout
    bad = subprocess.run([*_CLI, "view", str(data), "--follow", str(data)], capture_output=True, text=True, timeout=60)
    assert bad.returncode == 2 and bad.stderr.startswith("error:") and "--follow" in bad.stderr
