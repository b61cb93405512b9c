"""``skincal protocol --adaptive``: the motion chosen segment by segment (:mod:`skincal.workflows.adaptive`).

Each segment is written beside ``--out`` as ``NAME_001.EXT``, ``NAME_002.EXT``, ... (same format as
``--out``) as soon as it is chosen, for the robot to execute; at the end ``--out`` holds the whole
executed motion and ``--result`` the streaming calibrator's result (method ``online``).

* ``--simulate``: a simulated robot executes each segment (:func:`skincal.workflows.adaptive.run_simulated`)
  and the true errors are printed at the end;
* ``--port``: a real robot streams its joint states and the skin over UDP (the receiver of ``skincal
  record``, written to ``--record``); a segment counts as executed once the joint stream shows the robot
  at rest at the segment's end pose after the segment's duration (:class:`skincal.workflows.adaptive.LiveDesigner`).
"""

from __future__ import annotations

import glob
import math
from pathlib import Path

from skincal.cli.app import at_rate, console, joint_names, shown
from skincal.cli.signals import run_async
from skincal.errors import ConfigError


def segment_path(out: Path, k: int) -> Path:
    """The file of segment ``k`` (1-based) beside ``out``: ``NAME_00k.EXT``."""
    return out.with_name(f"{out.stem}_{k:03d}{out.suffix}")


def _say(text: str) -> None:
    console.print(shown(text), highlight=False, soft_wrap=True)


def run_adaptive(chain, out: Path, *, rate: float, seed: int, force: bool, target: str, result: Path | None,  # noqa: ANN001
                 max_motion: float, simulate: bool, noise: str, placement: str, units: int | None, joints: str,
                 port: int | None, bind: str, public: bool, record_out: Path | None,
                 inputs: tuple[Path, ...]) -> None:  # fmt: skip
    """The ``--adaptive`` branch of ``skincal protocol`` (module docstring); options checked before any work."""
    from skincal.io.atomic import check_output
    from skincal.workflows.live import parse_target

    goal = parse_target(target)
    if not (math.isfinite(max_motion) and max_motion > 0):
        raise ConfigError(f"--max-motion must be a positive number of seconds, got {max_motion}")
    result = result if result is not None else out.with_name(f"{out.stem}_result.json")
    if result.suffix.lower() != ".json":
        raise ConfigError(f"--result {result}: the result is written as .json")
    check_output(result, force=force, inputs=inputs)
    if result.resolve() == out.resolve():
        raise ConfigError(f"--result {result} is --out; give another file")
    earlier = sorted(
        glob.glob(glob.escape(str(out.with_name(out.stem))) + "_[0-9][0-9][0-9]" + glob.escape(out.suffix))
    )
    if earlier and (not force or out.suffix == ""):
        raise ConfigError(f"{earlier[0]} exists (a segment of an earlier run): remove it"
                          + ("" if out.suffix == "" else " or pass --force"))  # fmt: skip
    for path in earlier:
        if not Path(path).is_file() or Path(path).is_symlink():
            raise ConfigError(f"{path} exists and is not a segment file (a folder or a link): remove it")
    if simulate:
        for given, name in ((port, "--port"), (record_out, "--record")):
            if given is not None:
                raise ConfigError(f"{name} is for a real robot; --simulate simulates it")
        _remove_segments(earlier)
        _simulated(chain, out, result, rate=rate, seed=seed, goal=goal, max_motion=max_motion, noise=noise,
                   placement=placement, units=units, joints=joints)  # fmt: skip
        return
    if port is None or record_out is None:
        raise ConfigError("--adaptive needs --simulate, or --port and --record for a real robot's stream")
    for given, name in ((noise != "realistic" or None, "--noise"), (placement != "paper" or None, "--placement"),
                        (units, "--units"), (joints != "auto" or None, "--joints")):  # fmt: skip
        if given is not None:
            raise ConfigError(f"{name} applies to --simulate only")
    _live(chain, out, result, rate=rate, seed=seed, goal=goal, max_motion=max_motion, port=port, bind=bind,
          public=public, record_out=record_out, force=force, earlier=earlier)  # fmt: skip


def _remove_segments(earlier: list[str]) -> None:
    """``--force``: the segment files of an earlier run go before this run writes its own, so that no stale
    segment (a higher number than this run reaches) is left beside the new ones for the robot to execute."""
    for path in earlier:
        Path(path).unlink(missing_ok=True)


def _write_segment(chain, out: Path, k: int, segment, rate: float) -> Path:  # noqa: ANN001
    from skincal.protocol.export import export_trajectory

    path = segment_path(out, k)
    export_trajectory(at_rate(segment, rate), path, joint_names=joint_names(chain))
    return path


def _segment_line(record, path: Path) -> str:  # noqa: ANN001
    pos, rot = record.worst()
    done = sum(1 for s in record.statuses.values() if s.reached)
    worst = (f"worst std {pos:.3f} mm / {rot:.4f} deg" if math.isfinite(pos) and math.isfinite(rot)
             else "worst std undetermined")  # fmt: skip
    return (f"segment {record.index}: {record.candidate.describe()} -> {path.name}; motion {record.t_end:.1f} s; "
            f"{worst}; {done}/{len(record.statuses)} units at target")  # fmt: skip


def _finish(chain, out: Path, result_path: Path, trajectory, result, reached: bool, motion_s: float, n: int,  # noqa: ANN001
            rate: float, goal) -> None:  # noqa: ANN001  # fmt: skip
    from skincal.data.result import write_result
    from skincal.protocol.export import export_trajectory

    if trajectory is not None:
        export_trajectory(at_rate(trajectory, rate), out, joint_names=joint_names(chain))
        _say(f"wrote {out}: the whole motion, {motion_s:.1f} s in {n} segments")
    write_result(result, result_path)
    _say(f"wrote {result_path}: {len(result.units)} units calibrated (method online)")
    if reached:
        _say(f"target {goal.text()} reached by every unit after {motion_s:.1f} s of motion")
    else:
        console.print(f"[yellow]warning[/]: stopped before the target {goal.text()} ({motion_s:.1f} s of motion)",
                      highlight=False)  # fmt: skip


def _simulated(chain, out: Path, result_path: Path, *, rate: float, seed: int, goal, max_motion: float,  # noqa: ANN001
               noise: str, placement: str, units: int | None, joints: str) -> None:  # fmt: skip
    from skincal.bench.adaptive import worst
    from skincal.workflows.adaptive import run_simulated

    def on_segment(record) -> None:  # noqa: ANN001
        path = _write_segment(chain, out, record.index, record.candidate.trajectory, rate)
        _say(_segment_line(record, path))

    run = run_simulated(chain, placement, units, noise, seed, joints=joints, target=goal, max_motion_s=max_motion,
                        on_segment=on_segment)  # fmt: skip
    _finish(chain, out, result_path, run.trajectory, run.result, run.loop.reached, run.motion_s,
            len(run.loop.segments), rate, goal)  # fmt: skip
    if not run.errors.get("units"):
        _say("true errors (simulated truth): no unit calibrated")
        return
    pos, rot, links = worst(run.errors)
    _say(f"true errors (simulated truth): worst unit {pos:.3f} mm / {rot:.4f} deg; "
         f"links {'all right' if links else 'NOT all right'}")  # fmt: skip


def _live(chain, out: Path, result_path: Path, *, rate: float, seed: int, goal, max_motion: float, port: int,  # noqa: ANN001
          bind: str, public: bool, record_out: Path, force: bool, earlier: list[str]) -> None:  # fmt: skip
    import asyncio
    import signal

    import numpy as np

    from skincal.hw.net import check_bind
    from skincal.io.atomic import check_output
    from skincal.workflows.adaptive import LiveDesigner
    from skincal.workflows.live import record_live

    check_bind(bind, public, "--bind", "receive from beyond this machine")
    check_output(record_out, force=force)
    if record_out.resolve() in (out.resolve(), result_path.resolve()):
        raise ConfigError(f"--record {record_out} is another output; give another file")
    _remove_segments(earlier)
    designer = LiveDesigner(chain, np.random.default_rng([int(seed), 16]), max_motion_s=max_motion)

    def on_meter(feed, stats, recorder, receiver) -> None:  # noqa: ANN001
        record = designer.tick(feed)
        if designer.pending is not None and designer.pending_written is False:
            path = _write_segment(chain, out, designer.index, designer.pending, rate)
            designer.pending_written = True
            _say(f"segment {designer.index}: {designer.pending_text} -> {path.name}: run it on the robot")
        if record is not None:
            _say(_segment_line(record, segment_path(out, record.index)))

    async def main() -> tuple:
        stop = asyncio.Event()
        loop = asyncio.get_running_loop()
        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.add_signal_handler(sig, stop.set)

        def meter(feed, stats, recorder, receiver) -> None:  # noqa: ANN001
            on_meter(feed, stats, recorder, receiver)
            if designer.done:
                stop.set()

        return await record_live(record_out, chain, goal, stop=stop, on_meter=meter, port=port, host=bind,
                                 overwrite=force,
                                 on_start=lambda p: _say(f"listening on {bind}:{p}"))  # fmt: skip

    _summary, _stats, feed = run_async(main())
    outcome = feed.outcome()
    if outcome is None:
        _say("note: no joint states or no skin unit received: nothing calibrated")
        return
    _finish(chain, out, result_path, designer.trajectory(), outcome.result, outcome.reached, designer.motion_s,
            designer.index, rate, goal)  # fmt: skip
