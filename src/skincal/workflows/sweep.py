"""Run independent benchmark jobs in local processes or on an existing Dask cluster.

A job is a picklable object and ``fn`` a module-level function of it (so that a forked process or
a Dask worker can import it); ``fn(job)`` returns the job's record. Results come back in the order
of ``jobs``; ``progress`` is called with each record as soon as it is done (completion order).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any, TypeVar

from skincal.errors import ConfigError

J = TypeVar("J")
R = TypeVar("R")


def map_local(
    fn: Callable[[J], R], jobs: Sequence[J], workers: int = 1, progress: Callable[[R], None] | None = None
) -> list[R]:
    """``[fn(job) for job in jobs]`` in ``workers`` local processes (``1`` or less: in this process)."""
    if workers <= 1 or len(jobs) <= 1:
        out = []
        for job in jobs:
            out.append(fn(job))
            if progress is not None:
                progress(out[-1])
        return out
    from skincal.parallel import imap

    records: dict[int, R] = {}
    for k, record in imap(fn, jobs, workers, ordered=False):  # workers die with us
        records[k] = record
        if progress is not None:
            progress(record)
    return [records[k] for k in range(len(jobs))]


def map_dask(
    fn: Callable[[J], R], jobs: Sequence[J], address: Any, progress: Callable[[R], None] | None = None
) -> list[R]:
    """``[fn(job) for job in jobs]`` on an existing ``dask.distributed`` cluster (scheduler address or a ``Client``)."""
    try:
        from dask.distributed import Client, as_completed
    except ImportError:
        raise ConfigError("--dask needs dask.distributed: pip install 'skincal[dask]'") from None
    client = address if isinstance(address, Client) else Client(address, set_as_default=False)
    try:
        futures = client.map(fn, list(jobs), pure=False)
        for fut in as_completed(futures, loop=client.loop):
            record = fut.result()
            if progress is not None:
                progress(record)
        return [fut.result() for fut in futures]
    finally:
        if client is not address:
            client.close()


def map_jobs(
    fn: Callable[[J], R],
    jobs: Sequence[J],
    *,
    workers: int = 1,
    dask: Any = None,
    progress: Callable[[R], None] | None = None,
) -> list[R]:
    """:func:`map_dask` when a Dask scheduler (address or ``Client``) is given, else :func:`map_local`."""
    if dask is not None:
        return map_dask(fn, jobs, dask, progress)
    return map_local(fn, jobs, workers, progress)
