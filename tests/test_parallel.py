"""The one parallel runner (:mod:`skincal.parallel`): order, read-ahead window, forked closures."""

from __future__ import annotations

import os

import pytest

from skincal.parallel import can_fork, imap, running_forked


def test_serial_and_process_runs_agree_in_item_order():
    items = [3, -1, 4, -1, 5]
    assert list(imap(abs, items, 1)) == list(enumerate(map(abs, items)))
    assert list(imap(abs, items, 2)) == list(enumerate(map(abs, items)))
    unordered = list(imap(abs, items, 2, ordered=False))
    assert sorted(unordered) == list(enumerate(map(abs, items)))


@pytest.mark.skipif(not can_fork(), reason="needs fork")
def test_forked_closures_run_in_workers_and_items_are_read_within_the_window():
    """A closure (not picklable) runs in forked children; items are drawn at most ``window`` ahead."""
    parent = os.getpid()
    offset = 10
    drawn: list[int] = []

    def items():
        for k in range(6):
            drawn.append(k)
            yield k

    run = imap(lambda k: (k + offset, os.getpid()), items(), 2, fork=True, window=2)
    k, (value, pid) = next(run)
    assert (k, value) == (0, 10) and pid != parent
    assert len(drawn) <= 3  # two in flight, one drawn after the first result
    assert running_forked() == 1
    assert [v for _, (v, _) in run] == [11, 12, 13, 14, 15]
    assert running_forked() == 0


@pytest.mark.skipif(not can_fork(), reason="needs fork")
def test_a_worker_error_reaches_the_caller_and_releases_the_run():
    with pytest.raises(ZeroDivisionError):
        list(imap(lambda k: 1 // (k - 2), range(5), 2, fork=True))
    assert running_forked() == 0


def _blas_threads() -> list[int]:
    from threadpoolctl import threadpool_info

    return [int(i["num_threads"]) for i in threadpool_info() if i["user_api"] == "blas"]


def test_one_blas_thread_holds_inside_and_restores_after():
    from skincal.parallel import one_blas_thread

    before = _blas_threads()

    @one_blas_thread
    def inside(x: int) -> tuple[int, list[int]]:
        return x + 1, _blas_threads()

    value, threads = inside(1)
    assert value == 2 and threads and all(n == 1 for n in threads)
    assert _blas_threads() == before


def test_calibrate_runs_its_split_check_with_one_blas_thread(monkeypatch):
    """The split check's part fits ran with every BLAS thread: a 27 x 27 ``eigh`` took 15 ms instead of
    0.06 ms on a busy 2-core machine (the split check's share of mle's CPU halved with one)."""
    import skincal.calib.consistency as consistency
    from skincal.calib import calibrate
    from skincal.workflows.session import simulate_dataset

    seen: list[list[int]] = []
    real_check = consistency.check

    def check(*args, **kwargs):
        seen.append(_blas_threads())
        return real_check(*args, **kwargs)

    monkeypatch.setattr(consistency, "check", check)
    ds = simulate_dataset("panda", "random", 1, "realistic", "fast", seed=3)
    result = calibrate(ds, "mle")
    assert seen and all(n == 1 for n in seen[0])
    assert "consistency" in next(iter(result.units.values())).extras


def test_one_blas_thread_nested_keeps_the_limit_until_the_outermost_call_leaves():
    """Nested calls (calibrate inside a decorated caller) share one limit: the inner call's end must not restore
    it under the outer one, and the outer one's end restores what was before."""
    from skincal.parallel import one_blas_thread

    before = _blas_threads()
    seen: list[list[int]] = []

    @one_blas_thread
    def inner() -> None:
        seen.append(_blas_threads())

    @one_blas_thread
    def outer() -> None:
        inner()
        seen.append(_blas_threads())  # after the inner call has left

    outer()
    assert len(seen) == 2 and all(n == 1 for threads in seen for n in threads)
    assert _blas_threads() == before


def test_an_interrupted_run_does_not_wait_for_its_running_items():
    """Ctrl-C during a forked run terminates the running items instead of waiting for them (the split check's
    parts take seconds each: SIGTERM took 11 s to end a 24-unit calibrate; a service manager kills at 10 s)."""
    import signal
    import threading
    import time

    start = time.monotonic()
    main = threading.main_thread().ident
    assert main is not None
    timer = threading.Timer(1.0, lambda: signal.pthread_kill(main, signal.SIGINT))  # a real Ctrl-C, in its wait
    timer.start()
    try:
        with pytest.raises(KeyboardInterrupt):
            for _ in imap(time.sleep, [60.0, 60.0, 60.0], 2, fork=True):
                pass
    finally:
        timer.cancel()
    assert time.monotonic() - start < 10.0


def test_one_blas_thread_lists_the_libraries_again_only_after_an_import(monkeypatch):
    """Listing the BLAS libraries reads /proc/self/maps (1.7 ms): a streamed session's 13 000 updates spent 28 of
    their 67 s on it. The listing is kept until a module is imported (a library loads with a module)."""
    import sys
    import types

    import skincal.parallel as parallel

    monkeypatch.setattr(parallel, "_BLAS_CONTROLLER", None)

    @parallel.one_blas_thread
    def work() -> list[int]:
        return _blas_threads()

    assert all(n == 1 for n in work())
    first = parallel._BLAS_CONTROLLER
    assert first is not None and all(n == 1 for n in work()) and parallel._BLAS_CONTROLLER is first
    monkeypatch.setitem(sys.modules, "skincal_test_newly_imported", types.ModuleType("skincal_test_newly_imported"))
    assert all(n == 1 for n in work()) and parallel._BLAS_CONTROLLER is not first
