"""The one parallel runner: a function mapped over items in worker processes that die with their parent.

:func:`imap` runs ``fn(item)`` for each item in ``workers`` processes (one: in this process) and yields
``(index, result)``, in item order or as completed, with at most ``window`` items in flight (bounded
memory when items are large). With ``fork=True`` the workers are forked and ``fn`` may be any callable, a
closure too: it is inherited by the children (registered by a token before the pool starts) and only the
items are pickled. The three users: the benchmark sweeps (:mod:`skincal.workflows.sweep`), the
calibration of many units (:func:`skincal.calib.api.calibrate`) and the report's per-unit residuals
(:mod:`skincal.viz.content`).

A pool's worker outlives a parent killed with SIGKILL (nothing runs in the parent to stop it) and
keeps computing for nothing. :func:`die_with_parent` asks the Linux kernel to send the worker
SIGTERM when its parent dies (``prctl(PR_SET_PDEATHSIG)``); elsewhere it does nothing. Call it
first thing in a pool's initializer (:func:`worker_initializer`; :func:`imap`'s workers do).
"""

from __future__ import annotations

import ctypes
import ctypes.util
import itertools
import math
import multiprocessing
import os
import signal
import sys
import threading
from collections.abc import Callable, Generator, Iterable
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from functools import partial, wraps
from typing import Any, ParamSpec, TypeVar

T = TypeVar("T")
R = TypeVar("R")
P = ParamSpec("P")

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


_FORKED: dict[int, Callable[[Any], Any]] = {}
"""The functions of the running forked :func:`imap` calls by token, inherited by the forked workers."""
_TOKENS = itertools.count()
_BLAS_LIMIT: Any = None
"""The BLAS thread limit of a worker process (kept alive for the worker's life)."""


def can_fork() -> bool:
    """Whether this platform can fork worker processes (``imap(..., fork=True)``)."""
    return "fork" in multiprocessing.get_all_start_methods()


def running_forked() -> int:
    """How many forked :func:`imap` runs hold a function now (0 once every run has ended)."""
    return len(_FORKED)


_BLAS_LOCK = threading.Lock()
_BLAS_DEPTH = 0
_BLAS_LIMIT_NOW: Any = None
"""The :func:`one_blas_thread` limit in force (a ``threadpoolctl`` limiter) and how many calls are inside it."""


def one_blas_thread(fn: Callable[P, R]) -> Callable[P, R]:
    """Decorator: ``fn`` runs with one BLAS thread. A calibration's linear algebra is many small matrices
    (27 x 27 normal matrices, 3 x 3 rotations), which more threads only slow down, badly so on a busy
    machine: one ``eigh`` of a 27 x 27 matrix took 15 ms with OpenBLAS's two threads while another process
    ran, 0.06 ms with one; the unit fits ran with one already, the split check's part fits did not (12.0
    -> 5.6 CPU s for 6 units, simulated). Results do not depend on it. Overlapping calls (threads, nesting)
    share one limit, restored when the last leaves."""

    @wraps(fn)
    def limited(*args: P.args, **kwargs: P.kwargs) -> R:
        _enter_one_blas_thread()
        try:
            return fn(*args, **kwargs)
        finally:
            _leave_one_blas_thread()

    return limited


_BLAS_CONTROLLER: Any = None
_BLAS_MODULES = -1
"""The ``threadpoolctl`` controller of the loaded BLAS libraries, and ``len(sys.modules)`` when it listed them."""


def _blas_controller() -> Any:
    """The loaded BLAS libraries' controller, listed afresh only when modules were imported since the last
    listing (a library loads with a module; listing reads ``/proc/self/maps``: 1.7 ms a call, 28 of the 67 s
    a streamed 22-minute session took when each of its 13 000 updates listed them)."""
    global _BLAS_CONTROLLER, _BLAS_MODULES
    import scipy.linalg  # noqa: F401 - SciPy's own BLAS loaded before the libraries are listed

    if _BLAS_CONTROLLER is None or len(sys.modules) != _BLAS_MODULES:
        from threadpoolctl import ThreadpoolController

        _BLAS_CONTROLLER, _BLAS_MODULES = ThreadpoolController(), len(sys.modules)
    return _BLAS_CONTROLLER


def _enter_one_blas_thread() -> None:
    """The limit is the process's: the first of overlapping calls (threads, nesting) sets it, the last restores.
    The libraries are listed again when a module was imported since (:func:`_blas_controller`), so a BLAS
    loaded since is limited too."""
    global _BLAS_DEPTH, _BLAS_LIMIT_NOW
    with _BLAS_LOCK:
        if _BLAS_DEPTH == 0:
            _BLAS_LIMIT_NOW = _blas_controller().limit(limits=1, user_api="blas")
        _BLAS_DEPTH += 1


def _leave_one_blas_thread() -> None:
    global _BLAS_DEPTH, _BLAS_LIMIT_NOW
    with _BLAS_LOCK:
        _BLAS_DEPTH -= 1
        if _BLAS_DEPTH == 0 and _BLAS_LIMIT_NOW is not None:
            _BLAS_LIMIT_NOW.restore_original_limits()
            _BLAS_LIMIT_NOW = None


def _start_worker(one_blas_thread: bool) -> None:
    """Initializer of :func:`imap`'s workers: die with the parent; optionally one BLAS thread (``workers``
    processes already fill the cores; more threads each would oversubscribe them)."""
    die_with_parent()
    if one_blas_thread:
        from threadpoolctl import threadpool_limits

        global _BLAS_LIMIT
        _BLAS_LIMIT = threadpool_limits(limits=1, user_api="blas")


def _call_forked(token: int, item: Any) -> Any:
    """Entry point of a forked worker: the inherited function of run ``token`` on one (pickled) item."""
    return _FORKED[token](item)


def _terminate_workers(pool: ProcessPoolExecutor) -> None:
    """SIGTERM to every worker of ``pool`` now (an interrupted run: the signal reached this process only, and a
    worker's item can take seconds). ``ProcessPoolExecutor`` has no public way before Python 3.14's
    ``terminate_workers``; without its process table nothing is done (the shutdown then waits)."""
    for process in list((getattr(pool, "_processes", None) or {}).values()):
        if process.is_alive():
            process.terminate()


def imap(
    fn: Callable[[T], R],
    items: Iterable[T],
    workers: int,
    *,
    fork: bool = False,
    window: int | None = None,
    ordered: bool = True,
    one_blas_thread: bool = False,
) -> Generator[tuple[int, R], None, None]:
    """``(k, fn(item_k))`` for every item, computed in ``workers`` worker processes (``1`` or less: here, in order).

    Args:
        fn: a picklable module-level function, or with ``fork`` any callable (inherited by the children).
        items: consumed lazily: at most ``window`` items (None: all) are submitted before their results
            are taken.
        workers: worker processes; each dies with this process (:func:`die_with_parent`).
        fork: fork the workers (needs :func:`can_fork`); else the platform's default start method.
        ordered: yield in item order; else as the results come (the lowest index first among those done).
        one_blas_thread: limit each worker to one BLAS thread.

    Items not yet started when the caller stops iterating (or an error ends the run) are cancelled; the
    call returns once the running ones have ended. An interruption (Ctrl-C, SIGTERM: a ``BaseException``
    that is not an ``Exception``) terminates the running ones instead of waiting for them.
    """
    if workers <= 1:
        for k, item in enumerate(items):
            yield k, fn(item)
        return
    token: int | None = None
    call: Callable[[Any], Any] = fn
    if fork:
        token = next(_TOKENS)
        _FORKED[token] = fn
        call = partial(_call_forked, token)
    limit = math.inf if window is None else max(1, int(window))
    queue = enumerate(items)
    pending: dict[Future[Any], int] = {}
    pool = ProcessPoolExecutor(
        max_workers=int(workers),
        mp_context=multiprocessing.get_context("fork") if fork else None,
        initializer=_start_worker,
        initargs=(one_blas_thread,),
    )
    try:

        def refill() -> None:
            while len(pending) < limit:
                nxt = next(queue, None)
                if nxt is None:
                    return
                pending[pool.submit(call, nxt[1])] = nxt[0]

        refill()
        while pending:
            if ordered:
                future = next(iter(pending))
            else:
                done = wait(pending, return_when=FIRST_COMPLETED).done
                future = min(done, key=pending.__getitem__)
            result = future.result()
            k = pending.pop(future)
            refill()
            yield k, result
    except BaseException as exc:
        if not isinstance(exc, Exception | GeneratorExit):  # Ctrl-C, SIGTERM: the running items are not waited for
            _terminate_workers(pool)
        raise
    finally:
        pool.shutdown(wait=True, cancel_futures=True)
        if token is not None:
            _FORKED.pop(token, None)
