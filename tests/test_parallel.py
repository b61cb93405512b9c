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
