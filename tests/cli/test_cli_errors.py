"""The command line against careless and hostile input: every bad input ends as a one-line error with
exit 2 (never ``internal error``), outputs are never left half-written or as debris, workers die with
their parent, names reach the terminal escaped, and the viewer refuses cross-site connections."""

from __future__ import annotations

import os
import signal
import stat
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from skincal.cli import main
from skincal.io.atomic import atomic_path

pytestmark = pytest.mark.adversarial

LINUX = sys.platform.startswith("linux")


def _python(code: str, *args: str) -> subprocess.Popen:
    """A real Python process running ``code`` (stdout piped, line by line)."""
    return subprocess.Popen(
        [sys.executable, "-c", textwrap.dedent(code), *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def _wait_for(predicate, timeout_s: float = 30.0, poll_s: float = 0.05):
    """Poll ``predicate`` until it returns something truthy (returned) or ``timeout_s`` passes (None)."""
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        value = predicate()
        if value:
            return value
        time.sleep(poll_s)
    return None


def _children(pid: int) -> list[int]:
    """Pids of the live processes whose parent is ``pid`` (from /proc)."""
    out = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text()
        except OSError:
            continue
        fields = stat[stat.rindex(")") + 2 :].split()
        if int(fields[1]) == pid and fields[0] != "Z":
            out.append(int(entry.name))
    return out


def _alive(pid: int) -> bool:
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return False
    return stat[stat.rindex(")") + 2] != "Z"


# ------------------------------------------------------------------------------ temporaries
def test_atomic_path_removes_debris_of_dead_writers_only(tmp_path):
    target = tmp_path / "data.h5"
    done = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    dead_pid = int(done.stdout)  # a finished process: its pid is no longer alive
    assert not _alive(dead_pid)
    dead = tmp_path / f".data.h5.{dead_pid}.0123456789ab.tmp"
    live = tmp_path / f".data.h5.{os.getppid()}.0123456789ab.tmp"  # the test runner's parent is alive
    other = tmp_path / f".other.h5.{dead_pid}.0123456789ab.tmp"  # another target's: not ours to judge
    for path in (dead, live, other):
        path.write_bytes(b"x" * 1000)
    with atomic_path(target) as tmp:
        assert tmp.name.startswith(f".data.h5.{os.getpid()}.") and tmp.name.endswith(".tmp")
        tmp.write_bytes(b"new")
    assert target.read_bytes() == b"new"
    assert not dead.exists() and live.exists() and other.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([target.name, live.name, other.name])
    from skincal.io.atomic import remove_debris

    assert remove_debris(target) == []  # nothing more to remove


def test_atomic_path_refuses_a_folder_and_a_missing_folder_naming_the_target(tmp_path):
    from skincal.errors import ConfigError

    (tmp_path / "adir").mkdir()
    with pytest.raises(ConfigError, match=r"adir is a folder"), atomic_path(tmp_path / "adir") as tmp:
        tmp.write_bytes(b"x")
    with pytest.raises(ConfigError, match=r"r\.json: the folder .*nowhere does not exist"):
        with atomic_path(tmp_path / "nowhere" / "r.json") as tmp:
            tmp.write_bytes(b"x")
    assert [p.name for p in tmp_path.iterdir()] == ["adir"] and list((tmp_path / "adir").iterdir()) == []


@pytest.mark.skipif(os.name != "posix", reason="FIFOs and device nodes are POSIX")
def test_atomic_write_refuses_a_fifo_even_without_check_output(tmp_path):
    """The writer itself (not only the CLI's early check) never renames over a FIFO."""
    from skincal.errors import ConfigError
    from skincal.io.atomic import write_bytes_atomic

    fifo = tmp_path / "p.json"
    os.mkfifo(fifo)
    with pytest.raises(ConfigError, match="is a FIFO"):
        write_bytes_atomic(fifo, b"{}")
    assert stat.S_ISFIFO(os.stat(fifo).st_mode) and os.listdir(tmp_path) == ["p.json"]


SLOW_WRITER = """
    import sys, time
    from pathlib import Path
    from skincal.cli import app, main
    from skincal.io.atomic import atomic_path

    @app.command("slow-write")
    def slow_write(out: Path) -> None:
        with atomic_path(out) as tmp:
            tmp.write_bytes(b"x" * 100000)
            print("writing", tmp, flush=True)
            time.sleep(120)

    sys.exit(main(["slow-write", sys.argv[1]]))
"""


@pytest.mark.skipif(os.name != "posix", reason="POSIX signals")
@pytest.mark.parametrize(
    ("sig", "code", "message"), [(signal.SIGTERM, 143, "error: terminated"), (signal.SIGINT, 130, "error: interrupted")]
)
def test_a_signal_during_a_write_leaves_no_temporary(sig, code, message, tmp_path):
    out = tmp_path / "out.bin"
    proc = _python(SLOW_WRITER, str(out))
    try:
        line = proc.stdout.readline()
        assert line.startswith("writing"), proc.stderr.read()
        tmp = Path(line.split(maxsplit=1)[1].strip())
        assert tmp.exists()
        proc.send_signal(sig)
        _, err = proc.communicate(timeout=30)
    finally:
        proc.kill()
    assert proc.returncode == code  # Ctrl-C used to exit 0
    assert err.strip() == message
    assert not tmp.exists() and not out.exists()
    assert list(tmp_path.iterdir()) == []


FINALIZER_WRITER = """
    import sys, time, weakref
    from pathlib import Path
    from skincal.cli import app, main
    from skincal.io.atomic import atomic_path

    class Handle:
        pass

    def finalizer(_ref):  # h5py's object tracking runs such callbacks all the time while writing
        print("in finalizer", flush=True)
        time.sleep(20)

    @app.command("finalizer-write")
    def finalizer_write(out: Path) -> None:
        with atomic_path(out) as tmp:
            tmp.write_bytes(b"x" * 1000)
            handle = Handle()
            keep = weakref.ref(handle, finalizer)
            del handle  # the finalizer runs (and sleeps): the signal lands inside it
            time.sleep(3)

    sys.exit(main(["finalizer-write", sys.argv[1]]))
"""


@pytest.mark.skipif(os.name != "posix", reason="POSIX signals")
def test_sigterm_landing_in_a_finalizer_still_terminates(tmp_path):
    """Python ignores an exception raised in a weakref callback ("Exception ignored ..."): the
    signal would be lost and the command would finish as if never told to stop."""
    out = tmp_path / "out.bin"
    proc = _python(FINALIZER_WRITER, str(out))
    try:
        assert proc.stdout.readline().strip() == "in finalizer", proc.stderr.read()
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=60)
    finally:
        proc.kill()
    assert proc.returncode == 143, err
    assert err.strip().splitlines()[-1] == "error: terminated"
    assert list(tmp_path.iterdir()) == []


OTHER_THREAD_WRITER = """
    import signal, sys, threading, time
    from pathlib import Path
    from skincal.cli import app, main
    from skincal.io.atomic import atomic_path

    def elsewhere():  # the signal handled by another thread while the main one is already in sleep()
        time.sleep(0.5)
        signal.pthread_kill(threading.get_ident(), signal.SIGTERM)

    @app.command("slow-write")
    def slow_write(out: Path) -> None:
        with atomic_path(out) as tmp:
            tmp.write_bytes(b"x" * 1000)
            threading.Thread(target=elsewhere, daemon=True).start()
            print("writing", flush=True)
            time.sleep(120)

    sys.exit(main(["slow-write", sys.argv[1]]))
"""


@pytest.mark.skipif(not LINUX, reason="POSIX threads and signals")
def test_a_signal_that_lands_outside_the_main_threads_blocking_call_still_ends_it(tmp_path):
    """The C-level handler runs in another thread (or just before the main thread enters ``sleep``):
    Python's handler would wait for the call to return, 120 s; the watcher breaks the call."""
    proc = _python(OTHER_THREAD_WRITER, str(tmp_path / "out.bin"))
    try:
        assert proc.stdout.readline().strip() == "writing", proc.stderr.read()
        start = time.monotonic()
        _, err = proc.communicate(timeout=30)
    finally:
        proc.kill()
    assert proc.returncode == 143 and err.strip() == "error: terminated", err
    assert time.monotonic() - start < 10
    assert list(tmp_path.iterdir()) == []


SLOW_CLEANUP_WRITER = """
    import sys, time
    from pathlib import Path
    from skincal.cli import app, main
    from skincal.io.atomic import atomic_path

    @app.command("slow-write")
    def slow_write(out: Path) -> None:
        with atomic_path(out) as tmp:
            tmp.write_bytes(b"x" * 1000)
            try:
                print("writing", flush=True)
                time.sleep(120)
            finally:  # a clean-up that takes a moment (an HDF5 file closing)
                print("cleaning", flush=True)
                time.sleep(1.0)

    sys.exit(main(["slow-write", sys.argv[1]]))
"""


@pytest.mark.skipif(os.name != "posix", reason="POSIX signals")
@pytest.mark.parametrize(("first", "second", "code", "message"), [
    (signal.SIGTERM, signal.SIGINT, 143, "error: terminated"),
    (signal.SIGINT, signal.SIGTERM, 130, "error: interrupted"),
    (signal.SIGTERM, signal.SIGTERM, 143, "error: terminated"),
])
def test_a_second_signal_does_not_break_the_first_ones_clean_up(first, second, code, message, tmp_path):
    """SIGTERM then Ctrl-C 20 ms later ended by the Ctrl-C, raised inside the clean-up (a traceback, or
    its temporary left): the first signal wins."""
    proc = _python(SLOW_CLEANUP_WRITER, str(tmp_path / "out.bin"))
    try:
        assert proc.stdout.readline().strip() == "writing", proc.stderr.read()
        proc.send_signal(first)
        assert proc.stdout.readline().strip() == "cleaning"
        proc.send_signal(second)
        _, err = proc.communicate(timeout=30)
    finally:
        proc.kill()
    assert proc.returncode == code and err.strip() == message, err
    assert list(tmp_path.iterdir()) == []


ASYNC_THEN_WRITE = """
    import asyncio, signal, sys, time
    from pathlib import Path
    from skincal.cli import app, main
    from skincal.cli.signals import run_async
    from skincal.io.atomic import atomic_path

    async def session():  # as record does: the loop handles SIGTERM while it runs
        asyncio.get_running_loop().add_signal_handler(signal.SIGTERM, lambda: None)

    @app.command("async-write")
    def async_write(out: Path) -> None:
        run_async(session())  # the loop's close left SIGTERM at its default
        with atomic_path(out) as tmp:
            tmp.write_bytes(b"x" * 1000)
            print("writing", flush=True)
            time.sleep(120)

    sys.exit(main(["async-write", sys.argv[1]]))
"""


@pytest.mark.skipif(os.name != "posix", reason="POSIX signals")
def test_sigterm_after_an_event_loop_still_unwinds(tmp_path):
    """``asyncio.run`` with ``add_signal_handler`` leaves SIGTERM at its default when the loop closes:
    a SIGTERM during the work after the loop (record --live's calibration and result) killed the
    command without clean-up, its temporary left."""
    proc = _python(ASYNC_THEN_WRITE, str(tmp_path / "out.bin"))
    try:
        assert proc.stdout.readline().strip() == "writing", proc.stderr.read()
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=30)
    finally:
        proc.kill()
    assert proc.returncode == 143 and err.strip() == "error: terminated", err
    assert list(tmp_path.iterdir()) == []


# ------------------------------------------------------------------------------ workers
POOL_PARENT = """
    import sys, time
    import numpy as np
    which = sys.argv[1]
    if which == "sweep":
        from skincal.workflows.sweep import map_local
        print("ready", flush=True)
        map_local(time.sleep, [120.0, 120.0], workers=2)
    else:
        from skincal.calib.api import MethodSpec, calibrate, register
        from skincal.data.hdf5 import read_dataset

        def sleepy(problem):
            time.sleep(120.0)

        register("sleepy", MethodSpec(run_unit=sleepy, description="sleeps", exact_joint_states=False))
        ds = read_dataset(sys.argv[2])
        print("ready", flush=True)
        calibrate(ds, "sleepy", links={u: 2 for u in ds.units}, workers=2)
"""


@pytest.fixture(scope="module")
def small(tmp_path_factory):
    """A small simulated session (2 units, fast protocol) and its result."""
    root = tmp_path_factory.mktemp("adversarial")
    data = root / "data.h5"
    args = "simulate --robot panda --placement random --units 2 --protocol fast --seed 4 --out".split()
    assert main([*args, str(data)]) == 0
    result = root / "result.json"
    assert main(["calibrate", str(data), "--out", str(result), "--workers", "1"]) == 0
    return data, result


def _kill_parent_then_workers_die(*args: str) -> None:
    proc = _python(POOL_PARENT, *args)
    workers: list[int] = []
    try:
        assert proc.stdout.readline().strip() == "ready", proc.stderr.read()
        workers = _wait_for(lambda: (lambda c: c if len(c) >= 2 else None)(_children(proc.pid)), 60.0) or []
        assert len(workers) >= 2, "the pool did not start two workers"
        time.sleep(0.5)  # let the initializers run (a worker that forked later still learns of the death)
        proc.kill()  # SIGKILL: nothing runs in the parent
        proc.wait(timeout=10)
        assert _wait_for(lambda: not any(_alive(w) for w in workers), 20.0), "workers outlived their parent"
    finally:
        proc.kill()
        for w in workers:
            if _alive(w):
                os.kill(w, signal.SIGKILL)


@pytest.mark.skipif(not LINUX, reason="PR_SET_PDEATHSIG is Linux only")
def test_calibrate_workers_die_when_their_parent_is_killed(small):
    _kill_parent_then_workers_die("calibrate", str(small[0]))


@pytest.mark.skipif(not LINUX, reason="PR_SET_PDEATHSIG is Linux only")
def test_sweep_workers_die_when_their_parent_is_killed():
    _kill_parent_then_workers_die("sweep")


# ------------------------------------------------------------------------------ reachable bad inputs
def _variant(src: Path, dst: Path, edit) -> Path:
    """A copy of dataset ``src`` changed by ``edit(h5py.File)`` directly (no skincal writer in between)."""
    import shutil

    import h5py

    shutil.copy(src, dst)
    with h5py.File(dst, "r+") as f:
        edit(f)
    return dst


def _replace(f, path: str, value) -> None:
    del f[path]
    f[path] = value


def _one_line_error(capsys, *needles: str) -> str:
    out = capsys.readouterr()
    err = out.err.strip()
    assert len(err.splitlines()) == 1 and err.startswith("error: "), out.err
    assert "internal error" not in err and "Traceback" not in out.err + out.out
    for needle in needles:
        assert needle in err, err
    return err


def test_zero_gravity_is_refused_on_read(small, tmp_path, capsys):
    import numpy as np

    data = _variant(small[0], tmp_path / "g0.h5", lambda f: f["robot"].attrs.__setitem__("gravity", np.zeros(3)))
    capsys.readouterr()
    assert main(["calibrate", str(data), "--out", str(tmp_path / "r.json")]) == 2
    _one_line_error(capsys, "g0.h5", "gravity", "magnitude 0")
    assert main(["info", str(data)]) == 2
    _one_line_error(capsys, "gravity")
    assert not (tmp_path / "r.json").exists()


def test_imu_stamps_barely_overlapping_the_joint_stream(small, tmp_path, capsys):
    def shift(f):
        end = float(f["joints/t"][-1])
        for unit in f["imu"]:
            t = f[f"imu/{unit}/t"][...]
            _replace(f, f"imu/{unit}/t", t - t[0] + end - 0.1)  # the last 0.1 s of the joint stream only

    data = _variant(small[0], tmp_path / "late.h5", shift)
    capsys.readouterr()
    assert main(["calibrate", str(data), "--out", str(tmp_path / "r.json")]) == 2
    _one_line_error(capsys, "do not overlap the joint stream", "another clock")


def test_a_joint_glitch_far_beyond_the_limits_is_refused(small, tmp_path, capsys):
    def glitch(f):
        q = f["joints/q"][...]
        q[100, 2] = 1e30
        _replace(f, "joints/q", q)

    data = _variant(small[0], tmp_path / "glitch.h5", glitch)
    capsys.readouterr()
    assert main(["calibrate", str(data), "--out", str(tmp_path / "r.json")]) == 2
    _one_line_error(capsys, "joint 3", "sample 100", "1e+30", "limits")
    assert not (tmp_path / "r.json").exists()


def test_calibrate_into_a_missing_folder_fails_before_reading_the_dataset(tmp_path, capsys):
    png = tmp_path / "x.png"
    png.write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(100))  # not a dataset: reading it would fail differently
    assert main(["calibrate", str(png), "-o", str(tmp_path / "nonexistent" / "dir" / "r.json")]) == 2
    _one_line_error(capsys, "does not exist")


# ------------------------------------------------------------------------------ names reaching the terminal
MARKUP_NAME = "[bold red]su1"
"""A valid unit name (no control characters) that rich would read as markup and show as a red ``su1``."""
CONTROL_NAME = "su\x1b[2J1\nforged line"
"""ESC (clear the screen) and a newline: refused by the readers, or shown escaped."""


def _rename_unit(f, old: str, new: str) -> None:
    for group in ("imu", "truth", "tof"):
        if group in f and old in f[group]:
            f.move(f"{group}/{old}", f"{group}/{new}")


def _raw_control(text: str) -> bool:
    return any(ch in text for ch in ("\x1b", "\r")) or "\nforged line" in text


def test_info_and_calibrate_show_names_and_free_text_as_stored(small, tmp_path, capsys):
    def edit(f):
        _rename_unit(f, "su1", MARKUP_NAME)
        f.attrs["description"] = "session \x1b[31mred\x1b[0m\nsecond [blink]line[/]"

    data = _variant(small[0], tmp_path / "markup.h5", edit)
    capsys.readouterr()
    assert main(["info", str(data)]) == 0
    out = capsys.readouterr().out
    assert MARKUP_NAME in out  # shown literally, not as red text
    assert "\\x1b[31mred\\x1b[0m\\nsecond [blink]line[/]" in out and not _raw_control(out)
    result = tmp_path / "r.json"
    assert main(["calibrate", str(data), "--out", str(result), "--workers", "1"]) == 0
    out = capsys.readouterr().out
    assert MARKUP_NAME in out
    assert main(["evaluate", str(result), "--truth", str(data)]) == 0
    assert MARKUP_NAME in capsys.readouterr().out


def test_control_characters_in_names_never_reach_the_terminal_raw(small, tmp_path, capsys):
    import json

    data = _variant(small[0], tmp_path / "esc.h5", lambda f: _rename_unit(f, "su1", CONTROL_NAME))
    doc = json.loads(small[1].read_text())
    doc["units"][CONTROL_NAME] = doc["units"].pop("su1")
    doc["robot"] = "panda\x1b]0;owned\x07"
    result = tmp_path / "esc.json"
    result.write_text(json.dumps(doc))  # json.dumps writes the controls as \u001b escapes: a valid file
    for args in (
        ["info", str(data)],
        ["calibrate", str(data), "--out", str(tmp_path / "r.json"), "--workers", "1"],
        ["evaluate", str(result), "--truth", str(small[0]), "--allow-other-dataset"],
        ["report", str(result), "--dataset", str(small[0]), "--allow-other-dataset"],
        ["export", str(result), "-f", "csv", "-o", str(tmp_path / "e.csv")],
    ):
        code = main(args)
        out = capsys.readouterr()
        assert not _raw_control(out.out) and not _raw_control(out.err), args
        assert "internal error" not in out.err, args
        if code != 0:  # the reader refuses the name: one line saying why
            assert code == 2 and len(out.err.strip().splitlines()) == 1 and "control character" in out.err, args


# ------------------------------------------------------------------------------ the viewer's origin check
def _handshake(port: int, uri_host: str, origin: str | None = None, connect_to: str = "127.0.0.1") -> str:
    """Open a websocket to the viewer at ``connect_to:port`` with ``Host: uri_host:port`` (and
    ``Origin``) using the websockets client; ``"accepted"`` or ``"status <code>"``."""
    import asyncio

    import viser
    import websockets
    from websockets.asyncio.client import connect

    async def attempt() -> str:
        try:
            async with connect(
                f"ws://{uri_host}:{port}",
                host=connect_to,
                port=port,
                origin=origin,
                open_timeout=10,
                subprotocols=[f"viser-v{viser.__version__}"],
            ):
                return "accepted"
        except websockets.exceptions.InvalidStatus as exc:
            return f"status {exc.response.status_code}"

    return asyncio.run(attempt())


@pytest.fixture
def viewer(small):
    pytest.importorskip("viser")
    from skincal.data.result import read_result
    from skincal.kinematics import get_robot
    from skincal.viz.viewer import start_viewer

    v = start_viewer(read_result(small[1]), get_robot("panda"), host="127.0.0.1")
    yield v
    v.close()


def test_viewer_refuses_cross_site_and_rebinding_requests_with_403(viewer):
    import urllib.error
    import urllib.request

    port = viewer.server.get_port()
    assert viewer.url == f"http://127.0.0.1:{port}"
    own = f"http://127.0.0.1:{port}"
    assert _handshake(port, "127.0.0.1") == "accepted"  # a local client without Origin
    assert _handshake(port, "127.0.0.1", origin=own) == "accepted"  # the viewer's own page
    assert _handshake(port, "localhost", origin=f"http://localhost:{port}") == "accepted"
    assert _handshake(port, "127.0.0.1", origin="http://evil.example") == "status 403"  # cross-site
    assert _handshake(port, "127.0.0.1", origin=f"http://evil.example:{port}") == "status 403"
    assert _handshake(port, "127.0.0.1", origin="null") == "status 403"  # sandboxed frame, file://
    assert _handshake(port, "evil.example") == "status 403"  # DNS rebinding: a hostile name for 127.0.0.1
    assert _handshake(port, "evil.example", origin=f"http://evil.example:{port}") == "status 403"
    assert _handshake(port, "192.168.1.7") == "status 403"  # not the bound interface
    page = urllib.request.Request(own + "/", headers={"Host": "evil.example"})
    with pytest.raises(urllib.error.HTTPError) as refused:  # the client files too
        urllib.request.urlopen(page, timeout=10)
    assert refused.value.code == 403
    with urllib.request.urlopen(own + "/", timeout=10) as ok:
        assert ok.status == 200


def test_viewer_on_ipv6_loopback_prints_a_valid_url(small, capsys):
    import socket

    pytest.importorskip("viser")
    if not socket.has_ipv6:
        pytest.skip("no IPv6")
    try:
        socket.create_server(("::1", 0), family=socket.AF_INET6).close()
    except OSError:
        pytest.skip("no IPv6 loopback")
    assert main(["view", str(small[1]), "--host", "::1", "--duration", "0.2"]) == 0
    url = capsys.readouterr().out.split("skincal viewer:")[1].split()[0]
    assert url.startswith("http://[::1]:")
    from urllib.parse import urlsplit

    assert urlsplit(url).hostname == "::1" and urlsplit(url).port > 0


# ------------------------------------------------------------------------------ does the result belong to the dataset?
@pytest.fixture(scope="module")
def other(small, tmp_path_factory):
    """Another session of the same robot and unit names (another seed), and a copy of the small
    session whose robot is named differently."""
    import h5py

    root = tmp_path_factory.mktemp("other")
    data = root / "other.h5"
    args = "simulate --robot panda --placement random --units 2 --protocol fast --seed 5 --out".split()
    assert main([*args, str(data)]) == 0
    renamed = _variant(small[0], root / "renamed.h5", lambda f: f["robot"].attrs.__setitem__("name", "panda-2"))
    with h5py.File(renamed, "r") as f:
        assert f["robot"].attrs["name"] == "panda-2"
    return data, renamed


def test_evaluate_refuses_a_result_of_another_dataset(small, other, tmp_path, capsys):
    import json

    data, result = small
    capsys.readouterr()
    assert main(["evaluate", str(result), "--truth", str(other[0]), "--json"]) == 2
    _one_line_error(capsys, "result.json was computed from another dataset than", "other.h5", "--allow-other-dataset")
    assert main(["evaluate", str(result), "--truth", str(other[1])]) == 2  # same file content but for the robot
    _one_line_error(capsys, "robot 'panda'", "robot 'panda-2'")
    assert main(["evaluate", str(result), "--truth", str(other[0]), "--json", "--allow-other-dataset"]) == 0
    out = capsys.readouterr()
    assert json.loads(out.out)["units_total"] == 2  # stdout stays JSON; the warning goes to stderr
    assert out.err.startswith("warning: ") and "another dataset" in out.err
    assert main(["evaluate", str(result), "--truth", str(data), "--json"]) == 0  # its own dataset: no warning
    out = capsys.readouterr()
    assert out.err == "" and json.loads(out.out)["mean_position_error_mm"] < 1.0
    doc = json.loads(result.read_text())
    doc["dataset_sha256"] = ""
    unknown = tmp_path / "nohash.json"
    unknown.write_text(json.dumps(doc))
    assert main(["evaluate", str(unknown), "--truth", str(data), "--json"]) == 0  # accepted, with a warning
    err = capsys.readouterr().err.strip()
    assert err.startswith("warning: ") and "does not record the SHA-256" in err and len(err.splitlines()) == 1


def test_report_and_view_refuse_a_result_of_another_dataset(small, other, tmp_path, capsys):
    _, result = small
    capsys.readouterr()
    assert main(["report", str(result), "--dataset", str(other[0]), "--out", str(tmp_path / "r.html")]) == 2
    _one_line_error(capsys, "another dataset", "--allow-other-dataset")
    assert not (tmp_path / "r.html").exists()
    assert main(["report", str(result), "--dataset", str(other[0]), "--allow-other-dataset", "--format", "md"]) == 0
    out = capsys.readouterr()
    assert out.out.startswith("# skincal") and "warning: " in out.err
    pytest.importorskip("viser")
    assert main(["view", str(result), "--truth", str(other[0]), "--duration", "0"]) == 2
    _one_line_error(capsys, "another dataset")
    assert main(["view", str(result), "--play", str(other[1]), "--duration", "0"]) == 2  # another robot
    _one_line_error(capsys, "robot 'panda-2'")
    assert main(["view", str(result), "--play", str(other[0]), "--duration", "0"]) == 0  # another recording: fine
    assert "skincal viewer: http://127.0.0.1:" in capsys.readouterr().out


def test_report_without_out_prints_markdown_and_html_needs_out(small, capsys):
    data, result = small
    capsys.readouterr()
    assert main(["report", str(result), "--dataset", str(data)]) == 0  # the help's promise: markdown on stdout
    assert capsys.readouterr().out.startswith("# skincal calibration")
    assert main(["report", str(result), "--dataset", str(data), "--format", "html"]) == 2
    out = capsys.readouterr()
    assert "Invalid value for '--format'" in out.err and "--out" in out.err and "internal error" not in out.err


# ------------------------------------------------------------------------------ wrong kinds of files
@pytest.fixture(scope="module")
def wrong_files(small, tmp_path_factory):
    """Files of the wrong kind: an empty file, a folder, a PNG, and results a reader must refuse."""
    import json

    root = tmp_path_factory.mktemp("wrong")
    (root / "empty").write_bytes(b"")
    (root / "folder").mkdir()
    (root / "x.png").write_bytes(b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR" + bytes(64))
    doc = json.loads(small[1].read_text())
    (root / "no_units.json").write_text(json.dumps({**doc, "units": {}}))
    far = json.loads(small[1].read_text())
    next(iter(far["units"].values()))["position_m"] = [1e308, 0.0, 0.0]
    (root / "far.json").write_text(json.dumps(far))
    return {"dataset": small[0], "result": small[1], **{p.name: p for p in root.iterdir()}}


COMMANDS = [
    ("info {d}", ["result", "empty", "folder", "x.png"]),
    ("calibrate {d} -o {out}", ["result", "empty", "folder", "x.png"]),
    ("segment {d} -o {out}", ["result", "empty", "folder", "x.png"]),
    ("evaluate {r} --truth {dataset}", ["dataset", "empty", "folder", "x.png", "no_units.json", "far.json"]),
    ("evaluate {result} --truth {d}", ["result", "empty", "folder", "x.png"]),
    (
        "report {r} --dataset {dataset} --format md",
        ["dataset", "empty", "folder", "x.png", "no_units.json", "far.json"],
    ),
    ("report {result} --dataset {d} -o {out}", ["result", "empty", "folder", "x.png"]),
    ("export {r} -f csv -o {out}", ["dataset", "empty", "folder", "x.png", "no_units.json", "far.json"]),
    ("view {r} --duration 0", ["dataset", "empty", "folder", "x.png", "no_units.json", "far.json"]),
    ("view {result} --truth {d} --duration 0", ["result", "empty", "folder", "x.png"]),
    ("avoid --result {r} --duration 0.1", ["dataset", "empty", "folder", "x.png", "no_units.json"]),
    ("import {d} -o {out}", ["dataset", "result", "empty", "x.png"]),
]


@pytest.mark.parametrize(("command", "kinds"), COMMANDS, ids=[c.split()[0] + "-" + c.split()[1] for c, _ in COMMANDS])
def test_wrong_kinds_of_files_are_one_line_errors(command, kinds, wrong_files, tmp_path, capsys):
    for kind in kinds:
        out = tmp_path / f"out-{kind}"
        args = command.format(d=wrong_files[kind], r=wrong_files[kind], out=out, **wrong_files).split()
        capsys.readouterr()
        assert main(args) == 2, (args, capsys.readouterr())
        _one_line_error(capsys)
        assert not out.exists()


@pytest.mark.parametrize(
    "args",
    [
        "view {r} --port 70000 --duration 0",
        "view {r} --port -1 --duration 0",
        "view {r} --duration -1",
        "view {r} --duration nan",
        "view {r} --duration inf",
        "view {r} --host 10.255.255.1 --public --duration 0",  # not this machine's address
        "view {r} --host no.such.host.invalid --public --duration 0",
        "calibrate {d} -o {out} --seed -1 --method om",
    ],
)
def test_impossible_option_values_are_errors_not_hangs(args, small, tmp_path):
    """In a real process with a timeout: viser retries the next port on every error and used to wait
    forever when no port could work."""
    pytest.importorskip("viser")
    argv = args.format(d=small[0], r=small[1], out=tmp_path / "r.json").split()
    done = subprocess.run([sys.executable, "-m", "skincal", *argv], capture_output=True, text=True, timeout=60)
    assert done.returncode == 2, done
    assert "internal error" not in done.stderr and "Traceback" not in done.stderr
    assert done.stderr.strip().splitlines()[-1].lower().startswith("error")
    assert not (tmp_path / "r.json").exists()


@pytest.mark.parametrize(
    "argv",
    [["info", "a" * 5000], ["calibrate", "x.h5", "-o", "r.json", "--option", "b" * 5000 + "=1"],
     ["protocol", "--robot", "c" * 5000, "-o", "p.json"]],  # fmt: skip
)
def test_a_huge_echoed_input_is_shortened_and_the_reason_still_shows(argv, tmp_path, monkeypatch, capsys):
    """A 5000-character name or path was echoed whole: a 5000-character error line that buries its reason.
    The echoed run is cut in its middle (head and tail kept, the count named); the reason after it stays."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "x.h5").write_bytes(b"")
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: ") and "\n" not in err and len(err) < 800, (len(err), err[:300])
    assert "characters]..." in err
    assert err.endswith(("(File name too long)", ", joint_rate)", "DH chain file)")), err[-200:]


def test_shortened_keeps_ordinary_messages_unchanged():
    from skincal.names import LONG_WORD, shortened

    ordinary = "/tmp/" + "d" * (LONG_WORD - 6) + ": no such file"  # the colon is part of the run
    assert shortened(ordinary) == ordinary
    long = "x" * 1000
    out = shortened(f"name '{long}' is refused")
    # the quotes are part of the run: 1002 - 120 - 60 characters cut
    assert out.startswith("name 'xxx") and out.endswith("' is refused") and "[822 characters]" in out


OSC = "\x1b]0;owned\x07"
"""An OSC sequence: a terminal that receives it raw sets its window title (and worse sequences exist)."""


def _raw_control_char(text: str) -> bool:
    return any(ord(ch) < 0x20 and ch not in "\n" or 0x7F <= ord(ch) < 0xA0 for ch in text)


def test_report_shows_control_characters_in_free_text_as_escapes(files, tmp_path):
    """A result's warning with ``ESC ] 0;title BEL`` reached the terminal raw through ``report``
    (markdown on stdout) and the HTML table raw; ``evaluate`` and ``export`` already escaped it."""
    import json

    from cli_subprocess import run_cli

    _, data, result = files
    doc = json.loads(result.read_text())
    unit = next(iter(doc["units"]))
    doc["units"][unit]["warnings"] = [f"poor fit {OSC}\rcleared"]
    hostile = tmp_path / "hostile.json"
    hostile.write_text(json.dumps(doc))
    proc = run_cli(["report", str(hostile), "--dataset", str(data)], tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert "poor fit \\x1b]0;owned\\x07\\rcleared" in proc.stdout
    assert not _raw_control_char(proc.stdout + proc.stderr)
    page = tmp_path / "r.html"
    proc = run_cli(["report", str(hostile), "--dataset", str(data), "--out", str(page)], tmp_path)
    assert proc.returncode == 0, proc.stderr
    html = page.read_text()
    assert "poor fit \\x1b]0;owned\\x07\\rcleared" in html and not _raw_control_char(html)


ABSURD = [
    (["simulate", "--protocol", "fast", "--seed", "-1", "-o", "{tmp}/s.h5"], "--seed -1: a seed is an integer >= 0"),
    (["simulate", "--handheld", "--seed", "-1", "-o", "{tmp}/s.h5"], "--seed -1: a seed is an integer >= 0"),
    (["protocol", "--robot", "panda", "--seed", "-1", "-o", "{tmp}/p.json"], "--seed -1: a seed is an integer >= 0"),
    (["avoid", "--seed", "-1"], "--seed -1: a seed is an integer >= 0"),
    (["calibrate", "{data}", "--seed", "-1", "-o", "{tmp}/c.json"], "--seed -1: a seed is an integer >= 0"),
    (["emulate", "{data}", "--port", "9", "--seed", "-1"], "--seed -1: a seed is an integer >= 0"),
    (["emulate", "{data}", "--port", "9", "--jitter", "inf"], "--jitter inf s must be a mean delay in [0, 60] s"),
    (["emulate", "{data}", "--port", "9", "--jitter", "1e308"], "--jitter 1e+308 s must be a mean delay in [0, 60]"),
    (["emulate", "{data}", "--port", "9", "--jitter", "nan"], "--jitter nan s must be a mean delay in [0, 60] s"),
    (["record", "--out", "{tmp}/r.h5", "--port", "0", "--max-unit-samples", str(10**20)],
     "--max-unit-samples 100000000000000000000 must be at most 2^40"),
]


@pytest.mark.parametrize(("command", "message"), ABSURD, ids=[" ".join(c[:1] + c[-2:]) for c, _ in ABSURD])
def test_absurd_numbers_are_one_line_usage_errors(command, message, files, tmp_path, capsys):
    """``--seed -1``, ``emulate --jitter inf / 1e308`` and ``record --max-unit-samples 1e20`` were internal
    errors (exit 3, NumPy's or h5py's exception) after the work had started: now exit 2, one line, nothing written."""
    _, data, _ = files
    args = [a.format(data=data, tmp=tmp_path) for a in command]
    capsys.readouterr()
    assert main(args) == 2
    out = capsys.readouterr()
    err = out.err.strip().splitlines()
    assert err == [f"error: {message}"] or (len(err) == 1 and message in err[0]), out.err
    assert "sending" not in out.out and not list(tmp_path.iterdir())


# ------------------------------------------------------------------------------ absurd figures
@pytest.mark.parametrize(("args", "option"), [
    (["--port", "0"], "--port 0 must be in 1..65535"),
    (["--port", "70000"], "--port 70000 must be in 1..65535"),
    (["--duration", "-1"], "--duration -1 s must be a finite number > 0"),
    (["--duration", "nan"], "--duration nan s"),
    (["--duration", "inf"], "--duration inf s"),
    (["--drift-ppm", "1e12"], "--drift-ppm 1e+12 must be a finite number in [-10000, 10000]"),
    (["--drift-ppm", "nan"], "--drift-ppm nan"),
    (["--clock-offset", "nan"], "--clock-offset nan s must be a finite number in"),
    (["--clock-offset", "inf"], "--clock-offset inf s"),
    (["--clock-offset", "1e300"], "--clock-offset 1e+300 s"),
])
def test_emulate_refuses_absurd_figures_naming_the_option_before_reading(args, option, tmp_path, capsys):
    """Port 0 sent to nowhere and exited 0, a negative or NaN duration played nothing or everything, a NaN
    offset or drift was a NumPy warning and a packet error after 'sending ...'."""
    data = tmp_path / "data.h5"
    data.write_bytes(b"not read: the figures are checked first")
    port = [] if args[0] == "--port" else ["--port", "45999"]
    assert main(["emulate", str(data), *port, *args]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"error: {option}") and "\n" not in err, err
    assert data.read_bytes() == b"not read: the figures are checked first"


@pytest.mark.parametrize(("args", "message"), [
    (["--placement", "random", "--units", "100000"], "--units 100000 must be in 1..256"),
    (["--handheld", "--units", "0"], "--units 0 must be in 1..256"),
    (["--handheld", "--units", "100000"], "--units 100000 must be in 1..256"),
    (["--handheld", "--other-body", "100000"], "--other-body 100000 must be in 0..256"),
])
def test_simulate_refuses_unit_counts_beyond_its_bound_at_once(args, message, tmp_path, capsys):
    """``--handheld --units 0`` wrote 2 units; ``--units 100000`` still ran at 60 s."""
    start = time.monotonic()
    assert main(["simulate", "--out", str(tmp_path / "x.h5"), *args]) == 2
    assert capsys.readouterr().err.strip() == f"error: {message}"
    assert time.monotonic() - start < 5 and list(tmp_path.iterdir()) == []


@pytest.mark.skipif(os.name != "posix", reason="FIFOs")
def test_import_of_a_fifo_is_refused_at_once_instead_of_blocking(tmp_path, capsys):
    fifo = tmp_path / "recording.bag"
    os.mkfifo(fifo)  # nobody writes: opening it for reading blocks forever
    start = time.monotonic()
    assert main(["import", str(fifo), "--out", str(tmp_path / "d.h5")]) == 2
    err = capsys.readouterr().err.strip()
    assert err == f"error: {fifo}: is a FIFO (named pipe), expected a ROS bag", err
    assert time.monotonic() - start < 10 and sorted(p.name for p in tmp_path.iterdir()) == ["recording.bag"]
