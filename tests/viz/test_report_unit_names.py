"""Hostile unit names in the report: text that matplotlib would parse as mathtext (``$\\frac{$`` made
its parser fail with an internal error) is drawn as written, in every figure and through the CLI."""

from __future__ import annotations

import base64
import dataclasses
import html
import re
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from skincal.calib.metrics import Evaluation, UnitEvaluation
from skincal.cli import main
from skincal.data.hdf5 import write_dataset
from skincal.data.imu_calibration import ImuCalibration
from skincal.data.result import CalibrationResult, UnitResult, write_result
from skincal.kinematics import get_robot
from skincal.names import name_problem
from skincal.protocol import build_trajectory, get_protocol
from skincal.sim.analytic import simulate
from skincal.skin.imu import ImuModel
from skincal.skin.placement import paper_placement
from skincal.viz import plots
from skincal.viz.content import collect
from skincal.viz.report import render_html
from skincal.viz.summary import render_markdown

pytestmark = pytest.mark.adversarial

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
HOSTILE = ("$\\frac{$", "$x$", "a$b", "\\$", "$$", "^_{}%&#", "$\\alpha_{1}")


@pytest.fixture(scope="module")
def hostile_dataset():
    """Two simulated units (with a bias, so the bias figure names them too) renamed to mathtext."""
    chain = get_robot("panda")
    rng = np.random.default_rng(7)
    config = dataclasses.replace(get_protocol("paper-sim"), n_poses=3)
    placement = {k: v for k, v in paper_placement(chain).items() if k in ("su3", "su5")}
    ds = simulate(chain, placement, build_trajectory(chain, config, rng), ImuModel(accel_bias_std=0.2), rng)
    rename = dict(zip(("su3", "su5"), ("$\\frac{$", "$x$ <b>"), strict=True))
    return dataclasses.replace(
        ds,
        imu={rename[k]: v for k, v in ds.imu.items()},
        truth={rename[k]: v for k, v in ds.truth.items()},
        truth_sensor={rename[k]: v for k, v in ds.truth_sensor.items()},
    )


def _truth_result(ds) -> CalibrationResult:
    units = {
        name: UnitResult(pose, imu=ImuCalibration(accel_bias_mps2=np.asarray(ds.truth_sensor[name]["accel_bias"])))
        for name, pose in ds.truth.items()
    }
    return CalibrationResult("truth", "panda", "", 0.0, units)


def test_mathtext_names_are_drawn_in_every_figure(hostile_dataset):
    """Old code: ValueError from matplotlib's mathtext parser on the residual title / tick labels."""
    ds = hostile_dataset
    assert all(name_problem(n) is None for n in ds.units)  # legal unit names
    page = render_html(collect(_truth_result(ds), ds))
    images = re.findall(r'src="data:image/png;base64,([^"]+)"', page)
    assert len(images) == 3 + 2  # errors, bias, coverage, one residual figure per unit
    assert all(base64.b64decode(img)[:8] == PNG_MAGIC for img in images)
    for name in ds.units:
        assert f"<h3>{html.escape(name)}</h3>" in page
    assert "$x$ &lt;b&gt;" in page and "$x$ <b>" not in page
    md = render_markdown(collect(_truth_result(ds), ds, shown=0))
    assert "| $\\frac{$ |" in md


@pytest.mark.parametrize("name", HOSTILE)
def test_plain_shows_the_text_as_written(name):
    """The escaped label renders to the same pixels as the literal text drawn with parse_math=False."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    def pixels(**kwargs) -> np.ndarray:
        fig = Figure(figsize=(3, 0.5), dpi=60)
        canvas = FigureCanvasAgg(fig)
        fig.text(0.05, 0.3, **kwargs)
        canvas.draw()
        return np.asarray(canvas.buffer_rgba()).copy()

    escaped = pixels(s=plots.plain(name))
    literal = pixels(s=name, parse_math=False)
    assert (literal[..., :3] < 128).any()  # the text was drawn
    np.testing.assert_array_equal(escaped, literal)


@settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(st.text(alphabet="$\\{}^_ab%#&~", min_size=1, max_size=12), min_size=1, max_size=4, unique=True))
def test_any_dollar_and_backslash_name_draws(names):
    n = len(names)
    rng = np.random.default_rng(0)
    figs = [
        plots.activity_figure(rng.uniform(0.01, 20, (n, 3)), names),
        plots.bias_figure(names, rng.normal(size=(n, 3))),
        plots.error_figure(Evaluation(
            {u: UnitEvaluation(1, 1, True, 1.0, 0.1, 0.001) for u in names}, 1.0, 0.1, 0.001, n, n, ()
        )),
    ]
    for fig in figs:
        uri = plots.png_data_uri(fig, dpi=30)
        assert base64.b64decode(uri.split(",", 1)[1])[:8] == PNG_MAGIC


def test_cli_report_of_a_mathtext_unit(tmp_path: Path, hostile_dataset, capsys):
    """Through real files: the name survives the HDF5 dataset and the result JSON, and the report
    command exits 0 with the page written (old code: an internal matplotlib error)."""
    ds = hostile_dataset
    ds_path, res_path, out = tmp_path / "ds.h5", tmp_path / "res.json", tmp_path / "r.html"
    write_dataset(ds, ds_path)
    write_result(_truth_result(ds), res_path)
    assert main(["report", str(res_path), "--dataset", str(ds_path), "--out", str(out)]) == 0
    page = out.read_text()
    assert "<h3>$\\frac{$</h3>" in page
    assert main(["report", str(res_path), "--dataset", str(ds_path), "--format", "md"]) == 0
    captured = capsys.readouterr()
    assert "$\\frac{$" in captured.out and "Traceback" not in captured.err
