"""SIGTERM at the edges of a command (issue 27, "signals"): right after an output's temporary was made,
while a swallowed signal's re-send is being arranged, at the very end of the command and after the output
was renamed into place. Each ends with exit 143 and one line, leaves no temporary, and leaves under the
final name either nothing or the complete output (never a signal lost, never "Exception ignored")."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap

import pytest

from skincal.io import atomic
from skincal.io.atomic import atomic_path

pytestmark = [pytest.mark.adversarial, pytest.mark.skipif(os.name != "posix", reason="POSIX signals")]


def _run(code: str, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", textwrap.dedent(code), *args], capture_output=True, text=True,
                          timeout=60)  # fmt: skip


class _Signalled(BaseException):
    """What a signal handler raises (``Terminated`` is a ``SystemExit``, ``KeyboardInterrupt``)."""


def test_an_exception_right_after_the_temporary_was_made_removes_it(tmp_path, monkeypatch):
    """A SIGTERM landing between the temporary's creation and the block that removes it on error left
    ``.out.<pid>.<hex>.tmp`` behind (simulate, 1 run in 30 with the signal sent as the temporary appeared)."""
    real_open = os.open

    def open_then_signal(path, *args, **kwargs):
        fd = real_open(path, *args, **kwargs)
        if str(path).endswith(".tmp"):
            os.close(fd)
            raise _Signalled()  # as the handler would, at the next bytecode after the file was made
        return fd

    monkeypatch.setattr(atomic.os, "open", open_then_signal)
    with pytest.raises(_Signalled), atomic_path(tmp_path / "out.bin") as tmp:
        tmp.write_bytes(b"never")
    assert list(tmp_path.iterdir()) == []


def test_a_missing_or_unwritable_folder_is_still_the_one_line_error(tmp_path):
    from skincal.errors import ConfigError

    with pytest.raises(ConfigError, match="does not exist"), atomic_path(tmp_path / "no" / "out.bin"):
        pass
    if os.geteuid() != 0:  # root writes anywhere
        ro = tmp_path / "ro"
        ro.mkdir(mode=0o500)
        with pytest.raises(ConfigError, match="cannot write in"), atomic_path(ro / "out.bin"):
            pass


# A weakref callback (h5py runs them all the time) where the SIGTERM is raised: Python can only ignore
# the exception ("Exception ignored ..."); skincal keeps the signal pending and raises it again.
LOST_AT_THE_END = """
    import os, signal, sys, weakref
    from pathlib import Path
    from skincal.cli import app, main
    from skincal.io.atomic import write_bytes_atomic

    class Handle:
        pass

    def finalizer(_ref):
        os.kill(os.getpid(), signal.SIGTERM)
        sum(range(1000))  # the handler runs here and raises inside the callback

    @app.command("late")
    def late(out: Path) -> None:
        write_bytes_atomic(out, b"complete")
        handle = Handle()
        keep = weakref.ref(handle, finalizer)
        del handle  # the last thing the command does: it ends long before a re-send 10 ms later

    sys.exit(main(["late", sys.argv[1]]))
"""


def test_a_signal_lost_in_a_finalizer_at_the_commands_end_still_terminates(tmp_path):
    """The re-send of a swallowed signal came 10 ms later and was dropped when the command had ended by
    then: exit 0 as if never told to stop."""
    proc = _run(LOST_AT_THE_END, str(tmp_path / "out.bin"))
    assert proc.returncode == 143, (proc.returncode, proc.stderr)
    assert proc.stderr.strip() == "error: terminated"
    assert (tmp_path / "out.bin").read_bytes() == b"complete"  # renamed into place before the signal
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.bin"]


# The same, and a second delivery arrives while skincal's unraisable hook arranges the re-send (the
# watcher's kick does that): raised there, it was "Exception ignored in sys.unraisablehook" and lost.
SIGNAL_IN_THE_HOOK = """
    import os, signal, sys, time, weakref
    from pathlib import Path
    import skincal.cli.signals as S
    from skincal.cli import app, main
    from skincal.io.atomic import atomic_path

    class KickedTimer(S.threading.Timer):
        def start(self):
            os.kill(os.getpid(), signal.SIGTERM)  # a delivery while the hook runs
            sum(range(1000))
            super().start()

    S.threading.Timer = KickedTimer

    class Handle:
        pass

    def finalizer(_ref):
        os.kill(os.getpid(), signal.SIGTERM)
        sum(range(1000))

    @app.command("hooked")
    def hooked(out: Path) -> None:
        with atomic_path(out) as tmp:
            tmp.write_bytes(b"partial")
            handle = Handle()
            keep = weakref.ref(handle, finalizer)
            del handle
            time.sleep(0.5)
            tmp.write_bytes(b"complete")

    sys.exit(main(["hooked", sys.argv[1]]))
"""


def test_a_signal_during_the_unraisable_hook_is_not_lost(tmp_path):
    proc = _run(SIGNAL_IN_THE_HOOK, str(tmp_path / "out.bin"))
    assert "Exception ignored" not in proc.stderr and "Traceback" not in proc.stderr, proc.stderr
    assert proc.returncode == 143 and proc.stderr.strip() == "error: terminated", (proc.returncode, proc.stderr)
    assert list(tmp_path.iterdir()) == []  # stopped inside the block: nothing under the final name


AFTER_THE_RENAME = """
    import os, signal, sys
    from pathlib import Path
    from skincal.cli import app, main
    from skincal.io.atomic import write_bytes_atomic

    @app.command("after")
    def after(out: Path) -> None:
        write_bytes_atomic(out, b"complete")
        os.kill(os.getpid(), signal.SIGTERM)  # while the command prints its summary
        print("wrote", out)

    sys.exit(main(["after", sys.argv[1]]))
"""


def test_sigterm_after_the_output_was_renamed_into_place_exits_143_and_keeps_it_whole(tmp_path):
    """The contract (docs/interfaces.md, exit codes): a signal after an output is in place ends with 143 and
    that output is complete; one not yet in place is not written."""
    proc = _run(AFTER_THE_RENAME, str(tmp_path / "out.bin"))
    assert proc.returncode == 143 and proc.stderr.strip() == "error: terminated", (proc.returncode, proc.stderr)
    assert (tmp_path / "out.bin").read_bytes() == b"complete"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.bin"]


@pytest.mark.parametrize(("sig", "code", "message"), [(signal.SIGTERM, 143, "error: terminated"),
                                                        (signal.SIGINT, 130, "error: interrupted")])
def test_a_signal_while_unwinds_restores_the_handlers_is_raised_after(sig, code, message, tmp_path):
    """A signal received as the command ends, while the handlers are put back, is raised once they are."""
    script = f"""
        import os, signal, sys
        import skincal.cli.signals as S
        from skincal.cli import app, main

        real = S.signal.signal
        def restore(signum, handler):
            if handler is not S._on_signal and signum == signal.SIGTERM:
                os.kill(os.getpid(), {int(sig)})
                sum(range(1000))
            return real(signum, handler)
        S.signal.signal = restore

        @app.command("quick")
        def quick() -> None:
            print("done")

        sys.exit(main(["quick"]))
    """
    proc = _run(script)
    assert proc.returncode == code and proc.stderr.strip() == message, (proc.returncode, proc.stderr)
