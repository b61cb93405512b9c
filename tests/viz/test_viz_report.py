"""Calibration report: residual model, coverage, self-contained HTML, markdown, CLI, Chromium rendering."""

from __future__ import annotations

import base64
import dataclasses
import os
import re
from pathlib import Path

import numpy as np
import pytest

from skincal.calib import calibrate
from skincal.calib.metrics import evaluate
from skincal.calib.preprocess import JointInterpolator
from skincal.calib.residuals import activity_matrix, unit_residuals
from skincal.cli import main
from skincal.data.hdf5 import write_dataset
from skincal.data.imu_calibration import ImuCalibration
from skincal.data.result import CalibrationResult, UnitResult, write_result
from skincal.kinematics import get_robot
from skincal.protocol import build_trajectory, get_protocol
from skincal.sim.analytic import simulate
from skincal.skin.imu import ImuModel, get_imu_model
from skincal.skin.placement import paper_placement
from skincal.skin.pose import SkinUnitPose
from skincal.viz.content import collect
from skincal.viz.report import render_html, write_report
from skincal.viz.summary import render_markdown

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def report_dataset(imu: ImuModel, seed: int = 3, n_poses: int = 4):
    chain = get_robot("panda")
    rng = np.random.default_rng(seed)
    config = dataclasses.replace(get_protocol("paper-sim"), n_poses=n_poses)
    return simulate(chain, paper_placement(chain), build_trajectory(chain, config, rng), imu, rng)


@pytest.fixture(scope="module")
def biased():
    """Noise-free IMUs with bias (~0.4 m/s^2), scale/misalignment (~1 %) and a 15 ms latency."""
    imu = ImuModel(accel_bias_std=0.4, accel_scale_std=0.01, misalignment_std=0.005, latency_s=0.015)
    return report_dataset(imu)


@pytest.fixture(scope="module")
def calibrated():
    """A small realistic run: datasheet noise, the default calibrator."""
    ds = report_dataset(get_imu_model("datasheet"), seed=5)
    return ds, calibrate(ds, "mle")


@pytest.fixture(scope="module")
def page(calibrated) -> str:
    ds, result = calibrated
    return render_html(collect(result, ds))


def _truth_result(ds, *, sensor: bool, shift_m: float = 0.0) -> CalibrationResult:
    units = {}
    for name, pose in ds.truth.items():
        imu = None
        if sensor:
            s = ds.truth_sensor[name]
            imu = ImuCalibration(
                accel_bias_mps2=np.asarray(s["accel_bias"]),
                accel_scale_misalignment=np.asarray(s["accel_scale"])[:, None] * np.asarray(s["accel_misalignment"]),
                time_offset_s=float(s["time_offset_s"]),
            )
        moved = SkinUnitPose(pose.link, pose.R_link_su, pose.p_link_su + np.array([shift_m, 0.0, 0.0]))
        units[name] = UnitResult(moved, imu=imu)
    return CalibrationResult("truth", "panda", "", 0.0, units)


def test_residuals_vanish_for_the_true_pose_and_sensor_errors(biased):
    """The simulator computed the readings from the exact trajectory (an independent path); the
    report's prediction f = A R^T (u + K p) + b at t - tau must reproduce them."""
    interp = JointInterpolator(biased.joints, use_dataset_qdd=True)
    exact = _truth_result(biased, sensor=True)
    no_sensor = _truth_result(biased, sensor=False)
    shifted = _truth_result(biased, sensor=True, shift_m=0.01)
    for name in ("su1", "su4", "su6"):
        r = unit_residuals(biased, name, exact.units[name], interp)
        assert r.rms < 2e-3, (name, r.rms)
        assert np.allclose(r.predicted + r.residual, r.measured)
        # Leaving out the sensor errors or moving the unit by 1 cm shows up clearly.
        assert unit_residuals(biased, name, no_sensor.units[name], interp).rms > 0.1
        moved = unit_residuals(biased, name, shifted.units[name], interp)
        dynamic = moved.kind == 1
        assert np.sqrt(np.mean(np.sum(moved.residual[dynamic] ** 2, axis=1))) > 20 * r.rms
        # Per-segment RMS agrees with a direct computation on one segment.
        seg = int(r.segment[np.flatnonzero(r.kind == 1)[0]])
        sel = r.segment == seg
        assert r.segment_rms[seg] == pytest.approx(np.sqrt(np.mean(np.sum(r.residual[sel] ** 2, axis=1))))


def test_activity_matrix_marks_the_joints_that_move_each_unit(biased):
    units = list(biased.truth)
    act = activity_matrix(biased, units)
    assert act.shape == (len(units), 7)
    for i, name in enumerate(units):
        link = biased.truth[name].link
        assert np.all(act[i, :link] >= 1.0), (name, act[i])
        assert np.all(act[i, link:] < 1.0), (name, act[i])


def test_html_report_is_self_contained_and_shows_the_numbers(calibrated, page: str):
    ds, result = calibrated
    assert page.startswith("<!DOCTYPE html>")
    assert "<script" not in page.lower()
    assert not re.search(r"""(?:src|href)\s*=\s*["'](?!data:)""", page), "external resource referenced"
    assert "@import" not in page and "url(" not in page
    images = re.findall(r'src="data:image/png;base64,([^"]+)"', page)
    # coverage, bias, errors, one residual figure per unit
    assert len(images) == 3 + len(result.units)
    assert all(base64.b64decode(img)[:8] == PNG_MAGIC for img in images)
    ev = evaluate(result, ds)
    assert f"{ev.mean_position_error_mm:.3f}" in page
    for n, u in result.units.items():
        assert f">{n}<" in page
        assert " ".join(f"{x:+.4f}" for x in u.pose.quaternion_wxyz) in page
        assert f"{1e3 * u.imu.time_offset_s:+.2f}" in page


def test_html_escapes_text_and_flags_a_different_dataset(calibrated):
    ds, result = calibrated
    name = next(iter(result.units))
    unit = result.units[name]
    hostile = dataclasses.replace(unit, warnings=(*unit.warnings, "<script>alert(1)</script>"))
    one = dataclasses.replace(result, units={name: hostile}, dataset_sha256="def")
    page = render_html(collect(one, ds), dataset_sha256="abc")
    assert "<script" not in page.lower() and "&lt;script&gt;alert(1)&lt;/script&gt;" in page
    assert "differs from the one the result was computed from" in page
    same = render_html(collect(one, ds), dataset_sha256="def")
    assert "dataset file matches the result" in same


def test_markdown_summary_tables(calibrated):
    ds, result = calibrated
    content = collect(result, ds)
    md = render_markdown(content)
    ev = evaluate(result, ds)
    lines = md.splitlines()
    assert lines[0] == "# skincal calibration: mle on panda"
    for n, u in result.units.items():
        row = next(line for line in lines if line.startswith(f"| {n} | {u.pose.link} |"))
        assert " ".join(f"{x:+.4f}" for x in u.pose.p_link_su) in row
        err_row = next(line for line in lines if line.startswith(f"| {n} | {u.pose.link}/"))
        assert f"{ev.units[n].position_error_mm:.3f}" in err_row
    # Coverage: paper placement puts unit k on link k + 1 -> joints 1..k+1 move it.
    cov = [line for line in lines if line.startswith("| su")][-len(result.units):]
    for line in cov:
        cells = [c.strip() for c in line.strip("|").split("|")]
        link = result.units[cells[0]].pose.link
        assert cells[1:] == ["x"] * link + ["."] * (7 - link), line


def test_cli_report_html_and_md(tmp_path: Path, calibrated, capsys):
    ds, result = calibrated
    result = dataclasses.replace(result, units={k: result.units[k] for k in list(result.units)[:2]})  # faster
    ds_path, res_path = tmp_path / "ds.h5", tmp_path / "res.json"
    write_dataset(ds, ds_path)
    write_result(result, res_path)
    out = tmp_path / "report.html"
    assert main(["report", str(res_path), "--dataset", str(ds_path), "--out", str(out)]) == 0
    assert out.read_text().startswith("<!DOCTYPE html>")
    assert main(["report", str(res_path), "--dataset", str(ds_path), "--format", "md"]) == 0
    assert "## Errors against truth" in capsys.readouterr().out
    assert main(["report", str(res_path), "--dataset", str(ds_path), "--format", "pdf", "-o", str(out)]) == 2
    assert "--format must be 'html' or 'md'" in capsys.readouterr().err


def _find_chromium_or_skip() -> str:
    from skincal.viz.browser import find_chromium

    exe = find_chromium()
    if exe is None:
        pytest.skip("no Chromium: apt-get install chromium (Debian package) to run the rendering test")
    return exe


def test_report_renders_in_headless_chromium(tmp_path: Path, page: str):
    """The HTML renders to a non-blank PNG with no console errors and no failed loads."""
    from skincal.viz.browser import capture_page

    exe = _find_chromium_or_skip()
    path = tmp_path / "report.html"
    path.write_text(page)
    shot = capture_page(path.as_uri(), width=1280, height=1600, chromium=exe)
    assert shot.errors == [], shot.errors
    import matplotlib.image as mpimg

    png = tmp_path / "report.png"
    png.write_bytes(shot.png)
    img = mpimg.imread(png)[..., :3]
    assert img.shape[:2] == (1600, 1280)
    dark = np.mean(img, axis=2) < 0.5
    assert dark[:120].mean() > 0.002, "no heading text at the top"
    assert dark.mean() > 0.01, "page looks blank"
    save = os.environ.get("SKINCAL_SAVE_SCREENSHOTS")
    if save:
        Path(save).mkdir(parents=True, exist_ok=True)
        (Path(save) / "report.png").write_bytes(shot.png)


def test_report_of_a_result_with_undetermined_std_and_failed_units(tmp_path: Path, calibrated):
    """Never lose a result: a unit without a pose (listed under units with null pose fields) and a
    NaN std component go through the result file into the HTML and markdown reports."""
    from skincal.data.result import read_result

    ds, result = calibrated
    names = list(result.units)
    unit = result.units[names[1]]
    undetermined = dataclasses.replace(unit, position_std_m=np.array([1.6e-4, 6.6e-4, np.nan]),
                                       rotation_std_deg=np.array([0.02, np.nan, np.nan]))
    partial = dataclasses.replace(result, units={names[0]: result.units[names[0]], names[1]: undetermined},
                                  failed_units={names[2]: "diverged <badly>"})
    write_result(partial, tmp_path / "r.json")
    back = read_result(tmp_path / "r.json")
    assert list(back.units) == names[:2] and back.failed_units == {names[2]: "diverged <badly>"}
    page = render_html(collect(back, ds))
    text = re.sub(r'src="data:[^"]*"', "", page)
    assert not re.search(r"\bnan\b", text, re.IGNORECASE)
    assert "<h2>Units not calibrated</h2>" in page and f"<b>{names[2]}</b>: diverged &lt;badly&gt;" in page
    row = next(r for r in text.split("<tr") if f">{names[1]}<" in r)
    assert "0.160 0.660 n/a" in row and "0.020 n/a n/a" in row
    md = render_markdown(collect(back, ds))
    assert "## Not calibrated" in md and f"- {names[2]}: diverged <badly>" in md
    assert not re.search(r"\bnan\b", md, re.IGNORECASE)
    assert "0.160 0.660 n/a" in md


# ---------------------------------------------------------------------------- at scale (issue 19)
def test_worst_units_on_top_and_residual_plots_only_for_them(calibrated):
    """The page opens with the worst units by error against the truth and plots residuals only for
    those; every unit is still in the tables with its full-data residual RMS."""
    ds, result = calibrated
    ev = evaluate(result, ds)
    content = collect(result, ds, shown=2)
    expected = sorted(result.units, key=lambda u: -ev.units[u].position_error_mm)
    assert content.ranking.figure == "position error against the truth [mm]"
    assert list(content.ranking.values) == expected
    assert list(content.residuals) == expected[:2]
    interp = JointInterpolator(ds.joints)
    for name, r in content.residuals.items():
        full = unit_residuals(ds, name, result.units[name], interp)
        assert r.rms == pytest.approx(full.rms, rel=1e-12) and r.n_samples == len(full.t)
        np.testing.assert_array_equal(r.segment_rms, full.segment_rms)
    page = render_html(content, worst=2)
    top = page.split("<h2>Units</h2>")[0]
    assert "<h2>Worst units</h2>" in top and "The 2 worst of 6 unit(s)" in top
    cells = re.findall(r'<td class="l">(\d+)</td><td class="l">([^<]+)</td><td>([^<]+)</td>', top)
    assert [(int(i), n) for i, n, _ in cells] == [(1, expected[0]), (2, expected[1])]
    assert float(cells[0][2]) == pytest.approx(ev.units[expected[0]].position_error_mm, rel=1e-3)
    assert re.findall(r"<h3>([^<]+)</h3>", page) == expected[:2]
    assert "Shown for the 2 worst of 6 units" in page
    assert len(re.findall(r'src="data:image/png', page)) == 3 + 2
    for row in content.rows:  # the unit table keeps every unit's full-data RMS
        assert f"<td>{row.residual_rms_mps2:.4f}</td>" in page
    md = render_markdown(content, worst=3)
    assert "## Worst units" in md.split("## Units")[0]
    assert [line.split("|")[2].strip() for line in md.splitlines() if re.match(r"\| [123] \|", line)] == expected[:3]


def test_without_truth_units_are_ranked_by_residual_rms(calibrated):
    ds, result = calibrated
    real = dataclasses.replace(ds, truth={}, truth_sensor={})
    content = collect(result, real, shown=3)
    assert content.evaluation is None
    assert content.ranking.figure == "accelerometer residual RMS [m/s²]"
    rms = {r.name: r.residual_rms_mps2 for r in content.rows}
    assert list(content.ranking.values) == sorted(rms, key=lambda u: -rms[u])
    assert list(content.residuals) == list(content.ranking.values)[:3]


def test_thinned_residuals_keep_the_envelope():
    """At most max_points samples; every component's minimum and maximum in each bucket kept, so a
    one-sample spike anywhere survives; fewer samples than max_points are kept as they are."""
    from skincal.calib.residuals import envelope_indices

    rng = np.random.default_rng(4)
    for m, max_points in ((100_000, 2000), (8163, 2000), (12_345, 500), (3, 2000), (2000, 2000)):
        v = rng.normal(size=(m, 3))
        spike = int(rng.integers(m))
        v[spike, 1] = 50.0
        if m > 10:
            v[rng.integers(m, size=5), 2] = np.nan
        idx = envelope_indices(v, max_points)
        assert len(idx) <= max_points and np.all(np.diff(idx) > 0) and idx[0] == 0 and idx[-1] == m - 1
        assert spike in idx
        if m <= max_points:
            np.testing.assert_array_equal(idx, np.arange(m))
            continue
        assert len(idx) > 0.5 * max_points  # thinned to near the budget, not to a handful
        n_buckets = (max_points - 2) // 6
        size = -(-m // n_buckets)
        for b in rng.integers(n_buckets, size=20):  # per bucket, both extremes of every component kept
            sel = idx[(idx >= b * size) & (idx < (b + 1) * size)]
            block = v[b * size:(b + 1) * size]
            np.testing.assert_array_equal(np.nanmax(v[sel], axis=0), np.nanmax(block, axis=0))
            np.testing.assert_array_equal(np.nanmin(v[sel], axis=0), np.nanmin(block, axis=0))


def test_progress_reports_every_unit_and_figure(calibrated, tmp_path: Path):
    ds, result = calibrated
    seen: list[str] = []
    write_report(result, ds, tmp_path / "r.html", worst=2, progress=seen.append)
    units = [m for m in seen if m.startswith("residuals and coverage ")]
    assert units == [f"residuals and coverage {i + 1}/6: {n}" for i, n in enumerate(result.units)]
    assert sum(m.startswith("residual plot ") for m in seen) == 2
    assert seen[-1] == f"writing {tmp_path / 'r.html'}"


def test_figures_stay_page_sized_for_many_units():
    """Old code: figure widths/heights grew with the unit count (200 units: a 16000-pixel-wide bias
    plot, a 7600-pixel-tall coverage heatmap with 1400 written values)."""
    from skincal.viz import plots

    rng = np.random.default_rng(2)
    names = [f"unit{i}" for i in range(200)]
    from skincal.calib.metrics import Evaluation, UnitEvaluation

    units = {u: UnitEvaluation(1, 1, i % 7 > 0, float(rng.uniform()), 0.1, 0.001) for i, u in enumerate(names)}
    ev = Evaluation(units, None, None, None, len(units), len(units))
    for fig in (plots.activity_figure(rng.uniform(0.01, 30, (200, 7)), names),
                plots.bias_figure(names, rng.normal(size=(200, 3)), rng.normal(size=(200, 3))),
                plots.error_figure(ev)):
        png = base64.b64decode(plots.png_data_uri(fig).split(",", 1)[1])
        width, height = int.from_bytes(png[16:20], "big"), int.from_bytes(png[20:24], "big")
        assert width <= 1000 and height <= 400, (width, height)
        assert len(png) < 150_000
