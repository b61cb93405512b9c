"""Crash-safe HDF5 recorder of received skin and joint-state packets.

Layout (``docs/interfaces.md``, dataset version 1) plus recording fields, per stream group:

* ``/imu/<unit>/t`` (M,) s, ``accel`` (M, 3) m/s^2, ``gyro`` (M, 3) rad/s (if the unit's first IMU
  packet had it; NaN rows where a later packet did not);
* ``/tof/<unit>/t`` (K,) s, ``range`` (K,) m (NaN = no target);
* ``/joints/t`` (N,) s, ``q`` (N, n) rad, ``qd`` (N, n) rad/s (from joint-state packets of one robot);
* in each group also ``device_t_us`` (int64, the device timestamps as sent) and ``host_receive_t``
  (s, when the packet arrived), so the clock mapping can be redone offline; group attrs
  ``stream`` and ``source_id``.

``t`` is on the host clock, seconds since the recording started (root attr ``t_origin_host_s`` on
``host_clock``): ``t = fit.to_host(device_t_us * 1e-6) - t_origin`` with the stream's clock fit
(:mod:`skincal.hw.clock`). While recording, ``t`` uses the fit known at each flush (so it can step
by the change of that fit between flushes, normally well under a sample period);
:meth:`Recorder.finish` recomputes ``t`` with the final fits (since the device clock's last restart,
if it restarted), writes ``/clock/<stream>`` attrs and replaces the file atomically.

Datasets are chunked and resizable and the file is flushed every ``flush_every_samples`` samples or
``flush_every_s`` seconds; after a kill the file opens with h5py and holds everything up to the last
completed flush (root attr ``recording_complete`` stays false). A kill *during* a flush
(milliseconds) can leave the newest flush partly written: trust each group up to its shortest dataset.
"""

from __future__ import annotations

import datetime as _dt
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path

import h5py
import numpy as np

from skincal.data.atomic import atomic_path
from skincal.errors import ConfigError, DatasetError
from skincal.hw.clock import ClockFit
from skincal.hw.packet import JointPacket, SkinPacket
from skincal.hw.receiver import Delivery, StreamKey
from skincal.kinematics.chain import GRAVITY_BASE, SerialChain

_ROW_SHAPES = {"accel": (3,), "gyro": (3,), "range": (), "t": (), "device_t_us": (), "host_receive_t": ()}


@dataclass(frozen=True)
class RecordingSummary:
    """What :meth:`Recorder.finish` wrote: samples per group path (``imu/su1``), clock fits per stream."""

    path: Path
    samples: dict[str, int]
    clock: dict[StreamKey, ClockFit]
    ignored_samples: int


def default_unit_name(unit_id: int) -> str:
    """``su<id>``: the unit name of a unit id when no mapping is given."""
    return f"su{unit_id}"


class Recorder:
    """Append deliveries (:class:`~skincal.hw.receiver.Delivery`) to an HDF5 recording.

    Args:
        path: output file; refused if it exists unless ``overwrite``.
        robot: written to ``/robot`` (name, convention, DH table, limits) when given.
        unit_names: unit id -> name (default :func:`default_unit_name`).
        flush_every_samples, flush_every_s: flush thresholds (samples buffered, seconds since last).
        chunk_rows: HDF5 chunk length in samples.
        t_origin_s: host time of ``t = 0`` (default: now on ``host_clock``).
        on_flush: called with the total number of samples flushed so far after each flush.
    """

    def __init__(
        self,
        path: str | Path,
        *,
        robot: SerialChain | None = None,
        unit_names: Mapping[int, str] | None = None,
        flush_every_samples: int = 1000,
        flush_every_s: float = 1.0,
        chunk_rows: int = 1024,
        description: str = "",
        overwrite: bool = False,
        host_clock: Callable[[], float] = time.monotonic,
        t_origin_s: float | None = None,
        on_flush: Callable[[int], None] | None = None,
    ) -> None:
        if flush_every_samples < 1 or flush_every_s <= 0 or chunk_rows < 1:
            raise ConfigError("recorder: flush_every_samples >= 1, flush_every_s > 0 s and chunk_rows >= 1 required")
        self.path = Path(path)
        if self.path.exists() and not overwrite:
            raise ConfigError(f"{self.path}: file exists (choose another --out or allow overwriting)")
        self.unit_names = dict(unit_names or {})
        self.flush_every_samples, self.flush_every_s = int(flush_every_samples), float(flush_every_s)
        self.chunk_rows = int(chunk_rows)
        self.host_clock = host_clock
        self.t_origin_s = host_clock() if t_origin_s is None else float(t_origin_s)
        self.on_flush = on_flush
        self.ignored_samples = 0
        self.flushed_samples = 0
        self._pending: dict[str, dict[str, list[np.ndarray]]] = {}
        self._pending_samples = 0
        self._group_stream: dict[str, StreamKey] = {}
        self._joint_source: tuple[int, int] | None = None  # (robot id, n_joints)
        self._has_gyro: dict[str, bool] = {}
        self._last_flush_s = host_clock()
        try:
            self._file: h5py.File | None = h5py.File(self.path, "w")
        except OSError as exc:
            raise DatasetError(f"{self.path}: cannot create the recording: {exc}") from exc
        f = self._file
        f.attrs.update(
            format="skincal-dataset", version=1, description=description, recording_complete=False,
            t_origin_host_s=self.t_origin_s, host_clock=getattr(host_clock, "__name__", "host_clock"),
            started_utc=_dt.datetime.now(_dt.UTC).isoformat(), flushed_samples=0,
        )
        if robot is not None:
            write_robot(f, robot)
        f.flush()

    # -- input -----------------------------------------------------------------------------
    def _queue(self, group: str, key: StreamKey, rows: dict[str, np.ndarray]) -> None:
        self._group_stream[group] = key
        pending = self._pending.setdefault(group, {})
        for name, value in rows.items():
            pending.setdefault(name, []).append(value)
        self._pending_samples += len(rows["device_t_us"])

    def add(self, delivery: Delivery) -> None:
        """Buffer one in-order packet (call :meth:`maybe_flush` regularly)."""
        p, key = delivery.packet, delivery.key
        host = np.full(p.n_samples, delivery.host_receive_s - self.t_origin_s)
        common = {"device_t_us": p.t_us, "host_receive_t": host}
        if isinstance(p, JointPacket):
            n_joints = p.q.shape[1]
            if self._joint_source is None:
                self._joint_source = (p.source_id, n_joints)
            if self._joint_source != (p.source_id, n_joints):
                self.ignored_samples += p.n_samples  # one robot with a fixed joint count per recording
                return
            self._queue("joints", key, {**common, "q": p.q, "qd": p.qd})
            return
        assert isinstance(p, SkinPacket)
        name = self.unit_names.get(p.unit_id, default_unit_name(p.unit_id))
        if p.accel is not None:
            group = f"imu/{name}"
            has_gyro = self._has_gyro.setdefault(group, p.gyro is not None)
            rows = {**common, "accel": p.accel}
            if has_gyro:
                rows["gyro"] = p.gyro if p.gyro is not None else np.full((p.n_samples, 3), np.nan)
            self._queue(group, key, rows)
        if p.range is not None:
            self._queue(f"tof/{name}", key, {**common, "range": p.range})
        if p.accel is None and p.range is None:
            self.ignored_samples += p.n_samples  # gyro-only samples have no place in the layout

    # -- output ----------------------------------------------------------------------------
    def maybe_flush(self, fits: Mapping[StreamKey, ClockFit]) -> bool:
        """Flush if a threshold is reached; returns whether it flushed."""
        if self._pending_samples >= self.flush_every_samples or (
            self._pending_samples and self.host_clock() - self._last_flush_s >= self.flush_every_s
        ):
            self.flush(fits)
            return True
        return False

    def flush(self, fits: Mapping[StreamKey, ClockFit]) -> None:
        """Append everything buffered to the file and flush it to disk."""
        f = self._require_open()
        for group, columns in self._pending.items():
            rows = {name: np.concatenate(parts) for name, parts in columns.items()}
            fit = fits.get(self._group_stream[group])
            device_s = rows["device_t_us"] * 1e-6
            rows["t"] = (fit.to_host(device_s) if fit is not None else device_s) - self.t_origin_s
            self._append(f, group, rows)
        self.flushed_samples += self._pending_samples
        self._pending.clear()
        self._pending_samples = 0
        f.attrs["flushed_samples"] = self.flushed_samples
        f.flush()
        self._last_flush_s = self.host_clock()
        if self.on_flush is not None:
            self.on_flush(self.flushed_samples)

    def _append(self, f: h5py.File, group: str, rows: dict[str, np.ndarray]) -> None:
        g = f.require_group(group)
        if not g.attrs:
            kind, source = self._group_stream[group]
            g.attrs.update(stream=kind, source_id=source)
        n = len(rows["t"])
        for name, value in rows.items():
            value = np.asarray(value, dtype=np.int64 if name == "device_t_us" else np.float64)
            if name not in g:
                row_shape = value.shape[1:]
                g.create_dataset(name, shape=(0, *row_shape), maxshape=(None, *row_shape), dtype=value.dtype,
                                 chunks=(self.chunk_rows, *row_shape))
            ds = g[name]
            old = ds.shape[0]
            ds.resize(old + n, axis=0)
            ds[old:] = value

    def _require_open(self) -> h5py.File:
        if self._file is None:
            raise DatasetError(f"{self.path}: recording already finished")
        return self._file

    def close(self) -> None:
        """Stop without finalising: the file keeps the provisional times (as after a kill)."""
        if self._file is not None:
            self._file.close()
            self._file = None

    def finish(self, fits: Mapping[StreamKey, ClockFit]) -> RecordingSummary:
        """Flush, recompute every ``t`` with the final ``fits``, mark complete, replace atomically."""
        self.flush(fits)
        self.close()
        samples: dict[str, int] = {}
        with atomic_path(self.path) as tmp:
            with h5py.File(self.path, "r") as src, h5py.File(tmp, "w") as dst:
                dst.attrs.update(src.attrs)
                for name in src:
                    src.copy(src[name], dst, name=name)
                for group, key in self._group_stream.items():
                    g = dst[group]
                    fit = fits.get(key)
                    if fit is not None:  # the final fit covers the device clock since its last restart
                        device_us = g["device_t_us"][...]
                        back = np.flatnonzero(np.diff(device_us) < 0)
                        since = int(back[-1]) + 1 if back.size else 0
                        g["t"][since:] = fit.to_host(device_us[since:] * 1e-6) - self.t_origin_s
                        c = dst.require_group(f"clock/{key[0]}_{key[1]}")
                        c.attrs.update(offset_s=fit.offset_s, drift=fit.drift, device_ref_s=fit.device_ref_s,
                                       n_points=fit.n_points, span_s=fit.span_s)
                    samples[group] = int(g["t"].shape[0])
                dst.attrs.update(recording_complete=True, ignored_samples=self.ignored_samples)
        return RecordingSummary(self.path, samples, dict(fits), self.ignored_samples)

    def __enter__(self) -> Recorder:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def write_robot(f: h5py.File, robot: SerialChain, gravity: np.ndarray | None = None) -> None:
    """Write ``/robot`` (attrs ``name``, ``convention``, ``gravity``; ``dh``; joint limits if known)."""
    g = f.require_group("robot")
    g.attrs.update(name=robot.name, convention=robot.convention,
                   gravity=np.asarray(GRAVITY_BASE if gravity is None else gravity, dtype=float))
    g.create_dataset("dh", data=np.asarray(robot.dh, dtype=float))
    if robot.joint_lower is not None and robot.joint_upper is not None:
        g.create_dataset("joint_lower", data=np.asarray(robot.joint_lower, dtype=float))
        g.create_dataset("joint_upper", data=np.asarray(robot.joint_upper, dtype=float))
