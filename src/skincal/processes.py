"""Worker processes die with their parent.

A pool's worker outlives a parent killed with SIGKILL (nothing runs in the parent to stop it) and
keeps computing for nothing. :func:`die_with_parent` asks the Linux kernel to send the worker
SIGTERM when its parent dies (``prctl(PR_SET_PDEATHSIG)``); elsewhere it does nothing. Call it
first thing in a pool's initializer (:func:`worker_initializer`).
"""

from __future__ import annotations

import ctypes
import ctypes.util
import multiprocessing
import os
import signal
import sys

_PR_SET_PDEATHSIG = 1


def die_with_parent(sig: int = signal.SIGTERM) -> bool:
    """Have the kernel send ``sig`` to this process when its parent exits (Linux); returns whether
    that was arranged. SIGTERM gets its default action (terminate) back, since a forked worker
    inherits the parent's handler (:func:`skincal.cli.main` turns SIGTERM into an exception)."""
    if not sys.platform.startswith("linux"):
        return False
    signal.signal(sig, signal.SIG_DFL)
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
        if libc.prctl(_PR_SET_PDEATHSIG, int(sig), 0, 0, 0) != 0:
            return False
    except (OSError, AttributeError):
        return False
    parent = multiprocessing.parent_process()
    if parent is not None and os.getppid() != parent.pid:  # it died before prctl: we are already orphaned
        os.kill(os.getpid(), sig)
    return True


def worker_initializer() -> None:
    """Initializer of skincal's process pools: the worker dies with its parent."""
    die_with_parent()
