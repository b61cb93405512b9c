"""`skincal avoid` (issue 17): any robot, scenario files, --speed/--task/--mode/--margin/--resume, the
plot not clobbered, and one-line errors for bad options and bad scenario files."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from cli_subprocess import one_line_error, run_cli

from skincal.cli import main

pytest.importorskip("mujoco")

HAND = """
name: poke
human_speed: 2.0
people:
  - name: hand
    shape: sphere
    radius: 0.05
    speed: 0.5
    relative_to: flange
    start: 0.1
    waypoints:
      - {p: [0.8, 0.0, 0.0]}
      - {p: [0.3, 0.0, 0.0]}
"""


def test_scenario_file_on_ur5e_with_iso_margin_resume_and_pick_place(tmp_path, capsys):
    path = tmp_path / "poke.yaml"
    path.write_text(HAND)
    args = ["avoid", "--robot", "ur5e", "--scenario", str(path), "--duration", "1.2", "--speed", "1.0"]
    args += ["--task", "pick-place", "--margin", "iso", "--resume", "--json"]
    assert main(args) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["robot"] == "ur5e" and out["task"] == "pick-place" and out["margin"] == "iso" and out["resume"]
    assert out["scenario"] == "poke" and out["steps"] == 1200 and out["contacts"] == 0
    assert set(out["margin_terms"]) == {"S_h", "S_r", "S_s", "C", "Z_d", "Z_r"}
    assert out["margin_terms"]["C"] == pytest.approx(0.05)
    assert out["task_time_lost_s"] is not None and out["task_time_lost_s"] >= 0
    assert out["margin_m"] > out["margin_terms"]["Z_d"] > 0
    assert path.read_text() == HAND  # input untouched


def test_text_report_and_plot_not_clobbered(tmp_path, capsys):
    plot = tmp_path / "run.png"
    args = ["avoid", "--scenario", "none", "--duration", "0.3", "--plot", str(plot)]
    assert main(args) == 0
    out = capsys.readouterr().out
    assert "min(clearance - S_p)" in out and "margin fixed" in out and "on panda" in out
    assert plot.stat().st_size > 1000 and plot.with_suffix(".svg").exists()
    before = plot.read_bytes()
    assert main(args) == 2
    assert "exists" in capsys.readouterr().err and plot.read_bytes() == before
    assert main([*args, "--force"]) == 0


@pytest.mark.adversarial
@pytest.mark.parametrize(
    ("extra", "words"),
    [
        (["--mode", "dynamic"], "unknown --mode 'dynamic'"),
        (["--margin", "wide"], "unknown --margin 'wide'"),
        (["--task", "dance"], "unknown --task 'dance'"),
        (["--speed", "-1"], "--speed"),
        (["--speed", "nan"], "--speed"),
        (["--robot", "nosuch"], "unknown robot 'nosuch'"),
        (["--scenario", "nowhere"], "unknown scenario 'nowhere'"),
        (["--scenario", "\x1b[31mred"], "unknown scenario '\\x1b[31mred'"),
        (["--duration", "1e12"], "duration"),
        (["--plot", "x.pdf"], "must end in .png or .svg"),
    ],
)
def test_bad_options_one_line_exit_2(extra, words, capsys):
    assert main(["avoid", "--scenario", "none", "--duration", "0.1", *extra]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: ") and "\n" not in err and "\x1b" not in err
    assert words in err, err


@pytest.mark.adversarial
@pytest.mark.parametrize(
    ("text", "field"),
    [
        (HAND.replace("radius: 0.05", "radius: -0.05"), "people[0].radius"),
        (HAND.replace("radius: 0.05", "radius: .nan"), "people[0].radius"),
        (HAND.replace("speed: 0.5", "speed: fast"), "people[0].speed"),
        (HAND.replace("shape: sphere", "shape: sphere\n    colour: red"), "people[0].colour"),
        (
            HAND.replace("    waypoints:\n      - {p: [0.8, 0.0, 0.0]}\n      - {p: [0.3, 0.0, 0.0]}\n", ""),
            "people[0].waypoints",
        ),
        ("people: [" + ", ".join(["{name: a, shape: sphere, radius: 1}"] * 17) + "]", "people"),
    ],
)
def test_bad_scenario_file_one_line_naming_the_field(tmp_path, capsys, text, field):
    path = tmp_path / "bad.yaml"
    path.write_text(text)
    assert main(["avoid", "--scenario", str(path), "--duration", "0.1"]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and f"bad.yaml: {field}" in err, err


# the issue-16/17 review: scenario names and descriptions as written, bad durations and degradations
SCENARIO_WITH_MARKUP = """\
name: "[bold red]EVIL [blink]y"
description: "desc [bold]z[/bold] [link=http:x]q"
duration: 0.05
people:
  - name: "[red]hand"
    shape: sphere
    radius: 0.05
    speed: 0.5
    relative_to: flange
    waypoints:
      - {p: [0.5, 0.0, 0.0]}
      - {p: [0.2, 0.0, 0.0]}
"""


@pytest.mark.adversarial
def test_avoid_prints_scenario_names_and_descriptions_as_written(tmp_path: Path) -> None:
    """A scenario file's name and description are shown as stored, never read as rich markup (the tags
    were swallowed: ``scenario EVIL y (desc z q)``)."""
    (tmp_path / "mk.yaml").write_text(SCENARIO_WITH_MARKUP)
    proc = run_cli(["avoid", "--scenario", "mk.yaml"], tmp_path)
    assert proc.returncode == 0, proc.stderr
    first = proc.stdout.splitlines()[0]
    assert first.startswith("scenario [bold red]EVIL [blink]y (desc [bold]z[/bold] [link=http:x]q) on panda"), first


@pytest.mark.adversarial
@pytest.mark.parametrize("duration", ["1e-9", "0.0005"])
def test_avoid_refuses_a_run_too_short_to_have_a_step(tmp_path: Path, duration: str) -> None:
    """``--duration`` below one control step gave exit 3 (``internal error (ValueError: zero-size array
    ...)``); it is a one-line usage error."""
    line = one_line_error(run_cli(["avoid", "--scenario", "hand", "--duration", duration], tmp_path))
    assert "duration" in line and "0.02" in line


@pytest.mark.adversarial
def test_scenario_file_duration_too_short_is_refused_naming_the_field(tmp_path: Path) -> None:
    (tmp_path / "short.yaml").write_text(SCENARIO_WITH_MARKUP.replace("duration: 0.05", "duration: 0.0001"))
    line = one_line_error(run_cli(["avoid", "--scenario", "short.yaml"], tmp_path))
    assert line.startswith("error: short.yaml: duration: "), line


@pytest.mark.adversarial
def test_avoid_clips_a_long_description(tmp_path: Path) -> None:
    """A scenario description of any length (a 16 MB one was printed whole) is shown clipped to one line."""
    old = 'description: "desc [bold]z[/bold] [link=http:x]q"'
    text = SCENARIO_WITH_MARKUP.replace(old, f"description: {'x' * 5000}")
    (tmp_path / "long.yaml").write_text(text)
    proc = run_cli(["avoid", "--scenario", "long.yaml"], tmp_path)
    assert proc.returncode == 0, proc.stderr
    shown = proc.stdout.replace("\n", "")  # rich wraps the long line in a pipe
    assert "x" * 197 + "..." in shown and "x" * 198 not in shown, shown[:300]


@pytest.mark.adversarial
@pytest.mark.parametrize("degrade", ["1e308,5", "0.05,1e308"])
def test_avoid_refuses_an_absurd_degradation_on_one_line(tmp_path: Path, degrade: str) -> None:
    """``--degrade 1e308,5`` printed a numpy overflow warning (3 lines on stderr) before the error."""
    line = one_line_error(run_cli(["avoid", "--degrade", degrade, "--duration", "0.05"], tmp_path))
    assert "at most" in line



def test_an_unknown_body_region_is_one_line_naming_the_file_and_person(tmp_path, capsys):
    """Issue 28: `body_region` of a person part is checked before the run (exit 2, one line)."""
    path = tmp_path / "bad.yaml"
    path.write_text(HAND.replace("    radius: 0.05\n", "    radius: 0.05\n    body_region: elbowz\n"))
    assert main(["avoid", "--scenario", str(path), "--margin", "iso-pfl"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "bad.yaml: person 'hand': unknown body region 'elbowz'" in err[0]
