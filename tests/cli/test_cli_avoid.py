"""`skincal avoid` (issue 17): any robot, scenario files, --speed/--task/--mode/--margin/--resume, the
plot not clobbered, and one-line errors for bad options and bad scenario files."""

from __future__ import annotations

import json

import pytest

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
