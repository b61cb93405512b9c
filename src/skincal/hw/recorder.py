"""Crash-safe HDF5 recorder of received skin and joint-state packets.

Layout (``docs/interfaces.md``, dataset version 2) plus recording fields, per stream group:

* ``/imu/<unit>/t`` (M,) s, ``accel`` (M, 3) m/s^2, ``gyro`` (M, 3) rad/s (if the unit's first IMU
  packet had it; later IMU samples without gyro are then ignored: the contract wants it finite);
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

What reaches the file always passes :func:`skincal.data.hdf5.read_dataset` (given at least one IMU
sample, and ``robot`` when there is a joint-state stream: the contract wants a robot with joints; a
recording without a joint-state stream is an IMU-only dataset, with or without ``/robot``): per
group, a sample whose device time is not after
the previous one of the same device epoch is ignored (replays that got through, crafted times), so
``t`` is strictly increasing; across a flush, a restart or the final remap ``t`` is shifted forward
when a new clock fit would step it back. ToF samples of a unit wait until its IMU group exists (a
``/tof/<unit>`` needs an ``/imu/<unit>``). Each group keeps at most ``max_unit_samples`` samples
(default :data:`MAX_UNIT_SAMPLES`, ~11.6 h at 100 Hz, ~300 MB for an IMU group with gyro); more
are ignored. Every ignored sample is counted by reason (:attr:`Recorder.ignored`, root attrs
``ignored_samples`` and ``ignored_<reason>_samples``).

Datasets are chunked and resizable and the file is flushed every ``flush_every_samples`` samples or
``flush_every_s`` seconds; after a kill the file opens with h5py and holds everything up to the last
completed flush (root attr ``recording_complete`` stays false). A kill *during* a flush
(milliseconds) can leave the newest flush partly written: trust each group up to its shortest dataset.
"""

from __future__ import annotations

import datetime as _dt
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path

import h5py
import numpy as np

from skincal.data.writer import DatasetWriter
from skincal.errors import ConfigError, DatasetError
from skincal.hw.clock import ClockFit
from skincal.hw.packet import JointPacket, SkinPacket
from skincal.hw.receiver import Delivery, ReceiverStats, StreamKey
from skincal.io.atomic import atomic_path, release_claim
from skincal.kinematics.chain import SerialChain
from skincal.names import name_problem, printable

MAX_UNIT_SAMPLES = 1 << 22
"""Default cap on the samples one group (``imu/<unit>``, ``tof/<unit>``, ``joints``) keeps."""

IGNORE_REASONS = ("no_place", "other_robot", "no_gyro", "not_increasing", "over_cap", "group_taken", "bad_name",
                  "tof_without_imu")
"""Why samples were not recorded: gyro-only samples (no place in the layout); a second robot or joint
count; IMU samples without gyro in a group with gyro; device time not after the previous sample's;
beyond ``max_unit_samples``; a group already fed by another stream (two unit ids mapped to one name);
a unit name refused by :func:`skincal.names.name_problem`; ToF samples of a unit that never sent IMU."""

_MIN_STEP_S = 1e-9  # least increase of t between consecutive samples of a group
_TOF_WAIT_SAMPLES = 4096  # ToF samples kept per unit while its IMU group does not exist yet


@dataclass(frozen=True)
class RecordingSummary:
    """What :meth:`Recorder.finish` wrote: samples per group path (``imu/su1``), clock fits per stream,
    samples not recorded (total and by reason, see :data:`IGNORE_REASONS`)."""

    path: Path
    samples: dict[str, int]
    clock: dict[StreamKey, ClockFit]
    ignored_samples: int
    ignored: dict[str, int] = field(default_factory=dict)


def default_unit_name(unit_id: int) -> str:
    """``su<id>``: the unit name of a unit id when no mapping is given."""
    return f"su{unit_id}"


@dataclass
class _Group:
    key: StreamKey
    parts: list[dict[str, np.ndarray]] = field(default_factory=list)  # pending rows; "t" once sealed
    accepted: int = 0  # samples accepted (pending + written)
    written: int = 0  # rows in the file
    last_device_us: int | None = None  # newest accepted device time of the current epoch
    last_t: float | None = None  # last t written
    last_written_device_us: int | None = None  # its device time
    last_written_epoch: int = -1
    seg_start: int = 0  # first file row of the newest epoch written
    has_gyro: bool | None = None


def monotone_times(t: np.ndarray, epoch: np.ndarray, device_us: np.ndarray, prev_t: float | None,
                   prev_epoch: int, prev_device_us: int | None) -> np.ndarray:
    """``t`` (s, in row order) made strictly increasing after ``prev_t``: each run of one epoch is shifted
    forward when it would come closer to the row before it than half their device-time spacing (1 µs
    across epochs), as when a new clock fit steps back; any remaining non-increase (a degenerate fit,
    float resolution) is lifted by the least step. Times already increasing that way are returned as they are."""
    t = np.array(t, dtype=float)
    n = t.size
    if n == 0:
        return t
    starts = np.flatnonzero(np.r_[True, epoch[1:] != epoch[:-1]])
    stops = np.r_[starts[1:], n]
    for a, b in zip(starts.tolist(), stops.tolist(), strict=True):
        before_t = prev_t if a == 0 else t[a - 1]
        if before_t is None:
            continue
        same = prev_epoch == epoch[a] and prev_device_us is not None if a == 0 else epoch[a - 1] == epoch[a]
        before_d = prev_device_us if a == 0 else device_us[a - 1]
        gap = 0.5e-6 * (int(device_us[a]) - int(before_d)) if same and before_d is not None else 1e-6
        t[a:b] += max(0.0, before_t + max(gap, _MIN_STEP_S) - t[a])
    step = max(_MIN_STEP_S, 4 * float(np.spacing(np.max(np.abs(t)))))
    if np.all(np.diff(t) >= step) and (prev_t is None or t[0] - prev_t >= step):
        return t
    base = np.arange(1, n + 1) * step
    floor = -np.inf if prev_t is None else prev_t
    return base + np.maximum.accumulate(np.maximum(t - base, floor))


class Recorder:
    """Append deliveries (:class:`~skincal.hw.receiver.Delivery`) to an HDF5 recording.

    Args:
        path: output file; refused if it exists unless ``overwrite``.
        robot: written to ``/robot`` (name, convention, DH table, limits) when given.
        unit_names: unit id -> name (default :func:`default_unit_name`); each name must pass
            :func:`skincal.names.name_problem`.
        flush_every_samples, flush_every_s: flush thresholds (samples buffered, seconds since last).
        chunk_rows: HDF5 chunk length in samples.
        t_origin_s: host time of ``t = 0`` (default: now on ``host_clock``).
        on_flush: called with the total number of samples flushed so far after each flush.
        max_unit_samples: samples kept per group; more are ignored (``over_cap``).
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
        max_unit_samples: int = MAX_UNIT_SAMPLES,
    ) -> None:
        if flush_every_samples < 1 or flush_every_s <= 0 or chunk_rows < 1:
            raise ConfigError("recorder: flush_every_samples >= 1, flush_every_s > 0 s and chunk_rows >= 1 required")
        if max_unit_samples < 1:
            raise ConfigError(f"recorder: max_unit_samples {max_unit_samples} must be >= 1")
        self.path = Path(path)
        if self.path.exists() and not overwrite:
            raise ConfigError(f"{self.path}: file exists (choose another --out or allow overwriting)")
        self.unit_names = dict(unit_names or {})
        for unit_id, name in self.unit_names.items():
            problem = name_problem(name)
            if problem is not None:
                raise ConfigError(f"recorder: the name of unit {unit_id} ({printable(str(name))!r}) {problem}")
        names = list(self.unit_names.values())
        if len(set(names)) < len(names):  # (a default su<k> taken by a mapped name: group_taken at run time)
            clash = sorted(n for n in names if names.count(n) > 1)[0]
            raise ConfigError(f"recorder: unit name {printable(clash)!r} is given to two units")
        self.flush_every_samples, self.flush_every_s = int(flush_every_samples), float(flush_every_s)
        self.chunk_rows = int(chunk_rows)
        self.max_unit_samples = int(max_unit_samples)
        self.host_clock = host_clock
        self.t_origin_s = host_clock() if t_origin_s is None else float(t_origin_s)
        self.on_flush = on_flush
        self.ignored: dict[str, int] = dict.fromkeys(IGNORE_REASONS, 0)
        self.flushed_samples = 0
        self._groups: dict[str, _Group] = {}
        self._pending_samples = 0
        self._epoch: dict[StreamKey, int] = {}
        self._names: dict[int, str | None] = {}
        self._joint_source: tuple[int, int] | None = None  # (robot id, n_joints)
        self._last_flush_s = host_clock()
        try:  # without overwrite, a file that appeared since the check above is never truncated
            self._file: DatasetWriter | None = DatasetWriter(self.path, exclusive=not overwrite)
        except FileExistsError:
            raise ConfigError(f"{self.path}: a file appeared there as the recording started; not overwritten") from None
        except OSError as exc:
            raise DatasetError(f"{self.path}: cannot create the recording: {exc}") from exc
        release_claim(self.path)  # the live file is this recording's own: its final rewrite replaces it
        self._file.start(
            dict(
                description=description, recording_complete=False, t_origin_host_s=self.t_origin_s,
                host_clock=getattr(host_clock, "__name__", "host_clock"),
                started_utc=_dt.datetime.now(_dt.UTC).isoformat(), flushed_samples=0,
                max_unit_samples=self.max_unit_samples,
            ),
            robot,
            gravity=None,  # no root gravity in a recording without a robot; /robot gets the standard one
        )
        self._file.flush()

    @property
    def ignored_samples(self) -> int:
        """Samples received but not recorded (all reasons)."""
        return sum(self.ignored.values())

    # -- input -----------------------------------------------------------------------------
    def _unit_name(self, unit_id: int) -> str | None:
        if unit_id not in self._names:
            name = self.unit_names.get(unit_id, default_unit_name(unit_id))
            self._names[unit_id] = name if name_problem(name) is None else None
        return self._names[unit_id]

    def _queue(self, group: str, key: StreamKey, rows: dict[str, np.ndarray]) -> None:
        g = self._groups.get(group)
        if g is None:
            g = self._groups[group] = _Group(key)
        elif g.key != key:
            self.ignored["group_taken"] += len(rows["device_t_us"])
            return
        d = np.asarray(rows["device_t_us"], dtype=np.int64)
        before = np.iinfo(np.int64).min if g.last_device_us is None else g.last_device_us
        keep = d > np.maximum.accumulate(np.r_[before, d[:-1]])
        room = self.max_unit_samples - g.accepted
        self.ignored["not_increasing"] += int(d.size - keep.sum())
        if keep.sum() > room:
            idx = np.flatnonzero(keep)
            keep[idx[max(room, 0):]] = False
            self.ignored["over_cap"] += int(idx.size - max(room, 0))
        n = int(keep.sum())
        if n == 0:
            return
        part = {name: np.asarray(value)[keep] for name, value in rows.items()}
        part["epoch"] = np.full(n, self._epoch.get(key, 0), dtype=np.int64)
        g.parts.append(part)
        g.accepted += n
        g.last_device_us = int(part["device_t_us"][-1])
        self._pending_samples += n

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
                self.ignored["other_robot"] += p.n_samples  # one robot with a fixed joint count per recording
                return
            self._queue("joints", key, {**common, "q": p.q, "qd": p.qd})
            return
        assert isinstance(p, SkinPacket)
        name = self._unit_name(p.unit_id)
        if name is None:
            self.ignored["bad_name"] += p.n_samples
            return
        if p.accel is not None:
            group = f"imu/{name}"
            g = self._groups.get(group)
            has_gyro = (p.gyro is not None) if g is None or g.has_gyro is None else g.has_gyro
            if has_gyro and p.gyro is None:
                self.ignored["no_gyro"] += p.n_samples
            else:
                self._queue(group, key, {**common, "accel": p.accel, **({"gyro": p.gyro} if has_gyro else {})})
                if group in self._groups and self._groups[group].has_gyro is None:
                    self._groups[group].has_gyro = has_gyro
        if p.range is not None:
            self._queue(f"tof/{name}", key, {**common, "range": p.range})
        if p.accel is None and p.range is None:
            self.ignored["no_place"] += p.n_samples  # gyro-only samples have no place in the layout

    def restart(self, key: StreamKey, fit: ClockFit | None) -> None:
        """The device of ``key`` restarted (:class:`~skincal.hw.receiver.SkinReceiver` ``on_restart``):
        samples still pending get their times from ``fit``, the last fit of the old epoch, and later
        samples start a new epoch (device time may go back)."""
        self._epoch[key] = self._epoch.get(key, 0) + 1
        for g in self._groups.values():
            if g.key != key:
                continue
            g.last_device_us = None
            for part in g.parts:
                if "t" not in part:
                    part["t"] = self._times(part["device_t_us"], fit)

    # -- output ----------------------------------------------------------------------------
    def _times(self, device_us: np.ndarray, fit: ClockFit | None) -> np.ndarray:
        device_s = np.asarray(device_us, dtype=np.int64) * 1e-6
        return (fit.to_host(device_s) if fit is not None else device_s) - self.t_origin_s

    def maybe_flush(self, fits: Mapping[StreamKey, ClockFit]) -> bool:
        """Flush if a threshold is reached; returns whether it flushed."""
        if self._pending_samples >= self.flush_every_samples or (
            self._pending_samples and self.host_clock() - self._last_flush_s >= self.flush_every_s
        ):
            self.flush(fits)
            return True
        return False

    def flush(self, fits: Mapping[StreamKey, ClockFit]) -> None:
        """Append everything buffered to the file and flush it to disk (ToF of a unit whose IMU group
        does not exist yet stays buffered)."""
        f = self._require_open()
        written = 0
        for group in sorted(self._groups, key=lambda name: name.startswith("tof/")):  # IMU groups first
            g = self._groups[group]
            if not g.parts or (group.startswith("tof/") and f"imu/{group[4:]}" not in f):
                continue
            for part in g.parts:
                if "t" not in part:
                    part["t"] = self._times(part["device_t_us"], fits.get(g.key))
            rows = {name: np.concatenate([part[name] for part in g.parts]) for name in g.parts[0]}
            g.parts.clear()
            epoch = rows.pop("epoch")
            rows["t"] = monotone_times(rows["t"], epoch, rows["device_t_us"], g.last_t, g.last_written_epoch,
                                       g.last_written_device_us)
            changed = np.flatnonzero(np.r_[epoch[0] != g.last_written_epoch, epoch[1:] != epoch[:-1]])
            if changed.size:
                g.seg_start = g.written + int(changed[-1])
            self._append(f, group, g, rows)
            g.last_t, g.last_written_epoch = float(rows["t"][-1]), int(epoch[-1])
            g.last_written_device_us = int(rows["device_t_us"][-1])
            g.written += len(epoch)
            written += len(epoch)
        for g in self._groups.values():  # ToF waiting for its unit's IMU group: keep the newest few
            waiting = sum(len(part["device_t_us"]) for part in g.parts)
            while waiting > _TOF_WAIT_SAMPLES:
                n = len(g.parts.pop(0)["device_t_us"])
                waiting -= n
                g.accepted -= n
                self._pending_samples -= n
                self.ignored["tof_without_imu"] += n
        self.flushed_samples += written
        self._pending_samples -= written
        f.file.attrs["flushed_samples"] = self.flushed_samples
        f.flush()
        self._last_flush_s = self.host_clock()
        if self.on_flush is not None:
            self.on_flush(self.flushed_samples)

    def _append(self, f: DatasetWriter, group: str, g: _Group, rows: dict[str, np.ndarray]) -> None:
        typed = {name: np.asarray(value, dtype=np.int64 if name == "device_t_us" else np.float64)
                 for name, value in rows.items()}
        f.append(group, typed, {"stream": g.key[0], "source_id": g.key[1]}, self.chunk_rows)

    def _require_open(self) -> DatasetWriter:
        if self._file is None:
            raise DatasetError(f"{self.path}: recording already finished")
        return self._file

    def close(self) -> None:
        """Stop without finalising: the file keeps the provisional times (as after a kill)."""
        if self._file is not None:
            self._file.close()
            self._file = None

    def finish(self, fits: Mapping[StreamKey, ClockFit], stats: ReceiverStats | None = None) -> RecordingSummary:
        """Flush, recompute ``t`` of each group's newest epoch with the final ``fits`` (still strictly
        increasing), mark complete, write the counters (and the receiver's ``stats`` when given),
        replace atomically."""
        self.flush(fits)
        for g in self._groups.values():  # ToF of units that never sent IMU samples
            left = sum(len(part["device_t_us"]) for part in g.parts)
            self.ignored["tof_without_imu"] += left
            self._pending_samples -= left
            g.parts.clear()
        self.close()
        samples: dict[str, int] = {}
        with atomic_path(self.path) as tmp:
            with h5py.File(self.path, "r") as src, DatasetWriter(tmp) as writer:
                writer.copy_from(src)
                dst = writer.file
                for group, g in self._groups.items():
                    if not g.written:
                        continue
                    h = dst[group]
                    fit = fits.get(g.key)
                    if fit is not None and g.last_written_epoch == self._epoch.get(g.key, 0):
                        since = g.seg_start  # the final fit covers the device clock since its last restart
                        device_us = h["device_t_us"][since:]
                        prev_t = float(h["t"][since - 1]) if since else None
                        new_t = self._times(device_us, fit)
                        h["t"][since:] = monotone_times(new_t, np.zeros(new_t.size, dtype=np.int64), device_us,
                                                        prev_t, -1, None)
                        c = dst.require_group(f"clock/{g.key[0]}_{g.key[1]}")
                        c.attrs.update(offset_s=fit.offset_s, drift=fit.drift, device_ref_s=fit.device_ref_s,
                                       n_points=fit.n_points, span_s=fit.span_s)
                    samples[group] = int(h["t"].shape[0])
                dst.attrs.update(recording_complete=True, ignored_samples=self.ignored_samples,
                                 **{f"ignored_{reason}_samples": n for reason, n in self.ignored.items()})
                if stats is not None:
                    streams = stats.streams.values()
                    dst.attrs.update(
                        datagrams=stats.datagrams, malformed_datagrams=stats.malformed_total,
                        refused_datagrams=stats.refused, lost_packets=sum(s.lost for s in streams),
                        stale_packets=sum(s.stale for s in streams), restarts=sum(s.restarts for s in streams),
                    )
        return RecordingSummary(self.path, samples, dict(fits), self.ignored_samples, dict(self.ignored))

    def __enter__(self) -> Recorder:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


