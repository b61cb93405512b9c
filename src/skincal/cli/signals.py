"""SIGTERM and Ctrl-C while a command runs: the command unwinds like an exception (every ``finally`` and
:func:`skincal.io.atomic.atomic_path` clean-up runs, no temporary is left) and ends promptly with one
line, exit 143 (SIGTERM) or 130 (SIGINT).

A signal's Python handler runs in the main thread between two bytecodes, so it can be lost or delayed
in four ways, each handled here:

- **a second signal** (SIGTERM then Ctrl-C 20 ms later) would raise again inside the first one's
  clean-up, leaving its temporary or a traceback: the first signal wins, a further SIGTERM/SIGINT within
  :data:`GRACE_S` of it is ignored;
- **an exception Python can only ignore** (raised in a weakref callback or a ``__del__``, which h5py
  runs all the time): :func:`_redeliver` keeps the signal pending and sends it again a moment later; a
  signal arriving while that hook runs is kept pending too (raised there, it was "Exception ignored in
  sys.unraisablehook" and lost), and one still pending when the command ends (it ended within the
  moment) is raised as the command returns, so the exit code is still 143 / 130;
- **a blocking call entered just after the signal** (the signal lands between the interpreter's last
  check and ``sleep``/``read``/``select``, or the kernel hands it to another thread): the C-level
  handler has run, the Python one waits for the call to return, up to forever. A watcher thread learns
  of every signal through :func:`signal.set_wakeup_fd` and, while the main thread has not handled it,
  sends it to the main thread again every :data:`KICK_S` (:func:`signal.pthread_kill`) to break the call;
- **a handler replaced by a library** (``asyncio.run`` with ``add_signal_handler`` leaves SIGTERM at
  its default, which kills without clean-up): :func:`run_async` restores this module's handlers.
"""

from __future__ import annotations

import contextlib
import functools
import os
import signal
import sys
import threading
import time
from collections.abc import Iterator
from typing import Any

GRACE_S = 2.0
"""A further SIGTERM/SIGINT within this time of the first one is ignored: the first one's clean-up runs, s."""
KICK_S = 0.05
"""How long the watcher lets the main thread take to handle a signal before sending it to that thread again, s."""
_REDELIVER_S = 0.01
"""Delay before a swallowed signal is sent again, s."""
_SIGNALS = (signal.SIGTERM, signal.SIGINT)


class Terminated(SystemExit):
    """Raised in the main thread when the process receives SIGTERM: it unwinds the command like an
    exception; exit code 143 (128 + SIGTERM), as if killed by the signal."""

    def __init__(self) -> None:
        super().__init__(128 + signal.SIGTERM)


class _State:
    """What the handlers share: the signal being handled (None: none yet), since when, whether handling
    is on (a command is running), the signal received but not raised yet (``pending``: lost in an
    unraisable context, or received while ``deferring``) and whether raising is put off (``deferring``:
    inside the unraisable hook and while :func:`unwinds` restores the handlers)."""

    def __init__(self) -> None:
        self.signum: int | None = None
        self.at = 0.0
        self.active = False
        self.pending: int | None = None
        self.deferring = False


_state = _State()


def _exception(signum: int) -> BaseException:
    return Terminated() if signum == signal.SIGTERM else KeyboardInterrupt()


def _on_signal(signum: int, _frame: object) -> None:
    now = time.monotonic()
    if _state.signum is not None and now - _state.at < GRACE_S:
        return  # the first signal's exception is unwinding the command: let its clean-up finish
    if _state.deferring:  # raised here it would be lost: raised later (the hook's re-send, or unwinds' end)
        if _state.pending is None:
            _state.pending = signum
        return
    _state.signum, _state.at, _state.pending = signum, now, None
    raise _exception(signum)


def _redeliver(unraisable: object, *, fallback: object) -> None:
    """``sys.unraisablehook`` while a command runs: a signal's exception raised where Python can only
    ignore it (a weakref callback, a ``__del__``: it would print "Exception ignored" and carry on, the
    signal lost) is sent again a moment later, so it surfaces in the command's own code instead."""
    was_deferring, _state.deferring = _state.deferring, True  # a signal now (a watcher's kick) stays pending
    try:
        exc = getattr(unraisable, "exc_value", None)
        if isinstance(exc, Terminated):
            sig = signal.SIGTERM
        elif isinstance(exc, KeyboardInterrupt):
            sig = signal.SIGINT
        else:
            fallback(unraisable)  # type: ignore[operator]
            return
        _state.signum = None  # lost: the next delivery raises again
        if _state.pending is None:
            _state.pending = sig
        # from another thread, a moment later: delivered now, it would be raised inside this hook again
        timer = threading.Timer(_REDELIVER_S, _send_pending)
        timer.daemon = True
        timer.start()
    finally:
        _state.deferring = was_deferring


def _send_pending() -> None:
    """The timer of :func:`_redeliver`: the pending signal sent again while the command runs (one that is
    not, because the command ended, :func:`unwinds` raises)."""
    sig = _state.pending
    if _state.active and sig is not None:
        os.kill(os.getpid(), sig)


def _watch(read_fd: int, main_ident: int) -> None:
    """The watcher thread: reads the signal numbers the C-level handler writes to the wakeup fd; while
    the main thread's Python handler has not yet run for a SIGTERM/SIGINT (it is stuck in a blocking
    call), the signal is sent to the main thread again every :data:`KICK_S` (a few times at most), which
    interrupts the call. Signals handled by a command's own handler are left to it."""
    with contextlib.suppress(AttributeError, OSError, ValueError):
        signal.pthread_sigmask(signal.SIG_BLOCK, _SIGNALS)  # never picked by the kernel for them
    while True:
        try:
            data = os.read(read_fd, 64)
        except OSError:
            return
        if not data:
            return
        for sig in set(data) & set(_SIGNALS):
            for _ in range(40):
                time.sleep(KICK_S)
                handled = _state.signum is not None and time.monotonic() - _state.at < GRACE_S
                if not _state.active or handled or signal.getsignal(sig) is not _on_signal:
                    break
                with contextlib.suppress(OSError, ValueError):
                    signal.pthread_kill(main_ident, sig)


class _Watcher:
    """The wakeup-fd pipe and its thread, made once per process (the thread is a daemon and blocks in
    ``read``; a forked child drops the wakeup fd, it has no watcher)."""

    fds: tuple[int, int] | None = None

    @classmethod
    def write_fd(cls) -> int:
        if cls.fds is None:
            read_fd, write_fd = os.pipe()
            os.set_blocking(write_fd, False)
            cls.fds = (read_fd, write_fd)
            threading.Thread(target=_watch, args=(read_fd, threading.main_thread().ident),
                             name="skincal-signals", daemon=True).start()
            if hasattr(os, "register_at_fork"):
                os.register_at_fork(after_in_child=_forget_in_child)
        return cls.fds[1]


def _forget_in_child() -> None:
    """A forked worker shares the pipe but not the watcher: its signals must not kick the parent."""
    if _Watcher.fds is not None and threading.current_thread() is threading.main_thread():
        with contextlib.suppress(ValueError, OSError):
            if signal.set_wakeup_fd(-1) != _Watcher.fds[1]:
                signal.set_wakeup_fd(-1)
    _state.active = False


def _install() -> dict[int, Any]:
    """This module's handlers for SIGTERM, and for SIGINT unless it is ignored (a command started in the
    background of a non-interactive shell keeps ignoring Ctrl-C); returns the previous handlers."""
    previous = {}
    for sig in _SIGNALS:
        current = signal.getsignal(sig)
        if sig == signal.SIGINT and current == signal.SIG_IGN:
            continue
        previous[sig] = signal.signal(sig, _on_signal)
    return previous


@contextlib.contextmanager
def unwinds() -> Iterator[None]:
    """While the command runs: SIGTERM raises :class:`Terminated` and SIGINT ``KeyboardInterrupt`` (main
    thread only), the first signal wins, a swallowed one is delivered again, and one that lands before a
    blocking call still breaks it. The previous handlers, hook and wakeup fd are restored afterwards; a
    signal received but not raised by then (pending) is raised as the block ends.
    Commands that handle SIGTERM themselves (``record``) install their own handler inside."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous_hook = sys.unraisablehook
    previous_fd = None
    try:
        previous_fd = signal.set_wakeup_fd(_Watcher.write_fd(), warn_on_full_buffer=False)
    except (OSError, ValueError):  # no pipe: the other three guards still hold
        previous_fd = None
    _state.signum, _state.pending, _state.deferring, _state.active = None, None, False, True
    previous = _install()
    sys.unraisablehook = functools.partial(_redeliver, fallback=previous_hook)
    try:
        yield
    finally:
        _state.deferring = True  # a signal during the restore is kept, not raised half-way through it
        _state.active = False
        sys.unraisablehook = previous_hook
        recent = _state.signum is not None and time.monotonic() - _state.at < GRACE_S
        for sig, handler in previous.items():  # within the first signal's grace: a further one still ignored
            signal.signal(sig, _after_grace(handler, _state.at + GRACE_S) if recent else handler)
        if previous_fd is not None:
            with contextlib.suppress(OSError, ValueError):
                signal.set_wakeup_fd(previous_fd)
        _state.deferring = False
        pending, _state.pending = _state.pending, None
    if pending is not None:  # received, never raised (lost near the end, or during the restore): raised now
        raise _exception(pending)


def _after_grace(previous: Any, until: float) -> Any:
    """A handler that ignores SIGTERM/SIGINT until ``until`` (``time.monotonic``) and then does what ``previous``
    does: a command that ends within a first signal's grace (``stop_on_signals`` wrote its result) keeps its exit
    code when a second signal of a double press lands as the process exits."""

    def handler(signum: int, frame: Any) -> None:
        if time.monotonic() < until:
            return
        signal.signal(signum, previous)
        if callable(previous):
            previous(signum, frame)
        elif previous == signal.SIG_DFL:
            os.kill(os.getpid(), signum)

    return handler


def run_async(main: Any) -> Any:
    """``asyncio.run(main)``, then this module's handlers and wakeup fd back: a loop's
    ``add_signal_handler`` leaves SIGTERM at its default when the loop closes (a SIGTERM during the work
    after the loop would kill the command without its clean-up)."""
    import asyncio

    handlers = {sig: signal.getsignal(sig) for sig in _SIGNALS}
    main_thread = threading.current_thread() is threading.main_thread()
    wakeup = signal.set_wakeup_fd(-1) if main_thread else None
    if wakeup is not None and wakeup != -1:
        signal.set_wakeup_fd(wakeup)
    try:
        return asyncio.run(main)
    finally:
        if main_thread:
            for sig, handler in handlers.items():
                if handler is not None:
                    signal.signal(sig, handler)
            if wakeup is not None:
                with contextlib.suppress(OSError, ValueError):
                    signal.set_wakeup_fd(wakeup)


class StopRequest(threading.Event):
    """An event set by the first SIGINT (Ctrl-C) or SIGTERM inside :func:`stop_on_signals`; ``signum``
    says which (None: not set by a signal)."""

    signum: int | None = None


@contextlib.contextmanager
def stop_on_signals() -> Iterator[StopRequest]:
    """For a command whose normal end is a signal (``ros2``) or that writes what it has when asked to stop
    (``calibrate --follow``): the first SIGINT or SIGTERM sets the yielded event instead of raising, and puts
    the previous handlers back, so a later signal does what it did before (inside :func:`unwinds`: raises,
    nothing half-written is kept; one within :data:`GRACE_S` of the first is ignored there, so a double
    press does not lose what the first one asked to keep). Main thread only (elsewhere the event is never
    set by a signal); the previous handlers are restored when the block ends."""
    stop = StopRequest()
    if threading.current_thread() is not threading.main_thread():
        yield stop
        return
    previous: dict[int, Any] = {}

    def on_first(signum: int, _frame: Any) -> None:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        _state.signum, _state.at = signum, time.monotonic()  # handled: the watcher must not send it again
        stop.signum = signum
        stop.set()

    for sig in _SIGNALS:
        current = signal.getsignal(sig)
        if sig == signal.SIGINT and current == signal.SIG_IGN:  # a background job keeps ignoring Ctrl-C
            continue
        previous[sig] = signal.signal(sig, on_first)
    try:
        yield stop
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
