"""A recording session: a :class:`SkinReceiver` feeding a :class:`Recorder` until told to stop."""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable, Mapping
from pathlib import Path

from skincal.errors import ConfigError
from skincal.hw.receiver import Delivery, ReceiverStats, SkinReceiver
from skincal.hw.recorder import MAX_UNIT_SAMPLES, Recorder, RecordingSummary
from skincal.kinematics.chain import SerialChain


async def record(
    path: str | Path,
    *,
    host: str = "127.0.0.1",
    port: int = 0,
    duration_s: float | None = None,
    stop: asyncio.Event | None = None,
    robot: SerialChain | None = None,
    unit_names: Mapping[int, str] | None = None,
    flush_every_s: float = 1.0,
    flush_every_samples: int = 1000,
    overwrite: bool = False,
    description: str = "",
    reorder_window: int = 64,
    reorder_timeout_s: float = 0.2,
    tick_s: float = 0.05,
    on_start: Callable[[int], None] | None = None,
    on_tick: Callable[[ReceiverStats, Recorder, SkinReceiver], None] | None = None,
    on_flush: Callable[[int], None] | None = None,
    on_delivery: Callable[[Delivery, Recorder, SkinReceiver], None] | None = None,
    max_units: int = 64,
    max_robots: int = 4,
    max_unit_samples: int = MAX_UNIT_SAMPLES,
) -> tuple[RecordingSummary, ReceiverStats]:
    """Receive on ``host:port`` and record to ``path`` until ``duration_s`` (s) elapses or ``stop`` is set.

    ``on_start(port)`` is called once bound; ``on_tick(stats, recorder, receiver)`` every ``tick_s``
    seconds (live status); ``on_flush(total_samples)`` after each flush; ``on_delivery(delivery, recorder,
    receiver)`` with each in-order packet after the recorder took it (a live consumer). On the way out (normal end,
    ``stop``, or cancellation) the reorder buffers are drained and the file finished atomically, with
    the receiver's counters as root attributes. ``max_units``/``max_robots`` cap the sources accepted
    (:class:`SkinReceiver`), ``max_unit_samples`` the samples kept per group (:class:`Recorder`).
    Returns the recording summary and the final receiver counters.
    """
    if duration_s is not None and not duration_s > 0:  # NaN too: it would stop at once
        raise ConfigError(f"record: duration {duration_s} s must be > 0")
    stop = stop or asyncio.Event()
    if Path(path).exists() and not overwrite:  # fail before binding, and bind before creating the file
        raise ConfigError(f"{path}: file exists (choose another --out or allow overwriting)")
    receiver = SkinReceiver(host, port, reorder_window=reorder_window, reorder_timeout_s=reorder_timeout_s,
                            max_units=max_units, max_robots=max_robots)
    bound = await receiver.start()
    try:  # no await between binding and attaching the recorder: no datagram is handled in between
        recorder = Recorder(
            path, robot=robot, unit_names=unit_names, flush_every_s=flush_every_s,
            flush_every_samples=flush_every_samples, overwrite=overwrite, description=description,
            on_flush=on_flush, max_unit_samples=max_unit_samples,
        )
    except BaseException:
        await receiver.stop()
        raise
    if on_delivery is None:
        receiver.on_packet = recorder.add
    else:

        def deliver(delivery: Delivery) -> None:
            recorder.add(delivery)
            on_delivery(delivery, recorder, receiver)

        receiver.on_packet = deliver
    receiver.on_restart = recorder.restart
    if on_start is not None:
        on_start(bound)
    t_end = None if duration_s is None else time.monotonic() + duration_s
    try:
        while not stop.is_set() and (t_end is None or time.monotonic() < t_end):
            timeout = tick_s if t_end is None else max(0.0, min(tick_s, t_end - time.monotonic()))
            try:
                await asyncio.wait_for(stop.wait(), timeout)
            except TimeoutError:
                pass
            recorder.maybe_flush(receiver.clock_fits())
            if on_tick is not None:
                on_tick(receiver.stats(), recorder, receiver)
    finally:
        await receiver.stop()
        summary = recorder.finish(receiver.clock_fits(), receiver.stats())
    return summary, receiver.stats()
