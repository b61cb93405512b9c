"""The live session (issue 16): --target parsing, the meter's table (names escaped), a dataset followed
through the online calibrator until every unit reaches the target, and ``record --live``'s feed from
the real receiver with the real emulator on loopback."""

from __future__ import annotations

import asyncio
import math

import h5py
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from rich.console import Console

from skincal.calib.metrics import evaluate
from skincal.errors import ConfigError
from skincal.hw.emulator import DeviceClock, SkinEmulator
from skincal.viz.meter import meter_line, meter_table
from skincal.workflows.live import Target, follow_dataset, parse_target, record_live, report_spacing_checked
from skincal.workflows.session import simulate_dataset


@pytest.fixture(scope="module")
def fast_ds():
    """Six units (paper placement) on panda, realistic IMUs and controller joint states, fast protocol."""
    return simulate_dataset("panda", "paper", noise="realistic", protocol="fast", seed=1)


# -- --target ---------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("text", "position_m", "rotation_deg"),
    [
        ("0.3mm,0.05deg", 3e-4, 0.05),
        ("0.05deg,300um", 3e-4, 0.05),
        (" 0.3 mm , 0.05 deg ", 3e-4, 0.05),
        ("1e-3m,1mrad", 1e-3, math.degrees(1e-3)),
        ("0.1cm,3arcmin", 1e-3, 0.05),
        (".5MM,.1DEG", 5e-4, 0.1),
    ],
)
def test_target_takes_a_length_and_an_angle_with_units(text, position_m, rotation_deg):
    target = parse_target(text)
    assert target.position_m == pytest.approx(position_m) and target.rotation_deg == pytest.approx(rotation_deg)


@pytest.mark.adversarial
@pytest.mark.parametrize(
    "text",
    ["0.3", "0.3mm", "-1mm,0.05deg", "0mm,0.05deg", "nanmm,0.05deg", "infmm,1deg", "1e999mm,1deg", "0.3mm,0.3mm",
     "0.05deg,0.05deg", "0.3kg,0.05deg", "mm,deg", "0.3mm,0.05deg,1mm", "", ",", "0.3mm;0.05deg", "0x10mm,1deg",
     "1_0mm,1deg", "0.3mm,\x1b[2J1deg"],
)  # fmt: skip
def test_target_garbage_is_one_line_config_error(text):
    with pytest.raises(ConfigError) as info:
        parse_target(text)
    message = str(info.value)
    assert message.startswith("--target") and "\n" not in message and "\x1b" not in message


@pytest.mark.adversarial
@settings(max_examples=300, deadline=None)
@given(st.text(max_size=30))
def test_target_parser_never_crashes_and_accepts_only_finite_positive(text):
    try:
        target = parse_target(text)
    except ConfigError as exc:
        assert "\n" not in str(exc)
        return
    assert 0 < target.position_m < math.inf and 0 < target.rotation_deg < math.inf


# -- the meter --------------------------------------------------------------------------------------


def _status(name, reached, std_m, std_deg, missing="", link=3, best_joint=2):
    import dataclasses

    from skincal.calib.online import UnitStatus

    values = dict(
        unit=name, link=link, link_margin=4.0, pose=None, position_std_m=np.full(3, std_m),
        rotation_std_deg=np.full(3, std_deg), samples=1200, moving_samples=700, missing=missing,
        best_joint=best_joint, reached=reached, t_last=12.0, aligned=True,
    )  # fmt: skip
    return UnitStatus(**{f.name: values[f.name] for f in dataclasses.fields(UnitStatus)})


def _render(table) -> str:
    console = Console(width=200, record=True, force_terminal=True, color_system="truecolor")
    console.print(table)
    return console.export_text()


@pytest.mark.adversarial
def test_meter_table_shows_names_and_notes_as_stored():
    statuses = {
        "su\x1b[2Jx": _status("su\x1b[2Jx", False, math.inf, math.inf, "link undecided between 3 and 4", None),
        "[blink]su2": _status("[blink]su2", False, 5e-4, 0.02, "[red]no motion of joints 1-3 yet", 3, 0),
        "su3\u202e": _status("su3\u202e", True, 1e-4, 0.01),
    }
    text = _render(meter_table(statuses, 3e-4, 0.05, 12.0, 80.0, "follow [bold]x.h5", ("note [i]y",)))
    assert "\x1b[2J" not in text and "\u202e" not in text
    assert "su\\x1b[2Jx" in text and "su3\\u202e" in text  # control characters shown escaped
    assert "[blink]su2" in text and "[red]no motion of joints 1-3 yet" in text  # markup shown, not applied
    assert "follow [bold]x.h5: 1/3 units at target (0.3 mm, 0.05 deg); data 12.0 / 80.0 s" in text
    assert "note [i]y" in text
    assert "undetermined" in text and "0.500" in text and "0.0200" in text and "joint 1" in text
    assert "at target" in text and "?" in text  # undecided link
    line = meter_line(statuses, 3e-4, 0.05, 12.0, 80.0)
    assert line == ("data 12.0/80.0 s: 1/3 units at target; worst pos std undetermined (su\\x1b[2Jx); "
                    "worst rot std undetermined (su\\x1b[2Jx)")  # fmt: skip


# -- following a dataset ----------------------------------------------------------------------------


def test_follow_stops_at_the_target_before_the_data_end(fast_ds):
    seen: list[tuple[float, int]] = []
    # 1 mm: the fast protocol leaves one unit's std along its link's z at ~0.5 mm (mle's too)
    outcome = follow_dataset(
        fast_ds, Target(1e-3, 0.05), speed=None,
        on_meter=lambda s, t, end: seen.append((t, sum(u.reached for u in s.values()))),
    )  # fmt: skip
    print(f"target reached after {outcome.t_data:.1f} s of {outcome.t_end:.1f} s of data")
    assert outcome.reached and outcome.t_data < 0.6 * outcome.t_end
    assert all(s.reached for s in outcome.statuses.values())
    assert seen[0][1] < 6 and max(n for _, n in seen) == 6  # the meter saw it converge
    assert seen[-1][0] == pytest.approx(outcome.t_data)
    assert np.all(np.diff([t for t, _ in seen[:-1]]) > 0)
    result = outcome.result
    assert result.method == "online" and sorted(result.units) == sorted(fast_ds.units)
    doc = evaluate(result, fast_ds)
    assert doc.links_correct == 6
    for unit in doc.units.values():  # the std is honest: the error is within a few std of the target
        assert unit.position_error_mm < 1.5 and unit.rotation_error_deg < 0.1


def test_follow_without_stop_runs_to_the_end_and_unit_selection(fast_ds):
    outcome = follow_dataset(fast_ds, Target(1e-9, 1e-9), speed=None, units=["su2", "su5"])
    assert not outcome.reached and outcome.t_data == pytest.approx(outcome.t_end, abs=0.11)
    assert sorted(outcome.result.units) == ["su2", "su5"]
    with pytest.raises(ConfigError, match="no unit 'nope'"):
        follow_dataset(fast_ds, units=["nope"])


# -- record --live: the real emulator on loopback, a real UDP socket -------------------------------


def test_record_live_follows_the_received_stream_on_the_recording_clock(tmp_path, fast_ds):
    """The emulator plays 15 s of the dataset to ``record_live`` from device clocks far apart (units at
    +500 s, the robot at +2000 s, drifting); the calibrator's samples carry the recording's host times
    (its newest absorbed instant is near the recorded file's last), so the streams line up: every unit
    is followed and its link is the true one."""
    path = tmp_path / "live.h5"
    port: list[int] = []

    async def main():
        stop = asyncio.Event()
        task = asyncio.create_task(
            record_live(
                path,
                fast_ds.robot,
                Target(1e-9, 1e-9),
                stop=stop,
                warmup_s=0.5,
                on_start=port.append,
                flush_every_s=0.2,
                reorder_timeout_s=0.1,
            )
        )
        while not port:
            await asyncio.sleep(0.01)
        emu = SkinEmulator(fast_ds, port[0], rng=np.random.default_rng(3), duration_s=15.0,
                           clocks=dict.fromkeys(fast_ds.units, DeviceClock(500.0, 40.0)),
                           robot_clock=DeviceClock(2000.0, -20.0))  # fmt: skip
        report = await emu.run_async(max_wall_s=40)
        await asyncio.sleep(0.4)
        stop.set()
        return report, await task

    report, (summary, stats, feed) = asyncio.run(asyncio.wait_for(main(), 90))
    assert report.completed and stats.malformed_total == 0
    outcome = feed.outcome()
    assert outcome is not None and not outcome.reached and not outcome.notes
    assert sorted(outcome.statuses) == sorted(fast_ds.units) and outcome.result.method == "online"
    with h5py.File(path, "r") as f:
        assert f.attrs["recording_complete"]
        for unit, status in outcome.statuses.items():
            t_file = f[f"imu/{unit}/t"][...]
            assert 0.5 * t_file.size <= status.samples <= t_file.size
            assert abs(status.t_last - t_file[-1]) < 1.5  # host time of the recording (device time: 500 s off)
    truth = {u: p.link for u, p in fast_ds.truth.items()}
    assert {u: s.link for u, s in outcome.statuses.items()} == truth


# -- the update-cost benchmark ----------------------------------------------------------------------


def test_one_core_schedule_carries_the_backlog():
    from skincal.bench.online import one_core_schedule

    ends, backlog = one_core_schedule(np.array([0.1, 0.2, 0.3, 1.0]), np.array([0.05, 0.3, 0.01, 0.02]))
    np.testing.assert_allclose(ends, [0.15, 0.5, 0.51, 1.02])  # chunk 3 waits for chunk 2; chunk 4 for its data
    assert backlog == pytest.approx(0.3)


def test_online_benchmark_figures_add_up(fast_ds):
    from skincal.bench.online import online_report, run_online_benchmark

    doc = run_online_benchmark(dataset=fast_ds)
    assert doc["units"] == 6 and doc["units_in_result"] == 6 and doc["data_s"] == pytest.approx(77.5, abs=1.0)
    assert doc["imu_samples"] == sum(len(s.t) for s in fast_ds.imu.values())
    assert doc["cpu_s_per_data_s"] == pytest.approx(doc["cpu_s"] / doc["data_s"], rel=1e-2)
    assert doc["latency_s"] >= doc["finish_cpu_s"] + doc["result_cpu_s"] - 1e-3
    assert doc["status_cpu_s"] > 0 and doc["status_every_s"] == 0.5
    assert any("CPU s per s of data" in line for line in online_report(doc))


# -- the viewer's live mode -------------------------------------------------------------------------


def test_live_viewer_draws_the_units_and_their_ellipsoids_converging(fast_ds):
    import dataclasses

    pytest.importorskip("viser")
    from skincal.viz.model import ELLIPSOID_SIGMA
    from skincal.viz.viewer import scene_nodes, start_live_viewer, update_live

    snaps: list[dict] = []
    follow_dataset(fast_ds, speed=None, on_meter=lambda s, t, end: snaps.append(dict(s)))
    first = next(s for s in snaps if all(u.pose is not None for u in s.values()))
    last = snaps[-1]
    v = start_live_viewer(fast_ds.robot)
    try:
        nodes = scene_nodes(v.server)
        update_live(v, first, fast_ds.joints.q[0], "[x](javascript:alert(1)) *su1*")
        early = {n: np.array(nodes[f"/robot/link{s.pose.link}/live_sigma_{n}"].scale) for n, s in first.items()}
        update_live(v, last, fast_ds.joints.q[-1])
        for name, status in last.items():
            link = status.pose.link
            assert f"/robot/link{link}/live_{name}/board" in nodes
            semi = np.array(nodes[f"/robot/link{link}/live_sigma_{name}"].scale)
            np.testing.assert_allclose(semi, np.maximum(ELLIPSOID_SIGMA * status.position_std_m, 2e-4), rtol=1e-6)
            assert np.all(semi <= early[name] + 1e-12) and np.any(semi < early[name])  # converged
        assert v.live == {n: s.pose.link for n, s in last.items()}
        assert v.live_text.content.startswith("\\[x\\]\\(javascript:alert\\(1\\)\\) \\*su1\\*")
        name, status = next(iter(last.items()))
        other = 1 if status.pose.link != 1 else 2
        moved = dataclasses.replace(status, pose=dataclasses.replace(status.pose, link=other))
        update_live(v, {name: moved})  # the unit now believed on another link: drawn there only
        assert f"/robot/link{other}/live_{name}/board" in nodes
        assert f"/robot/link{status.pose.link}/live_{name}" not in nodes
        assert f"/robot/link{status.pose.link}/live_sigma_{name}" not in nodes
    finally:
        v.close()


def test_a_followed_recording_of_a_low_rate_joint_stream_carries_the_report_spacing_term(fast_ds):
    """``calibrate --follow`` of a recording whose joint stream is a robot's ~14 Hz reports: the result says
    what the report spacing does to each pose (``joint_rate``, as ``mle``'s result does, from the part of the
    recording replayed with every second and third report), or why it could not; std only grow. A
    controller's 1 kHz stream is left alone."""
    from skincal.workflows.monitoring import crop

    ds = simulate_dataset("panda", "random", units=1, noise="realistic", protocol="fast", seed=1, joints="report14")
    ds = crop(ds, -math.inf, float(ds.joints.t[0]) + 45.0)  # half the protocol: enough motion, half the replays
    from skincal.calib.online import OnlineCalibrator, replay

    cal = OnlineCalibrator(ds.robot, ds.units, ds.gravity)
    replay(ds, cal)
    base = cal.result()  # the calibrator's own result, without the report-spacing check
    out = follow_dataset(ds, speed=None, stop_at_target=False)
    assert set(out.result.units) == set(base.units) and out.result.units
    for name, unit in out.result.units.items():
        before = base.units[name]
        assert "joint_rate" not in before.extras
        said = any(n.startswith("joint-rate check not applied") for n in unit.notes)
        assert said or "joint_rate" in unit.extras, unit.notes
        if "joint_rate" in unit.extras:
            b = np.asarray(unit.extras["joint_rate"]["bias_position_m"])
            expected = np.sqrt(np.asarray(before.position_std_m) ** 2 + b**2)
            assert np.allclose(unit.position_std_m, expected, rtol=1e-9)
    assert report_spacing_checked(fast_ds, base, math.inf) is base  # 1 kHz: no replay, the result as it is


def test_a_stopped_follow_gives_the_result_of_the_data_so_far_and_says_so():
    """``stop`` set while following (a user's Ctrl-C): the result of the data until then, a note saying so;
    set during the report-spacing replays of a low-rate stream: the result without the term, said in a note
    (no term made of a replay cut short)."""
    import threading

    from skincal.workflows.monitoring import crop

    ds = simulate_dataset("panda", "random", units=1, noise="realistic", protocol="fast", seed=2, joints="report14")
    ds = crop(ds, -math.inf, float(ds.joints.t[0]) + 30.0)
    stop = threading.Event()

    def meter(_statuses, t_data, _t_end):
        if t_data >= 20.0:
            stop.set()

    lines: list[str] = []
    out = follow_dataset(ds, speed=None, stop_at_target=False, on_meter=meter, stop=stop, on_progress=lines.append)
    assert out.stopped and 20.0 <= out.t_data < 21.0 and out.t_end > 29.0
    assert any(n.startswith("stopped by the user after 20.") for n in out.result.notes), out.result.notes
    assert "report-spacing term of the low-rate joint stream not computed: stopped by the user before its replays" in (
        out.result.notes)  # fmt: skip
    assert not any(line.startswith("report spacing") for line in lines)  # stopped: no replays started
    assert out.result.units  # 20 s of a fast protocol calibrate the unit
    for name, unit in out.result.units.items():  # the last status is the written std (no cached split check)
        assert np.allclose(out.statuses[name].position_std_m, unit.position_std_m, rtol=1e-9)
        assert np.allclose(out.statuses[name].rotation_std_deg, unit.rotation_std_deg, rtol=1e-9)

    stop = threading.Event()
    stop.set()  # set before a replay whose one chunk is the last: that is the data's end, not a user's stop
    short = crop(ds, -math.inf, float(ds.joints.t[0]) + 8.0)
    out = follow_dataset(short, speed=None, stop_at_target=False, chunk_s=60.0, stop=stop)
    assert not out.stopped and not any(n.startswith("stopped by the user") for n in out.result.notes)

    stop = threading.Event()

    def progress(line: str) -> None:
        lines.append(line)
        if "replay 2 of 5" in line:
            stop.set()

    lines.clear()
    out = follow_dataset(ds, speed=None, stop_at_target=False, stop=stop, on_progress=progress)
    assert not out.stopped and out.t_data == pytest.approx(out.t_end)  # the data were followed to their end
    assert [line for line in lines if line.startswith("report spacing")][-1].startswith(
        "report spacing of the 13 Hz joint stream: replay 2 of 5"
    ), lines
    assert "report-spacing term of the low-rate joint stream not applied: stopped by the user during its replays" in (
        out.result.notes)  # fmt: skip
    assert all("joint_rate" not in u.extras for u in out.result.units.values())
