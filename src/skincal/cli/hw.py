"""``skincal record`` (UDP skin stream -> HDF5) and ``skincal emulate`` (dataset -> UDP skin stream)."""

from __future__ import annotations

import asyncio
import math
import signal
import threading
from pathlib import Path

import typer
from rich.live import Live
from rich.table import Table

from skincal.cli.app import Throttle, app, console, seed_option
from skincal.cli.signals import run_async
from skincal.errors import ConfigError


def _status_table(stats, recorder, receiver) -> Table:  # noqa: ANN001  (types from skincal.hw)
    table = Table(title=f"skincal record -> {recorder.path}  (flushed {recorder.flushed_samples} samples)",
                  title_justify="left")
    for col in ("stream", "packets", "samples", "lost", "late", "dup", "reordered", "stale", "restarts", "offset s",
                "drift ppm"):
        table.add_column(col, justify="left" if col == "stream" else "right")
    for key, s in stats.streams.items():
        fit = receiver.clock_fit(key)
        table.add_row(f"{key[0]} {key[1]}", str(s.received), str(s.samples), str(s.lost), str(s.late),
                      str(s.duplicates), str(s.out_of_order), str(s.stale), str(s.restarts),
                      "-" if fit is None else f"{fit.offset_s:.6f}",
                      "-" if fit is None else f"{fit.drift_ppm:.1f}")
    bad = ", ".join(f"{k} {v}" for k, v in sorted(stats.malformed.items())) or "none"
    table.caption = f"datagrams {stats.datagrams}; malformed: {bad}; refused (beyond --max-units): {stats.refused}"
    return table


MAX_UNIT_SAMPLES_BOUND = 1 << 40
"""Largest ``record --max-unit-samples``: far beyond any session, well within HDF5's 64-bit sizes."""
MAX_FLUSH_EVERY_S = 3600.0
"""Longest time between two flushes of a recording to disk, s (a crash loses at most this much)."""


@app.command()
def record(
    port: int = typer.Option(..., "--port", help="UDP port to listen on (0: any free port, printed)"),
    out: Path = typer.Option(..., "--out", help="output recording (.h5)"),
    duration: float | None = typer.Option(None, "--duration", help="stop after this many seconds"),
    bind: str = typer.Option("127.0.0.1", "--bind", help="address to bind; anything but loopback needs --public"),
    public: bool = typer.Option(False, "--public", help="allow a non-loopback --bind (any sender can then record)"),
    max_units: int = typer.Option(64, "--max-units", help="skin unit ids accepted (first seen); more are refused"),
    max_unit_samples: int | None = typer.Option(
        None, "--max-unit-samples", help="samples kept per unit stream (imu, tof) and joints; more are ignored "
        "(default 2^22: 11.6 h at 100 Hz)"),
    robot: str | None = typer.Option(None, "--robot", help="robot preset written to /robot (e.g. panda); needed for "
                                        "joint states: without it the first one stops the recording"),
    flush_every: float = typer.Option(1.0, "--flush-every", help="flush to disk at least every S seconds"),
    force: bool = typer.Option(False, "--force", help="overwrite --out if it exists"),
    live: bool = typer.Option(
        False, "--live", help="calibrate while recording (needs --robot and joint states): show the live meter and "
        "stop when every unit reaches --target"
    ),
    target: str | None = typer.Option(
        None, "--target", help="--live: std to reach on every axis, position and rotation with units "
        "(default 0.3mm,0.05deg)"
    ),
    result: Path | None = typer.Option(
        None, "--result", help="--live: write the online calibration result here (.json) when the target is reached "
        "or at the end"
    ),
    keep_recording: bool = typer.Option(
        False, "--keep-recording", help="--live: keep recording after the target is reached (until --duration or "
        "Ctrl-C)"
    ),
) -> None:
    """Record skin (and joint-state) UDP packets into an HDF5 dataset; Ctrl-C or SIGTERM stop cleanly."""
    from skincal.hw.net import check_bind
    from skincal.hw.recorder import MAX_UNIT_SAMPLES
    from skincal.hw.session import record as run_record
    from skincal.io.atomic import check_output
    from skincal.kinematics.presets import get_robot

    max_unit_samples = MAX_UNIT_SAMPLES if max_unit_samples is None else max_unit_samples
    check_output(out, force=force)  # before binding: a FIFO, a device or a missing folder loses no session
    check_bind(bind, public, "--bind", "receive from beyond this machine")
    chain = get_robot(robot) if robot else None
    if not 0 < flush_every <= MAX_FLUSH_EVERY_S:  # NaN, inf, 1e308: never flushed by time
        raise ConfigError(f"--flush-every {flush_every:g} s must be a number > 0 and at most {MAX_FLUSH_EVERY_S:g} s")
    _check_duration(duration, "to record until Ctrl-C")
    if max_units < 1 or max_unit_samples < 1:
        raise ConfigError(f"--max-units {max_units} and --max-unit-samples {max_unit_samples} must be >= 1")
    if max_unit_samples > MAX_UNIT_SAMPLES_BOUND:  # an HDF5 size is a 64-bit integer; 1e20 was an internal error
        raise ConfigError(f"--max-unit-samples {max_unit_samples} must be at most 2^40 "
                          f"({MAX_UNIT_SAMPLES_BOUND}: 348 years at 100 Hz)")

    if live:
        _record_live(out, chain, target, result, keep_recording, force,
                     dict(host=bind, port=port, duration_s=duration, overwrite=force, flush_every_s=flush_every,
                          max_units=max_units, max_unit_samples=max_unit_samples))  # fmt: skip
        return
    for given, name in ((target, "--target"), (result, "--result"), (keep_recording or None, "--keep-recording")):
        if given is not None:
            raise ConfigError(f"{name} applies to --live only")

    joints_without_robot: list[int] = []  # the robot id of the first joint-state packet, when no --robot

    async def main() -> tuple:
        from skincal.hw.packet import JointPacket

        stop = asyncio.Event()
        loop = asyncio.get_running_loop()
        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.add_signal_handler(sig, stop.set)

        def on_delivery(delivery, recorder, receiver) -> None:  # noqa: ANN001
            # a recording with joints needs its robot: stop at the first joint state, not after the session
            if isinstance(delivery.packet, JointPacket) and not joints_without_robot:
                joints_without_robot.append(int(delivery.key[1]))
                stop.set()

        with Live(console=console, refresh_per_second=4, transient=False) as live:
            return await run_record(
                out, host=bind, port=port, duration_s=duration, stop=stop, robot=chain, overwrite=force,
                flush_every_s=flush_every, max_units=max_units, max_unit_samples=max_unit_samples,
                on_start=lambda p: console.print(f"listening on {bind}:{p}", highlight=False),
                on_tick=lambda st, rec, rx: live.update(_status_table(st, rec, rx)),
                on_delivery=on_delivery if chain is None else None,
            )

    summary, stats = run_async(main())
    if joints_without_robot:
        out.unlink(missing_ok=True)
        raise ConfigError(
            f"joint states arrived (robot id {joints_without_robot[0]}) but no --robot was given: a recording with "
            f"joints needs its robot (info and calibrate would refuse it); stopped at once, {out} not kept: "
            "record again with --robot (e.g. --robot panda)"
        )
    if not console.is_terminal:
        console.line()
    _print_summary(summary, stats, chain)


def _print_summary(summary, stats, chain) -> None:  # noqa: ANN001  (types from skincal.hw)
    lost = sum(s.lost for s in stats.streams.values())
    stale = sum(s.stale for s in stats.streams.values())
    console.print(f"wrote {summary.path}: {sum(summary.samples.values())} samples in {len(summary.samples)} "
                  f"streams; lost {lost} packets, malformed {stats.malformed_total}, stale {stale}, refused "
                  f"{stats.refused}, ignored {summary.ignored_samples} samples", highlight=False)
    if not any(summary.samples.values()):
        console.print("note: nothing was received: the recording holds no samples (is the sender running and sending "
                      "to this port?)", highlight=False)
    elif "joints" not in summary.samples:
        console.print("note: no joint-state stream: an IMU-only dataset (calibrate it with --reference UNIT)",
                      highlight=False)


def _record_live(out: Path, chain, target_text: str | None, result: Path | None, keep_recording: bool, force: bool,
                 options: dict) -> None:  # noqa: ANN001
    """``record --live``: the recording session with the online calibrator fed from the same packets, the
    meter (a rich table on a terminal, a line per second otherwise), a stop at the target unless
    ``keep_recording``, and the result written atomically to ``result`` at the end."""

    from skincal.cli.app import shown
    from skincal.data.result import write_result
    from skincal.io.atomic import check_output
    from skincal.viz.meter import meter_line, meter_table
    from skincal.workflows.live import Target, parse_target, record_live

    if chain is None:
        raise ConfigError("--live needs --robot (the calibrator needs the robot's kinematics)")
    target = parse_target(target_text) if target_text is not None else Target()
    if result is not None:
        check_output(result, force=force, inputs=(out,))
        if result.resolve() == out.resolve():
            raise ConfigError(f"--result {result} is the recording --out; give another file")
    if out.exists() and not force:  # before binding (hw.session.record checks it too)
        raise ConfigError(f"{out}: file exists (choose another --out or allow overwriting)")
    throttle = Throttle(0.25 if console.is_terminal else 1.0)
    port = options.pop("port")

    async def main() -> tuple:
        stop = asyncio.Event()
        loop = asyncio.get_running_loop()
        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.add_signal_handler(sig, stop.set)
        live_view = Live(console=console, refresh_per_second=4, transient=False) if console.is_terminal else None

        def on_meter(feed, stats, recorder, receiver) -> None:  # noqa: ANN001
            if not throttle.due():
                return
            title = f"record --live -> {recorder.path} (flushed {recorder.flushed_samples} samples)"
            if live_view is not None:
                live_view.update(meter_table(feed.statuses, target.position_m, target.rotation_deg, feed.t_data,
                                             None, title, feed.notes()))  # fmt: skip
            else:
                line = meter_line(feed.statuses, target.position_m, target.rotation_deg, feed.t_data)
                console.print("; ".join([line, *feed.notes()]), markup=False, highlight=False, soft_wrap=True)

        if live_view is not None:
            live_view.start()
        try:
            return await record_live(
                out, chain, target, stop=stop, on_meter=on_meter, stop_at_target=not keep_recording, port=port,
                on_start=lambda p: console.print(f"listening on {options['host']}:{p}", highlight=False), **options,
            )  # fmt: skip
        finally:
            if live_view is not None:
                live_view.stop()

    summary, stats, feed = run_async(main())
    _print_summary(summary, stats, chain)
    outcome = feed.outcome()
    if outcome is None:
        console.print("note: no joint states or no skin unit received: nothing calibrated", highlight=False)
        return
    console.print(meter_line(outcome.statuses, target.position_m, target.rotation_deg, outcome.t_data),
                  markup=False, highlight=False, soft_wrap=True)  # fmt: skip
    for note in outcome.notes:
        console.print(f"note: {shown(note)}", highlight=False)
    if outcome.reached:
        console.print(f"target {target.text()} reached by every unit after {outcome.t_data:.1f} s", highlight=False)
    else:
        missing = sum(1 for s in outcome.statuses.values() if not s.reached)
        console.print(f"[yellow]warning[/]: recording ended before the target {target.text()}: {missing} of "
                      f"{len(outcome.statuses)} units not there", highlight=False)  # fmt: skip
    if result is not None:
        import dataclasses

        from skincal.data.result import sha256_file

        write_result(dataclasses.replace(outcome.result, dataset_sha256=sha256_file(out)), result)
        console.print(f"wrote {shown(result)}", highlight=False)


MAX_CLOCK_OFFSET_S = 1e6
"""Largest ``--clock-offset`` of ``emulate``, s (11.6 days: a device clock started long before the session)."""
MAX_DRIFT_PPM = 1e4
"""Largest ``--drift-ppm`` of ``emulate`` (1 %: real oscillators drift by well under 100 ppm)."""


def _check_duration(duration: float | None, absent: str) -> None:
    """Refuse a ``--duration`` that is not a finite number > 0 (NaN stopped at once, inf never); ``absent``
    says what leaving it out does."""
    if duration is not None and not (math.isfinite(duration) and duration > 0):
        raise ConfigError(f"--duration {duration:g} s must be a finite number > 0 (leave it out {absent})")


def _check_emulate_figures(port: int, duration: float | None, clock_offset: float, drift_ppm: float) -> None:
    """Refuse ``emulate``'s absurd figures before the dataset is read, each naming its option and range: port 0
    sent to nowhere, a negative or NaN duration played nothing or everything, a NaN/inf offset or drift was a
    NumPy warning and a packet error after 'sending ...' (issue 27, absurd numeric options)."""
    if not 1 <= port <= 65535:
        raise ConfigError(f"--port {port} must be in 1..65535")
    _check_duration(duration, "to play everything")
    if not (math.isfinite(clock_offset) and abs(clock_offset) <= MAX_CLOCK_OFFSET_S):
        raise ConfigError(f"--clock-offset {clock_offset:g} s must be a finite number in "
                          f"[-{MAX_CLOCK_OFFSET_S:g}, {MAX_CLOCK_OFFSET_S:g}]")
    if not (math.isfinite(drift_ppm) and abs(drift_ppm) <= MAX_DRIFT_PPM):
        raise ConfigError(f"--drift-ppm {drift_ppm:g} must be a finite number in "
                          f"[-{MAX_DRIFT_PPM:g}, {MAX_DRIFT_PPM:g}]")


@app.command()
def emulate(
    data: Path = typer.Argument(..., help="dataset to play (.h5)"),
    port: int = typer.Option(..., "--port", help="destination UDP port"),
    host: str = typer.Option("127.0.0.1", "--host", help="destination address (loopback by default)"),
    loss: float = typer.Option(0.0, "--loss", help="probability a packet is dropped"),
    duplicate: float = typer.Option(0.0, "--duplicate", help="probability a packet is sent twice"),
    reorder: float = typer.Option(0.0, "--reorder", help="probability a datagram is sent late"),
    reorder_depth: int = typer.Option(3, "--reorder-depth", help="a late datagram is sent after up to N others"),
    jitter: float = typer.Option(0.0, "--jitter", help="mean extra send delay, s"),
    corrupt: float = typer.Option(0.0, "--corrupt", help="probability a datagram has one corrupted byte"),
    speed: float = typer.Option(1.0, "--speed", help="data seconds per wall second"),
    batch: int = typer.Option(1, "--batch", help="samples per packet"),
    duration: float | None = typer.Option(None, "--duration", help="play only the first S seconds of data"),
    clock_offset: float = typer.Option(0.0, "--clock-offset", help="device clock offset of every unit, s"),
    drift_ppm: float = typer.Option(0.0, "--drift-ppm", help="device clock drift of every unit, ppm"),
    no_joints: bool = typer.Option(False, "--no-joints", help="do not send the joint-state stream"),
    seed: int = typer.Option(0, "--seed", callback=seed_option, help="seed of the fault generator"),
) -> None:
    """Play a dataset as skin units over UDP with optional loss, duplication, reordering and corruption."""
    _check_emulate_figures(port, duration, clock_offset, drift_ppm)
    import numpy as np

    from skincal.data.hdf5 import read_dataset
    from skincal.hw.emulator import DeviceClock, Faults, SkinEmulator

    ds = read_dataset(data)
    faults = Faults(loss=loss, duplicate=duplicate, reorder=reorder, reorder_depth=reorder_depth, jitter_s=jitter,
                    corrupt=corrupt)
    clock = DeviceClock(clock_offset, drift_ppm)
    emu = SkinEmulator(ds, port, host=host, faults=faults, rng=np.random.default_rng(seed), speed=speed,
                       batch=batch, clocks=dict.fromkeys([*ds.imu, *ds.tof], clock), duration_s=duration,
                       joints=not no_joints)
    plan = emu.plan
    console.print(f"sending {plan.datagrams_planned} datagrams to {host}:{port} at speed {speed:g} "
                  f"(units {', '.join(f'{n}={i}' for n, i in plan.unit_ids.items())})", highlight=False)
    main_thread = threading.current_thread() is threading.main_thread()  # signals only work there
    previous = signal.signal(signal.SIGTERM, lambda *_: emu.stop()) if main_thread else None
    try:
        report = emu.run()
    finally:
        if main_thread:
            signal.signal(signal.SIGTERM, previous)
    table = Table(title=f"sent {report.datagrams_sent} datagrams in {report.wall_s:.2f} s", title_justify="left")
    for col in ("stream", "packets", "dropped", "duplicated", "corrupted"):
        table.add_column(col, justify="left" if col == "stream" else "right")
    for key in sorted(report.packets):
        table.add_row(f"{key[0]} {key[1]}", str(report.packets[key]), str(len(report.dropped[key])),
                      str(len(report.duplicated[key])), str(len(report.corrupted[key])))
    console.print(table)
    if not report.completed:
        console.print("stopped early", highlight=False)
