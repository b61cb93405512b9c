"""A recorded dataset fed to the streaming calibrator as a live stream would be (:func:`replay`)."""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np

from skincal.calib.online.estimator import OnlineCalibrator
from skincal.data.dataset import Dataset
from skincal.errors import ConfigError


def replay(
    dataset: Dataset,
    calibrator: OnlineCalibrator,
    chunk_s: float = 0.1,
    speed: float | None = None,
    on_chunk: Callable[[float], bool | None] | None = None,
) -> None:
    """Feed ``dataset``'s joint states and IMU streams to ``calibrator`` in arrival order, ``chunk_s``
    of data at a time (each unit's samples by their stamps), at ``speed`` times real time (None: as
    fast as possible), calling ``update()`` per chunk and ``on_chunk(t_end)``; stops early when
    ``on_chunk`` returns True; ``finish()`` at the data's end only: after an early stop the calibrator stays as
    the stop found it (finishing would absorb the pending samples against a last joint block conditioned
    without its future margin: on a simulated Panda stopped at 13.6 s of 77.5 s, one unit's std 0.25 -> 1.5 mm)."""
    if dataset.joints is None:
        raise ConfigError("online calibration needs the dataset's joint states")
    if not (np.isfinite(chunk_s) and chunk_s > 0):
        raise ConfigError(f"chunk must be a positive number of seconds, got {chunk_s}")
    j = dataset.joints
    tj = np.asarray(j.t, dtype=float)
    streams = {u: dataset.imu[u] for u in calibrator.units if u in dataset.imu}
    t0 = float(tj[0])
    t_end = max([float(tj[-1])] + [float(np.asarray(s.t)[-1]) for s in streams.values() if len(s.t)])
    wall0 = time.perf_counter()
    cursor_j = 0
    cursors = dict.fromkeys(streams, 0)
    edge = t0
    while edge < t_end:
        edge = min(edge + chunk_s, t_end)
        last = edge >= t_end
        k = int(np.searchsorted(tj, edge, side="right")) if not last else tj.size
        if k > cursor_j:
            calibrator.add_joint_states(tj[cursor_j:k], j.q[cursor_j:k], j.qd[cursor_j:k])
            cursor_j = k
        for u, s in streams.items():
            ts = np.asarray(s.t, dtype=float)
            k = int(np.searchsorted(ts, edge, side="right")) if not last else ts.size
            c = cursors[u]
            if k > c:
                calibrator.add_imu(u, ts[c:k], s.accel[c:k], None if s.gyro is None else s.gyro[c:k])
                cursors[u] = k
        calibrator.update()
        if speed is not None and speed > 0:
            ahead = (edge - t0) / speed - (time.perf_counter() - wall0)
            if ahead > 0:
                time.sleep(ahead)
        if on_chunk is not None and on_chunk(edge):
            return  # stopped (at a target): the state it was judged on, not a last block without its margin
    calibrator.finish()
